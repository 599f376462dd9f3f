"""Running a validated pipeline: stages in order, then result.json, figures and the glTF scene.

Each plan stage builds (or loads its stored artifact), queries, and gets the
common metrics measured by the framework itself, independently of the
plugin: ``length_m`` (tip path), ``min_clearance_m`` (exact in R3, a
certified lower bound elsewhere), ``length_below_threshold_m``, ``build_s``
and ``query_s``. Execute stages take the path of an earlier plan stage.

The framework checks what plugins return before anything uses it
(:mod:`surgiplan.verify`): a path that is malformed, does not join the
stage's start and goal, leaves the bounds or is not certified clear makes the
stage ``invalid_result`` and nothing downstream runs on it; a status outside
:mod:`surgiplan.status` likewise. A plugin that raises ends its stage with
``error`` (the message names the plugin and its package) and ends the run.

Outputs are written atomically. A run first marks its output directory as in
progress (``.in-progress.json``, updated after every stage with the stages so
far) and removes a previous run's ``result.json``, so a directory never
holds a stale ``result.json`` beside new files. ``result.json`` is written
last, on success and on failure alike (with every stage so far and the run's
``status``); the marker is removed after it.
"""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .artifacts import artifact_key, load_artifact, save_artifact
from .config import ExecutorModel
from .devices import ExecutionReport, Trajectory
from .errors import OutputError, StageError, SurgiplanError
from .executors import DaskExecutor, Executor, LocalExecutor
from .guidance.stage import run_guide_stage
from .live import LiveFeed
from .outputs.figures import PathView, overview_figure, plan_figure
from .outputs.gltf import write_scene_glb
from .outputs.report import write_run_report
from .pipeline import Pipeline, StageSpec
from .planning import PlanningProblem, PlanResult
from .progress import NullProgress, Progress, StageProgress
from .results import StageContext, StageResult
from .status import PLUGIN_STATUSES, RunOutcomeStatus, RunStatus
from .storage import prepare_output_dir, to_jsonable, write_json_atomic
from .units import LENGTH_UNITS
from .verify import InvalidResult, verify_plan_result

log = logging.getLogger(__name__)


#: the marker a run keeps in its output directory while it runs
IN_PROGRESS = ".in-progress.json"


@dataclass
class RunOutcome:
    output_dir: Path
    results: list[StageResult]
    files: list[str] = field(default_factory=list)
    status: RunOutcomeStatus = RunOutcomeStatus.SUCCEEDED

    @property
    def ok(self) -> bool:
        return self.status is RunOutcomeStatus.SUCCEEDED and all(r.succeeded for r in self.results)


def begin_run(out: Path, pipeline_file: Path) -> Path:
    """Mark ``out`` as in progress and remove a previous run's ``result.json`` (before anything is written).

    Refuses a directory another live run is writing to.
    """
    marker = out / IN_PROGRESS
    if marker.exists():
        try:
            other = json.loads(marker.read_text())
            pid = int(other.get("pid", -1))
        except (OSError, ValueError, TypeError):
            other, pid = {}, -1
        if pid > 0 and pid != os.getpid() and _alive(pid):
            raise OutputError(
                f"another surgiplan run (pid {pid}, {other.get('pipeline_file', '?')}, started "
                f"{other.get('started', '?')}) is writing to {out}; wait for it or choose another --out",
                location="output.dir",
            )
    _write_marker(marker, pipeline_file, [])
    for stale in ("result.json", "report.html"):
        (out / stale).unlink(missing_ok=True)
    return marker


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _write_marker(marker: Path, pipeline_file: Path, results: list[StageResult]) -> None:
    write_json_atomic(
        marker,
        {
            "pid": os.getpid(),
            "pipeline_file": str(pipeline_file),
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "note": "a surgiplan run is writing here, or was killed: this directory is not a finished run",
            "stages_so_far": [to_jsonable({"name": r.name, "stage": r.stage, "status": r.status}) for r in results],
        },
    )


def make_executor(model: ExecutorModel, packages: dict[str, str] | None = None) -> Executor:
    """The pipeline's executor; a dask cluster is checked for the plugin ``packages`` ({name: version})."""
    if model.kind == "dask":
        return DaskExecutor(model.address, required=packages)
    return LocalExecutor(model.workers)


def _plugin_call(spec: StageSpec, what: str, fn, *args, **kwargs):
    """Call into a plugin; a crash becomes a :class:`StageError` naming the stage, the plugin and its package."""
    try:
        return fn(*args, **kwargs)
    except SurgiplanError as exc:
        if exc.location is None:  # say which stage it came from (e.g. a device's bus error)
            exc.location = f"{spec.location} ({spec.kind} stage '{spec.name}')"
        raise
    except Exception as exc:
        raise StageError(
            f"plugin '{spec.plugin.name}' ({spec.plugin.package} {spec.plugin.version}) failed in {what} of "
            f"{spec.kind} stage '{spec.name}': {type(exc).__name__}: {exc}",
            location=spec.location,
        ) from exc


# ----------------------------------------------------------------------------- plan stages


def path_metrics(space, path: np.ndarray, threshold: float | None) -> tuple[dict[str, Any], np.ndarray, np.ndarray]:
    """Common metrics of a path, measured on the scene; also the dense tips and clearances for figures."""
    path = np.atleast_2d(np.asarray(path, dtype=float))
    resolution = float(np.min(space.scene.extent)) / 1000.0
    dense = space.densify(path, resolution)
    tips = space.tip(dense)
    clearance = space.clearance(dense)
    if len(path) >= 2:
        min_clearance = float(np.min(space.segment_clearance(path[:-1], path[1:])))
    else:
        min_clearance = float(clearance.min())
    steps = np.linalg.norm(np.diff(tips, axis=0), axis=1)
    metrics: dict[str, Any] = {
        "length_m": float(steps.sum()),
        "min_clearance_m": min_clearance,
        "waypoints": len(path),
    }
    if threshold is not None:
        low = np.minimum(clearance[:-1], clearance[1:]) < threshold
        metrics["clearance_threshold_m"] = float(threshold)
        metrics["length_below_threshold_m"] = float(steps[low].sum())
    return metrics, tips, clearance


def run_plan_stage(spec: StageSpec, context: StageContext) -> tuple[StageResult, PathView | None]:
    planner = _plugin_call(spec, "construction", spec.plugin.cls, spec.settings)
    problem = PlanningProblem(
        spec.scene,
        spec.space,
        context.executor,
        context.progress,
        context.workdir,
        start=spec.start,
        goal=spec.goal,
        output_dir=context.output_dir,
    )
    started = time.perf_counter()
    artifact = None
    origin = "built"
    if spec.artifact is not None:
        key = artifact_key(spec.plugin, spec.settings, problem)
        artifact = _plugin_call(
            spec,
            "load_artifact",
            load_artifact,
            spec.artifact,
            planner,
            key,
            spec.plugin,
            problem,
            location=f"{spec.location}.artifact",
        )
        origin = "loaded" if artifact is not None else "built"
    if artifact is None:
        artifact = _plugin_call(spec, "build", planner.build, problem)
        if spec.artifact is not None:
            _plugin_call(spec, "save_artifact", save_artifact, spec.artifact, planner, artifact, key, spec.plugin)
    build_s = time.perf_counter() - started

    started = time.perf_counter()
    result: PlanResult = _plugin_call(spec, "query", planner.query, artifact, spec.start, spec.goal)
    query_s = time.perf_counter() - started

    unit, unit_scale = context_units(context)
    try:
        path = verify_plan_result(result, spec.space, spec.start, spec.goal, unit=unit, unit_scale=unit_scale)
    except InvalidResult as exc:
        return invalid_result(spec, f"{exc}"), None

    metrics = dict(result.metrics) if isinstance(result.metrics, dict) else {}
    metrics.setdefault("build_s", build_s)
    metrics.setdefault("query_s", query_s)
    if spec.artifact is not None:
        metrics["artifact"] = origin
    if path is not None and result.final_goal is not None:
        metrics["final_goal"] = np.asarray(result.final_goal, dtype=float).tolist()
    # the stage's own clearance_threshold (the user's choice) wins over the planner's
    threshold = spec.clearance_threshold if spec.clearance_threshold is not None else result.clearance_threshold
    stage = StageResult(
        "plan",
        spec.name,
        spec.plugin.name,
        str(result.status),
        path=path if path is not None else np.empty((0, spec.space.dimension)),
        message=str(result.message or ""),
        space=spec.space.kind,
        clearance_threshold=threshold,
        annotations=dict(result.annotations or {}),
        files=list(result.files or []),
    )
    view = None
    if path is not None:
        # measured by the framework on the scene, whatever the plugin reported
        common, tips, clearance = path_metrics(spec.space, path, threshold)
        metrics.update(common)
        stage.tip_path = spec.space.tip(path)
        highlights = [
            (r["start_m"], r["end_m"])
            for r in stage.annotations.get("critical_regions", [])
            if isinstance(r, dict) and "start_m" in r and "end_m" in r
        ]
        view = PathView(
            spec.name,
            tips,
            clearance,
            threshold,
            spec.space.tip(spec.start[None])[0],
            spec.space.tip(spec.goal[None])[0] if spec.goal is not None else None,
            highlights=highlights,
            detours=[
                np.asarray(d["tips_m"], dtype=float).reshape(-1, 3)
                for d in stage.annotations.get("detours", [])
                if isinstance(d, dict) and "tips_m" in d
            ],
        )
    stage.metrics = metrics
    return stage, view


def context_units(context: StageContext) -> tuple[str, float]:
    unit = getattr(context, "length_unit", "m") or "m"
    return unit, LENGTH_UNITS.get(unit, 1.0)


def invalid_result(spec: StageSpec, problem: str) -> StageResult:
    """The stage a refused plugin answer becomes: ``invalid_result``, naming the plugin and its package."""
    return StageResult(
        spec.kind,
        spec.name,
        spec.plugin.name,
        RunStatus.INVALID_RESULT.value,
        message=f"{spec.kind} plugin '{spec.plugin.name}' ({spec.plugin.package} {spec.plugin.version}) returned "
        f"an invalid result: {problem}",
    )


# ----------------------------------------------------------------------------- other stages


def run_simulate_stage(spec: StageSpec, context: StageContext) -> StageResult:
    model = _plugin_call(spec, "construction", spec.plugin.cls, spec.settings)
    started = time.perf_counter()
    result = _plugin_call(spec, "run_stage", model.run_stage, context)
    if not isinstance(result, StageResult):
        return invalid_result(spec, f"run_stage returned a {type(result).__name__}, not a StageResult")
    if result.status not in PLUGIN_STATUSES["simulate"]:
        choices = ", ".join(sorted(PLUGIN_STATUSES["simulate"]))
        return invalid_result(spec, f"status {result.status!r} is not a simulate status ({choices})")
    result.stage, result.name, result.plugin = "simulate", spec.name, spec.plugin.name
    if not isinstance(result.metrics, dict):
        result.metrics = {}
    result.metrics.setdefault("run_s", time.perf_counter() - started)
    return result


def run_execute_stage(
    spec: StageSpec, context: StageContext, plans: dict[str, tuple[StageSpec, StageResult]]
) -> StageResult:
    source_spec, source = plans[spec.path_from]
    if not source.succeeded or source.path is None or len(source.path) == 0:
        return StageResult(
            "execute",
            spec.name,
            spec.plugin.name,
            RunStatus.SKIPPED.value,
            message=f"plan stage '{source.name}' ended '{source.status}' without a path",
        )
    device = _plugin_call(spec, "construction", spec.plugin.cls, spec.settings)
    started = time.perf_counter()
    try:
        _plugin_call(spec, "configure", device.configure, context)
        _plugin_call(spec, "activate", device.activate)
        report = _plugin_call(
            spec, "execute", device.execute, Trajectory(np.asarray(source.path), source_spec.space, source.name)
        )
        _plugin_call(spec, "deactivate", device.deactivate)
    finally:
        try:
            device.shutdown()
        except Exception as exc:  # never mask the real error with a shutdown failure
            log.warning("device '%s' failed to shut down cleanly: %s", spec.plugin.name, exc)
    if not isinstance(report, ExecutionReport):
        return invalid_result(spec, f"execute returned a {type(report).__name__}, not an ExecutionReport")
    if report.status not in PLUGIN_STATUSES["execute"]:
        choices = ", ".join(sorted(PLUGIN_STATUSES["execute"]))
        return invalid_result(spec, f"status {report.status!r} is not an execute status ({choices})")
    metrics = dict(report.metrics or {})
    metrics.setdefault("run_s", time.perf_counter() - started)
    if report.faults:
        metrics.setdefault("faults", report.faults)
    return StageResult(
        "execute",
        spec.name,
        spec.plugin.name,
        str(report.status),
        # the executed tip path is the stage's path (r3, SI), so result.json and scene.glb both show it
        path=report.executed_tip_path,
        metrics=metrics,
        message=report.message,
        files=list(report.files),
        tip_path=report.executed_tip_path,
        space="r3",
        annotations=dict(report.annotations or {}),
    )


# ----------------------------------------------------------------------------- the run


def run_pipeline(pipeline: Pipeline, *, progress: Progress | None = None, live: LiveFeed | None = None) -> RunOutcome:
    """Run every stage and write result.json, figures and scene.glb into the output directory.

    ``result.json`` is written in every case, last: when a stage raises (the
    exception is re-raised after it, so the command line reports it) and when
    the run is interrupted, with every stage so far.
    """
    progress = progress or NullProgress()
    unit = pipeline.model.length_unit
    unit_scale = LENGTH_UNITS[unit]
    packages = {s.plugin.package: s.plugin.version for s in pipeline.stages}
    executor = make_executor(pipeline.model.executor, packages)  # a dask cluster is checked before writing
    log.info("pipeline '%s': %d stages, executor %s", pipeline.name, len(pipeline.stages), executor.describe())
    try:
        out = prepare_output_dir(pipeline.output_dir)
        marker = begin_run(out, pipeline.file)
    except BaseException:
        executor.close()
        raise
    results: list[StageResult] = []
    files: list[str] = []
    views: list[tuple[StageSpec, PathView]] = []
    plans: dict[str, tuple[StageSpec, StageResult]] = {}
    status = RunOutcomeStatus.SUCCEEDED
    pending: BaseException | None = None
    try:
        for spec in pipeline.stages:
            context = StageContext(
                spec.name,
                spec.scene,
                out,
                pipeline.base_dir,
                executor,
                StageProgress(progress, spec.name),
                {r.name: r for r in results},
                out / ".work" / spec.name,
                length_unit=unit,
                live=live or LiveFeed(),  # what the stage publishes, for `surgiplan view --live`
            )
            try:
                if spec.kind == "plan":
                    result, view = run_plan_stage(spec, context)
                    plans[spec.name] = (spec, result)
                    if view is not None:
                        view.title = _title(spec, result, unit, unit_scale)
                        views.append((spec, view))
                        if pipeline.model.output.figures:
                            name = f"{spec.name}.png"
                            plan_figure(out / name, spec.scene, view, unit=unit, unit_scale=unit_scale)
                            result.files.append(name)
                elif spec.kind == "simulate":
                    result = run_simulate_stage(spec, context)
                elif spec.kind == "guide":
                    result = run_guide_stage(
                        spec,
                        context,
                        plans,
                        record_path=pipeline.record,
                        pipeline_name=pipeline.name,
                        plugin_call=_plugin_call,
                    )
                else:
                    result = run_execute_stage(spec, context, plans)
            except KeyboardInterrupt as exc:
                results.append(_stage_failure(spec, RunStatus.INTERRUPTED, "interrupted"))
                status, pending = RunOutcomeStatus.INTERRUPTED, exc
                break
            except SurgiplanError as exc:
                results.append(_stage_failure(spec, RunStatus.ERROR, exc.message if exc.location else str(exc)))
                status, pending = RunOutcomeStatus.ERROR, exc
                break
            except Exception as exc:  # a bug in surgiplan itself; the record is still written
                results.append(_stage_failure(spec, RunStatus.ERROR, f"internal error: {type(exc).__name__}: {exc}"))
                status, pending = RunOutcomeStatus.ERROR, exc
                break
            results.append(result)
            _write_marker(marker, pipeline.file, results)
            log.info(
                "%s stage '%s' (%s): %s%s",
                spec.kind,
                spec.name,
                spec.plugin.name,
                result.status,
                f": {result.message}" if result.message else "",
            )
    finally:
        executor.close()
        progress.close()
    if status is RunOutcomeStatus.SUCCEEDED and not all(r.succeeded for r in results):
        status = RunOutcomeStatus.FAILED
    ran = {r.name for r in results}
    not_run = [s for s in pipeline.stages if s.name not in ran]

    try:
        if pipeline.model.output.figures and len(views) >= 2:
            overview_figure(
                out / "overview.png",
                [(s.scene, v) for s, v in views],
                unit=unit,
                unit_scale=unit_scale,
                title=pipeline.name,
            )
            files.append("overview.png")
        if pipeline.model.output.gltf:
            paths = [(r.name, r.tip_path) for r in results if r.tip_path is not None and len(r.tip_path) >= 2]
            endpoints = [
                (f"{s.name}:{k}", s.space.tip(getattr(s, k)[None])[0])
                for s, _ in views
                for k in ("start", "goal")
                if getattr(s, k) is not None
            ]
            write_scene_glb(out / "scene.glb", pipeline.scene, paths, endpoints)
            files.append("scene.glb")
    except Exception as exc:  # figures must not cost the run its record
        log.warning("could not write the run's overview figures: %s", exc)
        if pending is None:
            pending = exc
            status = RunOutcomeStatus.ERROR
    for r in results:
        files.extend(r.files)

    document = {
        "name": pipeline.name,
        "status": status.value,
        "surgiplan_version": __version__,
        "pipeline_file": str(pipeline.file),
        "units": "SI (m, rad, s, kg, Pa)",
        "length_unit": unit,
        "executor": pipeline.model.executor.kind,
        "stages": [r.to_json() for r in results],
        "not_run": [{"stage": s.kind, "name": s.name, "plugin": s.plugin.name} for s in not_run],
        "files": sorted(set(files)),
    }
    write_run_report(out, document, pipeline)  # report.html, last but one (lists itself in document["files"])
    write_json_atomic(out / "result.json", document)
    marker.unlink(missing_ok=True)
    outcome = RunOutcome(out, results, [*sorted(set(files)), "result.json"], status)
    if pending is not None:
        pending.outcome = outcome  # the command line still says where the record is
        raise pending
    return outcome


def _stage_failure(spec: StageSpec, status: RunStatus, message: str) -> StageResult:
    return StageResult(spec.kind, spec.name, spec.plugin.name, status.value, message=message)


def _title(spec: StageSpec, result: StageResult, unit: str, unit_scale: float) -> str:
    m = result.metrics
    k = 1.0 / unit_scale
    parts = [
        f"{spec.name} ({spec.plugin.name})",
        f"length {m['length_m'] * k:.4g} {unit}",
        f"min clearance {m['min_clearance_m'] * k:.3g} {unit}",
    ]
    if result.clearance_threshold is not None:
        parts.append(f"threshold {result.clearance_threshold * k:.3g} {unit}")
        parts.append(f"below threshold {m.get('length_below_threshold_m', 0.0) * k:.3g} {unit}")
    return ", ".join(parts)


def debug_enabled() -> bool:
    return os.environ.get("SURGIPLAN_DEBUG", "") not in ("", "0")
