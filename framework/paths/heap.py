"""The binary heaps and heuristic that the compiled A* searches share (safe_prm's roadmap, segmented_astar's pathmap).

numba functions over two parallel arrays (``keys``: priorities, ``items``: node
indices) preallocated by the caller to the most pushes a search can make, so a
search allocates nothing per step. :func:`push` and :func:`pop` keep stale
entries (a node pushed again when its cost drops; the search skips it when it
comes out settled); the ``indexed_*`` functions keep each node once, its place
in ``position`` (``position[item]``: its index in the heap, -1 once popped), and
lower its key in place (decrease-key), so a search pops only what it settles.
Not imported by :mod:`surgiplan.paths` (importing numba costs start-up); the
searches import this module directly.
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


@njit(cache=True, nogil=True, inline="always")
def _sift_up(keys, items, position, at, key, item):
    while at > 0:
        parent = (at - 1) >> 1
        if keys[parent] <= key:
            break
        keys[at], items[at] = keys[parent], items[parent]
        position[items[at]] = at
        at = parent
    keys[at], items[at] = key, item
    position[item] = at


@njit(cache=True, nogil=True)
def indexed_push(keys, items, position, size, key, item):
    """Add ``item`` (not in the heap) at priority ``key``; returns the new size."""
    _sift_up(keys, items, position, size, key, item)
    return size + 1


@njit(cache=True, nogil=True)
def indexed_decrease(keys, items, position, at, key):
    """Lower the priority of the entry at heap index ``at`` to ``key`` (not above its current one)."""
    _sift_up(keys, items, position, at, key, items[at])


@njit(cache=True, nogil=True)
def indexed_pop(keys, items, position, size):
    """Remove the item of least priority; returns (item, new size). ``size`` must be positive."""
    item = items[0]
    position[item] = -1
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
            position[items[at]] = at
            at = child
        keys[at], items[at] = key, last
        position[last] = at
    return item, size
