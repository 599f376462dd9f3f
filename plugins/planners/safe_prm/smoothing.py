"""Smoothing a path inside its certified clearance corridor, as a QP solved with OSQP.

Paper 000 §5 admits that the K-S roadmap's (repaired) paths are not smooth.
This stage shortens them and reduces their curvature without giving up any
clearance guarantee:

1. The path is densified; at each point q_i the body's clearance c_i is
   measured and its required margin m_i assigned (d_thresh on safe
   stretches; on a critical stretch the clearance the roadmap path had
   there, so smoothing never makes a critical passage tighter).
2. Each point may move inside a box of the configuration space in which no
   body point travels farther than the slack c_i - m_i, less half the
   spacing to its neighbours (:meth:`Space.corridor_halfwidths`): whatever
   the QP does, every waypoint keeps its margin, and since the clearance is
   1-Lipschitz the motions between neighbours keep it too.
3. The QP minimises  alpha * sum |q_{i+1} - q_i|^2 + beta * sum |q_{i+1} - 2 q_i + q_{i-1}|^2
   (in the space's metric coordinates) with the end points fixed: the first
   term shortens and spaces the points evenly, the second straightens them.
4. The motions between smoothed waypoints are re-verified with the space's
   certified check against their margins; where one fails, the boxes at
   its ends shrink and the QP is solved again. What comes out is certified,
   or the original path is returned unchanged.
5. Douglas-Peucker thinning (each kept chord re-verified) removes the
   redundant waypoints of straight stretches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from surgiplan.paths import thin
from surgiplan.spaces.base import Space


@dataclass
class SmoothingResult:
    path: np.ndarray
    margins: np.ndarray  # per segment of ``path`` (m)
    smoothed: bool
    rounds: int
    message: str = ""


def _difference(n: int, order: int) -> sp.csr_matrix:
    d = sp.eye(n, format="csr")
    for _ in range(order):
        d = (d[1:] - d[:-1]).tocsr()
    return d


class _CorridorQP:
    """The smoothing QP over a fixed densified path; rounds only change the corridor bounds.

    Variables are the displacements from the path in metric coordinates
    (z = q * weights), so OSQP's absolute tolerance is in metres. OSQP is set
    up once and warm-started when the bounds shrink.
    """

    def __init__(self, points: np.ndarray, weights: np.ndarray, alpha: float, beta: float) -> None:
        import osqp

        n, dim = points.shape
        self.shape = points.shape
        self.scale = np.tile(weights, n)
        self.z0 = points.reshape(-1) * self.scale
        eye_dim = sp.eye(dim, format="csc")
        d1 = sp.kron(_difference(n, 1), eye_dim, format="csc")
        d2 = sp.kron(_difference(n, 2), eye_dim, format="csc") if n >= 3 else sp.csc_matrix((0, n * dim))
        p = (alpha * (d1.T @ d1) + beta * (d2.T @ d2)).tocsc()
        self.solver = osqp.OSQP()
        self.solver.setup(
            sp.triu(p, format="csc"),
            p @ self.z0,
            sp.eye(n * dim, format="csc"),
            np.zeros(n * dim),
            np.zeros(n * dim),
            verbose=False,
            eps_abs=1e-8,
            eps_rel=1e-7,
            polishing=True,
            max_iter=10000,
            warm_starting=True,
        )

    def solve(self, lower: np.ndarray, upper: np.ndarray) -> np.ndarray | None:
        lo = lower.reshape(-1) * self.scale - self.z0
        hi = upper.reshape(-1) * self.scale - self.z0
        self.solver.update(l=lo, u=hi)
        result = self.solver.solve(raise_error=False)
        if "solved" not in str(getattr(result.info, "status", "")).lower() or result.x is None:
            return None
        dz = np.clip(result.x, lo, hi)  # OSQP meets bounds to its tolerance only
        return ((self.z0 + dz) / self.scale).reshape(self.shape)


def _verified(space: Space, path: np.ndarray, margins: np.ndarray) -> np.ndarray:
    """Per segment: certified to keep its margin (0 means collision-free)."""
    ok = np.zeros(len(path) - 1, dtype=bool)
    for margin in np.unique(margins):
        sel = margins == margin
        ok[sel] = space.motion_is_clear(path[:-1][sel], path[1:][sel], float(margin))
    return ok


def smooth_in_corridor(
    space: Space,
    path: np.ndarray,
    segment_margins: np.ndarray,
    *,
    resolution: float,
    alpha: float = 1.0,
    beta: float = 4.0,
    max_rounds: int = 12,
    thinning: float | None = None,
) -> SmoothingResult:
    """Shorten and straighten ``path`` keeping each segment's margin (m), certified.

    ``segment_margins[i]`` is the clearance the motion from waypoint i to
    i+1 must keep (0: collision-free). A waypoint keeps the larger margin of
    its two segments. ``resolution``: the tip spacing (m) of the densified
    path the QP works on; ``thinning``: the Douglas-Peucker tolerance (m) for
    the result, or None to keep every point.
    """
    path = np.atleast_2d(np.asarray(path, dtype=float))
    segment_margins = np.asarray(segment_margins, dtype=float)
    if len(path) < 2 or space.tip_path_length(path) <= resolution:
        return SmoothingResult(path, segment_margins, False, 0, "nothing to smooth")

    # densify, carrying each original segment's margin onto its pieces
    pieces = [path[:1]]
    margins = []
    for i in range(len(path) - 1):
        dense = space.densify(path[i : i + 2], resolution)[1:]
        pieces.append(dense)
        margins.append(np.full(len(dense), segment_margins[i]))
    dense = np.concatenate(pieces)
    seg_margins = np.concatenate(margins)
    point_margins = np.maximum(
        np.concatenate([seg_margins[:1], seg_margins]), np.concatenate([seg_margins, seg_margins[-1:]])
    )

    slack = np.minimum(space.clearance(dense) - point_margins, space.workspace_slack(dense))
    # Between two waypoints the clearance may dip by up to half their spacing (it is 1-Lipschitz), so
    # a waypoint moving less than its slack minus half the spacing to its farther neighbour keeps the
    # motions on both sides clear too: the first QP solution then passes re-verification.
    step = space.motion_speed_bound(dense[:-1], dense[1:])
    spacing = np.maximum(np.concatenate([step[:1], step]), np.concatenate([step, step[-1:]]))
    slack = np.maximum(slack - 0.5 * spacing, 0.0)
    halfwidths = space.corridor_halfwidths(dense, slack)
    shrink = np.ones(len(dense))
    qp = _CorridorQP(dense, np.asarray(space.coordinate_weights, dtype=float), alpha, beta)
    for round_ in range(1, max_rounds + 1):
        width = halfwidths * shrink[:, None]
        lower = np.maximum(dense - width, space.low)
        upper = np.minimum(dense + width, space.high)
        lower[[0, -1]] = dense[[0, -1]]
        upper[[0, -1]] = dense[[0, -1]]
        candidate = qp.solve(lower, upper)
        if candidate is None:
            return SmoothingResult(path, segment_margins, False, round_, "the QP did not solve")
        ok = _verified(space, candidate, seg_margins)
        if np.all(ok):
            out_margins = seg_margins
            if thinning is not None:
                candidate, out_margins = thin(space, candidate, seg_margins, thinning)
            return SmoothingResult(candidate, out_margins, True, round_)
        bad = np.flatnonzero(~ok)
        shrink[bad] *= 0.5
        shrink[bad + 1] *= 0.5
    return SmoothingResult(
        path, segment_margins, False, max_rounds, "smoothed motions could not all be certified; kept the roadmap path"
    )


def raise_clearance(
    space: Space, points: np.ndarray, movable: np.ndarray, *, step: float, target: float, iterations: int = 30
) -> np.ndarray:
    """Move the ``movable`` points of a path up the clearance field, across the path's direction.

    In a critical region (paper 000: a passage with no safe detour) the path
    cannot keep d_thresh, but it can keep as much clearance as the passage
    allows: each movable point climbs the body's clearance (numerical
    gradient in the space's metric coordinates, with the component along the
    path removed so points do not bunch up) by steps that halve whenever one
    would not increase its clearance, and stops once it reaches ``target``
    (d_thresh: more is not needed, and climbing further would wander off into
    open space). The result's clearance is never lower at any point; callers
    certify the motions between the moved points.
    """
    points = np.array(points, dtype=float)
    index = np.flatnonzero(movable)
    if not index.size:
        return points
    weights = np.asarray(space.coordinate_weights, dtype=float)
    dim = points.shape[1]
    h = 1e-6  # metres in metric coordinates
    step_size = np.full(index.size, float(step))
    current = space.clearance(points[index])
    for _ in range(iterations):
        q = points[index]
        probes = []
        for k in range(dim):
            e = np.zeros(dim)
            e[k] = h / weights[k]
            probes += [q + e, q - e]
        c = space.clearance(np.concatenate(probes)).reshape(2 * dim, -1)
        gradient = ((c[0::2] - c[1::2]) / (2 * h)).T  # (m, dim) in metric coordinates
        tangent = (points[np.minimum(index + 1, len(points) - 1)] - points[np.maximum(index - 1, 0)]) * weights
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
        gradient -= np.sum(gradient * tangent, axis=1, keepdims=True) * tangent
        norm = np.linalg.norm(gradient, axis=1, keepdims=True)
        direction = np.where(norm > 1e-12, gradient / np.maximum(norm, 1e-300), 0.0)
        candidate = np.clip(q + direction * step_size[:, None] / weights, space.low, space.high)
        gained = space.clearance(candidate)
        better = (gained > current) & space.within_limits(candidate) & space.in_workspace(candidate)
        better &= current < target
        points[index[better]] = candidate[better]
        current = np.where(better, gained, current)
        step_size = np.where(better | (current >= target), step_size, 0.5 * step_size)
        step_size = np.where(current >= target, 0.0, step_size)
        if np.all(step_size < 1e-6):  # micrometre steps: the clearance has peaked
            break
    return points


def shortcut(space: Space, path: np.ndarray, segment_margins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Greedy shortcutting: from each kept waypoint jump to the farthest one reachable by a certified motion.

    A chord replacing segments i..j-1 must keep the largest of their margins,
    so a shortcut never trades a safe stretch for a tighter one. One batched
    motion check per kept waypoint. Returns the path and its segment margins.
    """
    path = np.atleast_2d(path)
    n = len(path)
    if n < 3:
        return path, np.asarray(segment_margins, float)
    # running maximum of the margins from i to each later j
    keep = [0]
    margins = []
    i = 0
    while i < n - 1:
        later = np.arange(i + 2, n)
        best = i + 1
        if later.size:
            need = np.maximum.accumulate(segment_margins[i:])[later - i - 1]
            ok = np.zeros(later.size, dtype=bool)
            for margin in np.unique(need):
                sel = need == margin
                ok[sel] = space.motion_is_clear(np.repeat(path[i][None], sel.sum(), 0), path[later[sel]], float(margin))
            if np.any(ok):
                best = int(later[np.flatnonzero(ok)[-1]])
        margins.append(float(np.max(segment_margins[i:best])))
        keep.append(best)
        i = best
    return path[keep], np.array(margins)
