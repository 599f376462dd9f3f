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
result stays exact while far obstacles cost almost nothing.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .geometry import primitives as prim
from .geometry.shapes import Obstacle


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

    def __post_init__(self) -> None:
        self.bounds_min = np.asarray(self.bounds_min, dtype=float).reshape(3)
        self.bounds_max = np.asarray(self.bounds_max, dtype=float).reshape(3)
        if np.any(self.bounds_max <= self.bounds_min):
            raise ValueError(f"empty workspace bounds: min {self.bounds_min} max {self.bounds_max}")
        self.points = {k: np.asarray(v, dtype=float).reshape(3) for k, v in self.points.items()}
        names = [o.name for o in self.obstacles]
        duplicates = sorted({n for n in names if names.count(n) > 1})
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
        for obstacle in self.obstacles:
            if obstacle.name == name:
                return obstacle
        raise KeyError(name)

    def with_bounds(self, bounds_min, bounds_max) -> Scene:
        """The same obstacles and points in other workspace bounds."""
        return Scene(bounds_min, bounds_max, self.obstacles, dict(self.points), self.name)

    def in_bounds(self, points) -> np.ndarray:
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        return np.all((points >= self.bounds_min) & (points <= self.bounds_max), axis=1)

    # ------------------------------------------------------------------ distances
    def signed_distance(self, points, cutoff: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (m) from points (N, 3) to the nearest obstacle.

        Returns ``(distance, index)``; ``index`` is the obstacle's position in
        :attr:`obstacles` (``-1`` and ``inf`` when there are none). Distances
        below ``cutoff`` are exact; above it, the value is a lower bound that is
        itself at least ``cutoff`` (all a clear/not-clear decision needs).
        """
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        lower = [
            np.linalg.norm(points - centre, axis=1) - radius
            for centre, radius in (o.bounding_sphere for o in self.obstacles)
        ]
        return self._nearest(lower, lambda k, sel: self.obstacles[k].sdf(points[sel]), len(points), cutoff)

    def segment_distance(self, a, b, cutoff: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Minimum signed distance (m) to the obstacles along segments ``a[i] → b[i]``.

        Positive values are the exact segment-to-obstacle distance. Returns
        ``(distance, index of the nearest obstacle)``; ``cutoff`` as in
        :meth:`signed_distance`.
        """
        a = np.asarray(a, dtype=float).reshape(-1, 3)
        b = np.asarray(b, dtype=float).reshape(-1, 3)
        a, b = np.broadcast_arrays(a, b)
        lower = [
            prim.point_segment_distance(centre, a, b) - radius
            for centre, radius in (o.bounding_sphere for o in self.obstacles)
        ]
        return self._nearest(lower, lambda k, sel: self.obstacles[k].segment_sd(a[sel], b[sel]), len(a), cutoff)

    def _nearest(self, lower: Sequence[np.ndarray], exact, n: int, cutoff: float):
        best = np.full(n, np.inf)
        index = np.full(n, -1, dtype=np.int64)
        if not self.obstacles:
            return best, index
        floor = np.full(n, np.inf)  # smallest lower bound among obstacles skipped
        # nearest-looking obstacles first, so later ones are pruned more often
        order = np.argsort([np.median(lb) for lb in lower])
        for k in order:
            lb = lower[k]
            need = lb < np.minimum(best, cutoff)
            skipped = ~need
            floor[skipped] = np.minimum(floor[skipped], lb[skipped])
            if not np.any(need):
                continue
            sel = np.flatnonzero(need)
            d = exact(k, sel)
            better = d < best[sel]
            best[sel[better]] = d[better]
            index[sel[better]] = k
        # where nothing was computed exactly (all beyond cutoff) report the bound
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
        return hashlib.sha256(json.dumps(self.spec(), sort_keys=True).encode()).hexdigest()

    def describe_point(self, point) -> str:
        """``(x, y, z) mm`` for messages."""
        return "(" + ", ".join(f"{1000 * c:.4g}" for c in np.asarray(point).reshape(3)) + ") mm"


def resolve_point(scene: Scene, value, points: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
    """A point given by name or by coordinates (already in metres)."""
    points = scene.points if points is None else points
    if isinstance(value, str):
        return points[value]
    return np.asarray(value, dtype=float).reshape(3)
