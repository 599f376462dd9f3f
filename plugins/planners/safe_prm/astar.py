"""A* over a roadmap in compressed sparse rows, compiled with numba: the search of every safe-PRM query.

The roadmap's milestones are nodes 0..n-1 and the graph is CSR over them
(both directions of every edge). A query adds two virtual nodes without
touching the graph: the *start* n (its links are the source's out-edges)
and the *goal* n+1 (a milestone linked to it ends a path there at the
link's cost), plus an optional direct start-goal motion.

The heuristic is the space's distance to the target, ``|w * (x - x_t)|``
(the edge costs are that same weighted Euclidean distance), scaled down by
one part in 10^12 so that round-off can never make it exceed a true
remaining cost: it is admissible and consistent, so A* returns a shortest
path (Hart, Nilsson & Raphael 1968) while settling only the nodes whose
cost plus heuristic is below the answer, not the whole roadmap as a
Dijkstra search from the source does. ``tests/test_safe_prm.py`` checks the
paths and costs against scipy's Dijkstra.

A search allocates nothing: its per-node arrays live in a :class:`Workspace`
made once per roadmap, valid for one search by a generation stamp (a node
whose stamp is not the current search's is unvisited, so nothing is reset
between searches), and the open set is an indexed binary heap with
decrease-key (:mod:`surgiplan.paths.heap`), which holds each node at most
once. Why numba: a query is a handful of searches over up to ~100,000
directed edges; in pure Python each costs milliseconds, compiled a few tens
of microseconds. Compiled when the module is imported (cached on disk by
numba), so no build or query pays it.
"""

from __future__ import annotations

import threading

import numpy as np
from numba import njit
from surgiplan.paths.heap import distance, indexed_decrease, indexed_pop, indexed_push

#: the heuristic's safety factor against round-off (see the module docstring)
_SHRINK = 1.0 - 1e-12


class Workspace:
    """The per-node arrays of the searches on one roadmap of ``n`` milestones (and a lock: one query at a time)."""

    def __init__(self, n: int) -> None:
        size = n + 2
        self.stamp = np.zeros(size, dtype=np.int64)  # the search that last touched a node
        self.best = np.empty(size)
        self.heuristic = np.empty(size)
        self.parent = np.empty(size, dtype=np.int64)
        self.closed = np.zeros(size, dtype=np.bool_)
        self.end_stamp = np.zeros(size, dtype=np.int64)
        self.end_cost = np.empty(size)
        self.heap_keys = np.empty(size)
        self.heap_items = np.empty(size, dtype=np.int64)
        self.position = np.empty(size, dtype=np.int64)
        self.generation = np.zeros(1, dtype=np.int64)
        self.path = np.empty(size, dtype=np.int64)
        self.lock = threading.Lock()

    def arrays(self) -> tuple:
        return (
            self.stamp,
            self.best,
            self.heuristic,
            self.parent,
            self.closed,
            self.end_stamp,
            self.end_cost,
            self.heap_keys,
            self.heap_items,
            self.position,
            self.generation,
        )


@njit(cache=True, nogil=True)
def search(
    indptr,
    indices,
    data,
    scaled,
    source,
    source_targets,
    source_costs,
    source_use,
    source_point,
    target,
    target_links,
    target_costs,
    target_use,
    target_point,
    direct_cost,
    stamp,
    best,
    heuristic,
    parent,
    closed,
    end_stamp,
    end_cost,
    keys,
    items,
    position,
    generation,
    path,
):
    """Shortest path from ``source`` to ``target``; writes its nodes to ``path`` and returns (count, cost,
    settled), count 0 when the target cannot be reached.

    Nodes: milestones 0..n-1; ``source`` n is the virtual start (out-edges ``source_targets[source_use]`` at
    ``source_costs``, position ``source_point``), ``target`` n+1 the virtual goal (reached from
    ``target_links[target_use]`` at ``target_costs``, position ``target_point``); ``direct_cost`` a motion from
    the virtual start straight to the virtual goal (``inf``: none). ``scaled``: milestone coordinates times the
    space's weights. The remaining arguments are a :class:`Workspace`'s arrays.
    """
    n = scaled.shape[0]
    start_node = n
    goal_node = n + 1
    generation[0] += 1
    gen = generation[0]
    if target == goal_node:
        goal_at = target_point
        for k in range(target_links.shape[0]):
            if not target_use[k]:
                continue
            t = target_links[k]
            if end_stamp[t] != gen or target_costs[k] < end_cost[t]:
                end_stamp[t] = gen
                end_cost[t] = target_costs[k]
    else:
        goal_at = scaled[target]
    size = 0
    if source == start_node:
        stamp[start_node] = gen
        best[start_node] = 0.0
        parent[start_node] = -1
        closed[start_node] = True
        for k in range(source_targets.shape[0]):
            if not source_use[k]:
                continue
            t = source_targets[k]
            g = source_costs[k]
            if stamp[t] != gen:
                stamp[t] = gen
                closed[t] = False
                best[t] = g
                parent[t] = start_node
                position[t] = -1
            elif g < best[t]:
                best[t] = g
        for k in range(source_targets.shape[0]):
            t = source_targets[k]
            if source_use[k] and position[t] < 0:
                heuristic[t] = distance(scaled, t, goal_at) * _SHRINK
                size = indexed_push(keys, items, position, size, best[t] + heuristic[t], t)
        if target == goal_node and direct_cost < np.inf:
            stamp[goal_node] = gen
            closed[goal_node] = False
            best[goal_node] = direct_cost
            parent[goal_node] = start_node
            position[goal_node] = -1
            size = indexed_push(keys, items, position, size, direct_cost, goal_node)
    else:
        stamp[source] = gen
        closed[source] = False
        best[source] = 0.0
        parent[source] = -1
        position[source] = -1
        size = indexed_push(keys, items, position, size, 0.0, source)

    settled = 0
    found = -1
    while size > 0:
        v, size = indexed_pop(keys, items, position, size)
        closed[v] = True
        settled += 1
        if v == target:
            found = v
            break
        g = best[v]
        if target == goal_node and end_stamp[v] == gen:
            c = g + end_cost[v]
            if stamp[goal_node] != gen:
                stamp[goal_node] = gen
                closed[goal_node] = False
                best[goal_node] = c
                parent[goal_node] = v
                position[goal_node] = -1
                size = indexed_push(keys, items, position, size, c, goal_node)
            elif c < best[goal_node]:
                best[goal_node] = c
                parent[goal_node] = v
                indexed_decrease(keys, items, position, position[goal_node], c)
        for e in range(indptr[v], indptr[v + 1]):
            w = indices[e]
            c = g + data[e]
            if stamp[w] != gen:
                stamp[w] = gen
                closed[w] = False
                best[w] = c
                parent[w] = v
                position[w] = -1
                heuristic[w] = distance(scaled, w, goal_at) * _SHRINK
                size = indexed_push(keys, items, position, size, c + heuristic[w], w)
            elif not closed[w] and c < best[w]:
                best[w] = c
                parent[w] = v
                indexed_decrease(keys, items, position, position[w], c + heuristic[w])

    if found < 0:
        return 0, np.inf, settled
    count = 1
    v = found
    while parent[v] >= 0:
        v = parent[v]
        count += 1
    v = found
    for k in range(count - 1, -1, -1):
        path[k] = v
        v = parent[v]
    return count, best[found], settled


def shortest_path(
    graph,
    scaled: np.ndarray,
    source: int,
    target: int,
    *,
    source_links: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    target_links: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    direct_cost: float = np.inf,
    workspace: Workspace | None = None,
) -> tuple[np.ndarray, float, int]:
    """:func:`search` on a scipy CSR matrix; ``*_links`` = (milestones, costs, scaled position) of a virtual end.

    Returns (nodes, cost, settled): the nodes -1 for the virtual start and -2 for the virtual goal, empty when the
    target cannot be reached.
    """
    n = scaled.shape[0]
    workspace = workspace or Workspace(n)
    empty_i, empty_f, nowhere = np.empty(0, np.int64), np.empty(0), np.zeros(scaled.shape[1])
    st, sc, sp = source_links if source_links is not None else (empty_i, empty_f, nowhere)
    tt, tc, tp = target_links if target_links is not None else (empty_i, empty_f, nowhere)
    count, cost, settled = search(
        np.ascontiguousarray(graph.indptr, np.int32),
        np.ascontiguousarray(graph.indices, np.int32),
        np.ascontiguousarray(graph.data, np.float64),
        np.ascontiguousarray(scaled, np.float64),
        n if source_links is not None else int(source),
        np.ascontiguousarray(st, np.int64),
        np.ascontiguousarray(sc, np.float64),
        np.ones(len(st), dtype=np.bool_),
        np.ascontiguousarray(sp, np.float64),
        n + 1 if target_links is not None else int(target),
        np.ascontiguousarray(tt, np.int64),
        np.ascontiguousarray(tc, np.float64),
        np.ones(len(tt), dtype=np.bool_),
        np.ascontiguousarray(tp, np.float64),
        float(direct_cost),
        *workspace.arrays(),
        workspace.path,
    )
    nodes = workspace.path[:count].copy()
    nodes[nodes == n] = -1
    nodes[nodes == n + 1] = -2
    return nodes, cost, settled


def _compile() -> None:
    from scipy.sparse import csr_matrix

    graph = csr_matrix((np.ones(2), np.array([1, 0], np.int32), np.array([0, 1, 2], np.int32)), shape=(2, 2))
    points = np.zeros((2, 3))
    shortest_path(graph, points, 0, 1)


_compile()
