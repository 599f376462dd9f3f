"""Loading and validating pipeline and scene files.

Validation runs in four passes, and each reports every problem it finds
with the file, the YAML path and the line:

1. structure: the file against :class:`~surgiplan.config.PipelineModel`
   (unknown keys, wrong types, negative or NaN lengths);
2. plugins: each stage's plugin is looked up by name in the registry, and its
   ``settings`` (and ``space``) validated with that plugin's own model;
3. meaning: the scene is built (meshes loaded), and starts and goals are
   resolved and checked: known point names, inside the bounds, free;
4. resources: each plugin estimates from its settings what its stage will
   need (:mod:`surgiplan.resources`); more memory than the machine has is an
   error naming the setting.

:func:`load_pipeline` returns a :class:`Pipeline` ready to run; nothing has
been written anywhere.
"""

from __future__ import annotations

import re
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ValidationError

from .config import (
    GimbalConfigurationModel,
    PipelineModel,
    SceneModel,
    StageModel,
)
from .errors import ConfigError, ConfigErrors, PlanningInputError, SceneError, SurgiplanError, choices_hint
from .geometry.mesh import load_mesh
from .geometry.shapes import Box, Capsule, Cylinder, Mesh, Obstacle, Sphere, rotation_from_z
from .geometry.transforms import Pose
from .hookspecs import KINDS
from .models import QuaternionPoseModel
from .planning import Planner, PlanningProblem
from .registry import PluginInfo, PluginRegistry, default_registry
from .resources import too_large
from .scene import Scene
from .spaces.base import Space
from .units import LENGTH_SCALE_KEY, LENGTH_UNITS
from .yamlio import LineMap, format_path, line_of, load_yaml

#: validation-context key holding the directory relative input files resolve against
BASE_DIR_KEY = "base_dir"
#: validation-context key holding the trainee record's path (settings may read a trainee's proficiency from it)
RECORD_KEY = "record"

STAGE_PLUGIN_KIND = {stage: kind for kind, (_, stage) in KINDS.items() if stage}


# ----------------------------------------------------------------------------- validation errors


def _clean_loc(loc: tuple[Any, ...], data: Any, error_type: str) -> tuple[Any, ...]:
    """Drop pydantic's union tags and validator names: keep only keys present in the data."""
    out: list[Any] = []
    current = data
    for i, part in enumerate(loc):
        if isinstance(current, dict) and part in current:
            out.append(part)
            current = current[part]
        elif isinstance(current, list | tuple) and isinstance(part, int) and 0 <= part < len(current):
            out.append(part)
            current = current[part]
        elif i == len(loc) - 1 and error_type == "missing":
            out.append(part)
    return tuple(out)


def _unwrap_models(annotation: Any) -> list[type[BaseModel]]:
    found: list[type[BaseModel]] = []
    stack = [annotation]
    while stack:
        item = stack.pop()
        if isinstance(item, type) and issubclass(item, BaseModel):
            found.append(item)
        else:
            stack.extend(typing.get_args(item))
    return found


def _model_at(root: type[BaseModel], loc: tuple[Any, ...]) -> type[BaseModel] | None:
    model: type[BaseModel] | None = root
    for part in loc:
        if model is None:
            return None
        if isinstance(part, int):
            continue
        info = model.model_fields.get(part)
        if info is None:
            return None
        candidates = _unwrap_models(info.annotation)
        model = candidates[0] if len(candidates) == 1 else None
    return model


def validation_errors(
    exc: ValidationError,
    data: Any,
    *,
    file: Path | None,
    lines: LineMap,
    prefix: tuple[Any, ...] = (),
    root: type[BaseModel] | None = None,
) -> list[ConfigError]:
    """pydantic's errors as :class:`ConfigError` records with YAML paths and lines."""
    errors: list[ConfigError] = []
    for err in exc.errors(include_url=False):
        loc = _clean_loc(tuple(err["loc"]), data, err["type"])
        message = err["msg"].removeprefix("Value error, ").removeprefix("Assertion failed, ")
        if err["type"] == "extra_forbidden":
            key = str(loc[-1]) if loc else "?"
            parent = _model_at(root, loc[:-1]) if root is not None else None
            valid = sorted(parent.model_fields) if parent is not None else []
            message = f"unknown key '{key}'"
            if valid:
                message += f"; {choices_hint(key, valid)}"
        elif err["type"] == "missing":
            message = "required key is missing"
        full = (*prefix, *loc)
        errors.append(ConfigError(message, file=file, location=format_path(full), line=line_of(lines, full)))
    return errors


def validate_model(
    model: type[BaseModel],
    data: Any,
    *,
    file: Path | None = None,
    lines: LineMap | None = None,
    prefix: tuple[Any, ...] = (),
    context: dict[str, Any] | None = None,
) -> BaseModel:
    """``model.model_validate(data)``, raising :class:`ConfigErrors` that name file, path and line."""
    try:
        return model.model_validate(data, context=context or {})
    except ValidationError as exc:
        raise ConfigErrors(
            validation_errors(exc, data, file=file, lines=lines or {}, prefix=prefix, root=model)
        ) from None


# ----------------------------------------------------------------------------- scenes


def _context(unit: str, base_dir: Path) -> dict[str, Any]:
    return {LENGTH_SCALE_KEY: LENGTH_UNITS[unit], BASE_DIR_KEY: base_dir}


def _declared_unit(data: Any, default: str, file: Path, lines: LineMap, prefix: tuple[Any, ...]) -> str:
    unit = data.get("length_unit", default) if isinstance(data, dict) else default
    if unit is None:
        return default
    if unit not in LENGTH_UNITS:
        path = (*prefix, "length_unit")
        raise ConfigError(
            f"unknown length unit '{unit}'; choose one of: {', '.join(LENGTH_UNITS)}",
            file=file,
            location=format_path(path),
            line=line_of(lines, path),
        )
    return unit


def build_obstacle(model, base_dir: Path, unit: str, location: str, file: Path | None) -> Obstacle:
    """An :class:`Obstacle` from a validated :class:`~surgiplan.config.ObstacleModel`."""
    pose = model.pose.to_pose()
    name = model.name
    if model.box is not None:
        box = model.box
        if box.size is not None:
            return Box(name, pose, size=tuple(box.size))
        lo, hi = np.asarray(box.min), np.asarray(box.max)
        return Box(name, pose.compose(Pose(np.eye(3), 0.5 * (lo + hi))), size=tuple(hi - lo))
    if model.sphere is not None:
        return Sphere(name, pose, radius=model.sphere.radius)
    if model.cylinder is not None:
        return Cylinder(name, pose, radius=model.cylinder.radius, length=model.cylinder.length)
    if model.capsule is not None:
        capsule = model.capsule
        if capsule.length is not None:
            return Capsule(name, pose, radius=capsule.radius, length=capsule.length)
        a, b = np.asarray(capsule.a), np.asarray(capsule.b)
        length = float(np.linalg.norm(b - a))
        rotation = rotation_from_z((b - a) / length) if length > 0 else np.eye(3)
        return Capsule(name, pose.compose(Pose(rotation, 0.5 * (a + b))), radius=capsule.radius, length=length)
    mesh_model = model.mesh
    scale = LENGTH_UNITS[mesh_model.unit or unit] * mesh_model.scale
    path = (base_dir / mesh_model.file).resolve()
    try:
        mesh = load_mesh(path, scale, location=f"{location}.mesh")
    except SceneError as exc:
        exc.file = file
        raise
    return Mesh(name, pose, mesh=mesh)


def build_scene(
    model: SceneModel, *, base_dir: Path, unit: str, file: Path | None = None, prefix: str = "scene"
) -> Scene:
    """A :class:`Scene` from a validated :class:`SceneModel`; mesh files load here."""
    scene, errors = _build_scene_collecting(model, list(range(len(model.obstacles))), base_dir, unit, file, prefix)
    if errors:
        raise ConfigErrors(errors)
    return scene


def _build_scene_collecting(
    model: SceneModel, indices: list[int], base_dir: Path, unit: str, file: Path | None, prefix: str
) -> tuple[Scene, list[ConfigError]]:
    """The scene of every obstacle that builds, and the errors of those that do not (a mesh that cannot
    be loaded). ``indices``: each obstacle's index in the file (for the error locations)."""
    obstacles, errors = [], []
    for i, o in zip(indices, model.obstacles, strict=True):
        location = f"{prefix}.obstacles[{i}]" if prefix else f"obstacles[{i}]"
        try:
            obstacles.append(build_obstacle(o, base_dir, unit, location, file))
        except SurgiplanError as exc:
            if not isinstance(exc, ConfigError):
                exc = ConfigError(exc.message, file=exc.file or file, location=exc.location, line=exc.line)
            errors.append(exc)
    scene = Scene(
        np.asarray(model.bounds.min),
        np.asarray(model.bounds.max),
        obstacles,
        {k: np.asarray(v) for k, v in model.points.items()},
        model.name or "scene",
        unit,
    )
    return scene, errors


def scene_with_errors(
    raw: Any, *, file: Path, lines: LineMap, prefix: tuple[Any, ...], unit: str, base_dir: Path
) -> tuple[Scene | None, list[ConfigError]]:
    """Validate and build a scene, collecting every error. Obstacles with errors are left out of the
    scene returned (so the rest of the file can still be checked against it); errors in the bounds or
    points leave no scene (None)."""
    label = format_path(prefix)
    errors: list[ConfigError] = []
    context = _context(unit, base_dir)
    raw_obstacles = raw.get("obstacles") if isinstance(raw, dict) and isinstance(raw.get("obstacles"), list) else []
    indices = list(range(len(raw_obstacles)))
    try:
        model = validate_model(SceneModel, raw, file=file, lines=lines, prefix=prefix, context=context)
    except ConfigErrors as exc:
        errors.extend(exc.errors)
        pattern = re.compile(re.escape(f"{label}.obstacles[" if label else "obstacles[") + r"(\d+)\]")
        bad = set()
        for error in exc.errors:
            match = pattern.match(error.location or "")
            if match is None:
                return None, errors  # bounds, points, names: no scene to check the rest against
            bad.add(int(match.group(1)))
        indices = [i for i in indices if i not in bad]
        reduced = dict(raw, obstacles=[raw_obstacles[i] for i in indices])
        try:
            model = SceneModel.model_validate(reduced, context=context)
        except ValidationError:
            return None, errors
    scene, build_errors = _build_scene_collecting(model, indices, base_dir, unit, file, label)
    return scene, errors + build_errors


def load_scene(path: str | Path) -> Scene:
    """Read and build a scene file (its own ``length_unit``, meshes relative to it); every error at once."""
    scene, errors = _load_scene_collecting(Path(path))
    if errors:
        raise ConfigErrors(_sorted(errors))
    return scene


def _load_scene_collecting(path: Path) -> tuple[Scene | None, list[ConfigError]]:
    data, lines = load_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError("a scene file must be a mapping with bounds, obstacles and points", file=path)
    unit = _declared_unit(data, "m", path, lines, ())
    return scene_with_errors(data, file=path, lines=lines, prefix=(), unit=unit, base_dir=path.parent)


# ----------------------------------------------------------------------------- pipelines


@dataclass
class StageSpec:
    """A validated stage, ready to run."""

    index: int
    kind: str
    name: str
    plugin: PluginInfo
    settings: BaseModel
    location: str
    scene: Scene
    # plan stages
    space: Space | None = None
    start: np.ndarray | None = None
    goal: np.ndarray | None = None
    start_label: str = ""
    goal_label: str = ""
    artifact: Path | None = None
    clearance_threshold: float | None = None
    # execute and guide stages
    path_from: str | None = None
    # guide stages
    guidance: Any = None  # surgiplan.guidance.GuidanceSettings
    trainee: Any = None  # surgiplan.config.TraineeModel


@dataclass
class Pipeline:
    file: Path
    name: str
    model: PipelineModel
    scene: Scene
    stages: list[StageSpec]
    output_dir: Path
    base_dir: Path
    registry: PluginRegistry = field(repr=False, default_factory=default_registry)
    #: the trainee record guide stages write to (relative to the current directory)
    record: Path = Path("out/trainees.sqlite")


def looks_like_scene(data: Any) -> bool:
    """A mapping with a scene's keys and none of a pipeline's: a scene file."""
    return isinstance(data, dict) and "pipeline" not in data and bool({"bounds", "obstacles", "points"} & set(data))


def load_pipeline(
    path: str | Path, *, registry: PluginRegistry | None = None, output_dir: str | Path | None = None
) -> Pipeline:
    """Read, validate and resolve a pipeline file (all four passes).

    Every problem found is reported at once (:class:`ConfigErrors`, sorted by line): a stage whose
    structure is wrong is left out of the later passes, the others go on, so a file with three
    mistakes needs one ``surgiplan validate``, not three.
    """
    registry = registry or default_registry()
    path = Path(path)
    data, lines = load_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError("a pipeline file must be a mapping with name, scene and pipeline", file=path)
    if looks_like_scene(data):
        raise ConfigError(
            "this is a scene file (bounds, obstacles, points), not a pipeline; `surgiplan validate` checks it as "
            "a scene, and a pipeline uses it with 'scene: <this file>'",
            file=path,
        )
    base_dir = path.resolve().parent
    unit = _declared_unit(data, "m", path, lines, ())
    context = _context(unit, base_dir)
    record = data.get("record")
    context[RECORD_KEY] = Path(record if isinstance(record, str) else "out/trainees.sqlite")
    errors: list[ConfigError] = []

    # pass 1: structure (every error; the parts that are sound go on to the next passes)
    model: PipelineModel | None = None
    bad_stages: set[int] = set()
    try:
        model = validate_model(PipelineModel, data, file=path, lines=lines, context=context)
    except ConfigErrors as exc:
        errors.extend(exc.errors)
        for error in exc.errors:
            where = error.location or ""
            match = re.match(r"pipeline\[(\d+)\]", where)
            if match:
                bad_stages.add(int(match.group(1)))
    raw_stages = data.get("pipeline") if isinstance(data.get("pipeline"), list) else []
    stage_models: dict[int, StageModel] = {}
    for index, raw in enumerate(raw_stages):
        if model is not None:
            stage_models[index] = model.pipeline[index]
        elif index not in bad_stages:
            try:
                stage_models[index] = StageModel.model_validate(raw, context=context)
            except ValidationError:  # already reported as part of the file
                bad_stages.add(index)

    # the scene: inline (this file's unit unless it declares its own) or a scene file
    scene: Scene | None = None
    raw_scene = data.get("scene")
    try:
        if isinstance(raw_scene, str):
            scene_path = (base_dir / raw_scene).resolve()
            if not scene_path.is_file():
                raise ConfigError(
                    f"scene file not found: {scene_path}", file=path, location="scene", line=line_of(lines, ("scene",))
                )
            scene, scene_errors = _load_scene_collecting(scene_path)
            errors.extend(scene_errors)
        elif isinstance(raw_scene, dict):
            scene_unit = _declared_unit(raw_scene, unit, path, lines, ("scene",))
            scene, scene_errors = scene_with_errors(
                raw_scene, file=path, lines=lines, prefix=("scene",), unit=scene_unit, base_dir=base_dir
            )
            known = {(e.location, e.message) for e in errors}  # pass 1 reported the same ones already
            errors.extend(e for e in scene_errors if (e.location, e.message) not in known)
    except SurgiplanError as exc:
        errors.append(exc if exc.file is not None else ConfigError(exc.message, file=path, location=exc.location))

    if scene is not None:
        scene.unit = unit  # messages in the pipeline's unit, whatever the scene file's

    # pass 2: plugins and their settings (and spaces, when the scene is there to build them on)
    stages: list[StageSpec] = []
    names: set[str] = set()
    for index, stage in stage_models.items():
        try:
            spec = _resolve_stage(index, stage, raw_stages[index], registry, scene, path, lines, context, names)
        except ConfigErrors as exc:
            errors.extend(exc.errors)
            continue
        except SurgiplanError as exc:
            errors.append(ConfigError(exc.message, file=path, location=exc.location, line=exc.line))
            continue
        names.add(spec.name)
        stages.append(spec)

    # pass 3: meaning (needs the scene)
    complete: list[StageSpec] = []
    if scene is not None:
        for spec in stages:
            stage = stage_models[spec.index]
            try:
                if spec.kind == "plan":
                    _resolve_endpoints(spec, stage, path, lines)
                elif spec.kind in ("execute", "guide"):
                    _resolve_path_source(spec, stages, stage, path, lines)
            except ConfigErrors as exc:
                errors.extend(exc.errors)
                continue
            except SurgiplanError as exc:
                errors.append(
                    ConfigError(exc.message, file=path, location=exc.location, line=exc.line)
                    if not isinstance(exc, PlanningInputError)
                    else exc
                )
                continue
            complete.append(spec)

    # pass 4: resources, estimated from the settings before any work
    for spec in complete:
        errors.extend(_resource_errors(spec, path, lines))
    if errors:
        raise ConfigErrors(_sorted(errors))
    assert model is not None and scene is not None

    out = Path(output_dir) if output_dir is not None else Path(model.output.dir or Path("out") / model.name)
    return Pipeline(path, model.name, model, scene, stages, out, base_dir, registry, Path(model.record))


def _sorted(errors: list[ConfigError]) -> list[ConfigError]:
    """By file, then line (errors without a line keep their place at the end of their file)."""
    order = {}
    for e in errors:
        order.setdefault(str(e.file), len(order))
    return sorted(errors, key=lambda e: (order[str(e.file)], e.line if e.line is not None else 10**9))


def _resource_errors(spec: StageSpec, file: Path, lines: LineMap) -> list[ConfigError]:
    """Estimates above the machine's memory, each a :class:`ConfigError` at the setting that drives it."""
    cls = spec.plugin.cls
    try:
        if spec.kind == "plan":
            problem = PlanningProblem(spec.scene, spec.space, start=spec.start, goal=spec.goal)
            estimates = cls.estimate_resources(spec.settings, problem)
        else:
            estimates = cls.estimate_resources(spec.settings)
        estimates = list(estimates or [])
    except Exception as exc:
        where = ("pipeline", spec.index, "plugin")
        return [
            ConfigError(
                f"plugin '{spec.plugin.name}' ({spec.plugin.package} {spec.plugin.version}) failed to estimate "
                f"its resources: {type(exc).__name__}: {exc}",
                file=file,
                location=format_path(where),
                line=line_of(lines, where),
            )
        ]
    errors = []
    for estimate, message in too_large(estimates):
        where = ("pipeline", spec.index, "settings", *([estimate.setting] if estimate.setting else []))
        errors.append(ConfigError(message, file=file, location=format_path(where), line=line_of(lines, where)))
    return errors


def _resolve_stage(index, stage: StageModel, raw, registry, scene, file, lines, context, names) -> StageSpec:
    where = ("pipeline", index)
    location = format_path(where)
    kind = STAGE_PLUGIN_KIND[stage.stage]
    try:
        info = registry.get(kind, stage.plugin)
    except SurgiplanError as exc:
        raise ConfigError(
            exc.message, file=file, location=format_path((*where, "plugin")), line=line_of(lines, (*where, "plugin"))
        ) from None
    settings = validate_model(
        info.settings_model,
        raw.get("settings") or {},
        file=file,
        lines=lines,
        prefix=(*where, "settings"),
        context=context,
    )
    name = stage.name or _unique(stage.plugin, names)
    if name in names:
        raise ConfigError(
            f"stage name '{name}' is used twice; give each stage a unique name",
            file=file,
            location=format_path((*where, "name")),
            line=line_of(lines, (*where, "name")),
        )
    spec = StageSpec(index, stage.stage, name, info, settings, location, scene)
    if stage.stage == "guide":
        from .guidance.analysis import GuidanceSettings

        spec.guidance = validate_model(
            GuidanceSettings,
            raw.get("guidance") or {},
            file=file,
            lines=lines,
            prefix=(*where, "guidance"),
            context=context,
        )
        spec.trainee = stage.trainee
    if stage.stage != "plan":
        spec.path_from = stage.path_from
        return spec
    if stage.goal is None and getattr(info.cls, "requires_goal", True):
        raise ConfigError("a plan stage needs goal", file=file, location=location, line=line_of(lines, where))

    if stage.bounds is not None and scene is not None:
        spec.scene = scene.with_bounds(stage.bounds.min, stage.bounds.max)
    space_data = dict(raw.get("space") or {"kind": "r3"})
    space_kind = space_data.pop("kind", "r3")
    try:
        space_info = registry.get("space", str(space_kind))
    except SurgiplanError as exc:
        raise ConfigError(
            exc.message,
            file=file,
            location=format_path((*where, "space", "kind")),
            line=line_of(lines, (*where, "space")),
        ) from None
    space_settings = validate_model(
        space_info.settings_model, space_data, file=file, lines=lines, prefix=(*where, "space"), context=context
    )
    if spec.scene is not None:  # else the scene has errors of its own, already reported
        spec.space = space_info.cls.from_settings(space_settings, spec.scene)
    spec.clearance_threshold = stage.clearance_threshold
    if stage.artifact is not None:
        if info.cls.save_artifact is Planner.save_artifact:
            raise ConfigError(
                f"planner '{stage.plugin}' cannot store its artifact; remove 'artifact'",
                file=file,
                location=format_path((*where, "artifact")),
                line=line_of(lines, (*where, "artifact")),
            )
        spec.artifact = Path(stage.artifact)
    return spec


def _unique(base: str, names: set[str]) -> str:
    if base not in names:
        return base
    k = 2
    while f"{base}-{k}" in names:
        k += 1
    return f"{base}-{k}"


def _resolve_endpoints(spec: StageSpec, stage: StageModel, file: Path, lines: LineMap) -> None:
    errors: list[SurgiplanError] = []
    for key in ("start", "goal"):
        try:
            _resolve_endpoint(spec, stage, key, file, lines)
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


def _resolve_endpoint(spec: StageSpec, stage: StageModel, key: str, file: Path, lines: LineMap) -> None:
    space = spec.space
    scene = spec.scene
    where = ("pipeline", spec.index, key)
    location = format_path(where)
    line = line_of(lines, where)
    value = getattr(stage, key)
    if value is None:  # a goal the planner does not need (Planner.requires_goal)
        return
    if isinstance(value, str):
        if value not in scene.points:
            raise PlanningInputError(
                f"no point named '{value}'; {choices_hint(value, scene.points)}",
                file=file,
                location=location,
                line=line,
            )
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
        raise PlanningInputError(
            exc.message.removeprefix(f"{key}: "), file=file, location=location, line=line
        ) from None
    q = np.asarray(q, dtype=float)
    if not space.in_workspace(q[None, :])[0]:
        lo, hi = scene.describe_point(scene.bounds_min), scene.describe_point(scene.bounds_max)
        raise PlanningInputError(
            f"{key} {label} is outside the scene bounds {lo} to {hi}", file=file, location=location, line=line
        )
    if not space.within_limits(q[None, :])[0]:
        raise PlanningInputError(
            f"{key} {label} is outside the limits of the {space.kind} space",
            file=file,
            location=location,
            line=line,
        )
    clearance = float(space.clearance(q[None, :])[0])
    if not clearance > 0:
        nearest = int(space.nearest_obstacle(q[None, :])[0])
        what = f"obstacle '{scene.obstacles[nearest].name}'" if nearest >= 0 else "an obstacle"
        body = "lies inside" if space.kind == "r3" else "puts the instrument inside"
        raise PlanningInputError(
            f"{key} {label} {body} {what} (clearance {scene.describe_length(clearance)})",
            file=file,
            location=location,
            line=line,
        )
    setattr(spec, key, q)
    setattr(spec, f"{key}_label", label)


def _resolve_path_source(
    spec: StageSpec, stages: list[StageSpec], stage: StageModel, file: Path, lines: LineMap
) -> None:
    earlier = [s for s in stages if s.index < spec.index and s.kind == "plan"]
    where = ("pipeline", spec.index, "path_from")
    if spec.path_from is None:
        if not earlier:
            raise ConfigError(
                "an execute stage needs an earlier plan stage whose path it executes"
                if spec.kind == "execute"
                else "a guide stage needs an earlier plan stage whose path it recommends",
                file=file,
                location=format_path(("pipeline", spec.index)),
                line=line_of(lines, ("pipeline", spec.index)),
            )
        spec.path_from = earlier[-1].name
    elif spec.path_from not in {s.name for s in earlier}:
        raise ConfigError(
            f"no earlier plan stage named '{spec.path_from}'; "
            f"{choices_hint(spec.path_from, [s.name for s in earlier])}",
            file=file,
            location=format_path(where),
            line=line_of(lines, where),
        )
