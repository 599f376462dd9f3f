"""The scene: workspace bounds, named obstacles and named points of interest.

All queries are batched over numpy arrays and answer in metres:

* :meth:`Scene.signed_distance` — distance from points to the nearest
  obstacle (negative inside) and which obstacle it is;
* :meth:`Scene.segment_distance` — the minimum signed distance along straight
  segments: the exact clearance of a point moving along them, and, minus r,
  of a sphere of radius r (the swept volume is a capsule);
* :meth:`Scene.is_free` / :meth:`Scene.is_motion_clear` — the decisions
  planners need, *certified*: a motion reported clear with margin m keeps a
  clearance of at least m at every instant, not only at sampled points.

The workspace bounds limit where configurations may be; they are not
obstacles and do not count toward clearance.

Distances come from exact closed forms for the primitives (cross-checked
against coal in the tests) and from coal for meshes. A broad phase on
bounding spheres skips obstacles that cannot be the nearest one, so the
result stays exact while far obstacles cost almost nothing. A scene of
primitives only answers each batch in one compiled call
(``surgiplan.geometry.compiled``); with a mesh, the vectorised groups.
"""

from __future__ import annotations

import hashlib
import json
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .geometry import boxes
from .geometry import primitives as prim
from .geometry.groups import VECTORISED as COMPILED
from .geometry.groups import ShapeGroup, centre_inside, group_obstacles
from .geometry.shapes import Obstacle
from .units import LENGTH_UNITS


def meets_margin(clearance, margin: float) -> np.ndarray:
    """``clearance > 0`` when ``margin`` is 0 (touching is a collision), else ``clearance >= margin``."""
    clearance = np.asarray(clearance)
    return clearance > 0.0 if margin <= 0.0 else clearance >= margin


@dataclass
class Scene:
    """Workspace bounds (m), obstacles and named points (m)."""

    bounds_min: np.ndarray
    bounds_max: np.ndarray
    obstacles: list[Obstacle] = field(default_factory=list)
    points: dict[str, np.ndarray] = field(default_factory=dict)
    name: str = "scene"
    #: the length unit messages about this scene use (its file's, or the pipeline's); everything else is SI
    unit: str = "mm"

    def __post_init__(self) -> None:
        self.bounds_min = np.asarray(self.bounds_min, dtype=float).reshape(3)
        self.bounds_max = np.asarray(self.bounds_max, dtype=float).reshape(3)
        if np.any(self.bounds_max <= self.bounds_min):
            raise ValueError(f"empty workspace bounds: min {self.bounds_min} max {self.bounds_max}")
        self.points = {k: np.asarray(v, dtype=float).reshape(3) for k, v in self.points.items()}
        names = [o.name for o in self.obstacles]
        duplicates = sorted(n for n, times in Counter(names).items() if times > 1)  # linear: 10,000 voxel boxes
        if duplicates:
            raise ValueError(f"obstacle names must be unique; repeated: {', '.join(duplicates)}")

    # ------------------------------------------------------------------ basics
    @property
    def obstacle_names(self) -> list[str]:
        return [o.name for o in self.obstacles]

    @property
    def extent(self) -> np.ndarray:
        return self.bounds_max - self.bounds_min

    def obstacle(self, name: str) -> Obstacle:
        """The obstacle called ``name``; :class:`KeyError` when the scene has none of that name."""
        for obstacle in self.obstacles:
            if obstacle.name == name:
                return obstacle
        raise KeyError(name)

    def with_bounds(self, bounds_min, bounds_max) -> Scene:
        """The same obstacles and points in other workspace bounds."""
        return Scene(bounds_min, bounds_max, self.obstacles, dict(self.points), self.name, self.unit)

    def in_bounds(self, points) -> np.ndarray:
        """Per point (an (N, 3) array or one [x, y, z], m), whether it lies inside the workspace bounds (boundary
        included): a bool array of N."""
        return boxes.inside(np.asarray(points, dtype=float).reshape(-1, 3), self.bounds_min, self.bounds_max)

    # ------------------------------------------------------------------ distances
    def _prepare(self) -> None:
        """Bounding spheres, shape groups and (primitives only) the compiled kernels' packed arrays and tree,
        built once (obstacles do not change)."""
        if getattr(self, "_packed_ready", False):
            return
        self._prepare_groups()
        # primitives only: one compiled call per batch (geometry.compiled), else the vectorised groups
        self._packed = self._tree = None
        if self.obstacles and all(type(o) in COMPILED for o in self.obstacles):
            from .geometry import bvh, compiled

            self._packed = compiled.pack(self.obstacles, self._centres, self._radii)
            if len(self.obstacles) >= bvh.MIN_OBSTACLES:
                # many obstacles: a tree over their world boxes, so a query costs what is near it
                self._tree = bvh.build(self._packed[6], self._packed[7], self._radii)
        self._packed_ready = True

    def prepare(self) -> None:
        """Build the scene's distance structures now rather than at its first large query: the compiled kernels
        (numba, from its cache) and, for many obstacles, the tree. A stage calls it before its timed sections;
        a few-point check before it (a pipeline's validation) is answered without them."""
        if self.obstacles:
            self._prepare()

    def _prepare_groups(self) -> None:
        """Bounding spheres and shape groups (numpy only), built once."""
        if getattr(self, "_groups", None) is not None:
            return
        spheres = [o.bounding_sphere for o in self.obstacles]
        self._centres = np.array([c for c, _ in spheres]).reshape(-1, 3)
        self._radii = np.array([r for _, r in spheres], dtype=float)
        # the distance to a point inside an obstacle bounds the distance to the obstacle from above
        self._upper_ok = np.array([centre_inside(o) for o in self.obstacles], dtype=bool)
        self._groups = group_obstacles(self.obstacles)

    def __getstate__(self):
        state = self.__dict__.copy()
        for cached in ("_groups", "_centres", "_radii", "_upper_ok", "_packed", "_tree", "_packed_ready"):
            state.pop(cached, None)
        return state

    def signed_distance(self, points, cutoff: float | np.ndarray = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (m) from points (N, 3) to the nearest obstacle.

        Returns ``(distance, index)``; ``index`` is the obstacle's position in
        :attr:`obstacles` (``-1`` and ``inf`` when there are none). Distances
        below ``cutoff`` are exact; above it, the value is a lower bound that is
        itself at least ``cutoff`` (all a clear/not-clear decision needs), and
        the index is then not necessarily the nearest obstacle.
        """
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        return self._nearest(points, None, cutoff)

    def segment_distance(self, a, b, cutoff: float | np.ndarray = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Minimum signed distance (m) to the obstacles along segments ``a[i] → b[i]``.

        Positive values are the exact segment-to-obstacle distance. Returns
        ``(distance, index of the nearest obstacle)``; ``cutoff`` as in
        :meth:`signed_distance`.
        """
        a = np.asarray(a, dtype=float).reshape(-1, 3)
        b = np.asarray(b, dtype=float).reshape(-1, 3)
        a, b = np.broadcast_arrays(a, b)
        return self._nearest(a, b, cutoff)

    _CHUNK = 1_000_000  # (point, obstacle) pairs per block
    #: batches of at most this many queries, asked before anything needed the compiled kernels (a pipeline's
    #: validation: its start and goal), are answered by the vectorised groups: numba is not imported for them
    FEW = 64

    def _nearest(self, a: np.ndarray, b: np.ndarray | None, cutoff) -> tuple[np.ndarray, np.ndarray]:
        n = len(a)
        if not self.obstacles or n == 0:
            return np.full(n, np.inf), np.full(n, -1, dtype=np.int64)
        if n <= self.FEW and not getattr(self, "_packed_ready", False):
            self._prepare_groups()  # the same exact closed forms, numpy's (tests/test_compiled.py compares them)
        else:
            self._prepare()
        if getattr(self, "_tree", None) is not None:
            from .geometry import bvh

            return bvh.distances(self._packed, self._tree, a, b, cutoff)
        if getattr(self, "_packed", None) is not None:
            from .geometry import compiled

            return compiled.distances(self._packed, a, b, cutoff)
        cutoff = np.broadcast_to(np.asarray(cutoff, dtype=float), (n,))
        block = max(1, self._CHUNK // len(self.obstacles))
        if n > block:
            parts = [
                self._nearest(a[s : s + block], None if b is None else b[s : s + block], cutoff[s : s + block])
                for s in range(0, n, block)
            ]
            return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
        # broad phase on bounding spheres: lower bounds for every pair, an upper bound per query
        if b is None:
            centre_distance = np.linalg.norm(a[:, None, :] - self._centres[None], axis=2)
        else:
            centre_distance = prim.point_segment_distance(self._centres[None], a[:, None, :], b[:, None, :])
        lower = centre_distance - self._radii
        upper = np.min(np.where(self._upper_ok, centre_distance, np.inf), axis=1)
        need = lower < np.minimum(upper, cutoff)[:, None]
        exact = np.full(lower.shape, np.inf)
        # vectorised groups first (self._groups lists one-obstacle groups, e.g. meshes, last);
        # what they find prunes the costly one-at-a-time obstacles further
        for group in self._groups:
            if len(group.members) == 1 and not isinstance(group, ShapeGroup):
                best_so_far = np.min(exact, axis=1)
                need[:, group.members[0]] &= lower[:, group.members[0]] < np.minimum(best_so_far, cutoff)
            rows, cols = np.nonzero(need[:, group.members])
            if not rows.size:
                continue
            if b is None:
                d = group.sdf(a[rows], cols)
            else:
                d = group.segment_sd(a[rows], b[rows], cols)
            exact[rows, group.members[cols]] = d
        index = np.argmin(exact, axis=1)
        best = exact[np.arange(n), index]
        # pairs skipped by the broad phase are at least their lower bound away
        floor = np.min(np.where(need, np.inf, lower), axis=1)
        index = np.where(np.isfinite(best), index, -1)
        return np.minimum(best, floor), index

    # ------------------------------------------------------------------ decisions
    def clearance(self, points, radius: float = 0.0) -> np.ndarray:
        """Clearance (m) of spheres of ``radius`` centred at the points."""
        return self.signed_distance(points)[0] - radius

    def is_free(self, points, radius: float = 0.0, margin: float = 0.0) -> np.ndarray:
        """Whether spheres of ``radius`` at the points keep ``margin`` from every obstacle."""
        d, _ = self.signed_distance(points, cutoff=radius + margin + 1e-12)
        return meets_margin(d - radius, margin)

    def motion_clearance(self, a, b, radius: float = 0.0) -> np.ndarray:
        """Exact minimum clearance (m) of a sphere of ``radius`` moving straight from a to b."""
        return self.segment_distance(a, b)[0] - radius

    def is_motion_clear(self, a, b, radius: float = 0.0, margin: float = 0.0) -> np.ndarray:
        """Certified: True only if the moving sphere keeps ``margin`` at every instant."""
        d, _ = self.segment_distance(a, b, cutoff=radius + margin + 1e-12)
        return meets_margin(d - radius, margin)

    def body_distance(self, parts: Sequence, transforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance (m) from a rigid body of coal geometries to the obstacles, per pose.

        ``parts``: sequence of ``(coal geometry, 4x4 transform in the body frame)``;
        ``transforms``: (N, 4, 4) body poses in the world. Returns the minimum
        signed distance over parts and obstacles, and the nearest obstacle index.
        coal's value is used as is: exact when positive, its penetration depth
        estimate when negative.
        """
        import coal

        transforms = np.asarray(transforms, dtype=float).reshape(-1, 4, 4)
        n = len(transforms)
        best = np.full(n, np.inf)
        index = np.full(n, -1, dtype=np.int64)
        request = coal.DistanceRequest()
        result = coal.DistanceResult()
        obstacle_geometry = [(o.coal_geometry(), o.coal_transform()) for o in self.obstacles]
        for i in range(n):
            for geometry, local in parts:
                world = transforms[i] @ local
                placed = coal.Transform3s(world[:3, :3], world[:3, 3])
                for k, (og, ot) in enumerate(obstacle_geometry):
                    result.clear()
                    d = coal.distance(geometry, placed, og, ot, request, result)
                    if d < best[i]:
                        best[i] = d
                        index[i] = k
        return best, index

    # ------------------------------------------------------------------ identity
    def spec(self) -> dict:
        """Canonical SI description; two scenes with the same spec are the same scene."""
        return {
            "bounds": {"min": self.bounds_min.tolist(), "max": self.bounds_max.tolist()},
            "obstacles": [o.spec() for o in self.obstacles],
            "points": {k: v.tolist() for k, v in sorted(self.points.items())},
        }

    def digest(self) -> str:
        """The SHA-256 (hex) of :meth:`spec`: equal digests mean the same scene, in SI, whatever file it came from."""
        return hashlib.sha256(json.dumps(self.spec(), sort_keys=True).encode()).hexdigest()

    def describe_point(self, point) -> str:
        """``(x, y, z) mm`` for messages, in the scene's :attr:`unit`."""
        k = 1.0 / LENGTH_UNITS.get(self.unit, 1e-3)
        return "(" + ", ".join(f"{k * c:.4g}" for c in np.asarray(point).reshape(3)) + f") {self.unit}"

    def describe_length(self, value: float) -> str:
        """``3.5 mm`` for messages, in the scene's :attr:`unit`."""
        return f"{value / LENGTH_UNITS.get(self.unit, 1e-3):.3g} {self.unit}"


def resolve_point(scene: Scene, value, points: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
    """A point given by name or by coordinates (already in metres)."""
    points = scene.points if points is None else points
    if isinstance(value, str):
        return points[value]
    return np.asarray(value, dtype=float).reshape(3)
