"""A* over a roadmap in compressed sparse rows, compiled with numba: the search of every safe-PRM query.

The roadmap's milestones are nodes 0..n-1 and the graph is a CSR matrix
over them (both directions of every edge). A query adds two virtual nodes
without touching the matrix: the *start* (its links are the source's
out-edges) and the *goal* (a milestone linked to it ends a path there at
the link's cost), plus an optional direct start-goal motion.

The heuristic is the space's distance to the target, ``|w * (x - x_t)|``
(the edge costs are that same weighted Euclidean distance), scaled down by
one part in 10^12 so that round-off can never make it exceed a true
remaining cost: it is admissible and consistent, so A* returns a shortest
path (Hart, Nilsson & Raphael 1968) while settling only the nodes whose
cost plus heuristic is below the answer, not the whole roadmap as a
Dijkstra search from the source does. ``tests/test_safe_prm.py`` checks the
paths and costs against scipy's Dijkstra.

Why numba: a query is a handful of searches on a graph of up to ~100,000
directed edges; in pure Python each search costs milliseconds, and scipy's
Dijkstra settles every node within reach and needs the start's links as a
new CSR row per query. Compiled, a search that settles a few thousand
nodes takes tens of microseconds. ``cache=True`` keeps the compiled code
beside this file (or in numba's user cache when that is read-only), so
only the first run on a machine pays the compilation (about a second).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from surgiplan.paths.heap import distance, pop, push

#: the heuristic's safety factor against round-off (see the module docstring)
_SHRINK = 1.0 - 1e-12


@njit(cache=True, nogil=True)
def astar(
    indptr,
    indices,
    data,
    scaled,
    source,
    source_targets,
    source_costs,
    source_point,
    target,
    target_links,
    target_costs,
    target_point,
    direct_cost,
):
    """Shortest path from ``source`` to ``target`` over the CSR graph; returns (nodes, cost, settled).

    ``source``/``target``: a milestone index, or -1 for a virtual start
    (out-edges ``source_targets`` at ``source_costs``, position
    ``source_point``) or a virtual goal (reached from ``target_links`` at
    ``target_costs``, position ``target_point``). ``direct_cost``: a motion
    from the virtual start straight to the virtual goal (``inf``: none).
    ``scaled``: milestone coordinates times the space's weights. The path
    lists node indices, -1 for the virtual start (first) and -2 for the
    virtual goal (last); it is empty when the target cannot be reached.
    """
    n = scaled.shape[0]
    start_node = n  # the virtual start, in the per-query arrays
    goal_node = n + 1
    best = np.full(n + 2, np.inf)
    parent = np.full(n + 2, -1, dtype=np.int64)
    closed = np.zeros(n + 2, dtype=np.bool_)
    end_cost = np.full(n, np.inf)
    if target < 0:
        goal_at = target_point
        for k in range(target_links.shape[0]):
            t = target_links[k]
            if target_costs[k] < end_cost[t]:
                end_cost[t] = target_costs[k]
    else:
        goal_at = scaled[target]
    capacity = indices.shape[0] + source_targets.shape[0] + target_links.shape[0] + 4
    keys = np.empty(capacity)
    items = np.empty(capacity, dtype=np.int64)
    size = 0

    if source < 0:
        best[start_node] = 0.0
        for k in range(source_targets.shape[0]):
            t = source_targets[k]
            g = source_costs[k]
            if g < best[t]:
                best[t] = g
                parent[t] = start_node
        for k in range(source_targets.shape[0]):
            t = source_targets[k]
            if parent[t] == start_node and not closed[t]:
                size = push(keys, items, size, best[t] + distance(scaled, t, goal_at) * _SHRINK, t)
        if target < 0 and direct_cost < best[goal_node]:
            best[goal_node] = direct_cost
            parent[goal_node] = start_node
            size = push(keys, items, size, direct_cost, goal_node)
    else:
        best[source] = 0.0
        size = push(keys, items, size, 0.0, source)

    settled = 0
    found = -1
    while size > 0:
        v, size = pop(keys, items, size)
        if closed[v]:
            continue
        closed[v] = True
        settled += 1
        if v == goal_node or v == target:
            found = v
            break
        g = best[v]
        if target < 0 and end_cost[v] < np.inf:
            c = g + end_cost[v]
            if c < best[goal_node]:
                best[goal_node] = c
                parent[goal_node] = v
                size = push(keys, items, size, c, goal_node)
        for e in range(indptr[v], indptr[v + 1]):
            w = indices[e]
            if closed[w]:
                continue
            c = g + data[e]
            if c < best[w]:
                best[w] = c
                parent[w] = v
                size = push(keys, items, size, c + distance(scaled, w, goal_at) * _SHRINK, w)

    if found < 0:
        return np.empty(0, dtype=np.int64), np.inf, settled
    count = 1
    v = found
    while parent[v] >= 0:
        v = parent[v]
        count += 1
    out = np.empty(count, dtype=np.int64)
    v = found
    for k in range(count - 1, -1, -1):
        out[k] = -1 if v == start_node else (-2 if v == goal_node else v)
        v = parent[v]
    return out, best[found], settled


def shortest_path(
    graph,
    scaled: np.ndarray,
    source: int,
    target: int,
    *,
    source_links: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    target_links: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    direct_cost: float = np.inf,
) -> tuple[np.ndarray, float, int]:
    """:func:`astar` on a scipy CSR matrix; ``*_links`` = (milestones, costs, scaled position) of a virtual end."""
    empty_i, empty_f, nowhere = np.empty(0, np.int64), np.empty(0), np.zeros(scaled.shape[1])
    st, sc, sp = source_links if source_links is not None else (empty_i, empty_f, nowhere)
    tt, tc, tp = target_links if target_links is not None else (empty_i, empty_f, nowhere)
    return astar(
        graph.indptr,
        graph.indices,
        graph.data,
        scaled,
        -1 if source_links is not None else int(source),
        np.ascontiguousarray(st, np.int64),
        np.ascontiguousarray(sc, np.float64),
        np.ascontiguousarray(sp, np.float64),
        -1 if target_links is not None else int(target),
        np.ascontiguousarray(tt, np.int64),
        np.ascontiguousarray(tc, np.float64),
        np.ascontiguousarray(tp, np.float64),
        float(direct_cost),
    )
