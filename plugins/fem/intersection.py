"""Self-intersection of a deformed mesh's boundary surface (part of a state's validity).

Patil & Alterovitz §IV-A call a mesh state valid when it has no inverted
element and no self-penetration. Inverted elements are found from det F;
self-penetration here: two boundary triangles of the deformed mesh that
cross each other.

Method, vectorised over triangle pairs:

1. broad phase: the pairs of overlapping bounding boxes (a k-d tree over
   the boxes' centres, :func:`candidate_pairs`);
2. pairs that share an edge are skipped (they meet along it); pairs that
   share one vertex meet there, and cross beyond it exactly when the edge
   opposite the shared vertex of one triangle crosses the other triangle;
3. other pairs cross when one of the six edges crosses the other triangle.

An edge crosses a triangle when its end points lie strictly on opposite
sides of the triangle's plane and the line through it passes strictly
inside the triangle (signs of four orientation determinants; "strictly":
beyond 1e-10 l^3, l the longest edge, so rounding noise of coplanar
neighbours does not count).

What it guarantees: every transversal crossing of two boundary triangles is
reported (up to the rounding of the determinants), so a surface that passes
through itself is caught. Exactly coplanar touching (a degenerate,
measure-zero contact) is not reported, nor are surfaces that come close
without crossing.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

#: orientation determinants below TOL l^3 (m^3, l the longest edge) are rounding noise: coplanar neighbours
#: must not count as crossing; bounding boxes are padded by PAD times the largest extent of the positions
TOL, PAD = 1e-10, 1e-12


def _orient(a, b, c, d) -> np.ndarray:
    """Six times the signed volume of tetrahedra (a, b, c, d), batched."""
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)


def segments_cross_triangles(p, q, a, b, c, tol: float = 0.0) -> np.ndarray:
    """Whether segments p-q cross triangles (a, b, c), elementwise over (k, 3) arrays.

    Strictly: the orientation determinants must exceed ``tol`` (m^3) in size,
    so touching and coplanar cases are not crossings.
    """
    sp = _orient(a, b, c, p)
    sq = _orient(a, b, c, q)
    straddle = ((sp < -tol) & (sq > tol)) | ((sp > tol) & (sq < -tol))
    u = _orient(p, q, a, b)
    v = _orient(p, q, b, c)
    w = _orient(p, q, c, a)
    inside = ((u > tol) & (v > tol) & (w > tol)) | ((u < -tol) & (v < -tol) & (w < -tol))
    return straddle & inside


def candidate_pairs(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Pairs (k, 2) of boxes [lower, upper] (t, 3) that overlap, each once (i < j).

    Two boxes overlap only if their centres are, along every axis, at most
    the largest box size along that axis apart: in coordinates scaled by
    those sizes, within a Chebyshev distance of 1. A k-d tree (scipy's
    ``cKDTree.query_pairs``, compiled) finds those pairs, then the boxes
    themselves are compared (about three times faster than the uniform
    grid of cells of that size it replaces, which did the same in numpy).
    """
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    if len(lower) < 2:
        return np.empty((0, 2), dtype=np.int64)
    size = np.maximum((upper - lower).max(axis=0), 1e-300)
    centre = (0.5 * (lower + upper)) / size
    pairs = cKDTree(centre).query_pairs(1.0, p=np.inf, output_type="ndarray").astype(np.int64, copy=False)
    i, j = pairs[:, 0], pairs[:, 1]
    keep = np.all((lower[i] <= upper[j]) & (lower[j] <= upper[i]), axis=1)
    return pairs[keep]


def _one_side(corners: np.ndarray, normals: np.ndarray, points: np.ndarray, tol: float) -> np.ndarray:
    """Whether all three corners (k, 3, 3) lie on one side of the planes (normal, point), or within tol of them."""
    side = np.einsum("kvi,ki->kv", corners - points[:, None, :], normals)
    return np.all(side >= -tol, axis=1) | np.all(side <= tol, axis=1)


class _Adjacency:
    """What the surface's connectivity fixes once: the triangle pairs that share exactly one vertex (their
    bounding boxes always overlap: every state tests them), each with its triangles' vertices opposite the
    shared one, and the keys of all pairs sharing a vertex or an edge (never candidates of the broad phase)."""

    def __init__(self, triangles: np.ndarray) -> None:
        t = len(triangles)
        owner = np.repeat(np.arange(t), 3)
        vertex = triangles.ravel()
        order = np.argsort(vertex, kind="stable")
        vertex, owner = vertex[order], owner[order]
        starts = np.flatnonzero(np.r_[True, vertex[1:] != vertex[:-1]])
        counts = np.diff(np.r_[starts, len(vertex)])
        a, b = [], []
        for size in np.unique(counts):  # triangles around each vertex, grouped by how many there are
            fans = owner[starts[counts == size][:, None] + np.arange(size)]
            i, j = np.triu_indices(size, 1)
            a.append(fans[:, i].ravel())
            b.append(fans[:, j].ravel())
        a, b = np.concatenate(a), np.concatenate(b)
        pairs = np.unique(np.column_stack([np.minimum(a, b), np.maximum(a, b)]), axis=0)
        self.keys = pairs[:, 0] * t + pairs[:, 1]  # sorted
        ta, tb = triangles[pairs[:, 0]], triangles[pairs[:, 1]]
        same = ta[:, :, None] == tb[:, None, :]
        one = same.sum(axis=(1, 2)) == 1
        self.pairs = np.ascontiguousarray(pairs[one])
        same = same[one]
        ia = np.argmax(same.any(axis=2), axis=1)  # the shared vertex's slot in a
        ib = np.argmax(same.any(axis=1), axis=1)  # and in b
        rows = np.arange(len(self.pairs))
        ta, tb = ta[one], tb[one]
        #: (k, 2) the vertices of a opposite the shared one, and of b
        self.opposite_a = np.ascontiguousarray(np.column_stack([ta[rows, (ia + 1) % 3], ta[rows, (ia + 2) % 3]]))
        self.opposite_b = np.ascontiguousarray(np.column_stack([tb[rows, (ib + 1) % 3], tb[rows, (ib + 2) % 3]]))
        self.count = t


_ADJACENCY: dict[bytes, _Adjacency] = {}


def _adjacency(triangles: np.ndarray) -> _Adjacency:
    key = triangles.tobytes()
    found = _ADJACENCY.get(key)
    if found is None:
        if len(_ADJACENCY) > 8:
            _ADJACENCY.clear()
        found = _ADJACENCY[key] = _Adjacency(triangles)
    return found


def _straddles(x, plane: np.ndarray, normal: np.ndarray, ends: np.ndarray, tol: float) -> np.ndarray:
    """Whether the segments ``ends`` (k, 2) lie strictly on both sides of the planes through the first corner
    ``plane`` (k, 3) with (unnormalised) ``normal`` (k, 3): the straddle test of :func:`segments_cross_triangles`."""
    sp = np.einsum("ij,ij->i", normal, x[ends[:, 0]] - plane)
    sq = np.einsum("ij,ij->i", normal, x[ends[:, 1]] - plane)
    return ((sp < -tol) & (sq > tol)) | ((sp > tol) & (sq < -tol))


def self_intersections(x: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Pairs (k, 2) of boundary triangles (indices into ``triangles``) that cross each other at x.

    Pairs sharing one vertex (the fixed neighbours, most of the candidates) are tested directly: they cross
    only where the edge of one opposite the shared vertex straddles the other's plane, so a plane-side test
    decides almost all of them, and the few that straddle get the full test. The broad phase then only
    looks for pairs that share no vertex. One compiled call (:mod:`.intersection_kernels`);
    :func:`self_intersections_numpy` is the same method vectorised.
    """
    from .intersection_kernels import crossing_pairs

    x = np.ascontiguousarray(x, dtype=float).reshape(-1, 3)
    triangles = np.ascontiguousarray(triangles, dtype=np.int64)
    if len(triangles) == 0:
        return np.empty((0, 2), dtype=np.int64)
    adjacency = _adjacency(triangles)
    return crossing_pairs(x, triangles, adjacency.pairs, adjacency.opposite_a, adjacency.opposite_b, TOL, PAD)


def self_intersections_numpy(x: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """:func:`self_intersections` vectorised in numpy (the tests' second implementation)."""
    x = np.asarray(x, dtype=float).reshape(-1, 3)
    triangles = np.asarray(triangles, dtype=np.int64)
    corners = x[triangles]  # (t, 3, 3)
    # determinants below this (m^3) are rounding noise: coplanar neighbours must not count as crossing
    edge = float(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max()) if len(triangles) else 0.0
    tol = TOL * edge**3
    adjacency = _adjacency(triangles)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    found = []
    if len(adjacency.pairs):
        a, b = adjacency.pairs[:, 0], adjacency.pairs[:, 1]
        maybe_a = _straddles(x, corners[b, 0], normals[b], adjacency.opposite_a, tol)  # a's far edge through b
        maybe_b = _straddles(x, corners[a, 0], normals[a], adjacency.opposite_b, tol)
        check = np.flatnonzero(maybe_a | maybe_b)
        if len(check):
            ca, cb = corners[a[check]], corners[b[check]]
            oa, ob = adjacency.opposite_a[check], adjacency.opposite_b[check]
            hit = segments_cross_triangles(x[oa[:, 0]], x[oa[:, 1]], cb[:, 0], cb[:, 1], cb[:, 2], tol)
            hit |= segments_cross_triangles(x[ob[:, 0]], x[ob[:, 1]], ca[:, 0], ca[:, 1], ca[:, 2], tol)
            found.append(adjacency.pairs[check[hit]])
    pad = PAD * float(np.ptp(x, axis=0).max())
    pairs = candidate_pairs(corners.min(axis=1) - pad, corners.max(axis=1) + pad)
    if len(pairs):
        keys = pairs[:, 0] * adjacency.count + pairs[:, 1]
        at = np.minimum(np.searchsorted(adjacency.keys, keys), len(adjacency.keys) - 1)
        pairs = pairs[adjacency.keys[at] != keys] if len(adjacency.keys) else pairs  # share no vertex
    if len(pairs):
        found.append(_disjoint_crossings(pairs, corners, normals, tol))
    if not found:
        return np.empty((0, 2), dtype=np.int64)
    out = np.concatenate(found)
    return out[np.lexsort((out[:, 1], out[:, 0]))]


def _disjoint_crossings(pairs: np.ndarray, corners: np.ndarray, normals: np.ndarray, tol: float) -> np.ndarray:
    """Of candidate pairs sharing no vertex, those that cross (one of the six edges crosses the other)."""
    a, b = pairs[:, 0], pairs[:, 1]
    # a triangle entirely on one side of the other's plane cannot cross it (Moller 1997's early exit)
    maybe = ~_one_side(corners[a], normals[b], corners[b, 0], tol)
    maybe[maybe] &= ~_one_side(corners[b[maybe]], normals[a[maybe]], corners[a[maybe], 0], tol)
    pairs = pairs[maybe]
    ca = corners[pairs[:, 0]]
    cb = corners[pairs[:, 1]]
    hit = np.zeros(len(pairs), dtype=bool)
    for first, second in ((ca, cb), (cb, ca)):
        for e in range(3):
            p, q = first[:, e], first[:, (e + 1) % 3]
            hit |= segments_cross_triangles(p, q, second[:, 0], second[:, 1], second[:, 2], tol)
    return pairs[hit]


def _self_intersections_reference(x: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The direct method (every bounding-box candidate classified by shared vertices), for tests."""
    x = np.asarray(x, dtype=float).reshape(-1, 3)
    triangles = np.asarray(triangles, dtype=np.int64)
    corners = x[triangles]  # (t, 3, 3)
    pad = PAD * float(np.ptp(x, axis=0).max())
    pairs = candidate_pairs(corners.min(axis=1) - pad, corners.max(axis=1) + pad)
    # determinants below this (m^3) are rounding noise: coplanar neighbours must not count as crossing
    edge = float(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max())
    tol = TOL * edge**3
    if len(pairs) == 0:
        return pairs
    ta = triangles[pairs[:, 0]]
    tb = triangles[pairs[:, 1]]
    shared = (ta[:, :, None] == tb[:, None, :]).sum(axis=(1, 2))
    # a triangle entirely on one side of the other's plane cannot cross it (Moller 1997's early exit)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    a, b = pairs[:, 0], pairs[:, 1]
    maybe = shared < 2
    maybe[maybe] &= ~_one_side(corners[a[maybe]], normals[b[maybe]], corners[b[maybe], 0], tol)
    maybe[maybe] &= ~_one_side(corners[b[maybe]], normals[a[maybe]], corners[a[maybe], 0], tol)
    pairs, ta, tb, shared = pairs[maybe], ta[maybe], tb[maybe], shared[maybe]
    same = ta[:, :, None] == tb[:, None, :]  # (k, 3, 3)
    hit = np.zeros(len(pairs), dtype=bool)

    disjoint = np.flatnonzero(shared == 0)
    if len(disjoint):
        ca = corners[pairs[disjoint, 0]]
        cb = corners[pairs[disjoint, 1]]
        found = np.zeros(len(disjoint), dtype=bool)
        for first, second in ((ca, cb), (cb, ca)):
            for e in range(3):
                p, q = first[:, e], first[:, (e + 1) % 3]
                found |= segments_cross_triangles(p, q, second[:, 0], second[:, 1], second[:, 2], tol)
        hit[disjoint] = found

    touching = np.flatnonzero(shared == 1)
    if len(touching):
        s = same[touching]
        ia = np.argmax(s.any(axis=2), axis=1)  # the shared vertex's slot in a
        ib = np.argmax(s.any(axis=1), axis=1)  # and in b
        ca = corners[pairs[touching, 0]]
        cb = corners[pairs[touching, 1]]
        rows = np.arange(len(touching))
        found = segments_cross_triangles(
            ca[rows, (ia + 1) % 3], ca[rows, (ia + 2) % 3], cb[:, 0], cb[:, 1], cb[:, 2], tol
        ) | segments_cross_triangles(cb[rows, (ib + 1) % 3], cb[rows, (ib + 2) % 3], ca[:, 0], ca[:, 1], ca[:, 2], tol)
        hit[touching] = found
    return pairs[hit]
