"""A* over a roadmap in compressed sparse rows, compiled with numba: the search of every safe-PRM query.

The roadmap's milestones are nodes 0..n-1 and the graph is CSR over them
(both directions of every edge). A query adds two virtual nodes without
touching the graph: the *start* n (its links are the source's out-edges)
and the *goal* n+1 (a milestone linked to it ends a path there at the
link's cost), plus an optional direct start-goal motion.

The heuristic is the larger of two lower bounds on the cost to go: the
space's distance to the target, ``|w * (x - x_t)|`` (the edge costs are that
same weighted Euclidean distance), scaled down by one part in 10^12 so that
round-off can never make it exceed a true remaining cost, and the bound of
the roadmap's landmarks (:mod:`.landmarks`, loosened by a tolerance), which
follows the roadmap around obstacles. Both are admissible, so the search
returns a shortest path (Hart, Nilsson & Raphael 1968) while expanding only
the nodes whose cost plus heuristic is below the answer, not the whole
roadmap as a Dijkstra search from the source does. ``tests/test_safe_prm.py``
checks the paths and costs against scipy's Dijkstra.

The open set is a bucket queue, not a heap: entries go to buckets of width
``delta`` by their key (cost plus heuristic) and come out bucket by bucket,
in any order within one, so no comparison-driven sift decides each step (a
heap's pops, each a dozen unpredictable branches, were most of a search's
time). Within a bucket a node can come out before a cheaper way to it is
known; it is then expanded again when that way is found (label-correcting),
and the search ends only once the lowest bucket left cannot hold anything
cheaper than the best path to the target found, so the answer is still the
shortest path. With ``delta`` a small fraction of an edge, re-expansions are
rare. Keys far beyond the window of buckets wait in an overflow list and are
re-bucketed when the window moves on.

A search allocates nothing: its arrays live in a :class:`Workspace` made
once per roadmap, valid for one search by a generation stamp (a node whose
stamp is not the current search's is unvisited, so nothing is reset). Why
numba: a query is a handful of searches over up to ~100,000 directed edges;
in pure Python each costs milliseconds. Compiled when the module is
imported (cached on disk by numba), so no build or query pays it.
"""

from __future__ import annotations

import threading

import numpy as np
from numba import njit

#: the heuristic's safety factor against round-off (see the module docstring)
_SHRINK = 1.0 - 1e-12
#: buckets in the window (a power of two)
BUCKETS = 1 << 12
#: a bucket's width, as a fraction of the roadmap's mean edge cost
BUCKET_FRACTION = 1.0 / 32.0
# the record of a node: its stamp, cost so far, heuristic and parent side by side, 32 bytes (a visit touches one
# cache line of it, where separate arrays cost one each: a query after other work runs on cold caches)
_STAMP, _COST, _HEURISTIC, _PARENT = 0, 1, 2, 3


class Workspace:
    """The arrays of the searches on one roadmap of ``n`` milestones (and a lock: one query at a time)."""

    def __init__(self, n: int, entries: int) -> None:
        size = n + 2
        self.node = np.zeros((size, 4))  # stamp, cost, heuristic, parent
        self.end = np.zeros((size, 2))  # stamp, cost of the link to the virtual goal
        self.head = np.full(BUCKETS, -1, dtype=np.int32)  # empty buckets (a search leaves them so)
        self.entry_node = np.empty(entries, dtype=np.int32)
        self.entry_key = np.empty(entries)
        self.entry_next = np.empty(entries, dtype=np.int32)
        self.generation = np.zeros(1)
        self.path = np.empty(size, dtype=np.int64)
        self.lock = threading.Lock()

    def grow(self) -> None:
        """Twice the entries (a search that ran out of them is run again)."""
        entries = 2 * len(self.entry_node)
        self.entry_node = np.empty(entries, dtype=np.int32)
        self.entry_key = np.empty(entries)
        self.entry_next = np.empty(entries, dtype=np.int32)

    def arrays(self) -> tuple:
        """The arrays in the order :func:`search` takes them."""
        return (
            self.node,
            self.end,
            self.head,
            self.entry_node,
            self.entry_key,
            self.entry_next,
            self.generation,
            self.path,
        )


@njit(cache=True, nogil=True, inline="always")
def _heuristic(scaled, v, goal_at, far, low, high):
    """The larger of the straight-line bound and the landmarks' (see :mod:`.landmarks`) on v's cost to go."""
    total = 0.0
    for d in range(scaled.shape[1]):
        diff = scaled[v, d] - goal_at[d]
        total += diff * diff
    best = np.sqrt(total) * _SHRINK
    for j in range(low.shape[0]):
        to_landmark = far[v, j]
        if to_landmark < np.inf:  # v in the landmark's component
            best = max(best, low[j] - to_landmark, to_landmark - high[j])
    return best


@njit(cache=True, nogil=True)
def _landmark_bounds(far, tolerance, target, goal_node, target_links, target_costs, target_use, low, high):
    """Per landmark L, the bounds that make ``max(low - d(v, L), d(v, L) - high)`` a lower bound on v's cost to
    the target: d(t, L) both for a milestone t; for the virtual goal, reached through its links (t_k, c_k),
    ``min(d(t_k, L) + c_k)`` and ``max(d(t_k, L) - c_k)`` over the links in L's component (none: the landmark is
    left out, ``low`` -inf and ``high`` inf). Loosened by ``tolerance`` against round-off."""
    for j in range(low.shape[0]):
        low[j] = np.inf
        high[j] = -np.inf
        if target != goal_node:
            low[j] = high[j] = far[target, j]
        else:
            for k in range(target_links.shape[0]):
                to_landmark = far[target_links[k], j]
                if target_use[k] and to_landmark < np.inf:
                    low[j] = min(low[j], to_landmark + target_costs[k])
                    high[j] = max(high[j], to_landmark - target_costs[k])
        if low[j] == np.inf:
            low[j] = -np.inf
            high[j] = np.inf
        else:
            low[j] -= tolerance
            high[j] += tolerance


@njit(cache=True, nogil=True, inline="always")
def _top(top, bucket, window, size):
    """The slots of the window that may hold entries (``head[:top]``) once one is filed into ``bucket``."""
    slot = bucket - window
    return max(top, slot + 1) if slot < size else top


@njit(cache=True, nogil=True, inline="always")
def _file(e, bucket, window, head, entry_next, overflow):
    """Entry e into its bucket when the window holds it, else onto the overflow list; returns the list's head."""
    if bucket - window < head.shape[0]:
        entry_next[e] = head[bucket - window]
        head[bucket - window] = e
        return overflow
    entry_next[e] = overflow
    return e


@njit(cache=True, nogil=True)
def search(
    indptr,
    indices,
    data,
    scaled,
    far,
    tolerance,
    delta,
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
    node,
    end,
    head,
    entry_node,
    entry_key,
    entry_next,
    generation,
    path,
):
    """Shortest path from ``source`` to ``target``; writes its nodes to ``path`` and returns (count, cost,
    expanded), count 0 when the target cannot be reached and -1 when the workspace ran out of entries.

    Nodes: milestones 0..n-1; ``source`` n is the virtual start (out-edges ``source_targets[source_use]`` at
    ``source_costs``, position ``source_point``), ``target`` n+1 the virtual goal (reached from
    ``target_links[target_use]`` at ``target_costs``, position ``target_point``); ``direct_cost`` a motion from
    the virtual start straight to the virtual goal (``inf``: none). ``scaled``: milestone coordinates times the
    space's weights; ``far``: every milestone's roadmap distance to each landmark (float32,
    :func:`compact_landmarks`; no columns: the straight-line bound alone), ``tolerance`` the round-off allowed in
    them; ``delta`` the buckets' width. The remaining arguments are a :class:`Workspace`'s arrays.
    """
    n = scaled.shape[0]
    start_node = n
    goal_node = n + 1
    capacity = entry_node.shape[0]
    generation[0] += 1.0
    gen = generation[0]
    goal_at = target_point if target == goal_node else scaled[target]
    low = np.empty(far.shape[1])
    high = np.empty(far.shape[1])
    _landmark_bounds(far, tolerance, target, goal_node, target_links, target_costs, target_use, low, high)
    if target == goal_node:
        for k in range(target_links.shape[0]):
            if target_use[k]:
                t = target_links[k]
                if end[t, 0] != gen or target_costs[k] < end[t, 1]:
                    end[t, 0] = gen
                    end[t, 1] = target_costs[k]
    # every slot of head is empty (-1) between searches: a search empties the buckets it drains and, when it
    # ends, the slots it filed and left (head[:top]); clearing the whole window at each start was 16 kB written
    window_size = head.shape[0]
    top = 0
    used = 0
    # the first entries: the source itself, or the start's links (and the direct motion to the goal)
    goal_cost = np.inf
    node[start_node, _STAMP] = gen
    node[start_node, _COST] = 0.0
    node[start_node, _PARENT] = -1
    node[goal_node, _STAMP] = gen
    node[goal_node, _COST] = np.inf
    if source == start_node:
        for k in range(source_targets.shape[0]):
            if not source_use[k]:
                continue
            t = source_targets[k]
            if node[t, _STAMP] != gen:
                node[t, _STAMP] = gen
                node[t, _HEURISTIC] = _heuristic(scaled, t, goal_at, far, low, high)
            elif source_costs[k] >= node[t, _COST]:
                continue
            node[t, _COST] = source_costs[k]
            node[t, _PARENT] = start_node
            if t == target:
                goal_cost = min(goal_cost, source_costs[k])
        if target == goal_node and direct_cost < goal_cost:
            goal_cost = direct_cost
            node[goal_node, _COST] = direct_cost
            node[goal_node, _PARENT] = start_node
        for k in range(source_targets.shape[0]):
            t = source_targets[k]
            if source_use[k] and node[t, _PARENT] == start_node and node[t, _COST] == source_costs[k]:
                if used == capacity:
                    return -1, np.inf, 0
                entry_node[used] = t
                entry_key[used] = node[t, _COST] + node[t, _HEURISTIC]
                used += 1
    else:
        node[source, _STAMP] = gen
        node[source, _COST] = 0.0
        node[source, _HEURISTIC] = _heuristic(scaled, source, goal_at, far, low, high)
        node[source, _PARENT] = -1
        entry_node[0] = source
        entry_key[0] = node[source, _HEURISTIC]
        used = 1
        if source == target:
            goal_cost = 0.0
    base = np.inf
    for e in range(used):
        base = min(base, entry_key[e])
    overflow = -1
    for e in range(used):
        bucket = int((entry_key[e] - base) / delta)
        overflow = _file(e, bucket, 0, head, entry_next, overflow)
        top = _top(top, bucket, 0, window_size)
    pending = used
    current = 0  # the bucket being emptied (counted from base)
    window = 0  # the bucket at the window's first slot
    expanded = 0
    while pending > 0:
        if base + current * delta >= goal_cost:
            break  # nothing left can be cheaper than the path found
        if current - window >= window_size:
            # the window moves on: overflow entries that now fall within it go to their buckets
            window = current
            top = 0  # every slot drained on the way here
            e = overflow
            overflow = -1
            while e >= 0:
                following = entry_next[e]
                bucket = max(int((entry_key[e] - base) / delta), window)
                overflow = _file(e, bucket, window, head, entry_next, overflow)
                top = _top(top, bucket, window, window_size)
                e = following
        e = head[current - window]
        if e < 0:
            current += 1
            continue
        head[current - window] = entry_next[e]
        pending -= 1
        v = entry_node[e]
        g = node[v, _COST]
        if entry_key[e] != g + node[v, _HEURISTIC] or entry_key[e] >= goal_cost:
            continue  # a later, cheaper entry of v exists (or cannot help)
        if v == target:
            continue
        expanded += 1
        if target == goal_node and end[v, 0] == gen:
            c = g + end[v, 1]
            if c < goal_cost:
                goal_cost = c
                node[goal_node, _COST] = c
                node[goal_node, _PARENT] = v
        for k in range(indptr[v], indptr[v + 1]):
            w = indices[k]
            c = g + data[k]
            if node[w, _STAMP] != gen:
                node[w, _STAMP] = gen
                node[w, _HEURISTIC] = _heuristic(scaled, w, goal_at, far, low, high)
            elif c >= node[w, _COST]:
                continue
            node[w, _COST] = c
            node[w, _PARENT] = v
            if w == target:
                goal_cost = min(goal_cost, c)
                continue
            key = c + node[w, _HEURISTIC]
            if key >= goal_cost:
                continue
            if used == capacity:
                for b in range(top):
                    head[b] = -1
                return -1, np.inf, expanded
            entry_node[used] = w
            entry_key[used] = key
            bucket = max(int((key - base) / delta), current)
            overflow = _file(used, bucket, window, head, entry_next, overflow)
            top = _top(top, bucket, window, window_size)
            used += 1
            pending += 1
    for b in range(top):
        head[b] = -1

    if goal_cost == np.inf:
        return 0, np.inf, expanded
    count = 1
    v = target
    while node[v, _PARENT] >= 0:
        v = int(node[v, _PARENT])
        count += 1
    v = target
    for k in range(count - 1, -1, -1):
        path[k] = v
        v = int(node[v, _PARENT])
    return count, goal_cost, expanded


def bucket_width(edge_cost: np.ndarray) -> float:
    """The buckets' width for a roadmap: :data:`BUCKET_FRACTION` of its mean edge cost (positive)."""
    mean = float(np.mean(edge_cost)) if len(edge_cost) else 1.0
    return max(mean * BUCKET_FRACTION, 1e-12)


def landmark_tolerance(far: np.ndarray) -> float:
    """The round-off allowed in the landmark bounds: a millionth of the longest finite distance. The distances
    are stored as float32 (:func:`compact_landmarks`), each rounded by at most 2^-24 of itself, the node's and
    the target's both, 1.2e-7 of the longest at most; a distance summed over a path of up to thousands of edges
    is off by far less again."""
    finite = far[np.isfinite(far)]
    return 1e-6 * float(finite.max()) if finite.size else 0.0


#: bytes in a cache line: a node's :func:`search_records` row fills whole ones, starting at a line
CACHE_LINE = 64


def search_records(scaled: np.ndarray, far: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What :func:`search` reads of each node it reaches, side by side: its position (``scaled``, float64) and its
    landmark distances (``far``, float32 as :func:`compact_landmarks`) in one row of whole cache lines, the first
    row at a line's start (for 3 coordinates and 8 landmarks: 56 bytes, one line). A search reaches a thousand
    nodes or so, scattered; after other work each row is a miss, so one line a node instead of two or three is
    most of what a cold query costs. Returns the two as views of the rows (``scaled`` then ``far``)."""
    n, d = scaled.shape
    count = far.shape[1]
    width = -(-(8 * d + 4 * count) // CACHE_LINE) * CACHE_LINE // 8  # float64 columns, whole lines
    block = np.zeros(n * width + CACHE_LINE // 8)
    skip = (-block.ctypes.data % CACHE_LINE) // 8
    rows = block[skip : skip + n * width].reshape(n, width)
    rows[:, :d] = scaled
    landmarks = rows.view(np.float32)[:, 2 * d : 2 * d + count]
    landmarks[:] = far
    return rows[:, :d], landmarks


def compact_landmarks(far: np.ndarray) -> np.ndarray:
    """Landmark distances as the search reads them: float32, C order (32 bytes a node for 8 landmarks, half a
    cache line; they only bound the heuristic, loosened by :func:`landmark_tolerance`, so the costs the search
    adds stay exact float64)."""
    return np.ascontiguousarray(far, dtype=np.float32)


def shortest_path(
    graph,
    scaled: np.ndarray,
    source: int,
    target: int,
    *,
    source_links: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    target_links: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    direct_cost: float = np.inf,
    delta: float | None = None,
    far: np.ndarray | None = None,
) -> tuple[np.ndarray, float, int]:
    """:func:`search` on a scipy CSR matrix; ``*_links`` = (milestones, costs, scaled position) of a virtual end;
    ``delta``: the buckets' width (default :func:`bucket_width` of the graph's costs); ``far``: the nodes'
    distances to landmarks that bound the cost to go besides the straight line (:mod:`.landmarks`).

    Returns (nodes, cost, expanded): the nodes -1 for the virtual start and -2 for the virtual goal, empty when
    the target cannot be reached.
    """
    n = scaled.shape[0]
    workspace = Workspace(n, len(graph.indices) + n + 16)
    empty_i, empty_f, nowhere = np.empty(0, np.int64), np.empty(0), np.zeros(scaled.shape[1])
    st, sc, sp = source_links if source_links is not None else (empty_i, empty_f, nowhere)
    tt, tc, tp = target_links if target_links is not None else (empty_i, empty_f, nowhere)
    rows = (
        np.ascontiguousarray(graph.indptr, np.int32),
        np.ascontiguousarray(graph.indices, np.int32),
        np.ascontiguousarray(graph.data, np.float64),
    )
    far = compact_landmarks(np.empty((n, 0)) if far is None else far)
    arguments = (
        *rows,
        np.ascontiguousarray(scaled, np.float64),
        far,
        landmark_tolerance(far),
        float(delta) if delta is not None else bucket_width(graph.data),
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
    )
    while True:
        count, cost, expanded = search(*arguments, *workspace.arrays())
        if count >= 0:
            break
        workspace.grow()
    nodes = workspace.path[:count].copy()
    nodes[nodes == n] = -1
    nodes[nodes == n + 1] = -2
    return nodes, cost, expanded


def _compile() -> None:
    from scipy.sparse import csr_matrix

    graph = csr_matrix((np.ones(2), np.array([1, 0], np.int32), np.array([0, 1, 2], np.int32)), shape=(2, 2))
    shortest_path(graph, np.zeros((2, 3)), 0, 1)


_compile()
