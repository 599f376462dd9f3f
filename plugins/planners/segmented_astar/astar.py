"""A* over the contracted pathmap graph (junctions joined by chains), compiled with numba (paper 001 §5).

The junction graph is in compressed sparse rows: row ``v`` lists the chains
leaving junction v (``neighbour``, ``cost``; the entry index identifies the
chain taken). A query's start and goal are virtual nodes: the start reaches
junctions through its attachments (``start_junction`` at ``start_cost``), a
goal attachment ends a path at a junction (``goal_junction`` at
``goal_cost``), and ``direct_cost`` is a route that needs no junction (along
one chain, or a straight motion).

The heuristic is paper 001's h(v) = |x(v) - x_goal|, scaled down by one part
in 10^12 so that round-off cannot make it exceed a true remaining cost:
admissible and consistent (every chain is at least as long as the straight
line between its ends), so A* returns a shortest path. The tests compare
its costs with scipy's Dijkstra on the uncontracted graph.

This is safe_prm's compiled search adapted to chains (the planner packages
share no code but the core's; see the import contracts). Why numba: in pure
Python (heapq) a search and its bookkeeping cost about half a millisecond,
the whole online budget; compiled, tens of microseconds. ``cache=True``
stores the compiled code, so only a machine's first run compiles, and it is
loaded (or compiled) when the module is imported: no query pays it.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from surgiplan.paths.heap import distance, pop, push

_SHRINK = 1.0 - 1e-12


@njit(cache=True, nogil=True)
def astar_junctions(
    indptr, neighbour, cost, points, start_junction, start_cost, goal_junction, goal_cost, goal_point, direct_cost
):
    """Returns (entries, first, last, total, expanded).

    ``entries``: the CSR entries (chains) from the first junction to the last;
    ``first``: the start attachment used; ``last``: the goal attachment used
    (-1 when the direct route wins, -2 when there is no route); ``total``: the
    cost; ``expanded``: junctions settled.
    """
    n = points.shape[0]
    goal = n  # the virtual goal node
    best = np.full(n + 1, np.inf)
    came = np.full(n + 1, -1, dtype=np.int64)  # CSR entry into the node; -2 - k: start attachment k
    via = np.full(n + 1, -1, dtype=np.int64)  # for the goal: the goal attachment used
    closed = np.zeros(n + 1, dtype=np.bool_)
    end_cost = np.full(n, np.inf)
    end_index = np.full(n, -1, dtype=np.int64)
    for k in range(goal_junction.shape[0]):
        v = goal_junction[k]
        if goal_cost[k] < end_cost[v]:
            end_cost[v] = goal_cost[k]
            end_index[v] = k
    capacity = neighbour.shape[0] + start_junction.shape[0] + goal_junction.shape[0] + 2
    keys = np.empty(capacity)
    items = np.empty(capacity, dtype=np.int64)
    size = 0
    for k in range(start_junction.shape[0]):
        v = start_junction[k]
        if start_cost[k] < best[v]:
            best[v] = start_cost[k]
            came[v] = -2 - k
    for v in range(n):
        if came[v] <= -2:
            size = push(keys, items, size, best[v] + distance(points, v, goal_point) * _SHRINK, v)
    if direct_cost < np.inf:
        best[goal] = direct_cost
        size = push(keys, items, size, direct_cost, goal)
    expanded = 0
    while size > 0:
        v, size = pop(keys, items, size)
        if closed[v]:
            continue
        closed[v] = True
        if v == goal:
            break
        expanded += 1
        g = best[v]
        if end_index[v] >= 0 and g + end_cost[v] < best[goal]:
            best[goal] = g + end_cost[v]
            via[goal] = end_index[v]
            came[goal] = v
            size = push(keys, items, size, best[goal], goal)
        for e in range(indptr[v], indptr[v + 1]):
            w = neighbour[e]
            c = g + cost[e]
            if not closed[w] and c < best[w]:
                best[w] = c
                came[w] = e
                size = push(keys, items, size, c + distance(points, w, goal_point) * _SHRINK, w)
    if not closed[goal]:
        return np.empty(0, dtype=np.int64), -1, -2, np.inf, expanded
    if via[goal] < 0:
        return np.empty(0, dtype=np.int64), -1, -1, best[goal], expanded
    # walk back: junction by junction along the entries, to a start attachment
    v = came[goal]
    count = 0
    u = v
    while came[u] >= 0:
        count += 1
        u = _source_of(indptr, came[u])
    entries = np.empty(count, dtype=np.int64)
    u = v
    for k in range(count - 1, -1, -1):
        entries[k] = came[u]
        u = _source_of(indptr, came[u])
    return entries, -2 - came[u], via[goal], best[goal], expanded


@njit(cache=True, nogil=True)
def _source_of(indptr, entry):
    """The row (junction) a CSR entry belongs to (binary search in indptr)."""
    lo, hi = 0, indptr.shape[0] - 1
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        if indptr[mid] <= entry:
            lo = mid
        else:
            hi = mid
    return lo


def _compile() -> None:
    """Load (or compile) :func:`astar_junctions` for the types :class:`.graph.PathmapGraph` passes, when this
    module is imported: a query never pays it."""
    one_i, one_f = np.zeros(1, dtype=np.int64), np.zeros(1)
    astar_junctions(
        np.array([0, 0], dtype=np.int64),
        np.empty(0, np.int64),
        np.empty(0),
        np.zeros((1, 3)),
        one_i,
        one_f,
        one_i,
        one_f,
        np.zeros(3),
        np.inf,
    )


_compile()
