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


def self_intersections(x: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Pairs (k, 2) of boundary triangles (indices into ``triangles``) that cross each other at x."""
    x = np.asarray(x, dtype=float).reshape(-1, 3)
    triangles = np.asarray(triangles, dtype=np.int64)
    corners = x[triangles]  # (t, 3, 3)
    pad = 1e-12 * float(np.ptp(x, axis=0).max())
    pairs = candidate_pairs(corners.min(axis=1) - pad, corners.max(axis=1) + pad)
    # determinants below this (m^3) are rounding noise: coplanar neighbours must not count as crossing
    edge = float(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max())
    tol = 1e-10 * edge**3
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
