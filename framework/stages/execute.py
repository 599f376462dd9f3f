"""The ``execute`` stage: a device runs the path of an earlier plan stage.

::

    - stage: execute
      plugin: cast_gimbal               # a device (hook surgiplan_register_devices, surgiplan.Device)
      path_from: intermediate           # the plan stage whose path it runs (default: the last one)
      settings: {...}

The device goes through its lifecycle (configure, activate, execute, deactivate; shutdown however it ends)
and gets a :class:`~surgiplan.devices.Trajectory`: the planned path, its space, and the plan's clearance
threshold and critical regions. Its :class:`~surgiplan.devices.ExecutionReport` must carry an
:class:`~surgiplan.status.ExecuteStatus`.

The framework then re-measures the motion the device says it executed (:mod:`surgiplan.verify_motion`):
a contact, or a clearance below the device's safety margin, makes the stage ``unsafe`` (the run fails)
with where and how deep; a device that moved but reported no executed motion gets a warning. The
measurement is ``metrics.verified``.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from ..devices import Device, ExecutionReport, Trajectory
from ..hookspecs import PluginSpec, hookspec
from ..kinds import PathStageModel, PathStageSpec, PluginKind, StageKind, StageRun, planned, resolve_path_from
from ..outputs.report.timeline import motion_report
from ..results import StageResult
from ..status import ExecuteStatus, RunStatus
from ..verify_motion import TOLERANCE, unsafe_message, verify_motion

log = logging.getLogger(__name__)


class Hooks:
    """The hook execute stages take their plugins from."""

    @hookspec
    def surgiplan_register_devices(self) -> list[PluginSpec]:
        """Device plugins (subclasses of :class:`surgiplan.Device`). Used by ``stage: execute``."""


DEVICE = PluginKind("device", "surgiplan_register_devices", Device)


class ExecuteKind(StageKind):
    """``stage: execute``: a device plugin runs an earlier plan stage's path through its lifecycle; the framework
    re-measures the executed motion (:mod:`surgiplan.verify_motion`)."""

    name = "execute"
    description = "a device runs the path of an earlier plan stage"
    model = PathStageModel
    spec_type = PathStageSpec
    plugin_kind = DEVICE
    hookspecs = Hooks
    statuses = ExecuteStatus
    succeeded = frozenset({ExecuteStatus.COMPLETED.value})
    timed = True

    def check(self, spec: PathStageSpec, files) -> None:
        resolve_path_from(spec, files, "whose path it executes")

    def run(self, run: StageRun) -> StageResult:
        source = planned(run)
        if isinstance(source, StageResult):
            return source
        source_spec, plan = source
        spec = run.spec
        device = run.call("construction", spec.plugin.cls, spec.settings)
        trajectory = Trajectory(
            np.asarray(plan.path),
            source_spec.space,
            plan.name,
            clearance_threshold=plan.clearance_threshold,
            critical_regions=list(plan.critical_regions),
        )
        started = time.perf_counter()
        try:
            run.call("configure", device.configure, run.context)
            run.call("activate", device.activate)
            report = run.call("execute", device.execute, trajectory)
            run.call("deactivate", device.deactivate)
        finally:
            try:
                device.shutdown()
            except Exception as exc:  # never mask the real error with a shutdown failure
                log.warning("device '%s' failed to shut down cleanly: %s", spec.plugin.name, exc)
        if not isinstance(report, ExecutionReport):
            return run.invalid(f"execute returned a {type(report).__name__}, not an ExecutionReport")
        metrics = dict(report.metrics or {})
        metrics.setdefault("run_s", time.perf_counter() - started)
        if report.faults:
            metrics.setdefault("faults", report.faults)
        status, message, warnings = str(report.status), report.message, []
        if status != ExecuteStatus.REFUSED:  # it may have moved: what it says it did is measured
            check = verify_motion(report, trajectory)
            margin = device.safety_margin
            if check is None:
                warnings.append(
                    f"device '{spec.plugin.name}' reported no executed motion (executed_path, executed_tip_path or a "
                    "timeline): the framework could not check what it did"
                )
            else:
                metrics["verified"] = {**check.to_json(), "safety_margin_m": margin}
                if check.min_clearance_m <= 0 or check.min_clearance_m < margin - TOLERANCE:
                    claimed = metrics.get("executed_min_clearance_m")
                    claimed = float(claimed) if isinstance(claimed, int | float) else None
                    why = unsafe_message(check, margin, spec.scene, claimed)
                    device_said = f" (the device said: {status}{': ' + message if message else ''})"
                    status, message = RunStatus.UNSAFE.value, why + device_said
        return run.result(
            status,
            # the executed tip path is the stage's path (r3, SI), so result.json and scene.glb both show it
            path=report.executed_tip_path,
            metrics=metrics,
            message=message,
            warnings=warnings,
            files=[*report.files, *(f for f in run.recordings(device, warnings) if f not in report.files)],
            tip_path=report.executed_tip_path,
            space="r3",
            annotations={**dict(report.annotations or {}), "path_from": spec.path_from},
        )

    def details(self, result: StageResult, k: float, unit: str) -> list[str]:
        if result.status not in (ExecuteStatus.COMPLETED, ExecuteStatus.STOPPED, RunStatus.UNSAFE):
            return []
        m = result.metrics
        parts = []
        if "tracking_error_max_m" in m:
            rms = m.get("tracking_error_rms_m")
            text = f"tracking max {m['tracking_error_max_m'] * k:.3g} {unit}"
            parts.append(text + (f", rms {rms * k:.3g} {unit}" if rms is not None else ""))
        faults = m.get("faults") or []
        if faults:
            first = faults[0]
            what = first.get("kind") or first.get("cause") or "fault" if isinstance(first, dict) else str(first)
            parts.append(f"{len(faults)} fault{'s' if len(faults) != 1 else ''} ({what})")
        else:
            parts.append("no faults")
        return parts

    def report(self, stage, entry, inputs) -> None:
        motion_report(stage, entry, inputs)
