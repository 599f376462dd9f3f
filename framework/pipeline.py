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
    obstacles = [
        build_obstacle(o, base_dir, unit, f"{prefix}.obstacles[{i}]" if prefix else f"obstacles[{i}]", file)
        for i, o in enumerate(model.obstacles)
    ]
    return Scene(
        np.asarray(model.bounds.min),
        np.asarray(model.bounds.max),
        obstacles,
        {k: np.asarray(v) for k, v in model.points.items()},
        model.name or "scene",
    )


def load_scene(path: str | Path) -> Scene:
    """Read and build a scene file (its own ``length_unit``, meshes relative to it)."""
    path = Path(path)
    data, lines = load_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError("a scene file must be a mapping with bounds, obstacles and points", file=path)
    unit = _declared_unit(data, "m", path, lines, ())
    model = validate_model(SceneModel, data, file=path, lines=lines, context=_context(unit, path.parent))
    return build_scene(model, base_dir=path.parent, unit=unit, file=path, prefix="")


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
    # execute stages
    path_from: str | None = None


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


def load_pipeline(
    path: str | Path, *, registry: PluginRegistry | None = None, output_dir: str | Path | None = None
) -> Pipeline:
    """Read, validate and resolve a pipeline file (all four passes)."""
    registry = registry or default_registry()
    path = Path(path)
    data, lines = load_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError("a pipeline file must be a mapping with name, scene and pipeline", file=path)
    base_dir = path.resolve().parent
    unit = _declared_unit(data, "m", path, lines, ())
    context = _context(unit, base_dir)

    # pass 1: structure
    model: PipelineModel = validate_model(PipelineModel, data, file=path, lines=lines, context=context)

    # the scene: inline (this file's unit unless it declares its own) or a scene file
    if isinstance(model.scene, str):
        scene_path = (base_dir / model.scene).resolve()
        if not scene_path.is_file():
            raise ConfigError(
                f"scene file not found: {scene_path}", file=path, location="scene", line=line_of(lines, ("scene",))
            )
        scene = load_scene(scene_path)
    else:
        scene_unit = _declared_unit(data["scene"], unit, path, lines, ("scene",))
        if scene_unit != unit:
            scene_model = validate_model(
                SceneModel,
                data["scene"],
                file=path,
                lines=lines,
                prefix=("scene",),
                context=_context(scene_unit, base_dir),
            )
        else:
            scene_model = model.scene
        scene = build_scene(scene_model, base_dir=base_dir, unit=scene_unit, file=path)

    # pass 2: plugins and their settings
    errors: list[ConfigError] = []
    stages: list[StageSpec] = []
    names: set[str] = set()
    for index, (stage, raw) in enumerate(zip(model.pipeline, data["pipeline"], strict=True)):
        try:
            spec = _resolve_stage(index, stage, raw, registry, scene, path, lines, context, names)
        except ConfigErrors as exc:
            errors.extend(exc.errors)
            continue
        except SurgiplanError as exc:
            errors.append(ConfigError(exc.message, file=path, location=exc.location, line=exc.line))
            continue
        names.add(spec.name)
        stages.append(spec)
    if errors:
        raise ConfigErrors(errors)

    # pass 3: meaning
    for spec, stage in zip(stages, model.pipeline, strict=True):
        try:
            if spec.kind == "plan":
                _resolve_endpoints(spec, stage, path, lines)
            elif spec.kind == "execute":
                _resolve_path_source(spec, stages, stage, path, lines)
        except SurgiplanError as exc:
            errors.append(
                ConfigError(exc.message, file=path, location=exc.location, line=exc.line)
                if not isinstance(exc, PlanningInputError)
                else exc
            )
    if errors:
        raise ConfigErrors(errors)

    # pass 4: resources, estimated from the settings before any work
    for spec in stages:
        errors.extend(_resource_errors(spec, path, lines))
    if errors:
        raise ConfigErrors(errors)

    out = Path(output_dir) if output_dir is not None else Path(model.output.dir or Path("out") / model.name)
    return Pipeline(path, model.name, model, scene, stages, out, base_dir, registry)


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
    if stage.stage != "plan":
        spec.path_from = stage.path_from
        return spec
    if stage.goal is None and getattr(info.cls, "requires_goal", True):
        raise ConfigError("a plan stage needs goal", file=file, location=location, line=line_of(lines, where))

    if stage.bounds is not None:
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
    space = spec.space
    scene = spec.scene
    for key in ("start", "goal"):
        where = ("pipeline", spec.index, key)
        location = format_path(where)
        line = line_of(lines, where)
        value = getattr(stage, key)
        if value is None:  # a goal the planner does not need (Planner.requires_goal)
            continue
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
                f"{key} {label} {body} {what} (clearance {clearance * 1000:.3g} mm)",
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
                "an execute stage needs an earlier plan stage whose path it executes",
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
