"""Running a validated pipeline: stages in order, then result.json, figures and the glTF scene.

Each stage runs as its kind says (:meth:`surgiplan.kinds.StageKind.run`;
the built-in kinds are in :mod:`surgiplan.stages`). The runner knows no kind:
it gives each stage its context, checks what comes back (a
:class:`~surgiplan.results.StageResult` whose status is one its kind declares,
or one the framework sets), and keeps the record.

The framework checks what plugins return before anything uses it
(:mod:`surgiplan.verify`): a path that is malformed, does not join the
stage's start and goal, leaves the bounds or is not certified clear makes the
stage ``invalid_result`` and nothing downstream runs on it; a status outside
the kind's likewise. A plugin that raises ends its stage with ``error`` (the
message names the plugin and its package) and ends the run.

Outputs are written atomically. A run first locks its output directory
(:mod:`surgiplan.outputlock`: a second run into it is refused), then marks its output directory as in
progress (``.in-progress.json``, updated after every stage with the stages so
far) and removes a previous run's ``result.json``, so a directory never
holds a stale ``result.json`` beside new files. ``result.json`` is written
last, on success and on failure alike (with every stage so far and the run's
``status``); the marker is removed after it.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import __version__
from .config import ExecutorModel
from .errors import SurgiplanError
from .executors import DaskExecutor, Executor, LocalExecutor
from .kinds import RunState, StageKind, StageRun, StageSpec
from .live import LiveFeed
from .outputlock import claim
from .pipeline import Pipeline
from .progress import NullProgress, Progress, StageProgress
from .results import StageContext, StageResult
from .status import RunOutcomeStatus, RunStatus
from .storage import prepare_output_dir, remove_temporaries, to_jsonable, write_json_atomic
from .units import LENGTH_UNITS

log = logging.getLogger(__name__)


#: the marker a run keeps in its output directory while it runs
IN_PROGRESS = ".in-progress.json"


@dataclass
class RunOutcome:
    """What :func:`run_pipeline` did: the output directory, each stage's result in order, the files it wrote there
    (relative names) and the run's status; :attr:`ok` when the run and every stage succeeded."""

    output_dir: Path
    results: list[StageResult]
    files: list[str] = field(default_factory=list)
    status: RunOutcomeStatus = RunOutcomeStatus.SUCCEEDED

    @property
    def ok(self) -> bool:
        return self.status is RunOutcomeStatus.SUCCEEDED and all(r.succeeded for r in self.results)


def begin_run(out: Path, pipeline_file: Path) -> Path:
    """Mark ``out`` as in progress and remove a previous run's ``result.json`` (before anything is written).

    The caller holds ``out``'s lock (:func:`surgiplan.outputlock.claim`): no other run writes there.
    """
    marker = out / IN_PROGRESS
    _write_marker(marker, pipeline_file, [])
    for stale in ("result.json", "report.html"):
        (out / stale).unlink(missing_ok=True)
    left = remove_temporaries(out)  # a killed run's half-written temporary files: never read, now removed
    if left:
        log.info("removed %d temporary files a previous run left in %s", len(left), out)
    return marker


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


# ----------------------------------------------------------------------------- one stage


def run_stage(kind: StageKind, spec: StageSpec, context: StageContext, state: RunState) -> StageResult:
    """Run one stage as its kind says, and check what comes back."""
    run = StageRun(spec, context, state)
    result = kind.run(run)
    if not isinstance(result, StageResult):
        return run.invalid(f"the stage returned a {type(result).__name__}, not a StageResult")
    result.stage, result.name, result.plugin = spec.kind, spec.name, spec.plugin.name if spec.plugin else ""
    if spec.plugin is not None:  # provenance: which distribution, at which version, ran the stage
        result.package, result.version = spec.plugin.package, spec.plugin.version
    allowed = kind.plugin_statuses()
    if result.status not in allowed and result.status not in {s.value for s in RunStatus}:
        article = "an" if kind.name[:1] in "aeiou" else "a"
        choices = ", ".join(sorted(allowed))
        return run.invalid(f"status {result.status!r} is not {article} {kind.name} status ({choices})")
    if not isinstance(result.metrics, dict):
        result.metrics = {}
    return result


# ----------------------------------------------------------------------------- the run


def run_pipeline(pipeline: Pipeline, *, progress: Progress | None = None, live: LiveFeed | None = None) -> RunOutcome:
    """Run every stage and write result.json, figures and scene.glb into the output directory.

    ``result.json`` is written in every case, last: when a stage raises (the
    exception is re-raised after it, so the command line reports it) and when
    the run is interrupted, with every stage so far.
    """
    progress = progress or NullProgress()
    packages = {s.plugin.package: s.plugin.version for s in pipeline.stages if s.plugin is not None}
    executor = make_executor(pipeline.model.executor, packages)  # a dask cluster is checked before writing
    log.info("pipeline '%s': %d stages, executor %s", pipeline.name, len(pipeline.stages), executor.describe())
    lock = None
    try:
        out = prepare_output_dir(pipeline.output_dir)
        lock = claim(out, pipeline.file)  # a second run into the same directory is refused here, naming this one
        marker = begin_run(out, pipeline.file)
    except BaseException:
        executor.close()
        if lock is not None:
            lock.release()
        raise
    try:
        return _run_stages(pipeline, progress, live, executor, out, marker)
    finally:
        lock.release()


def _run_stages(
    pipeline: Pipeline, progress: Progress, live: LiveFeed | None, executor: Executor, out: Path, marker: Path
) -> RunOutcome:
    unit = pipeline.model.length_unit
    unit_scale = LENGTH_UNITS[unit]
    state = RunState(pipeline.name, out, pipeline.record, unit, unit_scale, figures=pipeline.model.output.figures)
    results: list[StageResult] = []
    files: list[str] = []
    status = RunOutcomeStatus.SUCCEEDED
    pending: BaseException | None = None
    kinds = {spec.kind: pipeline.kind(spec) for spec in pipeline.stages}
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
                result = run_stage(kinds[spec.kind], spec, context, state)
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
            state.results[spec.name], state.specs[spec.name] = result, spec
            _write_marker(marker, pipeline.file, results)
            log.info(
                "%s stage '%s' (%s): %s%s",
                spec.kind,
                spec.name,
                result.plugin,
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
        for kind in dict.fromkeys(kinds.values()):  # each kind once, in pipeline order
            files.extend(kind.finish(state))
        if pipeline.model.output.gltf:
            from .outputs.gltf import write_scene_glb  # trimesh: loaded when the scene is written, after the stages

            paths = [(r.name, r.tip_path) for r in results if r.tip_path is not None and len(r.tip_path) >= 2]
            markers = [
                marker
                for name, result in state.results.items()
                for marker in kinds[result.stage].markers(state.specs[name], result)
            ]
            write_scene_glb(out / "scene.glb", pipeline.scene, paths, markers)
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
        "not_run": [{"stage": s.kind, "name": s.name, "plugin": s.plugin.name if s.plugin else ""} for s in not_run],
        "files": sorted(set(files)),
    }
    from .outputs.report import write_run_report

    write_run_report(out, document, pipeline)  # report.html, last but one (lists itself in document["files"])
    write_json_atomic(out / "result.json", document)
    marker.unlink(missing_ok=True)
    outcome = RunOutcome(out, results, [*sorted(set(files)), "result.json"], status)
    if pending is not None:
        pending.outcome = outcome  # the command line still says where the record is
        raise pending
    return outcome


def _stage_failure(spec: StageSpec, status: RunStatus, message: str) -> StageResult:
    return StageResult(spec.kind, spec.name, spec.plugin.name if spec.plugin else "", status.value, message=message)
