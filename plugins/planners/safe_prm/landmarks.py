"""Landmarks for the safe PRM's A* (ALT: A*, landmarks, triangle inequality; Goldberg & Harrelson 2005).

At build, a few milestones of a roadmap are chosen as landmarks (the *farthest* strategy: each next one the
milestone farthest, in the roadmap, from those chosen, within the largest component) and their roadmap
distances to every milestone are stored, node-major (``far[v, j]``: milestone v to landmark j, ``inf`` in
another component). By the triangle inequality, for every landmark L the cost of any roadmap path from v to t
is at least ``|d(L, t) - d(L, v)|``: a lower bound that follows the roadmap around the obstacles, where the
straight-line distance cuts through them. :func:`.astar.search` takes the larger of the two bounds, so it
settles only the nodes that could still lie on a shortest path, far fewer than with the distance alone.

The distances come from :func:`dijkstra`, a binary-heap Dijkstra over the roadmap's CSR rows, compiled with
numba (``tests/test_safe_prm.py`` checks it against scipy's). Compiled when the module is imported.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: how many landmarks each roadmap gets (R and R_safe): the query's A* settles 5-20x fewer nodes than with the
#: straight-line bound alone; each costs one Dijkstra at build and 8 bytes per milestone
LANDMARKS = 8


@njit(cache=True, nogil=True)
def dijkstra(indptr, indices, data, source, out):
    """The roadmap distance from ``source`` to every node into ``out`` (``inf`` where unreachable)."""
    n = indptr.shape[0] - 1
    for v in range(n):
        out[v] = np.inf
    capacity = indices.shape[0] + 1
    heap_key = np.empty(capacity)
    heap_node = np.empty(capacity, dtype=np.int64)
    done = np.zeros(n, dtype=np.bool_)
    out[source] = 0.0
    heap_key[0] = 0.0
    heap_node[0] = source
    size = 1
    while size > 0:
        key, v = heap_key[0], heap_node[0]
        size -= 1
        # the last entry sifts down from the root
        last_key, last_node = heap_key[size], heap_node[size]
        i = 0
        while True:
            child = 2 * i + 1
            if child >= size:
                break
            if child + 1 < size and heap_key[child + 1] < heap_key[child]:
                child += 1
            if heap_key[child] >= last_key:
                break
            heap_key[i], heap_node[i] = heap_key[child], heap_node[child]
            i = child
        heap_key[i], heap_node[i] = last_key, last_node
        if done[v]:
            continue
        done[v] = True
        for e in range(indptr[v], indptr[v + 1]):
            w = indices[e]
            c = key + data[e]
            if c < out[w]:
                out[w] = c
                # sift up
                i = size
                size += 1
                while i > 0:
                    up = (i - 1) // 2
                    if heap_key[up] <= c:
                        break
                    heap_key[i], heap_node[i] = heap_key[up], heap_node[up]
                    i = up
                heap_key[i], heap_node[i] = c, w
    return out


@njit(cache=True, nogil=True)
def landmark_distances(indptr, indices, data, scaled, labels, count):
    """``count`` landmarks of the largest component (farthest strategy) and every node's roadmap distance to
    each: (n, count), ``inf`` where a node cannot reach it; fewer columns when the component is smaller."""
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
        dijkstra(indptr, indices, data, landmark, column)
        far[:, j] = column
        landmark, best = -1, -1.0
        for v in range(n):
            nearest[v] = min(nearest[v], column[v])
            if labels[v] == largest and nearest[v] > best:
                landmark, best = v, nearest[v]
    return far


def landmark_tolerance(far: np.ndarray) -> float:
    """The round-off allowed in the landmark bounds: a billionth of the longest finite distance (a distance
    summed over a path of up to thousands of edges is off by far less)."""
    finite = far[np.isfinite(far)]
    return 1e-9 * float(finite.max()) if finite.size else 0.0


def _compile() -> None:
    indptr = np.array([0, 1, 2], dtype=np.int32)
    indices = np.array([1, 0], dtype=np.int32)
    landmark_distances(indptr, indices, np.ones(2), np.zeros((2, 3)), np.zeros(2, dtype=np.int64), 2)


_compile()
