"""The self-intersection test of :mod:`.intersection`, compiled with numba: the same method, pair by pair.

Checking a deformed flap's surface for self-penetration is part of every equilibrium's validity; vectorised
in numpy it took about as long as the Newton solve of a 1 mm step of the flap (dozens of array calls over a
few thousand triangle pairs). Here one call does it: the pairs sharing one vertex (fixed by the surface's
connectivity) with the plane-side prefilter, then a uniform grid of cells as large as the largest triangle
box (the pairs of overlapping boxes are among neighbouring cells: the k-d tree's candidates; each pair of
neighbouring cells visited once, a cell's boxes stored together), the pairs sharing a vertex or an edge
skipped (by comparing their vertices), and Möller's early exit before the six edge-triangle tests. Points
are passed as tuples of scalars, not array views. The orientation determinants and the tolerance are those
of :func:`.intersection.segments_cross_triangles`; ``tests/test_fem_intersection.py`` checks the answers
against the direct method and coal. On the retraction flap lifted 30 mm (1,920 triangles) a check takes
1.4 ms (5.4 ms with views, a binary search per overlapping box pair and every pair visited twice).

Compiled when the module is imported (cached on disk by numba).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_FLAGS = {"cache": True, "nogil": True}
#: the 13 of a cell's 26 neighbours that follow it (each pair of neighbouring cells is visited once)
_FORWARD = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if (x, y, z) > (0, 0, 0)])


@njit(**_FLAGS)
def _orient(a, b, c, d):  # pragma: no cover
    """Six times the signed volume of the tetrahedron (a, b, c, d): (b - a) x (c - a) . (d - a).

    Points are 3-tuples of scalars (registers): array views built per test cost more than the test."""
    u0, u1, u2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    v0, v1, v2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    n0, n1, n2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
    return n0 * (d[0] - a[0]) + n1 * (d[1] - a[1]) + n2 * (d[2] - a[2])


@njit(**_FLAGS)
def _crosses(p, q, a, b, c, tol):  # pragma: no cover
    """The segment p-q crosses the triangle (a, b, c), strictly (as ``segments_cross_triangles``)."""
    sp = _orient(a, b, c, p)
    sq = _orient(a, b, c, q)
    if not ((sp < -tol and sq > tol) or (sp > tol and sq < -tol)):
        return False
    u = _orient(p, q, a, b)
    v = _orient(p, q, b, c)
    w = _orient(p, q, c, a)
    return (u > tol and v > tol and w > tol) or (u < -tol and v < -tol and w < -tol)


@njit(**_FLAGS)
def _side(normal, point, x):  # pragma: no cover
    return normal[0] * (x[0] - point[0]) + normal[1] * (x[1] - point[1]) + normal[2] * (x[2] - point[2])


@njit(**_FLAGS)
def _point(x, i):  # pragma: no cover
    return x[i, 0], x[i, 1], x[i, 2]


@njit(**_FLAGS)
def _straddles(normal, point, p, q, tol):  # pragma: no cover
    """The segment p-q lies strictly on both sides of the plane through ``point`` with ``normal``."""
    sp, sq = _side(normal, point, p), _side(normal, point, q)
    return (sp < -tol and sq > tol) or (sp > tol and sq < -tol)


@njit(**_FLAGS)
def _one_side(t_corners, normal, point, tol):  # pragma: no cover
    """All three corners on one side of the plane through ``point`` with ``normal`` (or within tol of it)."""
    above = below = True
    for corner in t_corners:
        value = _side(normal, point, corner)
        above &= value >= -tol
        below &= value <= tol
    return above or below


@njit(**_FLAGS)
def _share_vertex(triangles, i, j):  # pragma: no cover
    for a in range(3):
        for b in range(3):
            if triangles[i, a] == triangles[j, b]:
                return True
    return False


@njit(**_FLAGS)
def _triangles_cross(ci, cj, normal_i, normal_j, tol):  # pragma: no cover
    """Two triangles sharing no vertex cross: Möller's early exit, then the six edge-triangle tests."""
    if _one_side(ci, normal_j, cj[0], tol) or _one_side(cj, normal_i, ci[0], tol):
        return False
    for k in range(3):
        if _crosses(ci[k], ci[(k + 1) % 3], cj[0], cj[1], cj[2], tol):
            return True
    for k in range(3):
        if _crosses(cj[k], cj[(k + 1) % 3], ci[0], ci[1], ci[2], tol):
            return True
    return False


@njit(**_FLAGS)
def crossing_pairs(x, triangles, neighbours, opposite_a, opposite_b, tol_factor, pad_factor):  # pragma: no cover
    """Pairs (k, 2) of triangles that cross at x, sorted; ``neighbours`` (pairs sharing exactly one vertex)
    with their vertices opposite the shared one (:class:`.intersection._Adjacency`'s).

    The determinant tolerance is ``tol_factor`` l^3 (l the longest edge) and the boxes' padding ``pad_factor``
    times the largest extent of x, both computed here as :func:`.intersection.self_intersections_numpy` does."""
    t = triangles.shape[0]
    corners = np.empty((t, 3, 3))
    normals = np.empty((t, 3))
    lower = np.empty((t, 3))
    upper = np.empty((t, 3))
    longest = 0.0  # squared
    for i in range(t):
        for k in range(3):
            for d in range(3):
                corners[i, k, d] = x[triangles[i, k], d]
        c = corners[i]
        for k in range(3):  # the edges c_k - c_(k-1), as np.roll pairs them
            e0, e1, e2 = c[k, 0] - c[k - 1, 0], c[k, 1] - c[k - 1, 1], c[k, 2] - c[k - 1, 2]
            longest = max(longest, e0 * e0 + e1 * e1 + e2 * e2)
        u0, u1, u2 = c[1, 0] - c[0, 0], c[1, 1] - c[0, 1], c[1, 2] - c[0, 2]
        v0, v1, v2 = c[2, 0] - c[0, 0], c[2, 1] - c[0, 1], c[2, 2] - c[0, 2]
        normals[i, 0], normals[i, 1], normals[i, 2] = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
    extent = 0.0
    for d in range(3):
        low, high = np.inf, -np.inf
        for n in range(x.shape[0]):
            low, high = min(low, x[n, d]), max(high, x[n, d])
        extent = max(extent, high - low)
    tol = tol_factor * math.pow(math.sqrt(longest), 3.0)
    pad = pad_factor * extent
    for i in range(t):
        for d in range(3):
            lower[i, d] = min(corners[i, 0, d], corners[i, 1, d], corners[i, 2, d]) - pad
            upper[i, d] = max(corners[i, 0, d], corners[i, 1, d], corners[i, 2, d]) + pad
    found = np.empty((64, 2), dtype=np.int64)
    count = 0
    # 1. neighbours sharing one vertex: they cross only where the edge of one opposite that vertex crosses the
    # other, which it cannot unless it straddles the other's plane
    for r in range(neighbours.shape[0]):
        a, b = neighbours[r, 0], neighbours[r, 1]
        pa, qa = _point(x, opposite_a[r, 0]), _point(x, opposite_a[r, 1])
        pb, qb = _point(x, opposite_b[r, 0]), _point(x, opposite_b[r, 1])
        maybe_a = _straddles(_point(normals, b), _point(corners[b], 0), pa, qa, tol)
        maybe_b = _straddles(_point(normals, a), _point(corners[a], 0), pb, qb, tol)
        if not (maybe_a or maybe_b):
            continue
        ca = (_point(corners[a], 0), _point(corners[a], 1), _point(corners[a], 2))
        cb = (_point(corners[b], 0), _point(corners[b], 1), _point(corners[b], 2))
        if _crosses(pa, qa, cb[0], cb[1], cb[2], tol) or _crosses(pb, qb, ca[0], ca[1], ca[2], tol):
            if count == found.shape[0]:
                found = np.concatenate((found, np.empty_like(found)))
            found[count, 0], found[count, 1] = a, b
            count += 1
    # 2. the broad phase: cells as large as the largest box along each axis; overlapping boxes are in
    # neighbouring cells
    size = np.empty(3)
    low = np.empty(3)
    dims = np.empty(3, dtype=np.int64)
    for d in range(3):
        size[d] = 1e-300
        low[d] = np.inf
        high = -np.inf
        for i in range(t):
            size[d] = max(size[d], upper[i, d] - lower[i, d])
            low[d] = min(low[d], lower[i, d])
            high = max(high, upper[i, d])
        dims[d] = max(1, min(int((high - low[d]) / size[d]) + 1, 1 << 10))
    cells = dims[0] * dims[1] * dims[2]
    cell_of = np.empty(t, dtype=np.int64)
    first = np.zeros(cells + 1, dtype=np.int64)
    for i in range(t):
        c = 0
        for d in range(3):
            centre = 0.5 * (lower[i, d] + upper[i, d])
            c = c * dims[d] + min(int((centre - low[d]) / size[d]), dims[d] - 1)
        cell_of[i] = c
        first[c + 1] += 1
    for c in range(cells):
        first[c + 1] += first[c]
    fill = first[:cells].copy()
    members = np.empty(t, dtype=np.int64)
    boxes = np.empty((t, 6))  # in the members' order: a cell's boxes are read contiguously
    for i in range(t):
        e = fill[cell_of[i]]
        members[e] = i
        for d in range(3):
            boxes[e, d], boxes[e, 3 + d] = lower[i, d], upper[i, d]
        fill[cell_of[i]] += 1
    # each pair of cells once: a cell with itself and with the 13 of its 26 neighbours that follow it
    ranges = np.empty((1 + _FORWARD.shape[0], 2), dtype=np.int64)
    for ei in range(t):
        i = members[ei]
        ci = cell_of[i]
        cz = ci % dims[2]
        cy = (ci // dims[2]) % dims[1]
        cx = ci // (dims[2] * dims[1])
        ranges[0, 0], ranges[0, 1] = ei + 1, first[ci + 1]  # its own cell: the boxes after it
        n_ranges = 1
        for n in range(_FORWARD.shape[0]):
            gx, gy, gz = cx + _FORWARD[n, 0], cy + _FORWARD[n, 1], cz + _FORWARD[n, 2]
            if 0 <= gx < dims[0] and 0 <= gy < dims[1] and 0 <= gz < dims[2]:
                c = (gx * dims[1] + gy) * dims[2] + gz
                ranges[n_ranges, 0], ranges[n_ranges, 1] = first[c], first[c + 1]
                n_ranges += 1
        lo0, lo1, lo2, hi0, hi1, hi2 = (
            boxes[ei, 0],
            boxes[ei, 1],
            boxes[ei, 2],
            boxes[ei, 3],
            boxes[ei, 4],
            boxes[ei, 5],
        )
        for r in range(n_ranges):
            for e in range(ranges[r, 0], ranges[r, 1]):
                if (
                    lo0 > boxes[e, 3] or boxes[e, 0] > hi0
                    or lo1 > boxes[e, 4] or boxes[e, 1] > hi1
                    or lo2 > boxes[e, 5] or boxes[e, 2] > hi2
                ):  # fmt: skip
                    continue
                j = members[e]
                if _share_vertex(triangles, i, j):
                    continue  # they share a vertex or an edge: the neighbours above, or they meet along it
                corners_i = (_point(corners[i], 0), _point(corners[i], 1), _point(corners[i], 2))
                corners_j = (_point(corners[j], 0), _point(corners[j], 1), _point(corners[j], 2))
                if _triangles_cross(corners_i, corners_j, _point(normals, i), _point(normals, j), tol):
                    if count == found.shape[0]:
                        found = np.concatenate((found, np.empty_like(found)))
                    found[count, 0], found[count, 1] = min(i, j), max(i, j)
                    count += 1
    out = found[:count].copy()
    order = np.argsort(out[:, 0] * t + out[:, 1])
    return out[order]


def _compile() -> None:
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    triangles = np.array([[0, 1, 2], [0, 1, 3], [1, 2, 3], [0, 2, 3]], dtype=np.int64)
    none = np.empty((0, 2), dtype=np.int64)
    crossing_pairs(x, triangles, none, none, none, 1e-10, 1e-12)


_compile()
