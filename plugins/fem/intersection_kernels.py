"""The self-intersection test of :mod:`.intersection`, compiled with numba: the same method, pair by pair.

Checking a deformed flap's surface for self-penetration is part of every equilibrium's validity; vectorised
in numpy it took about as long as the Newton solve of a 1 mm step of the flap (dozens of array calls over a
few thousand triangle pairs). Here one call does it: the pairs sharing one vertex (fixed by the surface's
connectivity) with the plane-side prefilter, then a uniform grid of cells as large as the largest triangle
box (the pairs of overlapping boxes are among neighbouring cells: the k-d tree's candidates), the pairs
sharing a vertex or an edge skipped, and Möller's early exit before the six edge-triangle tests. The
orientation determinants and the tolerance are those of :func:`.intersection.segments_cross_triangles`;
``tests/test_fem_intersection.py`` checks the answers against the direct method and coal.

Compiled when the module is imported (cached on disk by numba).
"""

from __future__ import annotations

import numpy as np
from numba import njit

_FLAGS = {"cache": True, "nogil": True}


@njit(**_FLAGS)
def _orient(a, b, c, d):  # pragma: no cover
    """Six times the signed volume of the tetrahedron (a, b, c, d): (b - a) x (c - a) . (d - a)."""
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
def _side(normal, point, x, tol):  # pragma: no cover
    return normal[0] * (x[0] - point[0]) + normal[1] * (x[1] - point[1]) + normal[2] * (x[2] - point[2])


@njit(**_FLAGS)
def _one_side(corners, t, normals, s, tol):  # pragma: no cover
    """All three corners of triangle t on one side of triangle s's plane (or within tol of it)."""
    above = below = True
    for k in range(3):
        value = _side(normals[s], corners[s, 0], corners[t, k], tol)
        above &= value >= -tol
        below &= value <= tol
    return above or below


@njit(**_FLAGS)
def crossing_pairs(x, triangles, neighbours, opposite_a, opposite_b, shared_keys, tol, pad):  # pragma: no cover
    """Pairs (k, 2) of triangles that cross at x, sorted; ``neighbours`` (pairs sharing exactly one vertex)
    with their vertices opposite the shared one, ``shared_keys`` (sorted keys ``a * t + b`` of every pair
    sharing a vertex or an edge): :class:`.intersection._Adjacency`'s."""
    t = triangles.shape[0]
    corners = np.empty((t, 3, 3))
    normals = np.empty((t, 3))
    lower = np.empty((t, 3))
    upper = np.empty((t, 3))
    for i in range(t):
        for k in range(3):
            for d in range(3):
                corners[i, k, d] = x[triangles[i, k], d]
        c = corners[i]
        u0, u1, u2 = c[1, 0] - c[0, 0], c[1, 1] - c[0, 1], c[1, 2] - c[0, 2]
        v0, v1, v2 = c[2, 0] - c[0, 0], c[2, 1] - c[0, 1], c[2, 2] - c[0, 2]
        normals[i, 0], normals[i, 1], normals[i, 2] = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
        for d in range(3):
            lower[i, d] = min(corners[i, 0, d], corners[i, 1, d], corners[i, 2, d]) - pad
            upper[i, d] = max(corners[i, 0, d], corners[i, 1, d], corners[i, 2, d]) + pad
    found = np.empty((64, 2), dtype=np.int64)
    count = 0
    # 1. neighbours sharing one vertex: they cross only where the edge of one opposite that vertex crosses the
    # other, which it cannot unless it straddles the other's plane
    for r in range(neighbours.shape[0]):
        a, b = neighbours[r, 0], neighbours[r, 1]
        pa, qa = x[opposite_a[r, 0]], x[opposite_a[r, 1]]
        pb, qb = x[opposite_b[r, 0]], x[opposite_b[r, 1]]
        sp, sq = _side(normals[b], corners[b, 0], pa, tol), _side(normals[b], corners[b, 0], qa, tol)
        maybe_a = (sp < -tol and sq > tol) or (sp > tol and sq < -tol)
        sp, sq = _side(normals[a], corners[a, 0], pb, tol), _side(normals[a], corners[a, 0], qb, tol)
        maybe_b = (sp < -tol and sq > tol) or (sp > tol and sq < -tol)
        if not (maybe_a or maybe_b):
            continue
        hit = _crosses(pa, qa, corners[b, 0], corners[b, 1], corners[b, 2], tol)
        hit = hit or _crosses(pb, qb, corners[a, 0], corners[a, 1], corners[a, 2], tol)
        if hit:
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
    for i in range(t):
        members[fill[cell_of[i]]] = i
        fill[cell_of[i]] += 1
    for i in range(t):
        ci = cell_of[i]
        cz = ci % dims[2]
        cy = (ci // dims[2]) % dims[1]
        cx = ci // (dims[2] * dims[1])
        for gx in range(max(cx - 1, 0), min(cx + 1, dims[0] - 1) + 1):
            for gy in range(max(cy - 1, 0), min(cy + 1, dims[1] - 1) + 1):
                for gz in range(max(cz - 1, 0), min(cz + 1, dims[2] - 1) + 1):
                    c = (gx * dims[1] + gy) * dims[2] + gz
                    for e in range(first[c], first[c + 1]):
                        j = members[e]
                        if j <= i:
                            continue
                        overlap = True
                        for d in range(3):
                            if lower[i, d] > upper[j, d] or lower[j, d] > upper[i, d]:
                                overlap = False
                        if not overlap:
                            continue
                        key = i * t + j
                        at = np.searchsorted(shared_keys, key)
                        if at < shared_keys.shape[0] and shared_keys[at] == key:
                            continue  # they share a vertex or an edge
                        # 3. Möller's early exit, then the six edge-triangle tests
                        if _one_side(corners, i, normals, j, tol) or _one_side(corners, j, normals, i, tol):
                            continue
                        hit = False
                        for first_t, second_t in ((i, j), (j, i)):
                            for k in range(3):
                                if not hit and _crosses(
                                    corners[first_t, k],
                                    corners[first_t, (k + 1) % 3],
                                    corners[second_t, 0],
                                    corners[second_t, 1],
                                    corners[second_t, 2],
                                    tol,
                                ):
                                    hit = True
                        if hit:
                            if count == found.shape[0]:
                                found = np.concatenate((found, np.empty_like(found)))
                            found[count, 0], found[count, 1] = i, j
                            count += 1
    out = found[:count].copy()
    order = np.argsort(out[:, 0] * t + out[:, 1])
    return out[order]


def _compile() -> None:
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    triangles = np.array([[0, 1, 2], [0, 1, 3], [1, 2, 3], [0, 2, 3]], dtype=np.int64)
    none = np.empty((0, 2), dtype=np.int64)
    crossing_pairs(x, triangles, none, none, none, np.empty(0, dtype=np.int64), 1e-12, 1e-12)


_compile()
