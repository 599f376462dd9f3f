"""The binary heap and heuristic that the compiled A* searches share (safe_prm's roadmap, segmented_astar's pathmap).

numba functions over two parallel arrays (``keys``: priorities, ``items``: node
indices) preallocated by the caller to the most pushes a search can make, so a
search allocates nothing per step. Not imported by :mod:`surgiplan.paths`
(importing numba costs start-up); the searches import this module directly.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def push(keys, items, size, key, item):
    """Add ``item`` at priority ``key`` to the heap of ``size`` entries; returns the new size."""
    at = size
    while at > 0:
        parent = (at - 1) >> 1
        if keys[parent] <= key:
            break
        keys[at], items[at] = keys[parent], items[parent]
        at = parent
    keys[at], items[at] = key, item
    return size + 1


@njit(cache=True, nogil=True)
def pop(keys, items, size):
    """Remove the item of least priority; returns (item, new size). ``size`` must be positive."""
    item = items[0]
    size -= 1
    if size > 0:
        key, last = keys[size], items[size]
        at = 0
        while True:
            child = 2 * at + 1
            if child >= size:
                break
            if child + 1 < size and keys[child + 1] < keys[child]:
                child += 1
            if keys[child] >= key:
                break
            keys[at], items[at] = keys[child], items[child]
            at = child
        keys[at], items[at] = key, last
    return item, size


@njit(cache=True, nogil=True)
def distance(points, v, target):
    """Euclidean distance from ``points[v]`` to ``target`` (the searches' heuristic, before its shrink)."""
    total = 0.0
    for d in range(points.shape[1]):
        diff = points[v, d] - target[d]
        total += diff * diff
    return np.sqrt(total)
