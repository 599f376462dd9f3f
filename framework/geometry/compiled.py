"""The scene's distance queries compiled (numba), for scenes made of the primitive shapes.

The same exact distances as :mod:`.primitives` (box, sphere, cylinder, capsule; the same formulas, point by
point instead of array by array) and the same broad phase as :meth:`surgiplan.scene.Scene._nearest` (bounding
spheres give lower bounds; an obstacle whose bound cannot beat the nearest found so far, or the cutoff, is
skipped), in one call per batch: a planner's thousands of small queries (a roadmap's milestones and edges, a
query's two ends) cost microseconds instead of the dozens of numpy calls each batch takes vectorised.
``tests/test_geometry.py`` checks them against the numpy functions and coal.

Compiled when this module is imported (for the argument types the scene passes; cached on disk by numba: the
first import on a machine compiles, later ones load), which the scene does when it prepares its obstacles,
before any planner times anything.
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np
from numba import njit

from ..threads import cpu_threads, in_parallel

#: obstacle kinds, in the ``kinds`` array
BOX, SPHERE, CYLINDER, CAPSULE = 0, 1, 2, 3

_EPS = 1e-300
_TINY = 1e-24
_GOLDEN_ITERATIONS = 80
_BRACKET_TOLERANCE = 1e-10
_INV_PHI = (np.sqrt(5.0) - 1.0) / 2.0

_FLAGS = {"cache": True, "nogil": True, "error_model": "numpy"}
#: a batch of at least this many queries is answered in halves at once (:func:`surgiplan.threads.in_parallel`),
#: each half a few hundred microseconds: far more than handing one to another thread
SPLIT_AT = 1024


@njit(**_FLAGS)
def _point_segment(px, py, pz, ax, ay, az, bx, by, bz):
    """Distance from a point to the segment a→b (as ``primitives.point_segment_distance``)."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    length_sq = dx * dx + dy * dy + dz * dz
    t = 0.0
    if length_sq > _EPS:
        t = ((px - ax) * dx + (py - ay) * dy + (pz - az) * dz) / length_sq
        t = min(max(t, 0.0), 1.0)
    cx, cy, cz = px - (ax + t * dx), py - (ay + t * dy), pz - (az + t * dz)
    return np.sqrt(cx * cx + cy * cy + cz * cz)


@njit(**_FLAGS)
def _segment_segment(p1, q1, p2, q2):
    """Distance between segments p1→q1 and p2→q2 (Ericson 2005, §5.1.9; as ``primitives.segment_segment_distance``)."""
    d1 = q1 - p1
    d2 = q2 - p2
    r = p1 - p2
    a = d1 @ d1
    e = d2 @ d2
    f = d2 @ r
    c = d1 @ r
    b = d1 @ d2
    a_safe = max(a, _TINY)
    e_safe = max(e, _TINY)
    denom = a * e - b * b
    s = 0.0
    if denom > _TINY * max(a * e, _TINY):
        s = min(max((b * f - c * e) / (denom if denom > 0 else 1.0), 0.0), 1.0)
    t = (b * s + f) / e_safe
    if t < 0.0:
        s = min(max(-c / a_safe, 0.0), 1.0)
    elif t > 1.0:
        s = min(max((b - c) / a_safe, 0.0), 1.0)
    t = min(max(t, 0.0), 1.0)
    if a <= _TINY:
        s = 0.0
        t = min(max(f / e_safe, 0.0), 1.0)
    elif e <= _TINY:
        s = min(max(-c / a_safe, 0.0), 1.0)
    if e <= _TINY:
        t = 0.0
    diff = (p1 + s * d1) - (p2 + t * d2)
    return np.sqrt(diff @ diff)


@njit(**_FLAGS)
def _box_sdf(x, y, z, hx, hy, hz):
    qx, qy, qz = abs(x) - hx, abs(y) - hy, abs(z) - hz
    ox, oy, oz = max(qx, 0.0), max(qy, 0.0), max(qz, 0.0)
    return np.sqrt(ox * ox + oy * oy + oz * oz) + min(max(qx, max(qy, qz)), 0.0)


@njit(**_FLAGS)
def _box_segment(a, b, h):
    """Minimum signed distance to a centred box along a→b (as ``primitives.box_segment_sd``, exact)."""
    d = b - a
    knots = np.empty(8)
    knots[0], knots[7] = 0.0, 1.0
    for k in range(3):
        lo_cross = (-h[k] - a[k]) / d[k]
        hi_cross = (h[k] - a[k]) / d[k]
        knots[1 + k] = min(max(lo_cross if np.isfinite(lo_cross) else 0.0, 0.0), 1.0)
        knots[4 + k] = min(max(hi_cross if np.isfinite(hi_cross) else 0.0, 0.0), 1.0)
    for i in range(1, 8):  # insertion sort of the eight knots
        v = knots[i]
        j = i - 1
        while j >= 0 and knots[j] > v:
            knots[j + 1] = knots[j]
            j -= 1
        knots[j + 1] = v
    unsigned = np.inf
    for piece in range(7):
        lo, hi = knots[piece], knots[piece + 1]
        mid = 0.5 * (lo + hi)
        quad_a = 0.0
        quad_b = 0.0
        for k in range(3):
            p = a[k] + mid * d[k]
            if p < -h[k] or p > h[k]:
                target = -h[k] if p < -h[k] else h[k]
                quad_a += d[k] * d[k]
                quad_b += 2.0 * d[k] * (a[k] - target)
        t = -quad_b / (2.0 * quad_a) if quad_a > 0 else mid
        t = min(max(t, lo), hi)
        total = 0.0
        for k in range(3):
            o = max(abs(a[k] + t * d[k]) - h[k], 0.0)
            total += o * o
        unsigned = min(unsigned, np.sqrt(total))
    if unsigned > 0.0:
        return unsigned
    # the segment enters the box: the interior distance is the maximum of six affine functions of t, smallest at
    # an end point or where two of them cross
    alpha = np.empty(6)
    beta = np.empty(6)
    for k in range(3):
        alpha[k], alpha[3 + k] = a[k] - h[k], -a[k] - h[k]
        beta[k], beta[3 + k] = d[k], -d[k]
    best = min(_box_sdf(a[0], a[1], a[2], h[0], h[1], h[2]), _box_sdf(b[0], b[1], b[2], h[0], h[1], h[2]))
    for j in range(6):
        for k in range(j + 1, 6):
            t = (alpha[k] - alpha[j]) / (beta[j] - beta[k])
            t = min(max(t if np.isfinite(t) else 0.0, 0.0), 1.0)
            best = min(best, _box_sdf(a[0] + t * d[0], a[1] + t * d[1], a[2] + t * d[2], h[0], h[1], h[2]))
    return best


@njit(**_FLAGS)
def _cylinder_sdf(x, y, z, radius, half_height):
    qx, qz = np.sqrt(x * x + y * y) - radius, abs(z) - half_height
    ox, oz = max(qx, 0.0), max(qz, 0.0)
    return np.sqrt(ox * ox + oz * oz) + min(max(qx, qz), 0.0)


@njit(**_FLAGS)
def _cylinder_segment(a, b, radius, half_height):
    """Golden-section search of the convex signed distance along a→b, conservative by the bracket's bound (as
    ``primitives.convex_segment_sd``)."""
    d = b - a
    length = np.sqrt(d @ d)
    lo, hi = 0.0, 1.0
    x1 = hi - _INV_PHI * (hi - lo)
    x2 = lo + _INV_PHI * (hi - lo)
    f1 = _cylinder_sdf(a[0] + x1 * d[0], a[1] + x1 * d[1], a[2] + x1 * d[2], radius, half_height)
    f2 = _cylinder_sdf(a[0] + x2 * d[0], a[1] + x2 * d[1], a[2] + x2 * d[2], radius, half_height)
    for _ in range(_GOLDEN_ITERATIONS):
        if length * (hi - lo) < 2 * _BRACKET_TOLERANCE:
            break
        if f1 <= f2:
            hi = x2
            x2, f2 = x1, f1
            x1 = hi - _INV_PHI * (hi - lo)
            f1 = _cylinder_sdf(a[0] + x1 * d[0], a[1] + x1 * d[1], a[2] + x1 * d[2], radius, half_height)
        else:
            lo = x1
            x1, f1 = x2, f2
            x2 = lo + _INV_PHI * (hi - lo)
            f2 = _cylinder_sdf(a[0] + x2 * d[0], a[1] + x2 * d[1], a[2] + x2 * d[2], radius, half_height)
    centre = 0.5 * (lo + hi)
    value = _cylinder_sdf(a[0] + centre * d[0], a[1] + centre * d[1], a[2] + centre * d[2], radius, half_height)
    ends = min(
        _cylinder_sdf(a[0], a[1], a[2], radius, half_height), _cylinder_sdf(b[0], b[1], b[2], radius, half_height)
    )
    return min(value - length * 0.5 * (hi - lo), ends)


@njit(**_FLAGS)
def _local(p, rotation, translation, out):
    """``p`` in an obstacle's frame: (p - t) R, as ``groups.ShapeGroup._local``."""
    for j in range(3):
        out[j] = (
            (p[0] - translation[0]) * rotation[0, j]
            + (p[1] - translation[1]) * rotation[1, j]
            + (p[2] - translation[2]) * rotation[2, j]
        )


@njit(**_FLAGS)
def _exact(kind, params, la, lb, segment, axis_a, axis_b):
    if kind == BOX:
        if segment:
            return _box_segment(la, lb, params)
        return _box_sdf(la[0], la[1], la[2], params[0], params[1], params[2])
    if kind == SPHERE:
        if segment:
            return _point_segment(0.0, 0.0, 0.0, la[0], la[1], la[2], lb[0], lb[1], lb[2]) - params[0]
        return np.sqrt(la @ la) - params[0]
    if kind == CYLINDER:
        if segment:
            return _cylinder_segment(la, lb, params[0], params[1])
        return _cylinder_sdf(la[0], la[1], la[2], params[0], params[1])
    axis_a[2], axis_b[2] = -params[1], params[1]  # capsule: its axis from -l/2 to l/2 on z
    if segment:
        return _segment_segment(la, lb, axis_a, axis_b) - params[0]
    return _point_segment(la[0], la[1], la[2], 0.0, 0.0, -params[1], 0.0, 0.0, params[1]) - params[0]


@njit(**_FLAGS)
def nearest(kinds, rotations, translations, params, centres, radii, low, high, a, b, segment, cutoff, distance, index):
    """The nearest obstacle's signed distance (and its index) from points ``a[i]`` (``segment`` False) or along
    segments ``a[i] → b[i]``, into ``distance`` and ``index``; as :meth:`Scene._nearest`: exact below
    ``cutoff[i]``, above it a lower bound that is itself at least the cutoff (index -1 when no obstacle was
    measured exactly).

    Broad phase: each obstacle's lower bound is the larger of its bounding sphere's and its world box's (``low``,
    ``high``; for a segment, the gap between the segment's box and it); obstacles are measured in order of that
    bound, and one whose bound cannot beat the nearest found so far (or the cutoff) is skipped."""
    m = kinds.shape[0]
    lower = np.empty(m)
    rank = np.empty(m, dtype=np.int64)
    la = np.empty(3)
    lb = np.empty(3)
    axis_a = np.zeros(3)
    axis_b = np.zeros(3)
    for i in range(a.shape[0]):
        upper = np.inf
        for o in range(m):
            # the bound of bvh._obstacle_bound, written out here: calling a shared function (returning the bound and
            # the centre's gap) made this loop 1.5-2.5x slower (20,000 points, block world and hall)
            c = centres[o]
            box_gap = 0.0
            if segment:
                gap = _point_segment(c[0], c[1], c[2], a[i, 0], a[i, 1], a[i, 2], b[i, 0], b[i, 1], b[i, 2])
                for k in range(3):
                    g = max(min(a[i, k], b[i, k]) - high[o, k], low[o, k] - max(a[i, k], b[i, k]), 0.0)
                    box_gap += g * g
            else:
                dx, dy, dz = a[i, 0] - c[0], a[i, 1] - c[1], a[i, 2] - c[2]
                gap = np.sqrt(dx * dx + dy * dy + dz * dz)
                for k in range(3):
                    g = max(a[i, k] - high[o, k], low[o, k] - a[i, k], 0.0)
                    box_gap += g * g
            # outside the world box, at least the gap to it; within it (maybe inside), only the sphere's bound
            lower[o] = max(gap - radii[o], np.sqrt(box_gap)) if box_gap > 0 else gap - radii[o]
            upper = min(upper, gap)  # every primitive contains its centre: a bound from above
            # insertion by lower bound: the likely nearest first
            j = o
            while j > 0 and lower[rank[j - 1]] > lower[o]:
                rank[j] = rank[j - 1]
                j -= 1
            rank[j] = o
        best = np.inf
        nearest_index = -1
        floor = np.inf
        for r in range(m):
            o = rank[r]
            if lower[o] >= min(upper, cutoff[i], best):
                floor = min(floor, lower[o])
                continue
            _local(a[i], rotations[o], translations[o], la)
            if segment:
                _local(b[i], rotations[o], translations[o], lb)
            value = _exact(kinds[o], params[o], la, lb, segment, axis_a, axis_b)
            if value < best:
                best, nearest_index = value, o
        distance[i] = min(best, floor)
        index[i] = nearest_index


def pack(obstacles, centres: np.ndarray, radii: np.ndarray) -> tuple | None:
    """The obstacles as the arrays :func:`nearest` takes, or None when one is not a primitive (a mesh)."""
    from .shapes import Box, Capsule, Cylinder, Sphere

    kinds, params = [], []
    for o in obstacles:
        if type(o) is Box:
            kinds.append(BOX)
            params.append(o.half_extents)
        elif type(o) is Sphere:
            kinds.append(SPHERE)
            params.append([o.radius, 0.0, 0.0])
        elif type(o) is Cylinder:
            kinds.append(CYLINDER)
            params.append([o.radius, 0.5 * o.length, 0.0])
        elif type(o) is Capsule:
            kinds.append(CAPSULE)
            params.append([o.radius, 0.5 * o.length, 0.0])
        else:
            return None
    m = len(kinds)
    kinds = np.asarray(kinds, dtype=np.int64)
    rotations = np.ascontiguousarray(np.array([o.pose.rotation for o in obstacles], dtype=float).reshape(m, 3, 3))
    translations = np.ascontiguousarray(np.array([o.pose.translation for o in obstacles], dtype=float).reshape(m, 3))
    params = np.ascontiguousarray(np.array(params, dtype=float).reshape(m, 3))
    # each obstacle's world box, exact (a mesh's vertices would lie inside a sphere's or cylinder's surface)
    extent = np.empty((m, 3))
    for o in range(m):
        r, (p0, p1, p2) = rotations[o], params[o]
        if kinds[o] == BOX:
            extent[o] = np.abs(r) @ np.array([p0, p1, p2])
        elif kinds[o] == SPHERE:
            extent[o] = p0
        else:  # cylinder: the axis's reach plus the rim's; capsule: the axis's reach plus the radius
            along = np.abs(r[:, 2]) * p1
            extent[o] = along + (p0 * np.sqrt(np.clip(1.0 - r[:, 2] ** 2, 0.0, 1.0)) if kinds[o] == CYLINDER else p0)
    extent = extent * (1.0 + 1e-12) + 1e-15
    return (
        kinds,
        rotations,
        translations,
        params,
        np.ascontiguousarray(centres, dtype=float).reshape(m, 3),
        np.ascontiguousarray(radii, dtype=float).reshape(m),
        np.ascontiguousarray(translations - extent),
        np.ascontiguousarray(translations + extent),
    )


def distances(packed: tuple, a: np.ndarray, b: np.ndarray | None, cutoff) -> tuple[np.ndarray, np.ndarray]:
    """:func:`nearest` on points (``b`` None) or segments: (distance, index) as ``Scene._nearest`` returns them; a
    batch of :data:`SPLIT_AT` or more in slices on the process's threads (the same answers)."""
    a = _plain(a)
    n = len(a)
    cut = np.empty(n)
    cut[:] = cutoff
    distance = np.empty(n)
    index = np.empty(n, dtype=np.int64)
    segment = b is not None
    b = _plain(b) if segment else a
    threads = cpu_threads() if n >= SPLIT_AT else 1
    cuts = [n * part // threads for part in range(threads + 1)]
    in_parallel(
        [
            (nearest, (*packed, a[lo:hi], b[lo:hi], segment, cut[lo:hi], distance[lo:hi], index[lo:hi]))
            for lo, hi in pairwise(cuts)
        ]
    )
    return distance, index


def _plain(x) -> np.ndarray:
    """C-contiguous, writeable float64 (a read-only array, such as np.broadcast_arrays returns, is another type
    to numba: it would compile again)."""
    x = np.ascontiguousarray(x, dtype=float)
    return x if x.flags.writeable else x.copy()


def unit_box() -> tuple:
    """One box of half-extent 1 at the origin, packed as :func:`pack` packs a scene: what the kernels (here and in
    :mod:`.bvh`) are compiled on when their modules are imported."""
    vectors = np.zeros((1, 3))
    ones = np.ones((1, 3))
    return np.zeros(1, dtype=np.int64), np.eye(3)[None].copy(), vectors, ones, vectors, np.ones(1), -ones, ones


def compile_all() -> None:
    """Load (or compile) :func:`nearest` for the argument types the scene passes."""
    for b in (None, np.zeros((1, 3))):  # points, then segments
        distances(unit_box(), np.zeros((1, 3)), b, 1.0)


compile_all()
