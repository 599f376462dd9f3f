"""The ``plan`` stage: a planner builds (or loads its stored artifact), then answers the stage's query.

::

    - stage: plan
      name: intermediate
      plugin: safe_prm                  # a planner (hook surgiplan_register_planners, surgiplan.Planner)
      settings: {proficiency: intermediate}
      space: {kind: r3}                 # or cast_gimbal, se3 (surgiplan_register_spaces)
      start: entry                      # a point name, coordinates, a gimbal configuration or a pose
      goal: target
      clearance_threshold: 4 mm         # the clearance the path keeps (surgiplan.clearance)
      artifact: out/roadmap.npz         # a planner that stores its build reuses it

The framework checks the answer (:mod:`surgiplan.verify`), then measures, whatever the plugin reported:
``length_m`` (tip path), ``min_clearance_m`` (exact in R3, a certified lower bound elsewhere),
``length_below_threshold_m``, ``build_s`` (the build, or the load of a stored one; storing it is
``store_s``), ``query_s`` (the query, as the planner times it if it does; ``answer_s`` the whole call), and
the path's critical regions (:func:`surgiplan.clearance.critical_regions`). A planner that keeps the
threshold everywhere and returns a path below it gives ``invalid_result``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import model_validator

from ..artifacts import artifact_key, load_artifact, save_artifact
from ..clearance import ClearancePolicy, ClearanceThreshold, critical_regions, intervals, threshold_value
from ..config import BoundsModel, Endpoint, GimbalConfigurationModel
from ..errors import ConfigError, ConfigErrors, PlanningInputError, SurgiplanError, choices_hint
from ..hookspecs import PluginSpec, hookspec
from ..kinds import FileContext, PluginKind, StageKind, StageModel, StageRun, StageSpec
from ..models import QuaternionPoseModel
from ..planning import Planner, PlanningProblem, PlanResult
from ..resources import ResourceEstimate
from ..results import StageResult
from ..spaces.base import Space
from ..status import PlanStatus
from ..units import Length
from ..validation import validate_model
from ..verify import InvalidResult, verify_plan_result
from ..yamlio import format_path, line_of

log = logging.getLogger(__name__)

#: below the threshold by less than this (m) is round-off, not a violation, for planners that keep it everywhere
THRESHOLD_TOLERANCE = 1e-9


class Hooks:
    """The hook plan stages take their plugins from."""

    @hookspec
    def surgiplan_register_planners(self) -> list[PluginSpec]:
        """Planner plugins (subclasses of :class:`surgiplan.Planner`) this package provides.

        Used by ``stage: plan``. Return a list of :class:`PluginSpec`.
        """


PLANNER = PluginKind("planner", "surgiplan_register_planners", Planner)


class PlanStageModel(StageModel):
    """The keys of a plan stage."""

    space: dict[str, Any] | None = None
    start: Endpoint | None = None
    goal: Endpoint | None = None
    artifact: str | None = None
    bounds: BoundsModel | None = None
    clearance_threshold: Length | None = None

    @model_validator(mode="after")
    def _has_start(self):
        if self.start is None:  # goal: checked with the planner (Planner.requires_goal)
            raise ValueError("a plan stage needs start")
        return self


@dataclass
class PlanSpec(StageSpec):
    """A validated plan stage."""

    space: Space | None = None
    start: np.ndarray | None = None
    goal: np.ndarray | None = None
    start_label: str = ""
    goal_label: str = ""
    artifact: Path | None = None
    clearance_threshold: ClearanceThreshold | None = None


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


class PlanKind(StageKind):
    """``stage: plan``: a planner plugin builds (or loads its stored build) and answers the stage's query; the
    framework checks the path (:mod:`surgiplan.verify`) and measures its metrics and critical regions."""

    name = "plan"
    description = "a planner builds (or loads its stored build), then answers the stage's query"
    model = PlanStageModel
    spec_type = PlanSpec
    plugin_kind = PLANNER
    hookspecs = Hooks
    statuses = PlanStatus
    succeeded = frozenset({PlanStatus.SOLVED.value})

    # ------------------------------------------------------------------ validation
    def resolve(self, spec: PlanSpec, files: FileContext) -> None:
        keys: PlanStageModel = spec.keys
        where = ("pipeline", spec.index)
        cls = spec.plugin.cls
        if keys.goal is None and getattr(cls, "requires_goal", True):
            raise files.error("a plan stage needs goal", *where)
        if keys.bounds is not None and spec.scene is not None:
            spec.scene = spec.scene.with_bounds(keys.bounds.min, keys.bounds.max)
        raw_space = dict(keys.space or {"kind": "r3"})
        space_kind = raw_space.pop("kind", "r3")
        try:
            space_info = files.registry.get("space", str(space_kind))
        except SurgiplanError as exc:
            raise ConfigError(
                exc.message,
                file=files.file,
                location=format_path((*where, "space", "kind")),
                line=line_of(files.lines, (*where, "space")),
            ) from None
        space_settings = validate_model(
            space_info.settings_model,
            raw_space,
            file=files.file,
            lines=files.lines,
            prefix=(*where, "space"),
            context=files.validation,
        )
        if spec.scene is not None:  # else the scene has errors of its own, already reported
            spec.space = space_info.cls.from_settings(space_settings, spec.scene)
        spec.clearance_threshold = self._threshold(spec, files)
        if keys.artifact is not None:
            if cls.save_artifact is Planner.save_artifact:
                raise files.error(
                    f"planner '{keys.plugin}' cannot store its artifact; remove 'artifact'", *where, "artifact"
                )
            spec.artifact = Path(keys.artifact)

    def _threshold(self, spec: PlanSpec, files: FileContext) -> ClearanceThreshold | None:
        """The stage's clearance threshold: its ``clearance_threshold``, or what the planner's settings ask for;
        two explicit values that differ are refused, naming both."""
        keys: PlanStageModel = spec.keys
        where = ("pipeline", spec.index)
        cls = spec.plugin.cls
        setting = cls.threshold_setting
        if setting and setting in spec.settings.model_fields_set:
            files.warn(
                f"settings.{setting} is deprecated: write clearance_threshold on the stage, the one name of the "
                f"clearance a plan keeps (settings.{setting} still works, for one release)",
                *where,
                "settings",
                setting,
            )
        asked, explicit = cls.clearance_threshold_from(spec.settings)
        if keys.clearance_threshold is None:
            threshold = asked
        else:
            threshold = ClearanceThreshold(keys.clearance_threshold, f"{spec.location}.clearance_threshold")
            if asked is not None and explicit and abs(asked.value - threshold.value) > 1e-12:
                scene = spec.scene
                show = scene.describe_length if scene is not None else (lambda v: f"{v:g} m")
                raise files.error(
                    f"clearance_threshold {show(threshold.value)} differs from the {show(asked.value)} that "
                    f"{asked.source} asks for; give one of them",
                    *where,
                    "clearance_threshold",
                )
        if threshold is not None and threshold.value > 0 and cls.clearance_policy is None:
            raise files.error(
                f"planner '{keys.plugin}' does not plan with a clearance threshold; remove clearance_threshold",
                *where,
                "clearance_threshold",
            )
        return threshold

    def check(self, spec: PlanSpec, files: FileContext) -> None:
        errors: list[SurgiplanError] = []
        for key in ("start", "goal"):
            try:
                self._endpoint(spec, key, files)
            except SurgiplanError as exc:
                errors.append(exc)
        if len(errors) == 1:
            raise errors[0]
        if errors:
            raise ConfigErrors(
                [
                    e
                    if isinstance(e, ConfigError)
                    else ConfigError(e.message, file=e.file, location=e.location, line=e.line)
                    for e in errors
                ]
            )

    @staticmethod
    def _endpoint(spec: PlanSpec, key: str, files: FileContext) -> None:
        space, scene = spec.space, spec.scene
        where = ("pipeline", spec.index, key)

        def refuse(message: str) -> PlanningInputError:
            return files.error(message, *where, error=PlanningInputError)

        value = getattr(spec.keys, key)
        if value is None:  # a goal the planner does not need (Planner.requires_goal)
            return
        if isinstance(value, str):
            if value not in scene.points:
                raise refuse(f"no point named '{value}'; {choices_hint(value, scene.points)}")
            label = f"point '{value}' {scene.describe_point(scene.points[value])}"
            value = scene.points[value]
        elif isinstance(value, GimbalConfigurationModel):
            label = "configuration"
            value = np.array([value.yaw, value.pitch, value.insertion, value.roll])
        elif isinstance(value, QuaternionPoseModel):
            label = f"pose at {scene.describe_point(value.xyz)}"
            value = value.model_dump()
        else:
            label = scene.describe_point(value)
            value = np.asarray(value, dtype=float)
        try:
            q = space.configuration(value, what=key)
        except PlanningInputError as exc:
            raise refuse(exc.message.removeprefix(f"{key}: ")) from None
        q = np.asarray(q, dtype=float)
        if not space.in_workspace(q[None, :])[0]:
            lo, hi = scene.describe_point(scene.bounds_min), scene.describe_point(scene.bounds_max)
            raise refuse(f"{key} {label} is outside the scene bounds {lo} to {hi}")
        if not space.within_limits(q[None, :])[0]:
            raise refuse(f"{key} {label} is outside the limits of the {space.kind} space")
        clearance = float(space.clearance(q[None, :])[0])
        if not clearance > 0:
            nearest = int(space.nearest_obstacle(q[None, :])[0])
            what = f"obstacle '{scene.obstacles[nearest].name}'" if nearest >= 0 else "an obstacle"
            body = "lies inside" if space.kind == "r3" else "puts the instrument inside"
            raise refuse(f"{key} {label} {body} {what} (clearance {scene.describe_length(clearance)})")
        setattr(spec, key, q)
        setattr(spec, f"{key}_label", label)

    def problem(self, spec: PlanSpec, **run: Any) -> PlanningProblem:
        return PlanningProblem(
            spec.scene,
            spec.space,
            start=spec.start,
            goal=spec.goal,
            clearance_threshold=spec.clearance_threshold,
            **run,
        )

    def estimate_resources(self, spec: PlanSpec) -> list[ResourceEstimate]:
        return list(spec.plugin.cls.estimate_resources(spec.settings, self.problem(spec)) or [])

    # ------------------------------------------------------------------ running
    def run(self, run: StageRun) -> StageResult:
        spec: PlanSpec = run.spec
        context = run.context
        planner = run.call("construction", spec.plugin.cls, spec.settings)
        problem = self.problem(
            spec,
            executor=context.executor,
            progress=context.progress,
            workdir=context.workdir,
            output_dir=context.output_dir,
        )
        run.call("bind", planner.bind, problem)
        # the scene's compiled distance kernels load here, as the planner's did at its construction: not timed
        spec.scene.prepare()
        artifact = None
        origin = "built"
        store_s = 0.0
        # build_s: the build (or the load of a stored one) alone; storing it is store_s; neither counts anything
        # done once per process (compiled kernels load when their modules are imported)
        started = time.perf_counter()
        if spec.artifact is not None:
            key = artifact_key(spec.plugin, spec.settings, problem)
            location = f"{spec.location}.artifact"
            artifact = run.call(
                "load_artifact", load_artifact, spec.artifact, planner, key, spec.plugin, problem, location=location
            )
            origin = "loaded" if artifact is not None else "built"
        if artifact is None:
            started = time.perf_counter()
            artifact = run.call("build", planner.build, problem)
            build_s = time.perf_counter() - started
            if spec.artifact is not None:
                stored = time.perf_counter()
                run.call("save_artifact", save_artifact, spec.artifact, planner, artifact, key, spec.plugin)
                store_s = time.perf_counter() - stored
        else:
            build_s = time.perf_counter() - started

        # query_s: the whole answer, unless the planner reports its own query time (safe_prm: the roadmap query,
        # its smoothing apart as smooth_s)
        started = time.perf_counter()
        result: PlanResult = run.call("query", planner.query, artifact, spec.start, spec.goal)
        query_s = time.perf_counter() - started

        state = run.state
        try:
            path = verify_plan_result(
                result, spec.space, spec.start, spec.goal, unit=state.length_unit, unit_scale=state.unit_scale
            )
        except InvalidResult as exc:
            return run.invalid(f"{exc}")
        value = threshold_value(spec.clearance_threshold)
        threshold = spec.clearance_threshold if value > 0 else None
        regions = []
        if path is not None and threshold is not None:
            regions = critical_regions(spec.space, path, value)
            if spec.plugin.cls.clearance_policy is not ClearancePolicy.EXCEPT_CRITICAL:
                below = [r for r in regions if r.min_clearance_m < value - THRESHOLD_TOLERANCE]
                if below:
                    return run.invalid(self._below(spec, below, value))
                regions = []
        self._deprecated_answers(spec, result, value)

        metrics = dict(result.metrics) if isinstance(result.metrics, dict) else {}
        metrics.setdefault("build_s", build_s)
        metrics.setdefault("query_s", query_s)
        metrics.setdefault("answer_s", query_s)
        if spec.artifact is not None:
            metrics["artifact"] = origin
            metrics["store_s"] = store_s
        if path is not None and result.final_goal is not None:
            metrics["final_goal"] = np.asarray(result.final_goal, dtype=float).tolist()
        annotations = dict(result.annotations or {})
        annotations.pop("critical_regions", None)  # the framework's own measurement replaces a planner's
        stage = run.result(
            str(result.status),
            path=path if path is not None else np.empty((0, spec.space.dimension)),
            message=str(result.message or ""),
            space=spec.space.kind,
            clearance_threshold=threshold,
            critical_regions=regions,
            annotations=annotations,
            files=list(result.files or []),
        )
        if path is not None:
            # measured by the framework on the scene, whatever the plugin reported
            common, tips, clearance = path_metrics(spec.space, path, threshold.value if threshold else None)
            metrics.update(common)
            stage.tip_path = spec.space.tip(path)
            from ..outputs.figures import PathView, plan_figure  # matplotlib: once there is a path to draw

            view = PathView(
                spec.name,
                tips,
                clearance,
                threshold.value if threshold else None,
                spec.space.tip(spec.start[None])[0],
                spec.space.tip(spec.goal[None])[0] if spec.goal is not None else None,
                highlights=intervals(regions),
                detours=[
                    np.asarray(d["tips_m"], dtype=float).reshape(-1, 3)
                    for d in annotations.get("detours", [])
                    if isinstance(d, dict) and "tips_m" in d
                ],
            )
            stage.metrics = metrics
            view.title = self._title(spec, stage, state.length_unit, state.unit_scale)
            state.kept.setdefault(self.name, []).append((spec, view))
            if state.figures:
                name = f"{spec.name}.png"
                plan_figure(
                    state.output_dir / name, spec.scene, view, unit=state.length_unit, unit_scale=state.unit_scale
                )
                stage.files.append(name)
        stage.metrics = metrics
        return stage

    @staticmethod
    def _below(spec: PlanSpec, regions, threshold: float) -> str:
        scene = spec.scene
        first = regions[0]
        near = f" (near {', '.join(repr(o) for o in first.obstacles)})" if first.obstacles else ""
        return (
            f"its path runs below the {scene.describe_length(threshold)} clearance threshold "
            f"({spec.clearance_threshold.source}), which planner '{spec.plugin.name}' keeps everywhere: "
            f"{len(regions)} stretch(es), the first from {scene.describe_length(first.start_m)} to "
            f"{scene.describe_length(first.end_m)} along it, clearance {scene.describe_length(first.min_clearance_m)}"
            f"{near}"
        )

    @staticmethod
    def _deprecated_answers(spec: PlanSpec, result: PlanResult, threshold: float) -> None:
        claimed = getattr(result, "clearance_threshold", None)
        if claimed is not None and abs(float(claimed) - threshold) > 1e-12:
            log.warning(
                "plan stage '%s': planner '%s' returned clearance_threshold %g m, which is deprecated and ignored; "
                "the stage's threshold is %g m (PlanningProblem.clearance_threshold)",
                spec.name,
                spec.plugin.name,
                float(claimed),
                threshold,
            )
        if isinstance(result.annotations, dict) and "critical_regions" in result.annotations:
            log.info(
                "plan stage '%s': planner '%s' reported critical regions in its annotations; the framework measures "
                "them itself (surgiplan.clearance)",
                spec.name,
                spec.plugin.name,
            )

    @staticmethod
    def _title(spec: PlanSpec, result: StageResult, unit: str, unit_scale: float) -> str:
        m = result.metrics
        k = 1.0 / unit_scale
        parts = [
            f"{spec.name} ({spec.plugin.name})",
            f"length {m['length_m'] * k:.4g} {unit}",
            f"min clearance {m['min_clearance_m'] * k:.3g} {unit}",
        ]
        if result.clearance_threshold is not None:
            parts.append(f"threshold {float(result.clearance_threshold) * k:.3g} {unit}")
            parts.append(f"below threshold {m.get('length_below_threshold_m', 0.0) * k:.3g} {unit}")
        return ", ".join(parts)

    def finish(self, state) -> list[str]:
        from ..outputs.figures import overview_figure

        views = state.kept.get(self.name, [])
        if not state.figures or len(views) < 2:
            return []
        overview_figure(
            state.output_dir / "overview.png",
            [(s.scene, v) for s, v in views],
            unit=state.length_unit,
            unit_scale=state.unit_scale,
            title=state.pipeline_name,
        )
        return ["overview.png"]

    def markers(self, spec: PlanSpec, result: StageResult) -> list[tuple[str, np.ndarray]]:
        if result.tip_path is None or spec.space is None:
            return []
        return [
            (f"{spec.name}:{k}", spec.space.tip(getattr(spec, k)[None])[0])
            for k in ("start", "goal")
            if getattr(spec, k) is not None
        ]

    # ------------------------------------------------------------------ presenting
    def report(self, stage, entry, inputs) -> None:
        from ..outputs.report.paths import plan_report

        plan_report(stage, entry, inputs.specs.get(stage["name"]), inputs.scene, inputs.notes)
