"""The framework re-measures what a device says it executed, as it re-checks what a planner returns.

A device reports its executed motion in its :class:`~surgiplan.devices.ExecutionReport`:

* ``executed_path`` with ``executed_space``: the executed configurations in a space that knows the
  device's geometry (the gimbal's whole shaft, the gripper's jaws); default space: the plan's;
* else ``executed_tip_path`` (m): the tip, a sphere of ``tip_radius`` (default: the plan space's tip
  radius in r3, else 0);
* else the tips of its ``timeline`` annotation.

:func:`verify_motion` measures that motion on the scene with the space's own certified clearance between
consecutive samples (exact for a tip sphere), whatever the device reported, and says where it came
closest: the sample, its time when the device gave times (``executed_t`` or the timeline's ``t``), the
arc length along the executed tips, and the obstacle. The execute stage turns a contact, or a clearance
below the device's safety margin (:attr:`~surgiplan.devices.Device.safety_margin`), into the status ``unsafe``;
a device that reports no executed motion gets a warning.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .spaces.r3 import R3Space

#: below the safety margin by less than this (m) is round-off, not a violation
TOLERANCE = 1e-9


@dataclass
class MotionCheck:
    """What the framework measured of an executed motion."""

    #: how the motion was measured (for messages and result.json)
    geometry: str
    samples: int
    #: least clearance (m) between consecutive samples (at the sample when there is one)
    min_clearance_m: float
    #: the segment (or sample) where it is least, its time (s) and arc length (m) along the executed tips
    index: int
    t: float | None
    arc_m: float
    obstacle: str
    tip: list[float] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """The check as the execute stage records it (``metrics.verified`` in ``result.json``): where the motion came
        closest as ``at: {sample, t_s, arc_m, tip_m}``."""
        return {
            "geometry": self.geometry,
            "samples": self.samples,
            "min_clearance_m": self.min_clearance_m,
            "at": {"sample": self.index, "t_s": self.t, "arc_m": self.arc_m, "tip_m": self.tip},
            "obstacle": self.obstacle,
        }


def _finite(array: Any, columns: int | None = None) -> np.ndarray | None:
    try:
        a = np.asarray(array, dtype=float)
    except (TypeError, ValueError):
        return None
    if a.ndim != 2 or len(a) == 0 or (columns is not None and a.shape[1] != columns):
        return None
    return a


def executed_motion(report, trajectory) -> tuple[Any, np.ndarray, np.ndarray | None, str] | None:
    """(space, configurations, times, description) of what the device says it executed; None if nothing."""
    timeline = (report.annotations or {}).get("timeline") if isinstance(report.annotations, dict) else None
    times = report.executed_t if report.executed_t is not None else (timeline or {}).get("t")
    times = np.asarray(times, dtype=float).ravel() if times is not None else None
    space = report.executed_space or trajectory.space
    path = _finite(report.executed_path, space.dimension) if report.executed_path is not None else None
    if path is not None:
        what = f"the {space.kind} body along {len(path):,} executed configurations"
    else:
        tips = _finite(report.executed_tip_path, 3)
        if tips is None and isinstance(timeline, dict):
            tips = _finite(timeline.get("tip"), 3)
        if tips is None:
            return None
        radius = report.tip_radius
        if radius is None:
            radius = float(getattr(trajectory.space, "tip_radius", 0.0) or 0.0) if trajectory.space.kind == "r3" else 0
        space = R3Space(trajectory.space.scene, float(radius))
        path = tips
        scene = trajectory.space.scene
        what = f"the tip, a sphere of {scene.describe_length(float(radius))}, along {len(path):,} executed positions"
    if times is not None and len(times) != len(path):
        times = None
    return space, path, times, what


def verify_motion(report, trajectory) -> MotionCheck | None:
    """Measure the executed motion on the scene (None: the device reported none)."""
    found = executed_motion(report, trajectory)
    if found is None:
        return None
    space, path, times, what = found
    finite = np.all(np.isfinite(path), axis=1)
    path = path[finite]
    times = times[finite] if times is not None else None
    if len(path) == 0:
        return None
    if len(path) >= 2:
        clearance = space.segment_clearance(path[:-1], path[1:])
        index = int(np.argmin(clearance))
        # the sample of that segment nearer the obstacle names it
        ends = space.clearance(path[index : index + 2])
        at = index + int(np.argmin(ends))
    else:
        clearance = space.clearance(path)
        index = at = 0
    tips = space.tip(path)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(tips, axis=0), axis=1))])
    nearest = int(space.nearest_obstacle(path[at : at + 1])[0])
    obstacles = space.scene.obstacles
    return MotionCheck(
        geometry=what,
        samples=len(path),
        min_clearance_m=float(clearance[index]),
        index=int(at),
        t=float(times[at]) if times is not None and np.isfinite(times[at]) else None,
        arc_m=float(arc[at]),
        obstacle=obstacles[nearest].name if 0 <= nearest < len(obstacles) else "",
        tip=tips[at].tolist(),
    )


def unsafe_message(check: MotionCheck, margin: float, scene, claimed: float | None) -> str:
    """Why an executed motion is unsafe: where, how deep, against which margin (in the scene's unit)."""
    where = f"at sample {check.index}" + (f", t = {check.t:.3g} s" if check.t is not None else "")
    where += f", {scene.describe_length(check.arc_m)} along the executed path"
    near = f" obstacle '{check.obstacle}'" if check.obstacle else " an obstacle"
    if check.min_clearance_m <= 0:
        what = f"it enters{near} {scene.describe_length(-check.min_clearance_m)} deep ({where})"
    else:
        what = (
            f"it comes within {scene.describe_length(check.min_clearance_m)} of{near} ({where}), below the device's "
            f"safety margin of {scene.describe_length(margin)}"
        )
    said = ""
    if claimed is not None and claimed > check.min_clearance_m + 1e-6:
        said = f"; the device reported a least clearance of {scene.describe_length(claimed)}"
    return f"the framework measured the executed motion ({check.geometry}): {what}{said}"
