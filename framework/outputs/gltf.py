"""The scene and its paths as one glTF binary (``scene.glb``) for any glTF viewer.

Obstacles are grey meshes (one node each, or for many obstacles one merged mesh a group: :mod:`.merged`);
each path is a coloured tube (visible at any zoom)
plus its polyline; starts and goals are small spheres. Coordinates are in
metres (glTF's unit), z up as in the scene.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import trimesh

from ..scene import Scene
from ..storage import write_bytes_atomic
from .merged import drawn_meshes

PALETTE = [
    (31, 111, 180),
    (214, 39, 40),
    (44, 160, 44),
    (255, 127, 14),
    (148, 103, 189),
    (140, 86, 75),
]


def _tube(points: np.ndarray, radius: float, colour) -> trimesh.Trimesh | None:
    parts = []
    for a, b in itertools.pairwise(points):
        if np.linalg.norm(b - a) > 1e-12:
            parts.append(trimesh.creation.cylinder(radius=radius, segment=np.stack([a, b]), sections=8))
    parts += [trimesh.creation.icosphere(subdivisions=1, radius=radius).apply_translation(p) for p in points]
    if not parts:
        return None
    tube = trimesh.util.concatenate(parts)
    tube.visual.face_colors = np.array([*colour, 255], dtype=np.uint8)
    return tube


def write_scene_glb(
    path: Path, scene: Scene, paths: Sequence[tuple[str, np.ndarray]], endpoints: Sequence[tuple[str, np.ndarray]] = ()
) -> None:
    """Write ``scene.glb``: obstacles, ``paths`` [(name, tip points (n, 3))], ``endpoints``."""
    out = trimesh.Scene()
    for drawn in drawn_meshes(scene.obstacles):  # one node an obstacle, or one a group of many (merged.py)
        mesh = trimesh.Trimesh(drawn.vertices, drawn.faces, process=False)
        mesh.visual.face_colors = np.array([160, 160, 160, 200], dtype=np.uint8)
        out.add_geometry(mesh, node_name=f"obstacle:{drawn.name}", geom_name=f"obstacle:{drawn.name}")
    radius = float(np.min(scene.extent)) * 0.006
    for i, (name, tips) in enumerate(paths):
        tips = np.asarray(tips, dtype=float)
        if len(tips) < 2:
            continue
        colour = PALETTE[i % len(PALETTE)]
        tube = _tube(tips, radius, colour)
        if tube is not None:
            out.add_geometry(tube, node_name=f"path:{name}", geom_name=f"path:{name}")
        line = trimesh.load_path(tips)
        line.colors = np.tile(np.array([*colour, 255], dtype=np.uint8), (len(line.entities), 1))
        out.add_geometry(line, node_name=f"polyline:{name}", geom_name=f"polyline:{name}")
    for name, point in endpoints:
        marker = trimesh.creation.icosphere(subdivisions=2, radius=2.5 * radius)
        marker.apply_translation(np.asarray(point, dtype=float))
        marker.visual.face_colors = np.array([20, 20, 20, 255], dtype=np.uint8)
        out.add_geometry(marker, node_name=f"point:{name}", geom_name=f"point:{name}")
    # the workspace bounds as a wireframe box
    lo, hi = scene.bounds_min, scene.bounds_max
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    edges = [(0, 1), (0, 2), (0, 4), (1, 3), (1, 5), (2, 3), (2, 6), (3, 7), (4, 5), (4, 6), (5, 7), (6, 7)]
    box = trimesh.load_path(corners[np.array(edges)])
    out.add_geometry(box, node_name="bounds", geom_name="bounds")
    write_bytes_atomic(path, out.export(file_type="glb"))
