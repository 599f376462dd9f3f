"""Sampling gripper configurations in SE(3) (paper 002 §IV-A, Fig. 4).

* **uniform**: positions uniform in a workspace box;
* **guided** (user-guided heuristic sampling): the surgeon gives a probable
  retraction path, a straight line from the grasp to an estimated final
  position, or a polyline through waypoints; positions are drawn in a
  neighbourhood of it (gaussian, or uniform in a tube), uniformly along its
  length.

Orientations: the grasp's orientation turned by a rotation drawn uniformly
(Haar measure) from the ball of rotations of angle at most ``max_rotation``;
the local optimisation then relaxes each sample's rotation.

Samples are ordered for warm starts: a greedy nearest-neighbour tour from
the grasp, so consecutive equilibria are close and each solve starts near
its answer.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation
from surgiplan.geometry.transforms import canonical_quaternion

from .settings import SamplingModel


def rotations_in_ball(rng: np.random.Generator, n: int, max_angle: float) -> Rotation:
    """``n`` rotations uniform in SO(3) restricted to angles <= ``max_angle`` (rad).

    The Haar measure's angle density is proportional to 1 - cos(theta); its
    CDF, (theta - sin theta) / pi, is inverted numerically on the restricted range.
    """
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    if max_angle <= 0:
        return Rotation.from_rotvec(np.zeros((n, 3)))
    grid = np.linspace(0.0, max_angle, 2049)
    cdf = grid - np.sin(grid)
    angles = np.interp(rng.uniform(0.0, cdf[-1], size=n), cdf, grid)
    return Rotation.from_rotvec(axes * angles[:, None])


def guide_polyline(grasp: np.ndarray, waypoints, goal: np.ndarray | None) -> np.ndarray:
    """The surgeon's path (k, 3): the grasp position, the waypoints, then the goal position."""
    points = [np.asarray(grasp[:3], float), *[np.asarray(w, float) for w in waypoints]]
    if goal is not None:
        points.append(np.asarray(goal[:3], float))
    return np.array(points)


def _along(polyline: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    lengths = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    s = fractions * cumulative[-1]
    return np.column_stack([np.interp(s, cumulative, polyline[:, k]) for k in range(3)])


def sample_positions(settings: SamplingModel, rng: np.random.Generator, n: int, polyline: np.ndarray | None):
    """``n`` gripper positions (n, 3) m."""
    if settings.kind == "uniform":
        return rng.uniform(np.asarray(settings.region.min), np.asarray(settings.region.max), size=(n, 3))
    centres = _along(polyline, rng.uniform(0.0, 1.0, size=n))
    if settings.neighbourhood == "gaussian":
        return centres + rng.normal(scale=settings.spread, size=(n, 3))
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    radii = settings.spread * rng.uniform(0.0, 1.0, size=n) ** (1.0 / 3.0)  # uniform in the ball
    return centres + directions * radii[:, None]


def sample_configurations(
    settings: SamplingModel,
    grasp: np.ndarray,
    space,
    seed_offset: int = 0,
    goal: np.ndarray | None = None,
) -> np.ndarray:
    """``settings.samples`` configurations (s, 7) inside the space's limits, for the grasp ``grasp`` (7,)."""
    rng = np.random.default_rng([settings.seed, seed_offset])
    polyline = guide_polyline(grasp, settings.waypoints, goal) if settings.kind == "guided" else None
    base = Rotation.from_quat(grasp[3:])
    found: list[np.ndarray] = []
    total = 0
    for _ in range(100):  # rejection of positions outside the workspace bounds
        n = 2 * (settings.samples - total) + 16
        positions = sample_positions(settings, rng, n, polyline)
        rotations = rotations_in_ball(rng, n, settings.max_rotation) * base
        q = np.concatenate([positions, canonical_quaternion(rotations.as_quat())], axis=1)
        q = q[space.within_limits(q)]
        found.append(q[: settings.samples - total])
        total += len(found[-1])
        if total >= settings.samples:
            break
    q = np.concatenate(found) if found else np.empty((0, 7))
    if len(q) < settings.samples:
        raise ValueError(
            "cannot draw the samples inside the workspace bounds: the sampling region lies (almost) outside them"
        )
    return q


def tour_order(space, start: np.ndarray, q: np.ndarray) -> np.ndarray:
    """A greedy nearest-neighbour tour of ``q`` from ``start`` in the space's metric (indices)."""
    remaining = np.ones(len(q), dtype=bool)
    order = np.empty(len(q), dtype=np.int64)
    current = np.asarray(start, float)
    for k in range(len(q)):  # each step one vectorised distance evaluation
        d = np.where(remaining, space.distance(current[None, :], q), np.inf)
        nearest = int(np.argmin(d))
        order[k] = nearest
        remaining[nearest] = False
        current = q[nearest]
    return order
