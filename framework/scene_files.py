"""Scene files: validate a scene (a file, or a pipeline's ``scene:`` block) and build it, meshes loaded.

Every problem is collected with its file, YAML path and line; obstacles that fail are left out of the
scene returned so the rest of a pipeline can still be checked against it.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from .config import SceneModel
from .errors import ConfigError, ConfigErrors, SceneError, SurgiplanError
from .geometry.mesh import load_mesh
from .geometry.shapes import Box, Capsule, Cylinder, Mesh, Obstacle, Sphere, rotation_from_z
from .geometry.transforms import Pose
from .scene import Scene
from .units import LENGTH_UNITS
from .validation import declared_unit, sorted_errors, validate_model, validation_context
from .yamlio import LineMap, format_path, line_of, load_yaml


def build_obstacles(model, base_dir: Path, unit: str, location: str, file: Path | None) -> list[Obstacle]:
    """The obstacles of a validated :class:`~surgiplan.config.ObstacleModel`: one, or an occupancy grid's boxes
    (named ``<name>#<k>``, greedy meshing: ``surgiplan.geometry.occupancy``)."""
    if model.occupancy_grid is None:
        return [build_obstacle(model, base_dir, unit, location, file)]
    from .geometry import occupancy

    grid = model.occupancy_grid
    where = f"{location}.occupancy_grid"
    voxel, origin = np.asarray(grid.voxel_size), np.asarray(grid.origin)
    try:
        if grid.file is not None:
            occupied = occupancy.read_grid((base_dir / grid.file).resolve(), grid.key, grid.threshold, where)
        else:
            points = occupancy.read_points((base_dir / grid.points).resolve(), LENGTH_UNITS[grid.unit or unit], where)
            occupied = occupancy.voxelise(points, voxel, origin, where)
        if not occupied.any():
            raise SceneError("the occupancy grid has no occupied voxel (is 'threshold' right?)", location=where)
    except SceneError as exc:
        exc.file = file
        raise
    centres, sizes = occupancy.boxes_in_space(occupancy.greedy_boxes(occupied), voxel, origin)
    pose = model.pose.to_pose()
    return [
        Box(f"{model.name}#{k}", pose.compose(Pose(np.eye(3), c)), size=tuple(s))
        for k, (c, s) in enumerate(zip(centres, sizes, strict=True))
    ]


def build_obstacle(model, base_dir: Path, unit: str, location: str, file: Path | None) -> Obstacle:
    """An ``Obstacle`` from a validated :class:`~surgiplan.config.ObstacleModel`."""
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
    """A :class:`~surgiplan.scene.Scene` from a validated :class:`~surgiplan.config.SceneModel`; mesh files load
    here."""
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
            obstacles.extend(build_obstacles(o, base_dir, unit, location, file))
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
    context = validation_context(unit, base_dir)
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
    for error in build_errors:  # a file the scene names (a mesh, a grid): the line of the key that names it
        if error.line is None and error.location:
            error.line = line_of(lines, location_path(error.location))
    return scene, errors + build_errors


def location_path(location: str) -> tuple[Any, ...]:
    """``scene.obstacles[3].mesh`` -> ``("scene", "obstacles", 3, "mesh")`` (the inverse of ``format_path``)."""
    return tuple(int(p) if p.isdigit() else p for p in re.findall(r"[^.\[\]]+", location))


def load_scene(path: str | Path) -> Scene:
    """Read and build a scene file (its own ``length_unit``, meshes relative to it); every error at once."""
    scene, errors = _load_scene_collecting(Path(path))
    if errors:
        raise ConfigErrors(sorted_errors(errors))
    return scene


def _load_scene_collecting(path: Path) -> tuple[Scene | None, list[ConfigError]]:
    data, lines = load_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError("a scene file must be a mapping with bounds, obstacles and points", file=path)
    unit = declared_unit(data, "m", path, lines, ())
    return scene_with_errors(data, file=path, lines=lines, prefix=(), unit=unit, base_dir=path.parent)


def looks_like_scene(data: Any) -> bool:
    """A mapping with a scene's keys and none of a pipeline's: a scene file."""
    return isinstance(data, dict) and "pipeline" not in data and bool({"bounds", "obstacles", "points"} & set(data))
