"""Why a CiA 402 device refuses a trajectory before any motion, and the report it then gives.

A device refuses, with the reason, a path whose joint waypoints leave the
joint limits or whose tip leaves the plan's workspace bounds
(:func:`check_path`), a timed motion whose certified clearance is below the
safety margin (:func:`certification_refusal`), and whatever its own mapping
of the path to joints cannot do (:class:`Refusal`, raised by
:meth:`.device.Cia402Device.joint_path`). Nothing moves: the execute stage
ends ``refused`` (:func:`refused`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from surgiplan.devices import ExecutionReport
from surgiplan.errors import SurgiplanError
from surgiplan.plugins.devices.kinematics.model import KinematicModel
from surgiplan.status import ExecuteStatus

from .certify import Certificate
from .timing import JointTrajectory


class Refusal(SurgiplanError):
    """A trajectory the device will not start; the message says why.

    :meth:`.device.Cia402Device.run` turns it into a refused execution (:func:`refused`); one that escaped
    would be the user's to fix (a plan the device cannot execute): exit status 2.
    """


def refused(reason: str, metrics: dict[str, Any] | None = None) -> ExecutionReport:
    """The report of a refused execution: nothing moved."""
    # the execute stage's metric names stay the same whatever happened: nothing tracked, no fault
    out = {**(metrics or {}), "cycles": 0, "refused": True, "faults": []}
    out |= {"tracking_error_max_m": None, "tracking_error_rms_m": None}
    return ExecutionReport(ExecuteStatus.REFUSED, out, message=f"refused before any motion: {reason}")


def check_path(model: KinematicModel, q: np.ndarray, scene) -> None:
    """Refuse joint waypoints outside the joint limits, or a tip leaving the workspace bounds of ``scene`` (the
    plan's scene: its bounds are the workspace planned in)."""
    outside = ~model.within_limits(q, 1e-9)
    if np.any(outside):
        i = int(np.argmax(outside))
        j = int(np.argmax((q[i] < model.lower - 1e-9) | (q[i] > model.upper + 1e-9)))
        raise Refusal(
            f"waypoint {i} needs joint '{model.joint_names[j]}' at {q[i, j]:.4g}, outside its limits "
            f"[{model.lower[j]:.4g}, {model.upper[j]:.4g}]"
        )
    tips = model.tip_positions(q)
    inside = scene.in_bounds(tips)
    if not np.all(inside):
        i = int(np.argmin(inside))
        raise Refusal(
            f"waypoint {i} puts the tip at {np.round(tips[i], 5).tolist()} m, outside the workspace bounds "
            f"{scene.bounds_min.tolist()} to {scene.bounds_max.tolist()} m"
        )


def certification_refusal(
    certificates: list[Certificate],
    planned: JointTrajectory,
    model: KinematicModel,
    margin: float,
    metrics: dict[str, Any],
) -> str | None:
    """The reason to refuse the timed motion ``planned`` if its certified clearance (every body, between the
    samples too: ``certificates``) comes closer than ``margin``, else None. Adds the certified clearances to
    ``metrics``."""
    for certificate in certificates:
        metrics[f"certified_{certificate.body}_min_clearance_m"] = certificate.lowest
    worst = min(certificates, key=lambda c: c.lowest)
    metrics["certified_min_clearance_m"] = worst.lowest
    metrics["safety_margin_m"] = margin
    if worst.lowest >= margin:
        return None
    k, fraction = worst.segment, worst.fraction
    q = planned.q[k] + fraction * (planned.q[min(k + 1, len(planned.q) - 1)] - planned.q[k])
    tip = model.tip_positions(q[None])[0]
    what = "a collision" if worst.lowest < 0 else f"closer than the safety margin {margin * 1000:g} mm"
    return (
        f"the timed motion's certified {worst.body} clearance is {worst.lowest * 1000:.2f} mm "
        f"({worst.lowest:.6f} m), {what}, at t = {(k + fraction) * planned.period:.3f} s of "
        f"{planned.duration:.3f} s with the tip at {np.round(tip * 1000, 1).tolist()} mm (certified along the "
        "whole motion the drives would interpolate, between the samples too)"
    )
