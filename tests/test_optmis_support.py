"""A small world for the optMIS / pathmap / segmented A* tests, built once per test process.

60 x 40 x 30 mm: a wall W1 with a way round its end and over its top, a post
P1 (a cylinder), and a sealed cup (four walls and a lid, standing on the
workspace floor) holding one point of interest, which is therefore
unreachable from every other one. Nine points of interest, 36 pairs, 8 of
them unreachable. The search space is coarse so that the tests stay fast.
"""

from __future__ import annotations

import functools

import numpy as np
from surgiplan import InlineExecutor, PlanningProblem
from surgiplan.geometry.shapes import Box, Cylinder
from surgiplan.geometry.transforms import Pose
from surgiplan.scene import Scene
from surgiplan.spaces import R3Space

MM = 1e-3
TIP_RADIUS = 0.2 * MM

POINTS_MM = {
    "a": (5, 10, 5),
    "b": (30, 10, 5),
    "c": (10, 35, 20),
    "d": (45, 8, 15),
    "e": (21, 14, 25),
    "f": (35, 32, 3),
    "g": (5, 30, 3),
    "h": (30, 30, 12),
    "cup": (54, 32, 4),
}
#: settings of a coarse, fast search space (SI)
SETTINGS = {"grid_spacing": 4 * MM, "surface_spacing": 2 * MM, "neighbours": 12, "seed": 3}


def box(name, lo_mm, hi_mm) -> Box:
    lo, hi = np.asarray(lo_mm, float) * MM, np.asarray(hi_mm, float) * MM
    return Box(name, Pose(np.eye(3), 0.5 * (lo + hi)), size=tuple(hi - lo))


def small_world(points=POINTS_MM) -> Scene:
    obstacles = [
        box("W1", (18, 0, 0), (24, 28, 22)),
        Cylinder("P1", Pose(np.eye(3), np.array([40, 20, 12.5]) * MM), radius=3 * MM, length=25 * MM),
        # the cup: walls 1 mm thick around (50..58, 28..36), 10 mm tall, and a lid
        box("cup-south", (49, 27, 0), (59, 28, 10)),
        box("cup-north", (49, 36, 0), (59, 37, 10)),
        box("cup-west", (49, 28, 0), (50, 36, 10)),
        box("cup-east", (58, 28, 0), (59, 36, 10)),
        box("cup-lid", (49, 27, 10), (59, 37, 11)),
    ]
    return Scene(
        np.zeros(3),
        np.array([60, 40, 30]) * MM,
        obstacles,
        {k: np.asarray(v, float) * MM for k, v in points.items()},
        "small-world",
    )


def space(scene=None) -> R3Space:
    return R3Space(scene or small_world(), TIP_RADIUS)


def problem(workdir=None, executor=None, scene=None) -> PlanningProblem:
    s = space(scene)
    return PlanningProblem(s.scene, s, executor or InlineExecutor(), workdir=workdir)


@functools.cache
def offline():
    """The search space and repository of the small world (built once)."""
    from surgiplan.plugins.planners.optmis.offline import OptMISSettings, run_offline

    return run_offline(problem(), OptMISSettings(**SETTINGS))


@functools.cache
def pathmap_artifact():
    """The segmented_astar artifact of the small world (pathmap and online graph)."""
    from surgiplan.plugins.planners.segmented_astar.pathmap import build_pathmap
    from surgiplan.plugins.planners.segmented_astar.search import SegmentedAStar

    result = offline()
    pathmap = build_pathmap(result.repository, space(), n_s=3)
    return SegmentedAStar._artifact(pathmap, space(), [])


def polyline_length(points) -> float:
    return float(np.linalg.norm(np.diff(np.asarray(points), axis=0), axis=1).sum())


def scene_yaml(points=POINTS_MM) -> str:
    """The small world as a scene file (mm), for command-line tests."""
    lines = [
        "name: small-world",
        "length_unit: mm",
        "bounds: {min: [0, 0, 0], max: [60, 40, 30]}",
        "obstacles:",
        "  - {name: W1, box: {min: [18, 0, 0], max: [24, 28, 22]}}",
        "  - {name: P1, cylinder: {radius: 3, length: 25}, pose: {xyz: [40, 20, 12.5]}}",
        "  - {name: cup-south, box: {min: [49, 27, 0], max: [59, 28, 10]}}",
        "  - {name: cup-north, box: {min: [49, 36, 0], max: [59, 37, 10]}}",
        "  - {name: cup-west, box: {min: [49, 28, 0], max: [50, 36, 10]}}",
        "  - {name: cup-east, box: {min: [58, 28, 0], max: [59, 36, 10]}}",
        "  - {name: cup-lid, box: {min: [49, 27, 10], max: [59, 37, 11]}}",
        "points:",
    ]
    lines += [f"  {name}: [{x}, {y}, {z}]" for name, (x, y, z) in points.items()]
    return "\n".join(lines) + "\n"
