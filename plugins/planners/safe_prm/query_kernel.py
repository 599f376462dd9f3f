"""The links and the search and repair of a safe-PRM query, compiled (paper 000, Algorithms 2-4).

:func:`link_ends` finds the start's and goal's K-S neighbours and certifies their links by covering balls.
Given the links (:mod:`.query` completes any the balls leave open), :func:`search_and_repair` checks that start
and goal share a component of R, finds the shortest path P in R (:func:`.astar.search`), and, unless every
milestone and edge of P is safe, repairs it (Algorithm 4): from each safe node p_l the last safe node p_m of P in
the same R_safe component is found, and P[l..m] is replaced by the shortest path between them in R_safe.
Components come from the roadmap's labels (computed once, at build) merged through the query's own links: the
start joins the components of every milestone it links to (and the goal likewise, and the two when a direct
motion joins them), exactly what a union-find over the roadmap plus the two ends holds.

Both take the roadmap as one :class:`Roadmap` (R and R_safe as :class:`.astar.Graph`, the components, the
grid), built once per roadmap. The same answer as the plain implementation in ``tests/test_safe_prm.py``
(scipy's Dijkstra on an explicit graph, repair by the definition), which the tests check; compiled when the
module is imported.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .astar import Ends, Graph, search
from .kernels import k_s_nearest

#: edge kinds in the kernel's output
SAFE_EDGE, RISK_EDGE = 0, 1


class Roadmap(NamedTuple):
    """What a query takes of a roadmap pair (:attr:`.roadmap.RoadmapPair.arrays`), milestones in the grid's order."""

    free: Graph
    safe: Graph
    #: whether each milestone is in C_safe, and its clearance less nothing, at most its workspace slack
    safe_flags: np.ndarray
    slack: np.ndarray
    #: the connected component of each milestone in R and in R_safe, and how many there are
    free_labels: np.ndarray
    free_count: int
    safe_labels: np.ndarray
    safe_count: int
    #: the grid (:class:`.roadmap.Grid`): the scaled milestones, its origin, cells per axis, cell side, first
    #: milestone of each cell
    points: np.ndarray
    origin: np.ndarray
    dims: np.ndarray
    cell: float
    first: np.ndarray
    #: the K-S strategy
    k: int
    s: float
    d_thresh: float
    #: the milestones (configurations)
    milestones: np.ndarray


# The helpers below take plain arrays: a bundle (a NamedTuple of arrays) handed to a function called in a loop is
# built again at every call, each of its arrays reference-counted (a path's edge kinds took 10 us that way, 0.1 us
# with the arrays); the kernels take their bundles apart once.


@njit(cache=True, nogil=True)
def _linked(targets, use, node):
    for k in range(targets.shape[0]):
        if use[k] and targets[k] == node:
            return True
    return False


@njit(cache=True, nogil=True)
def _joins(labels, targets, use, label):
    for k in range(targets.shape[0]):
        if use[k] and labels[targets[k]] == label:
            return True
    return False


@njit(cache=True, nogil=True)
def _class(v, n, labels, count, start_targets, start_use, goal_targets, goal_use, ends_joined):
    """The component of node v once the start and goal are linked in: a roadmap label, or ``count`` for the
    start's merged component, ``count + 1`` for the goal's (``count`` too when the two are joined)."""
    goal_class = count if ends_joined else count + 1
    if v == n:
        return count
    if v == n + 1:
        return goal_class
    label = labels[v]
    if _joins(labels, start_targets, start_use, label):
        return count
    if _joins(labels, goal_targets, goal_use, label):
        return goal_class
    return label


@njit(cache=True, nogil=True)
def _ends_joined(labels, start_targets, start_use, goal_targets, goal_use, direct):
    if direct:
        return True
    for k in range(goal_targets.shape[0]):
        if goal_use[k] and _joins(labels, start_targets, start_use, labels[goal_targets[k]]):
            return True
    return False


@njit(cache=True, nogil=True)
def _kinds(path, count, kinds, n, safe_flags, indptr, indices, ends_safe, start, goal, direct_safe):
    """Each edge of ``path``: :data:`SAFE_EDGE` when both nodes are safe and the edge is one of R_safe (``indptr``,
    ``indices``: its rows; the query's safe links ``start`` and ``goal``; the direct motion when
    ``direct_safe``), else :data:`RISK_EDGE`. Returns how many are risky."""
    start_targets, start_use, goal_targets, goal_use = start.targets, start.use, goal.targets, goal.use
    risky = 0
    for k in range(count - 1):
        a, b = path[k], path[k + 1]
        lo, hi = min(a, b), max(a, b)
        ok = True
        for v in (lo, hi):
            if (v < n and not safe_flags[v]) or (v == n and not ends_safe[0]) or (v == n + 1 and not ends_safe[1]):
                ok = False
        if ok and hi < n:
            ok = False
            for e in range(indptr[lo], indptr[lo + 1]):
                if indices[e] == hi:
                    ok = True
                    break
        elif ok:
            if lo == n:
                ok = direct_safe
            elif hi == n:
                ok = _linked(start_targets, start_use, lo)
            else:
                ok = _linked(goal_targets, goal_use, lo)
        kinds[k] = SAFE_EDGE if ok else RISK_EDGE
        risky += not ok
    return risky


@njit(cache=True, nogil=True)
def search_and_repair(roadmap, start, goal, start_safe, goal_safe, ends_safe, direct_cost, direct_safe, source, target,
                      work):  # fmt: skip
    """Algorithms 2-4 from ``source`` to ``target`` (the start n / goal n+1, or a milestone a risky end was
    projected to). ``start``, ``goal``: the ends' links (:class:`.astar.Ends`, every link usable in R);
    ``start_safe``, ``goal_safe``: which of them are R_safe links. Returns (status, nodes, edge kinds, repairs,
    settled, avoided nodes, avoided offsets): status 0 found, 1 start and goal in different components of R, 2
    no path in R, 3 the workspace ran out of entries (grow it and ask again); the nodes of each risky stretch a
    repair replaced are ``avoided[offsets[i]:offsets[i + 1]]``. ``work``: a :class:`.astar.Workspace`'s arrays."""
    n = roadmap.points.shape[0]
    path = work.path
    direct = direct_cost < np.inf
    start_targets, goal_targets, every_start, every_goal = start.targets, goal.targets, start.use, goal.use
    labels, count = roadmap.free_labels, roadmap.free_count
    joined = _ends_joined(labels, start_targets, every_start, goal_targets, every_goal, direct)
    empty = np.empty(0, dtype=np.int64)
    nothing = np.empty(0, dtype=np.uint8)
    failed = np.zeros(1, dtype=np.int64)
    ends = (start_targets, every_start, goal_targets, every_goal)
    if _class(source, n, labels, count, *ends, joined) != _class(target, n, labels, count, *ends, joined):
        return 1, empty, nothing, 0, 0, empty, failed
    found, _, settled = search(roadmap.free, source, target, start, goal, direct_cost, work)
    if found < 0:
        return 3, empty, nothing, 0, settled, empty, failed
    if found == 0:
        return 2, empty, nothing, 0, settled, empty, failed
    core = path[:found].copy()
    kinds = np.empty(max(found - 1, 0), dtype=np.uint8)
    # the R_safe links: every search and test of R_safe below sees only these
    safe_start = Ends(start_targets, start.costs, start_safe, start.point)
    safe_goal = Ends(goal_targets, goal.costs, goal_safe, goal.point)
    safe_flags, safe_graph = roadmap.safe_flags, roadmap.safe
    # what deciding an edge's kind takes (:func:`_kinds`)
    safety = (n, safe_flags, safe_graph.indptr, safe_graph.indices, ends_safe, safe_start, safe_goal, direct_safe)
    risky = _kinds(core, found, kinds, *safety)
    offsets = np.zeros(1, dtype=np.int64)
    if risky == 0:  # Algorithm 3: a path already safe is returned as it is
        return 0, core, kinds, 0, settled, empty, offsets

    # Algorithm 4: the R_safe component of every safe node of the path
    safe_direct = direct and direct_safe
    safe_labels, safe_count = roadmap.safe_labels, roadmap.safe_count
    safe_ends = (start_targets, start_safe, goal_targets, goal_safe)
    joined_safe = _ends_joined(safe_labels, *safe_ends, safe_direct)
    label = np.full(found, -1, dtype=np.int64)
    for k in range(found):
        v = core[k]
        if (v < n and safe_flags[v]) or (v == n and ends_safe[0]) or (v == n + 1 and ends_safe[1]):
            label[k] = _class(v, n, safe_labels, safe_count, *safe_ends, joined_safe)
    out = np.empty(n + 2, dtype=np.int64)
    size = 0
    avoided = np.empty(found, dtype=np.int64)
    avoided_size = 0
    offsets = np.zeros(found + 1, dtype=np.int64)
    stretches = 0
    repaired = 0
    no_direct = np.inf if not safe_direct else direct_cost
    l = 0
    while l < found:
        m = l
        if label[l] >= 0:
            for k in range(found - 1, l, -1):
                if label[k] == label[l]:
                    m = k
                    break
        if m <= l:
            out[size] = core[l]
            size += 1
            l += 1
            continue
        all_safe = True
        for k in range(l, m):
            if kinds[k] != SAFE_EDGE:
                all_safe = False
        if all_safe:
            for k in range(l, m):
                out[size] = core[k]
                size += 1
        else:
            sub, _, more = search(safe_graph, core[l], core[m], safe_start, safe_goal, no_direct, work)
            settled += more
            if sub < 0:
                return 3, empty, nothing, 0, settled, empty, failed
            if sub == 0:  # pragma: no cover - the same component guarantees a path
                for k in range(l, m):
                    out[size] = core[k]
                    size += 1
            else:
                repaired += 1
                for k in range(l, m + 1):
                    if (k > l and kinds[k - 1] != SAFE_EDGE) or (k < m and kinds[k] != SAFE_EDGE):
                        avoided[avoided_size] = core[k]
                        avoided_size += 1
                stretches += 1
                offsets[stretches] = avoided_size
                for k in range(sub - 1):
                    out[size] = path[k]
                    size += 1
        l = m  # p_m is the last of its component on the path: the next round appends it and moves on
    result = out[:size].copy()
    result_kinds = np.empty(max(size - 1, 0), dtype=np.uint8)
    _kinds(result, size, result_kinds, *safety)
    return 0, result, result_kinds, repaired, settled, avoided[:avoided_size].copy(), offsets[: stretches + 1].copy()


@njit(cache=True, nogil=True)
def _covered(slack_a, slack_b, reach, margin):
    """:func:`surgiplan.paths.certify_edges`'s rule for one motion: 1 covered by the two end balls, 0 an end
    cannot keep ``margin``, 2 undecided (the space's exact check decides)."""
    if margin <= 0:
        if not (slack_a > 0 and slack_b > 0):
            return 0
    elif not (slack_a >= 0 and slack_b >= 0):
        return 0
    return 1 if slack_a + slack_b > reach else 2


@njit(cache=True, nogil=True)
def link_ends(roadmap, ends, ends_slack, ends_safe):
    """The start's and goal's K-S neighbours and how their links are certified, for a space whose motions are
    Euclidean (``Space.euclidean_motions``: the neighbour distance is the link's cost and speed bound).

    ``ends`` (2, d); ``ends_slack``: their clearance, at most the workspace slack. Returns (targets, owner, cost,
    free, keeps d_thresh, direct cost, direct free, direct keeps d_thresh, how many of the entries are the
    start's, whether any decision is left to the space): the decisions as :func:`_covered` gives them (1, 0, or
    2: ask the space), the neighbours a motion cannot reach (0) left out, the start's entries first; the direct
    start-goal motion only when within ``s`` (else its cost is inf)."""
    k, s, d_thresh, slack, safe = roadmap.k, roadmap.s, roadmap.d_thresh, roadmap.slack, roadmap.safe_flags
    grid = (roadmap.points, roadmap.origin, roadmap.dims, roadmap.cell, roadmap.first)
    kk = max(k, 1)
    index = np.empty((2, kk), dtype=np.int64)
    distance = np.empty((2, kk))
    counts = np.zeros(2, dtype=np.int64)
    for i in range(2):
        counts[i] = k_s_nearest(ends[i], *grid, k, s, -1, index[i], distance[i])
    m = counts[0] + counts[1]
    targets = np.empty(m, dtype=np.int64)
    owner = np.empty(m, dtype=np.int64)
    cost = np.empty(m)
    free = np.empty(m, dtype=np.int8)
    keeps = np.zeros(m, dtype=np.int8)
    at = 0
    split = 0
    for i in range(2):
        if i == 1:
            split = at
        for slot in range(counts[i]):
            t = index[i, slot]
            reach = distance[i, slot]
            targets[at], owner[at], cost[at] = t, i, reach
            free[at] = _covered(ends_slack[i], slack[t], reach, 0.0)
            if free[at] == 0:
                continue  # never a link
            keeps[at] = 0
            if ends_safe[i] and safe[t]:
                keeps[at] = (
                    free[at]
                    if d_thresh <= 0
                    else _covered(ends_slack[i] - d_thresh, slack[t] - d_thresh, reach, d_thresh)
                )
            at += 1
    total = 0.0
    for j in range(ends.shape[1]):
        diff = ends[1, j] - ends[0, j]
        total += diff * diff
    direct = np.sqrt(total)
    direct_free = direct_keeps = 0
    if direct <= s:
        direct_free = _covered(ends_slack[0], ends_slack[1], direct, 0.0)
        if direct_free != 0 and ends_safe[0] and ends_safe[1]:
            direct_keeps = (
                direct_free
                if d_thresh <= 0
                else _covered(ends_slack[0] - d_thresh, ends_slack[1] - d_thresh, direct, d_thresh)
            )
    else:
        direct = np.inf
    undecided = direct_free == 2 or direct_keeps == 2
    for e in range(at):
        undecided = undecided or free[e] == 2 or keeps[e] == 2
    return (
        targets[:at],
        owner[:at],
        cost[:at],
        free[:at],
        keeps[:at],
        direct,
        direct_free,
        direct_keeps,
        split,
        undecided,
    )
