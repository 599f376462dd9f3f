"""Running a validated pipeline: stages in order, then result.json, figures and the glTF scene.

Each plan stage builds (or loads its stored artifact), queries, and gets the
common metrics measured by the framework itself, independently of the
plugin: ``length_m`` (tip path), ``min_clearance_m`` (exact in R3, a
certified lower bound elsewhere), ``length_below_threshold_m``, ``build_s``
and ``query_s``. Execute stages take the path of an earlier plan stage.

Outputs are written atomically; ``result.json`` is written last, so its
presence means the run finished.
"""

from __future__ import annotations

import logging
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .artifacts import artifact_key, load_artifact, save_artifact
from .config import ExecutorModel
from .devices import Trajectory
from .errors import OutputError, StageError, SurgiplanError
from .executors import DaskExecutor, Executor, LocalExecutor
from .outputs.figures import PathView, overview_figure, plan_figure
from .outputs.gltf import write_scene_glb
from .pipeline import Pipeline, StageSpec
from .planning import PlanningProblem, PlanResult
from .progress import NullProgress, Progress
from .results import StageContext, StageResult
from .storage import write_json_atomic
from .units import LENGTH_UNITS

log = logging.getLogger(__name__)


@dataclass
class RunOutcome:
    output_dir: Path
    results: list[StageResult]
    files: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return all(r.succeeded for r in self.results)


def prepare_output_dir(path: Path) -> Path:
    """Create the output directory and prove it is writable, before any work starts."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-test-"):
            pass
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise OutputError(f"cannot write to output directory {path}: {reason}", location="output.dir") from None
    return path


def make_executor(model: ExecutorModel) -> Executor:
    if model.kind == "dask":
        return DaskExecutor(model.address)
    return LocalExecutor(model.workers)


def _plugin_call(spec: StageSpec, what: str, fn, *args, **kwargs):
    """Call into a plugin; a crash becomes a :class:`StageError` naming the stage and plugin."""
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

    metrics = dict(result.metrics)
    metrics.setdefault("build_s", build_s)
    metrics.setdefault("query_s", query_s)
    if spec.artifact is not None:
        metrics["artifact"] = origin
    # the stage's own clearance_threshold (the user's choice) wins over the planner's
    threshold = spec.clearance_threshold if spec.clearance_threshold is not None else result.clearance_threshold
    stage = StageResult(
        "plan",
        spec.name,
        spec.plugin.name,
        result.status.value,
        path=np.asarray(result.path),
        message=result.message,
        space=spec.space.kind,
        clearance_threshold=threshold,
        annotations=dict(result.annotations),
        files=list(result.files),
    )
    view = None
    if result.solved and len(result.path) >= 1:
        common, tips, clearance = path_metrics(spec.space, result.path, threshold)
        for k, v in common.items():
            metrics.setdefault(k, v)
        stage.tip_path = spec.space.tip(np.atleast_2d(result.path))
        highlights = [
            (r["start_m"], r["end_m"])
            for r in result.annotations.get("critical_regions", [])
            if "start_m" in r and "end_m" in r
        ]
        view = PathView(
            spec.name,
            tips,
            clearance,
            threshold,
            spec.space.tip(spec.start[None])[0],
            spec.space.tip(spec.goal[None])[0] if spec.goal is not None else None,
            highlights=highlights,
        )
    stage.metrics = metrics
    return stage, view


# ----------------------------------------------------------------------------- other stages


def run_simulate_stage(spec: StageSpec, context: StageContext) -> StageResult:
    model = _plugin_call(spec, "construction", spec.plugin.cls, spec.settings)
    started = time.perf_counter()
    result = _plugin_call(spec, "run_stage", model.run_stage, context)
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
            "skipped",
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
    metrics = dict(report.metrics)
    metrics.setdefault("run_s", time.perf_counter() - started)
    if report.faults:
        metrics.setdefault("faults", report.faults)
    return StageResult(
        "execute",
        spec.name,
        spec.plugin.name,
        report.status,
        # the executed tip path is the stage's path (r3, SI), so result.json and scene.glb both show it
        path=report.executed_tip_path,
        metrics=metrics,
        message=report.message,
        files=list(report.files),
        tip_path=report.executed_tip_path,
        space="r3",
    )


# ----------------------------------------------------------------------------- the run


def run_pipeline(pipeline: Pipeline, *, progress: Progress | None = None) -> RunOutcome:
    """Run every stage and write result.json, figures and scene.glb into the output directory."""
    progress = progress or NullProgress()
    out = prepare_output_dir(pipeline.output_dir)
    unit = pipeline.model.length_unit
    unit_scale = LENGTH_UNITS[unit]
    results: list[StageResult] = []
    files: list[str] = []
    views: list[tuple[StageSpec, PathView]] = []
    plans: dict[str, tuple[StageSpec, StageResult]] = {}
    executor = make_executor(pipeline.model.executor)
    try:
        for spec in pipeline.stages:
            context = StageContext(
                spec.name,
                spec.scene,
                out,
                pipeline.base_dir,
                executor,
                progress,
                {r.name: r for r in results},
                out / ".work" / spec.name,
            )
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
            else:
                result = run_execute_stage(spec, context, plans)
            results.append(result)
    finally:
        executor.close()
        progress.close()

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
    for r in results:
        files.extend(r.files)

    document = {
        "name": pipeline.name,
        "surgiplan_version": __version__,
        "pipeline_file": str(pipeline.file),
        "units": "SI (m, rad, s, kg, Pa)",
        "executor": pipeline.model.executor.kind,
        "stages": [r.to_json() for r in results],
        "files": sorted(set(files)),
    }
    write_json_atomic(out / "result.json", document)
    return RunOutcome(out, results, [*sorted(set(files)), "result.json"])


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
