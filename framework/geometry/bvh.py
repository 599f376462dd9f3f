"""A bounding-volume hierarchy over the obstacles' world boxes: the broad phase of a scene with many obstacles.

:func:`surgiplan.geometry.compiled.nearest` measures a query against every obstacle's bound and sorts them,
which costs O(m log m) a query for m obstacles: 10,000 voxel boxes make a roadmap's 100,000 edge checks take a
minute. Here the obstacles' world boxes (the exact ones :func:`~surgiplan.geometry.compiled.pack` computes) are
split top-down (median of the longest axis, :data:`LEAF` obstacles a leaf) into a tree of boxes, and a query
descends it nearer child first, skipping every node whose box is no nearer than the nearest obstacle found so
far (or the cutoff): the cost grows with the obstacles near the query, not with all of them.

The answers are those of :func:`~surgiplan.geometry.compiled.nearest`: the same exact distances
(:func:`~surgiplan.geometry.compiled._exact`, on the same per-obstacle bounds), exact below the cutoff and above
it a lower bound that is itself at least the cutoff. Only two things may differ, both where the brute force
promises nothing: which of two obstacles at exactly the same distance is named, and the value of a lower bound
above the cutoff. ``tests/test_broadphase.py`` compares the two on a scene of 300 boxes, to 1e-9 m, and the
certified verdicts of edges.

For a point the distance to a node's box is exact; for a segment the bound is the larger of the gap between the
segment's box and the node's, and the distance from the node's centre to the segment less its half diagonal.
coal's ``DynamicAABBTreeCollisionManager`` answers the same question: ``benchmarks/bench_scale.py`` measures both.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .compiled import _FLAGS, _exact, _local, _plain, _point_segment, unit_box

#: obstacles in a leaf at most
LEAF = 4
#: scenes of at least this many primitives query through the tree (below it, the brute force's sort is as fast)
MIN_OBSTACLES = 64


def build(low: np.ndarray, high: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, ...]:
    """The tree over boxes ``low``/``high`` (m, 3) of obstacles of bounding radii ``radii``: ``(node_low,
    node_high, node_depth, child, start, count, order)``; ``node_depth`` the largest radius in a node (how deep
    inside one of its obstacles a point may be).

    Node 0 is the root; a node with ``child[n] >= 0`` is inner, its children ``child[n]`` and ``child[n] + 1``;
    a leaf holds obstacles ``order[start[n] : start[n] + count[n]]``."""
    m = len(low)
    centre = 0.5 * (low + high)
    order = np.arange(m, dtype=np.int64)
    capacity = 2 * m + 1  # a binary tree of at most m leaves
    node_low = np.zeros((capacity, 3))
    node_high = np.zeros((capacity, 3))
    node_depth = np.zeros(capacity)
    child = np.full(capacity, -1, dtype=np.int64)
    start = np.zeros(capacity, dtype=np.int64)
    count = np.zeros(capacity, dtype=np.int64)
    used = 1
    stack = [(0, 0, m)]
    while stack:
        node, s, e = stack.pop()
        members = order[s:e]
        node_low[node] = low[members].min(axis=0) if e > s else 0.0
        node_high[node] = high[members].max(axis=0) if e > s else 0.0
        node_depth[node] = radii[members].max() if e > s else 0.0
        start[node], count[node] = s, e - s
        if e - s <= LEAF:
            continue
        spread = centre[members].max(axis=0) - centre[members].min(axis=0)
        axis = int(np.argmax(spread))
        half = (e - s) // 2
        order[s:e] = members[np.argpartition(centre[members, axis], half)]
        child[node] = used
        stack += [(used, s, s + half), (used + 1, s + half, e)]
        used += 2
    return (
        np.ascontiguousarray(node_low[:used]),
        np.ascontiguousarray(node_high[:used]),
        node_depth[:used].copy(),
        child[:used].copy(),
        start[:used].copy(),
        count[:used].copy(),
        order,
    )


@njit(**_FLAGS)
def _node_bound(lo, hi, depth, a, b, i, segment):
    """A lower bound on the signed distance from query ``i`` (a point, or the segment a→b) to the obstacles in box
    lo-hi, of bounding radii at most ``depth``: the gap to the box, or within it no less than ``-depth``."""
    gap = 0.0
    for k in range(3):
        if segment:
            g = max(min(a[i, k], b[i, k]) - hi[k], lo[k] - max(a[i, k], b[i, k]), 0.0)
        else:
            g = max(a[i, k] - hi[k], lo[k] - a[i, k], 0.0)
        gap += g * g
    bound = np.sqrt(gap)
    if segment:
        cx, cy, cz = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])
        hx, hy, hz = 0.5 * (hi[0] - lo[0]), 0.5 * (hi[1] - lo[1]), 0.5 * (hi[2] - lo[2])
        sphere = _point_segment(cx, cy, cz, a[i, 0], a[i, 1], a[i, 2], b[i, 0], b[i, 1], b[i, 2])
        bound = max(bound, sphere - np.sqrt(hx * hx + hy * hy + hz * hz))
    return bound if bound > 0.0 else -depth


@njit(**_FLAGS)
def _obstacle_bound(o, centres, radii, low, high, a, b, i, segment):
    """As :func:`~surgiplan.geometry.compiled.nearest` bounds obstacle ``o``: its sphere's and world box's."""
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
    return max(gap - radii[o], np.sqrt(box_gap)) if box_gap > 0 else gap - radii[o]


@njit(**_FLAGS)
def nearest(
    kinds,
    rotations,
    translations,
    params,
    centres,
    radii,
    low,
    high,
    node_low,
    node_high,
    node_depth,
    child,
    start,
    count,
    order,
    a,
    b,
    segment,
    cutoff,
    distance,
    index,
):
    """:func:`~surgiplan.geometry.compiled.nearest` through the tree: the nearest obstacle's signed distance
    (exact below ``cutoff[i]``, else a lower bound at least the cutoff) and index, into ``distance``/``index``."""
    depth = 64
    stack = np.empty(depth * 2, dtype=np.int64)
    stack_bound = np.empty(depth * 2)
    la = np.empty(3)
    lb = np.empty(3)
    axis_a = np.zeros(3)
    axis_b = np.zeros(3)
    for i in range(a.shape[0]):
        best = np.inf
        nearest_index = -1
        floor = np.inf
        top = 0
        stack[0] = 0
        stack_bound[0] = _node_bound(node_low[0], node_high[0], node_depth[0], a, b, i, segment)
        top = 1
        while top > 0:
            top -= 1
            node = stack[top]
            bound = stack_bound[top]
            if bound >= min(cutoff[i], best):
                floor = min(floor, bound)
                continue
            first = child[node]
            if first < 0:
                for r in range(start[node], start[node] + count[node]):
                    o = order[r]
                    lower = _obstacle_bound(o, centres, radii, low, high, a, b, i, segment)
                    if lower >= min(cutoff[i], best):
                        floor = min(floor, lower)
                        continue
                    _local(a[i], rotations[o], translations[o], la)
                    if segment:
                        _local(b[i], rotations[o], translations[o], lb)
                    value = _exact(kinds[o], params[o], la, lb, segment, axis_a, axis_b)
                    if value < best:
                        best, nearest_index = value, o
                continue
            near = _node_bound(node_low[first], node_high[first], node_depth[first], a, b, i, segment)
            far = _node_bound(node_low[first + 1], node_high[first + 1], node_depth[first + 1], a, b, i, segment)
            # the nearer child on top of the stack: visited first
            if near <= far:
                stack[top], stack_bound[top] = first + 1, far
                stack[top + 1], stack_bound[top + 1] = first, near
            else:
                stack[top], stack_bound[top] = first, near
                stack[top + 1], stack_bound[top + 1] = first + 1, far
            top += 2
        distance[i] = min(best, floor)
        index[i] = nearest_index


def distances(packed: tuple, tree: tuple, a: np.ndarray, b: np.ndarray | None, cutoff) -> tuple[np.ndarray, np.ndarray]:
    """:func:`nearest` on points (``b`` None) or segments, as :func:`surgiplan.geometry.compiled.distances`."""
    a = _plain(a)
    n = len(a)
    cut = np.empty(n)
    cut[:] = cutoff
    distance = np.empty(n)
    index = np.empty(n, dtype=np.int64)
    segment = b is not None
    nearest(*packed, *tree, a, _plain(b) if segment else a, segment, cut, distance, index)
    return distance, index


def compile_all() -> None:
    """Load (or compile) :func:`nearest` for the argument types the scene passes."""
    packed = unit_box()
    tree = build(packed[6], packed[7], packed[5])
    for b in (None, np.zeros((1, 3))):  # points, then segments
        distances(packed, tree, np.zeros((1, 3)), b, 1.0)


compile_all()
