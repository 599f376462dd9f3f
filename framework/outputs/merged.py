"""The scene's obstacles as the outputs draw them: one mesh an obstacle for a few, merged meshes for many.

A scene of a few obstacles is drawn obstacle by obstacle (a node of ``scene.glb``, a pickable mesh of
``report.html`` and a label of the figures each, by name). Above :data:`MAX_SEPARATE` obstacles (a voxelised scan's
thousands of boxes) that would cost a draw call, a node and a label each: the outputs then draw one mesh a group,
where a group is an occupancy grid's boxes (the obstacles named ``<grid>#<k>``) or all the other obstacles
together, all of one material (the outputs give every obstacle the same one). The boxes' triangles are built in
one vectorised step (no trimesh object a box), the other shapes through their own meshes.

Nothing is decimated below what a pixel shows: a box is already its 12 triangles, and a merged mesh keeps every
one (a figure's top view keeps only the upward faces, whose footprint is the whole box's: see
``figures.py``), so a scanned trainer's voxels all stay visible.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.shapes import Box, Obstacle

#: scenes of more obstacles than this are drawn as merged meshes, one a group
MAX_SEPARATE = 64

# a box of unit extents centred at the origin: 8 corners (x fastest, as trimesh's) and 12 triangles, outward
_CORNERS = np.array([[x, y, z] for z in (-0.5, 0.5) for y in (-0.5, 0.5) for x in (-0.5, 0.5)], dtype=float)
_TRIANGLES = np.array(
    [
        [0, 2, 1], [1, 2, 3],  # z-
        [4, 5, 6], [5, 7, 6],  # z+
        [0, 1, 4], [1, 5, 4],  # y-
        [2, 6, 3], [3, 6, 7],  # y+
        [0, 4, 2], [2, 4, 6],  # x-
        [1, 3, 5], [3, 7, 5],  # x+
    ],
    dtype=np.int64,
)  # fmt: skip
#: the same faces as quadrilaterals (corners in outward order): what a figure draws, half the polygons
_QUADS = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]], dtype=np.int64)


@dataclass
class DrawnMesh:
    """What an output draws as one mesh: a name, how many obstacles it holds, world vertices (m) and faces."""

    name: str
    count: int
    vertices: np.ndarray
    faces: np.ndarray
    kind: str
    #: the boxes' faces as quadrilaterals (vertex indices, (q, 4)); the first ``quad_triangles`` faces are theirs
    quads: np.ndarray | None = None
    quad_triangles: int = 0


def box_triangles(boxes: list[Box]) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (8 n, 3) and outward triangles (12 n, 3) of boxes, in the world, in one vectorised step."""
    if not boxes:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    size = np.array([b.size for b in boxes], dtype=float)
    rotation = np.array([b.pose.rotation for b in boxes], dtype=float)
    translation = np.array([b.pose.translation for b in boxes], dtype=float)
    local = _CORNERS[None] * size[:, None, :]
    world = np.einsum("bij,bkj->bki", rotation, local) + translation[:, None, :]
    faces = _TRIANGLES[None] + 8 * np.arange(len(boxes))[:, None, None]
    return world.reshape(-1, 3), faces.reshape(-1, 3)


def group_of(obstacle: Obstacle) -> str:
    """The merged mesh an obstacle is drawn in: its occupancy grid's name, or ``obstacles``."""
    return obstacle.name.split("#", 1)[0] if "#" in obstacle.name else "obstacles"


def drawn_meshes(obstacles: list[Obstacle]) -> list[DrawnMesh]:
    """The obstacles as drawn: one :class:`DrawnMesh` each, or above :data:`MAX_SEPARATE` one a group."""
    if len(obstacles) <= MAX_SEPARATE:
        out = []
        for o in obstacles:
            mesh = o.to_trimesh()
            out.append(
                DrawnMesh(o.name, 1, np.asarray(mesh.vertices), np.asarray(mesh.faces), type(o).__name__.lower())
            )
        return out
    groups: dict[str, list[Obstacle]] = {}
    for o in obstacles:
        groups.setdefault(group_of(o), []).append(o)
    out = []
    for name, members in groups.items():
        boxes = [o for o in members if type(o) is Box]
        vertices, faces = box_triangles(boxes)
        parts_v, parts_f, first = [vertices], [faces], len(vertices)
        for o in members:
            if type(o) is Box:
                continue
            mesh = o.to_trimesh()
            parts_v.append(np.asarray(mesh.vertices))
            parts_f.append(np.asarray(mesh.faces) + first)
            first += len(mesh.vertices)
        quads = (_QUADS[None] + 8 * np.arange(len(boxes))[:, None, None]).reshape(-1, 4)
        out.append(
            DrawnMesh(name, len(members), np.concatenate(parts_v), np.concatenate(parts_f), "merged", quads, len(faces))
        )
    return out
