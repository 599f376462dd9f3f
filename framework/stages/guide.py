"""The ``guide`` stage: follow an instrument live against an earlier plan stage's recommended path.

::

    - stage: guide
      name: attempt
      plugin: synthetic_trainee        # a pose source (hook surgiplan_register_sources): cast_gimbal, ...
      path_from: beginner              # the plan stage whose path is recommended (default: the last one)
      settings: {level: beginner, seed: 3}
      guidance: {deviation_tolerance: 4 mm}        # surgiplan.guidance.GuidanceSettings
      assessment: {idle_speed: 2, weights: {safety: 0.4}}   # surgiplan.guidance.metrics.AssessmentSettings
      trainee: {name: alice, task: block-world, level: beginner}   # record the attempt (optional)
      ghost: {trainee: ann, attempt: best}         # show an expert's recorded attempt beside the trainee

The source runs in a thread of its own and hands samples over a queue: the
stage measures each as it arrives (:class:`~surgiplan.guidance.analysis.Guide`)
against the plan's clearance threshold and critical regions, publishes it on
the live feed, and never waits on a silent source longer than
``guidance.silence_timeout`` (the attempt then ends ``stopped`` with the
reason). Per-sample latency is from the moment the source produced the sample
to the end of its analysis.

Writes ``<stage>.png`` and ``<stage>-samples.csv``; with ``trainee:``, the
attempt (samples and metrics) goes into the trainee record in one transaction,
and when the task has a proficiency benchmark the stage's metrics say where
the trainee stands at its gate. With ``ghost:``, each sample carries the
expert's position at the same progress along their own recommended path
(:mod:`surgiplan.guidance.ghost`), on the live feed and in the report.
"""

from __future__ import annotations

import contextlib
import math
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from ..clearance import ClearanceThreshold, intervals, threshold_value
from ..errors import StageError, SurgiplanError, choices_hint
from ..guidance.analysis import GuidanceSettings, Guide
from ..guidance.assessment import record_attempt
from ..guidance.ghost import GhostKeys, load_ghost
from ..guidance.metrics import AssessmentSettings
from ..guidance.record import RecordError, TraineeRecord
from ..guidance.source import GuideContext, PoseSample, PoseSource, SourceStopped
from ..hookspecs import PluginSpec, hookspec
from ..kinds import (
    FileContext,
    PathStageModel,
    PathStageSpec,
    PluginKind,
    StageKind,
    StageRun,
    planned,
    resolve_path_from,
)
from ..models import StrictModel
from ..outputs.report.timeline import motion_report
from ..results import StageResult
from ..scheduling import SlackCollector, helpers_scheduled, paced_section, precise_timer_slack, set_realtime_priority
from ..status import GuideStatus
from ..validation import validate_model


class Hooks:
    """The hook guide stages take their plugins from."""

    @hookspec
    def surgiplan_register_sources(self) -> list[PluginSpec]:
        """Pose sources (subclasses of :class:`surgiplan.PoseSource`): the instrument followed by ``stage: guide``."""


SOURCE = PluginKind("source", "surgiplan_register_sources", PoseSource)


class TraineeKeys(StrictModel):
    """Whose attempt a guide stage records, at which task (``trainee: {name, task}``)."""

    name: str = Field(min_length=1)
    task: str = Field(min_length=1)
    #: the trainee's level (the group a lab puts them in: expert, intermediate, beginner, ...), kept in the record
    level: str | None = Field(default=None, min_length=1)


class GuideStageModel(PathStageModel):
    """The keys of a guide stage."""

    #: the analysis (surgiplan.guidance.GuidanceSettings, validated once the file's unit is known)
    guidance: dict[str, Any] | None = None
    #: the skill metrics and score (surgiplan.guidance.metrics.AssessmentSettings, in the file's unit)
    assessment: dict[str, Any] | None = None
    trainee: TraineeKeys | None = None
    ghost: GhostKeys | None = None


@dataclass
class GuideSpec(PathStageSpec):
    guidance: GuidanceSettings | None = None
    assessment: AssessmentSettings | None = None
    #: the assessment's port, resolved (m)
    port: np.ndarray | None = None
    trainee: TraineeKeys | None = None
    ghost: GhostKeys | None = None


_END = object()


def _close_quietly(source) -> None:
    """Close a pose source; never mask the attempt's outcome with a close failure."""
    try:
        source.close()
    except Exception:
        pass


class _Reader:
    """Runs the source's iterator in a thread; samples (stamped on arrival) and its end go through a queue."""

    def __init__(self, iterator, priority: int | None = None, maxsize: int = 10_000) -> None:
        self.queue: queue.Queue = queue.Queue(maxsize=maxsize)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(iterator, priority), name="guide-source", daemon=True)
        self.thread.start()

    def _run(self, iterator, priority: int | None) -> None:
        # this thread's scheduling as the stage's (allowed: the stage's thread asked first) and a 1 us timer slack,
        # so that a paced source wakes on time
        set_realtime_priority(priority)
        precise_timer_slack()
        try:
            for sample in iterator:
                if self.stop.is_set():
                    return
                self.queue.put((time.perf_counter(), sample))
            self.queue.put((time.perf_counter(), _END))
        except BaseException as exc:  # handed to the stage, which names the plugin
            self.queue.put((time.perf_counter(), exc))


def _check_sample(sample: Any, index: int, previous_t: float, space) -> str:
    """Why sample ``index`` of a source cannot be used ('' if it can): not a PoseSample, time not finite or going
    back, a pose that is not finite numbers, or a tip outside the scene's bounds."""
    if not isinstance(sample, PoseSample):
        return f"sample {index}: it yielded a {type(sample).__name__}, not a PoseSample"
    if not (isinstance(sample.t, int | float) and math.isfinite(sample.t)):
        return f"sample {index}: sample time {sample.t!r} is not a finite number"
    if sample.t < previous_t:
        return f"sample {index}: sample time {sample.t:.6g} s is before the previous sample's {previous_t:.6g} s"
    if sample.q is None and sample.tip is None:
        return f"sample {index}: it has neither q nor tip"
    value, size = (sample.q, space.dimension) if sample.q is not None else (sample.tip, 3)
    array = np.asarray(value, dtype=float)
    what = "q" if sample.q is not None else "tip"
    if array.shape != (size,) or not np.all(np.isfinite(array)):
        return f"sample {index}: its {what} {array.tolist()} is not {size} finite numbers"
    scene = space.scene
    tip = space.tip(array[None])[0] if sample.q is not None else array
    if not scene.in_bounds(tip)[0]:
        return (
            f"sample {index}: its tip {scene.describe_point(tip)} is outside the scene bounds "
            f"{scene.describe_point(scene.bounds_min)} to {scene.describe_point(scene.bounds_max)}"
        )
    return ""


def _decimated(points: np.ndarray, most: int = 2000) -> list[list[float]]:
    step = max(1, math.ceil(len(points) / most))
    return np.concatenate([points[:-1:step], points[-1:]]).tolist()


class _InvalidSample(SurgiplanError):
    """A sample the stage refuses (the stage becomes ``invalid_result``)."""


class GuideKind(StageKind):
    """``stage: guide``: a pose-source plugin's samples followed live against an earlier plan stage's recommended
    path (:class:`~surgiplan.guidance.Guide`); with ``trainee:``, the attempt is scored and kept in the trainee
    record."""

    name = "guide"
    description = "an instrument followed live against an earlier plan stage's recommended path"
    model = GuideStageModel
    spec_type = GuideSpec
    plugin_kind = SOURCE
    hookspecs = Hooks
    statuses = GuideStatus
    succeeded = frozenset({GuideStatus.COMPLETED.value})
    timed = True

    def resolve(self, spec: GuideSpec, files: FileContext) -> None:
        where = ("pipeline", spec.index, "guidance")
        raw = spec.keys.guidance or {}
        spec.guidance = validate_model(
            GuidanceSettings, raw, file=files.file, lines=files.lines, prefix=where, context=files.validation
        )
        if "threshold" in spec.guidance.model_fields_set:
            files.warn(
                "guidance.threshold is deprecated: a guide stage judges the attempt against its plan stage's "
                "clearance_threshold; set it there (this value is still used, for one release)",
                *where,
                "threshold",
            )
        spec.assessment = validate_model(
            AssessmentSettings,
            spec.keys.assessment or {},
            file=files.file,
            lines=files.lines,
            prefix=("pipeline", spec.index, "assessment"),
            context=files.validation,
        )
        spec.trainee = spec.keys.trainee
        spec.ghost = spec.keys.ghost
        if spec.ghost is not None and spec.ghost.task is None and spec.trainee is None:
            raise files.error(
                "ghost needs a task: give ghost.task, or a trainee: block", "pipeline", spec.index, "ghost"
            )

    def check(self, spec: GuideSpec, files: FileContext) -> None:
        resolve_path_from(spec, files, "whose path it recommends")
        plan = next((s for s in files.earlier if s.name == spec.path_from), None)
        check_plan = getattr(spec.plugin.cls, "check_plan", None)
        refused = check_plan(spec.settings, plan) if plan is not None and check_plan is not None else None
        if refused is not None:
            message, keys = refused
            raise files.error(message, "pipeline", spec.index, "settings", *keys)
        port = spec.assessment.port
        if isinstance(port, str):
            if files.scene is None:
                return
            if port not in files.scene.points:
                raise files.error(
                    f"no point named '{port}' in the scene; {choices_hint(port, list(files.scene.points))}",
                    *("pipeline", spec.index, "assessment", "port"),
                )
            spec.port = np.asarray(files.scene.points[port], float)
        elif port is not None:
            spec.port = np.asarray(port, float)
        if spec.ghost is not None:
            self._check_ghost(spec, files)

    @staticmethod
    def _check_ghost(spec: GuideSpec, files: FileContext) -> None:
        """The ghost's attempt is in the record now, or an earlier guide stage of the pipeline records one (it is
        read when the stage runs)."""
        from ..guidance.ghost import choose_attempt
        from ..validation import RECORD_KEY

        task = spec.ghost.task or spec.trainee.task
        for earlier in files.earlier:
            keys = getattr(earlier, "trainee", None)
            if earlier.index < spec.index and keys is not None and (keys.name, keys.task) == (spec.ghost.trainee, task):
                if spec.ghost.attempt in ("best", "last", "first"):
                    return
        path = Path(files.validation.get(RECORD_KEY) or "out/trainees.sqlite")
        where = ("pipeline", spec.index, "ghost")
        if not path.is_file():
            raise files.error(f"no trainee record at {path} to take the ghost from (see record:)", *where)
        try:
            with TraineeRecord(path) as record:
                choose_attempt(record, spec.ghost, task)
        except RecordError as exc:
            raise files.error(exc.message, *where) from None

    def run(self, run: StageRun) -> StageResult:
        from ..guidance.report import attempt_figure, write_samples_csv  # matplotlib: loaded when it runs

        source = planned(run, minimum=2)
        if isinstance(source, StageResult):
            return source
        source_spec, source_result = source
        spec, context = run.spec, run.context
        space = source_spec.space
        path = np.asarray(source_result.path, float)
        regions = list(source_result.critical_regions)
        critical = intervals(regions)
        settings = spec.guidance
        guide = Guide(
            space,
            path,
            spec.scene,
            threshold_value(source_result.clearance_threshold),
            critical,
            settings,
            unit=context.length_unit,
            assessment=spec.assessment,
            port=spec.port,
        )
        ghost = None
        if spec.ghost is not None:
            try:
                with TraineeRecord(run.state.record) as record:
                    ghost = load_ghost(record, spec.ghost, spec.ghost.task or spec.trainee.task)
            except RecordError as exc:
                raise StageError(f"ghost: {exc.message}", location=f"{spec.location}.ghost") from None
        gcontext = GuideContext(
            context,
            path,
            guide.tips,
            space,
            spec.scene,
            guide.threshold,
            critical,
            settings.silence_timeout,
            critical_regions=regions,
            trainee=spec.trainee.name if spec.trainee is not None else None,
            task=spec.trainee.task if spec.trainee is not None else None,
            record=Path(run.state.record) if spec.trainee is not None else None,
        )
        live = context.live
        live.publish(
            "stage",
            {
                "name": spec.name,
                "kind": "guide",
                "plugin": spec.plugin.name,
                "path_from": spec.path_from,
                "recommended": guide.tips.tolist(),
                "threshold": guide.threshold,
                "critical": critical,
                "deviation_tolerance": settings.deviation_tolerance,
                **({"ghost": ghost.describe(), "ghost_path": _decimated(ghost.tips)} if ghost else {}),
            },
        )
        source = run.call("construction", spec.plugin.cls, spec.settings)
        reader = None
        started = time.perf_counter()
        # this thread takes each sample from the source's as it arrives: both run under SCHED_FIFO at
        # guidance.realtime_priority, or ask a short slice at ordinary priority, so that a waking one preempts what
        # has run longer (a browser rendering the live view). Python's switch interval stays: the live feed's sender
        # releases the GIL on its send within tens of microseconds, and a short interval would make this thread
        # hand the GIL over in the middle of a sample's analysis (measured: SCHED_FIFO with 0.2 ms, the viewer
        # delayed a sample by up to 1.9 ms; with Python's 5 ms, 0.25 ms). The heap as it stands is frozen out of the
        # collector's sight, so that its passes scan only what the attempt makes, and the automatic passes are off:
        # _follow runs them itself once a sample is done and none is waiting (SlackCollector). An automatic pass
        # falls inside a sample's analysis: 0.25 ms a generation-0 pass of an attempt, 1-2 ms beside a live page
        # (two of the five samples a viewer delayed in one benchmark run)
        with contextlib.ExitStack() as attempt:
            attempt.callback(_close_quietly, source)  # last: after the scheduling is given back
            try:
                attempt.enter_context(
                    paced_section(settings.realtime_priority, pause_collector=True, switch_interval=None)
                )
                # the live feed's sender too (one below): preempted while holding the GIL, it held this thread up
                attempt.enter_context(helpers_scheduled(settings.realtime_priority, live.threads()))
            except OSError as exc:
                raise StageError(
                    f"guide stage '{spec.name}': guidance.realtime_priority {settings.realtime_priority} "
                    f"(SCHED_FIFO) is not allowed here ({exc.strerror or exc}): run with CAP_SYS_NICE (or as root), "
                    "or remove the key",
                    location=spec.location,
                ) from None
            try:
                run.call("open", source.open, gcontext)
                iterator = run.call("samples", source.samples)
                reader = _Reader(iter(iterator), settings.realtime_priority)
                with context.progress.task("following the instrument (% of the path)", total=100) as task:
                    status, message = _follow(reader, spec, settings, space, guide, ghost, live, task)
            except _InvalidSample as exc:
                return run.invalid(str(exc))
            finally:
                if reader is not None:
                    reader.stop.set()
        events = guide.finish()
        if not guide.measurements:
            return run.result(
                GuideStatus.STOPPED.value, message=message or f"source '{spec.plugin.name}' sent no sample"
            )
        if status is not GuideStatus.STOPPED:
            status = GuideStatus.COMPLETED if guide.reached_goal else GuideStatus.INCOMPLETE
            if status is GuideStatus.INCOMPLETE:
                message = (
                    f"the attempt ended {guide.k * (guide.length - guide.measurements[-1].progress):.3g} {guide.unit} "
                    "before the end of the recommended path"
                )
        metrics: dict[str, Any] = guide.metrics()
        metrics["run_s"] = time.perf_counter() - started
        out = Path(context.output_dir)
        files = []
        csv_name, png_name = f"{spec.name}-samples.csv", f"{spec.name}.png"
        write_samples_csv(out / csv_name, guide)
        files.append(csv_name)
        attempt_figure(
            out / png_name,
            guide,
            f"{spec.name} ({spec.plugin.name}): {status.value}, score {metrics['score']:.0f}, "
            f"deviation rms {metrics['deviation_rms_m'] * guide.k:.3g} {guide.unit}, "
            f"min clearance {metrics['min_clearance_m'] * guide.k:.3g} {guide.unit}, {len(events)} event(s)",
        )
        files.append(png_name)
        warnings: list[str] = []
        files += run.recordings(source, warnings)  # e.g. the bus trace of a device the source ran
        assistance = getattr(source, "assistance", None)
        if assistance is not None:
            metrics["assistance"] = assistance
        if spec.trainee is not None:
            metrics["record"] = record_attempt(
                run.state.record,
                spec.trainee,
                guide,
                metrics,
                events,
                status=status.value,
                pipeline=run.state.pipeline_name,
                stage=spec.name,
                source=spec.plugin.name,
                output_dir=str(out),
                assistance=assistance,
            )
            gate = metrics["record"].pop("gate")
            if gate is not None:
                metrics["gate"] = gate
        live.publish("status", {"status": status.value, "message": message})
        tips = np.array([m.tip for m in guide.measurements])
        annotations = {
            "timeline": guide.timeline(settings.timeline_rate),
            "events": [e.to_json() for e in events],
            "path_from": spec.path_from,
            "recommended_tips": guide.tips.tolist(),
        }
        if ghost is not None:
            annotations["ghost"] = {**ghost.describe(), "tips": _decimated(ghost.tips)}
            metrics["ghost"] = ghost.describe()
        return run.result(
            status.value,
            path=tips,
            metrics=metrics,
            message=message,
            files=files,
            tip_path=tips,
            space="r3",
            clearance_threshold=self._judged_against(spec, source_result, guide.threshold),
            critical_regions=regions,
            annotations=annotations,
            warnings=warnings,
        )

    @staticmethod
    def _judged_against(spec: GuideSpec, plan: StageResult, threshold: float) -> ClearanceThreshold | None:
        """The threshold the attempt was judged against: the plan's (or a deprecated guidance.threshold)."""
        if threshold <= 0:
            return None
        if threshold == threshold_value(plan.clearance_threshold):
            return plan.clearance_threshold
        return ClearanceThreshold(threshold, f"{spec.location}.guidance.threshold")

    def details(self, result: StageResult, k: float, unit: str) -> list[str]:
        m = result.metrics
        if "score" not in m:
            return []
        events = m.get("events") or {}
        listed = ", ".join(f"{n} {kind.replace('_', ' ')}" for kind, n in events.items() if n)
        lines = [
            f"score {m['score']:.0f}",
            f"deviation rms {m['deviation_rms_m'] * k:.3g} {unit}, max {m['deviation_max_m'] * k:.3g} {unit}",
            f"events: {listed or 'none'}",
            f"{m.get('duration_s', 0):.3g} s",
        ]
        if isinstance(m.get("gate"), dict):
            lines.append(f"gate {m['gate'].get('status', '')}")
        return lines

    def report(self, stage, entry, inputs) -> None:
        motion_report(stage, entry, inputs)


def _follow(reader: _Reader, spec, settings, space, guide: Guide, ghost, live, task) -> tuple[GuideStatus, str]:
    """Measure each sample the source sends as it arrives, until its end, a stop or a silence (the attempt's status
    and message then); publishes each to the live view, then runs the collector's pass if one is due (the
    automatic passes are off). Raises StageError for a plugin that failed, and _InvalidSample for a sample that is
    not one."""
    status, message = GuideStatus.INCOMPLETE, ""
    previous_t = -math.inf
    received = 0
    collect = SlackCollector()
    while True:
        try:
            arrived, item = reader.queue.get(timeout=settings.silence_timeout)
        except queue.Empty:
            status = GuideStatus.STOPPED
            message = (
                f"source '{spec.plugin.name}' sent no pose for {settings.silence_timeout:g} s "
                f"(guidance.silence_timeout); the attempt is stopped"
            )
            break
        if item is _END:
            break
        if isinstance(item, SourceStopped):
            status, message = GuideStatus.STOPPED, f"source '{spec.plugin.name}' stopped: {item}"
            break
        if isinstance(item, BaseException):
            raise StageError(
                f"plugin '{spec.plugin.name}' ({spec.plugin.package} {spec.plugin.version}) failed in "
                f"samples of guide stage '{spec.name}': {type(item).__name__}: {item}",
                location=spec.location,
            ) from item
        problem = _check_sample(item, received, previous_t, space)
        if problem:
            raise _InvalidSample(problem)
        received += 1
        previous_t = float(item.t)
        m, changes = guide.measure(item)
        if ghost is not None:
            m.ghost = ghost.at(m.progress / max(guide.length, 1e-12))
        m.delay = time.perf_counter() - arrived
        if live.active:
            live.publish(
                "tip",
                {
                    "t": m.t,
                    "tip": m.tip.tolist(),
                    "deviation": m.deviation,
                    "clearance": m.clearance,
                    "progress": m.progress,
                    "critical": m.critical,
                    "closest": m.closest.tolist(),
                    **({"ghost": m.ghost.tolist()} if m.ghost is not None else {}),
                    # when the sample arrived, on the wall clock (the viewer measures cue latency)
                    "wall": time.time() - m.delay,
                },
            )
            for what, event in changes:
                live.publish(
                    "event",
                    {"t": m.t, "change": what, **event.to_json(), "message": guide.describe(event)},
                )
        task.update(100.0 * min(m.progress / max(guide.length, 1e-12), 1.0))
        collect(idle=reader.queue.empty())  # the sample is done: the collector's pass, if one is due, now
    return status, message
