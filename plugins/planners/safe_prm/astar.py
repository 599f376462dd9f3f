"""A* over a roadmap in compressed sparse rows, compiled with numba: the search of every safe-PRM query.

The roadmap's milestones are nodes 0..n-1 and the graph is CSR over them
(both directions of every edge), held with each milestone's search record in
a :class:`Graph`. A query adds two virtual nodes without touching the graph:
the *start* n (its links are the source's out-edges) and the *goal* n+1 (a
milestone linked to it ends a path there at the link's cost), plus an
optional direct start-goal motion (:class:`Ends`).

The heuristic is a lower bound on the cost to go: the bound of the
roadmap's landmarks (:mod:`.landmarks`), which follows the roadmap around
obstacles (0 for a node in a component no landmark reaches), or, on a
roadmap without landmarks, the space's distance to the target,
``|w * (x - x_t)|`` (the edge costs are that same weighted Euclidean
distance), scaled down by one part in 10^12 so that round-off can never make
it exceed a true remaining cost. Both are admissible, so the search returns
a shortest path (Hart, Nilsson & Raphael 1968) while expanding only the
nodes whose cost plus heuristic is below the answer, not the whole roadmap
as a Dijkstra search from the source does. ``tests/test_safe_prm.py`` checks
the paths and costs against scipy's Dijkstra. The larger of the two bounds
settles 6-14 % fewer nodes than the landmarks' alone (block world, 5,000
milestones, 15 queries a level), but reading each node's position and taking
a square root cost more than that: queries took 24-32 % longer (interleaved,
both orders).

The landmark distances are stored as 16-bit *marks*: a mark q of a distance
d is ``floor(d / quantum)``, the quantum the roadmap's longest landmark
distance over 65,534 (a few micrometres), so d lies within one quantum of
``q * quantum`` either way, round-off included. For a target t the bound of
landmark L on a node v's cost to go is then ``(|q_t - q_v| - 2) * quantum``:
the triangle inequality's ``|d(L, t) - d(L, v)|`` less the two marks' slack,
still admissible. A node's marks fill at most one 64-byte cache line
(:func:`search_graph`), so a node reached for the first time costs one line
of roadmap data, and the marks' bounds are integer lanes the compiler
vectorises.

The open set is a bucket queue, not a heap: entries go to buckets of width
``delta`` by their key (cost plus heuristic) and come out bucket by bucket,
in any order within one, so no comparison-driven sift decides each step (a
heap's pops, each a dozen unpredictable branches, were most of a search's
time). Within a bucket a node can come out before a cheaper way to it is
known; it is then expanded again when that way is found (label-correcting),
and the search ends only once the lowest bucket left cannot hold anything
cheaper than the best path to the target found, so the answer is still the
shortest path. The buckets are narrow (:data:`BUCKET_FRACTION` of a mean
edge): with a good heuristic many edges cost little more than the heuristic
drops along them, and wide buckets let such chains come out of order (a
quarter more expansions at 1/32 of an edge than at 1/256). Keys far beyond
the window of buckets wait in an overflow list and are re-bucketed when the
window moves on.

A search allocates nothing: its arrays live in a :class:`Workspace` made
once per roadmap, valid for one search by a generation stamp (a node whose
stamp is not the current search's is unvisited, so nothing is reset). Node
indices are unsigned (the CSR arrays are ``uint32``): a signed index costs
each array access a wraparound test, most of a relaxation's instructions.
Why numba: a query is a handful of searches over up to ~100,000 directed
edges; in pure Python each costs milliseconds. Compiled when the module is
imported (cached on disk by numba), so no build or query pays it.
"""

from __future__ import annotations

import threading
from typing import NamedTuple

import numpy as np
from numba import njit

#: the heuristic's safety factor against round-off (see the module docstring)
_SHRINK = 1.0 - 1e-12
#: buckets in the window (a power of two)
BUCKETS = 1 << 12
#: a bucket's width, as a fraction of the roadmap's mean edge cost
BUCKET_FRACTION = 1.0 / 256.0
# the record of a node: its stamp, cost so far, heuristic and parent side by side, 32 bytes (a visit touches one
# cache line of it, where separate arrays cost one each: a query after other work runs on cold caches)
_STAMP, _COST, _HEURISTIC, _PARENT = 0, 1, 2, 3
#: bytes in a cache line: a node's search record fills whole ones, starting at a line
CACHE_LINE = 64
#: the mark of a milestone in another component than the landmark (no distance)
UNREACHED = 65535
#: a landmark bound that never wins (a landmark no target link can use); the bounds are int32 lanes
_NO_BOUND = 1 << 24


class Graph(NamedTuple):
    """A roadmap as :func:`search` reads it (:func:`search_graph` makes one)."""

    #: CSR rows over the milestones (``uint32``), both directions of every edge, and the edges' costs
    indptr: np.ndarray
    indices: np.ndarray
    data: np.ndarray
    #: each milestone's position (coordinates times the space's weights), float64 (n, d): R and R_safe share it
    points: np.ndarray
    #: each milestone's landmark marks, uint16 (n, width): landmark j's in column j, a row never across two cache
    #: lines
    marks: np.ndarray
    landmarks: int
    quantum: float
    #: the buckets' width (:func:`bucket_width`)
    delta: float


class Ends(NamedTuple):
    """A query's virtual start or goal: the milestones it links to, the links' costs, which of them the search may
    use, and its position (scaled)."""

    targets: np.ndarray
    costs: np.ndarray
    use: np.ndarray
    point: np.ndarray


class Work(NamedTuple):
    """A :class:`Workspace`'s arrays, as :func:`search` takes them."""

    node: np.ndarray  # (n + 2, 4): stamp, cost, heuristic, parent
    end: np.ndarray  # (n + 2, 2): stamp, cost of the link to the virtual goal
    head: np.ndarray  # the window's buckets (empty, -1, between searches)
    entry_node: np.ndarray
    entry_key: np.ndarray
    entry_next: np.ndarray
    generation: np.ndarray
    path: np.ndarray


def _work(n: int, entries: int) -> Work:
    size = n + 2
    return Work(
        np.zeros((size, 4)),
        np.zeros((size, 2)),
        np.full(BUCKETS, -1, dtype=np.int32),
        np.empty(entries, dtype=np.uint32),
        np.empty(entries),
        np.empty(entries, dtype=np.int32),
        np.zeros(1),
        np.empty(size, dtype=np.int64),
    )


class Workspace:
    """The arrays of the searches on one roadmap of ``n`` milestones (and a lock: one query at a time)."""

    def __init__(self, n: int, entries: int) -> None:
        self.n = n
        self.arrays = _work(n, entries)
        self.lock = threading.Lock()

    def grow(self) -> None:
        """Twice the entries (a search that ran out of them is run again)."""
        grown = _work(self.n, 2 * len(self.arrays.entry_node))
        self.arrays = self.arrays._replace(
            entry_node=grown.entry_node, entry_key=grown.entry_key, entry_next=grown.entry_next
        )


@njit(cache=True, nogil=True)
def _landmark_bounds(marks, landmarks, quantum, target, goal_node, targets, costs, use, low, high):
    """Per landmark, the marks that make ``max(low - q_v, q_v - high) * quantum`` a lower bound on v's cost to the
    target: q_t less and more 2 for a milestone t; for the virtual goal, reached through its links (t_k, c_k:
    ``targets``, ``costs`` where ``use``), ``min(q(t_k) + c_k / quantum)`` less 2 and ``max(q(t_k) - c_k / quantum)``
    more 2 over the links in the landmark's component (none: the landmark bounds nothing)."""
    for j in range(landmarks):
        lowest = np.inf
        highest = -np.inf
        if target != goal_node:
            mark = marks[target, j]
            if mark != UNREACHED:
                lowest = highest = float(mark)
        else:
            for k in range(targets.shape[0]):
                mark = marks[targets[k], j]
                if use[k] and mark != UNREACHED:
                    lowest = min(lowest, mark + costs[k] / quantum)
                    highest = max(highest, mark - costs[k] / quantum)
        if lowest == np.inf:
            low[j] = -_NO_BOUND
            high[j] = _NO_BOUND
        else:  # a bound clipped to the lanes' range is only weaker
            low[j] = min(np.floor(lowest) - 2, _NO_BOUND)
            high[j] = max(np.ceil(highest) + 2, -_NO_BOUND)


@njit(cache=True, nogil=True)
def search(graph, source, target, start, goal, direct_cost, work):
    """Shortest path from ``source`` to ``target`` in ``graph``; writes its nodes to ``work.path`` and returns
    (count, cost, expanded), count 0 when the target cannot be reached and -1 when the workspace ran out of
    entries.

    Nodes: milestones 0..n-1; ``source`` n is the virtual start (its out-edges are ``start``'s links),
    ``target`` n+1 the virtual goal (reached through ``goal``'s links); ``direct_cost`` a motion from the
    virtual start straight to the virtual goal (``inf``: none). ``work``: a :class:`Workspace`'s arrays.
    """
    # the bundles taken apart once (their fields read in the loops would cost a reference count each)
    indptr, indices, data = graph.indptr, graph.indices, graph.data
    points, marks, landmarks, quantum = graph.points, graph.marks, graph.landmarks, graph.quantum
    n, dimension = points.shape
    start_targets, start_costs, start_use = start.targets, start.costs, start.use
    goal_targets, goal_costs, goal_use = goal.targets, goal.costs, goal.use
    node, end, head = work.node, work.end, work.head
    entry_node, entry_key, entry_next = work.entry_node, work.entry_key, work.entry_next
    start_node = n
    goal_node = n + 1
    capacity = entry_node.shape[0]
    generation = work.generation
    generation[0] += 1.0
    gen = generation[0]
    goal_at = goal.point if target == goal_node else points[target]
    low = np.empty(landmarks, dtype=np.int32)
    high = np.empty(landmarks, dtype=np.int32)
    _landmark_bounds(marks, landmarks, quantum, target, goal_node, goal_targets, goal_costs, goal_use, low, high)

    # The search's steps as closures: compiled into its own code with the arrays they use, where a call passing
    # arrays costs more than what it does (numba passes each array as seven words and counts references to it)
    window_size = head.shape[0]
    unsigned_landmarks = np.uint64(landmarks)  # an unsigned index needs no test for wrapping around
    nothing = np.int32(-_NO_BOUND)

    def heuristic(v):
        """The landmarks' bound on v's cost to go, the straight line's when the roadmap has no landmarks (see the
        module docstring)."""
        total = 0.0
        if landmarks == 0:
            for d in range(dimension):
                diff = points[v, d] - goal_at[d]
                total += diff * diff
        best = nothing
        for j in range(unsigned_landmarks):  # int32 lanes, eight to a vector instruction
            mark = np.int32(marks[v, j])
            bound = max(np.int32(low[j] - mark), np.int32(mark - high[j]))
            best = max(best, bound if mark != UNREACHED else nothing)
        return max(np.sqrt(total) * _SHRINK, best * quantum)

    def file(e, bucket, window, overflow):
        """Entry e into its bucket when the window holds it, else onto the overflow list; returns the list's head."""
        if bucket - window < window_size:
            entry_next[e] = head[bucket - window]
            head[bucket - window] = e
            return overflow
        entry_next[e] = overflow
        return e

    def top_after(top, bucket, window):
        """The slots of the window that may hold entries (``head[:top]``) once one is filed into ``bucket``."""
        slot = bucket - window
        return max(top, slot + 1) if slot < window_size else top

    if target == goal_node:
        for k in range(goal_targets.shape[0]):
            if goal_use[k]:
                t = goal_targets[k]
                if end[t, 0] != gen or goal_costs[k] < end[t, 1]:
                    end[t, 0] = gen
                    end[t, 1] = goal_costs[k]
    # every slot of head is empty (-1) between searches: a search empties the buckets it drains and, when it
    # ends, the slots it filed and left (head[:top]); clearing the whole window at each start was 16 kB written
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
        for k in range(start_targets.shape[0]):
            if not start_use[k]:
                continue
            t = start_targets[k]
            if node[t, _STAMP] != gen:
                node[t, _STAMP] = gen
                node[t, _HEURISTIC] = heuristic(t)
            elif start_costs[k] >= node[t, _COST]:
                continue
            node[t, _COST] = start_costs[k]
            node[t, _PARENT] = start_node
            if t == target:
                goal_cost = min(goal_cost, start_costs[k])
        if target == goal_node and direct_cost < goal_cost:
            goal_cost = direct_cost
            node[goal_node, _COST] = direct_cost
            node[goal_node, _PARENT] = start_node
        for k in range(start_targets.shape[0]):
            t = start_targets[k]
            if start_use[k] and node[t, _PARENT] == start_node and node[t, _COST] == start_costs[k]:
                if used == capacity:
                    return -1, np.inf, 0
                entry_node[used] = t
                entry_key[used] = node[t, _COST] + node[t, _HEURISTIC]
                used += 1
    else:
        node[source, _STAMP] = gen
        node[source, _COST] = 0.0
        node[source, _HEURISTIC] = heuristic(source)
        node[source, _PARENT] = -1
        entry_node[0] = source
        entry_key[0] = node[source, _HEURISTIC]
        used = 1
        if source == target:
            goal_cost = 0.0
    base = np.inf
    for e in range(used):
        base = min(base, entry_key[e])
    delta = graph.delta
    inverse = 1.0 / delta
    overflow = -1
    for e in range(used):
        bucket = int((entry_key[e] - base) * inverse)
        overflow = file(e, bucket, 0, overflow)
        top = top_after(top, bucket, 0)
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
                bucket = max(int((entry_key[e] - base) * inverse), window)
                overflow = file(e, bucket, window, overflow)
                top = top_after(top, bucket, window)
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
                node[w, _HEURISTIC] = heuristic(w)
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
            bucket = max(int((key - base) * inverse), current)
            overflow = file(used, bucket, window, overflow)
            top = top_after(top, bucket, window)
            used += 1
            pending += 1
    for b in range(top):
        head[b] = -1

    if goal_cost == np.inf:
        return 0, np.inf, expanded
    path = work.path
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


def bucket_width(edge_cost: np.ndarray, fraction: float = BUCKET_FRACTION) -> float:
    """The buckets' width for a roadmap: ``fraction`` of its mean edge cost (positive)."""
    mean = float(np.mean(edge_cost)) if len(edge_cost) else 1.0
    return max(mean * fraction, 1e-12)


@njit(cache=True, nogil=True)
def _mark(far, marks):
    """Each landmark distance ``far[v, j]`` as its mark into ``marks[v, j]`` (``floor(d / quantum)``, :data:`UNREACHED`
    for ``inf``); returns the quantum, the longest finite distance over 65,534."""
    longest = 0.0
    for v in range(far.shape[0]):
        for j in range(far.shape[1]):
            if far[v, j] < np.inf:
                longest = max(longest, far[v, j])
    quantum = longest / (UNREACHED - 1) if longest > 0 else 1.0
    for v in range(far.shape[0]):
        for j in range(far.shape[1]):
            d = far[v, j]
            marks[v, j] = min(np.floor(d / quantum), UNREACHED - 1) if d < np.inf else UNREACHED
    return quantum


def search_graph(indptr, indices, data, points: np.ndarray, far: np.ndarray, delta: float) -> Graph:
    """A roadmap's :class:`Graph`: its CSR rows (as ``uint32``), the milestones' positions ``points`` (scaled,
    float64, shared) and their landmark distances (``far``, (n, L), ``inf`` in another component) as marks, a row
    of 8, 16 or 32 marks (16, 32 or 64 bytes) per milestone, the first at a cache line's start: a row never spans
    two lines. A search reaches a thousand nodes or so, scattered; after other work each is a miss, so one line a
    node is most of what a cold query costs."""
    n, count = far.shape
    width = 8 if count <= 8 else 16 if count <= 16 else 32
    if count > width:
        raise ValueError(f"at most 32 landmarks, not {count}")
    block = np.zeros(n * width + CACHE_LINE // 2, dtype=np.uint16)
    skip = (-block.ctypes.data % CACHE_LINE) // 2
    marks = block[skip : skip + n * width].reshape(n, width)
    quantum = _mark(np.ascontiguousarray(far, dtype=np.float64), marks)
    return Graph(
        np.ascontiguousarray(indptr, dtype=np.uint32),
        np.ascontiguousarray(indices, dtype=np.uint32),
        np.ascontiguousarray(data, dtype=np.float64),
        np.ascontiguousarray(points, dtype=np.float64),
        marks,
        count,
        quantum,
        float(delta),
    )


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
    searched = search_graph(
        graph.indptr,
        graph.indices,
        graph.data,
        np.ascontiguousarray(scaled, np.float64),
        np.empty((n, 0)) if far is None else far,
        delta if delta is not None else bucket_width(graph.data),
    )

    def ends(links):
        empty_i, empty_f, nowhere = np.empty(0, np.int64), np.empty(0), np.zeros(scaled.shape[1])
        targets, costs, point = links if links is not None else (empty_i, empty_f, nowhere)
        targets = np.ascontiguousarray(targets, np.int64)
        return Ends(targets, np.ascontiguousarray(costs, np.float64), np.ones(len(targets), np.bool_),
                    np.ascontiguousarray(point, np.float64))  # fmt: skip

    source = n if source_links is not None else int(source)
    target = n + 1 if target_links is not None else int(target)
    while True:
        count, cost, expanded = search(
            searched, source, target, ends(source_links), ends(target_links), float(direct_cost), workspace.arrays
        )
        if count >= 0:
            break
        workspace.grow()
    nodes = workspace.arrays.path[:count].copy()
    nodes[nodes == n] = -1
    nodes[nodes == n + 1] = -2
    return nodes, cost, expanded


def _compile() -> None:
    from scipy.sparse import csr_matrix

    graph = csr_matrix((np.ones(2), np.array([1, 0], np.int32), np.array([0, 1, 2], np.int32)), shape=(2, 2))
    shortest_path(graph, np.zeros((2, 3)), 0, 1)


_compile()
