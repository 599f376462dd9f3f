"""Landmarks for the safe PRM's A* (ALT: A*, landmarks, triangle inequality; Goldberg & Harrelson 2005).

At build, a few milestones of a roadmap are chosen as landmarks (the *farthest* strategy: each next one the
milestone farthest, in the roadmap, from those chosen, within the largest component) and their roadmap
distances to every milestone are stored, node-major (``far[v, j]``: milestone v to landmark j, ``inf`` in
another component). By the triangle inequality, for every landmark L the cost of any roadmap path from v to t
is at least ``|d(L, t) - d(L, v)|``: a lower bound that follows the roadmap around the obstacles, where the
straight-line distance cuts through them. :func:`.astar.search` takes the larger of the two bounds, so it
settles only the nodes that could still lie on a shortest path, far fewer than with the distance alone.

The distances come from :func:`dijkstra`, the query's own bucket search run to exhaustion without a heuristic
(``tests/test_safe_prm_query.py`` checks them against scipy's Dijkstra). Compiled when the module is imported.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .astar import BUCKETS, search

#: how many landmarks each roadmap gets (R and R_safe): the query's A* settles 5-20x fewer nodes than with the
#: straight-line bound alone; each costs one Dijkstra at build and 8 bytes per milestone
LANDMARKS = 8


@njit(cache=True, nogil=True)
def dijkstra(indptr, indices, data, delta, source, out):
    """The roadmap distance from ``source`` to every node into ``out`` (``inf`` where unreachable):
    :func:`.astar.search` with no heuristic and a target it never reaches (a virtual goal without links), so it
    runs until its queue is empty, when every reachable node holds its exact distance (``delta``: the buckets'
    width, :func:`.astar.bucket_width`)."""
    n = indptr.shape[0] - 1
    entries = indices.shape[0] + n + 64
    node = np.zeros((n + 2, 4))
    end = np.zeros((n + 2, 2))
    head = np.full(BUCKETS, -1, dtype=np.int32)
    generation = np.zeros(1)
    path = np.empty(n + 2, dtype=np.int64)
    nothing, no_landmarks = np.empty((n, 0)), np.empty((n, 0), dtype=np.float32)
    no_links, no_costs, no_use, nowhere = np.empty(0, np.int64), np.empty(0), np.empty(0, np.bool_), np.empty(0)
    while True:
        entry_node = np.empty(entries, dtype=np.int32)
        entry_key = np.empty(entries)
        entry_next = np.empty(entries, dtype=np.int32)
        count, _, _ = search(
            indptr, indices, data, nothing, no_landmarks, 0.0, delta,
            source, no_links, no_costs, no_use, nowhere,
            n + 1, no_links, no_costs, no_use, nowhere, np.inf,
            node, end, head, entry_node, entry_key, entry_next, generation, path,
        )  # fmt: skip
        if count >= 0:
            break
        entries *= 2  # ran out of entries (re-expansions): again with twice as many
    for v in range(n):
        out[v] = node[v, 1] if node[v, 0] == generation[0] else np.inf
    return out


@njit(cache=True, nogil=True)
def landmark_distances(indptr, indices, data, scaled, labels, count, delta):
    """``count`` landmarks of the largest component (farthest strategy) and every node's roadmap distance to
    each: (n, count), ``inf`` where a node cannot reach it; fewer columns when the component is smaller
    (``delta``: :func:`dijkstra`'s)."""
    n = scaled.shape[0]
    if n == 0 or count == 0:
        return np.empty((n, 0))
    sizes = np.zeros(n, dtype=np.int64)
    for v in range(n):
        sizes[labels[v]] += 1
    largest = np.argmax(sizes)
    count = min(count, sizes[largest])
    # the first landmark: the component's node farthest from its centroid
    d = scaled.shape[1]
    centre = np.zeros(d)
    for v in range(n):
        if labels[v] == largest:
            for k in range(d):
                centre[k] += scaled[v, k]
    for k in range(d):
        centre[k] /= sizes[largest]
    first, best = -1, -1.0
    for v in range(n):
        if labels[v] == largest:
            total = 0.0
            for k in range(d):
                total += (scaled[v, k] - centre[k]) ** 2
            if total > best:
                first, best = v, total
    far = np.empty((n, count))
    column = np.empty(n)
    nearest = np.full(n, np.inf)  # each node's distance to the nearest landmark so far
    landmark = first
    for j in range(count):
        dijkstra(indptr, indices, data, delta, landmark, column)
        far[:, j] = column
        landmark, best = -1, -1.0
        for v in range(n):
            nearest[v] = min(nearest[v], column[v])
            if labels[v] == largest and nearest[v] > best:
                landmark, best = v, nearest[v]
    return far


def _compile() -> None:
    indptr = np.array([0, 1, 2], dtype=np.int32)
    indices = np.array([1, 0], dtype=np.int32)
    landmark_distances(indptr, indices, np.ones(2), np.zeros((2, 3)), np.zeros(2, dtype=np.int64), 2, 0.1)


_compile()
