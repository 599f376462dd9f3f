"""The search and repair of a safe-PRM query in one compiled call (paper 000, Algorithms 2-4).

Given the start's and goal's certified links (:mod:`.query` finds them), :func:`search_and_repair` checks that
start and goal share a component of R, finds the shortest path P in R (:func:`.astar.search`), and, unless
every milestone and edge of P is safe, repairs it (Algorithm 4): from each safe node p_l the last safe node p_m
of P in the same R_safe component is found, and P[l..m] is replaced by the shortest path between them in
R_safe. Components come from the roadmap's labels (computed once, at build) merged through the query's own
links: the start joins the components of every milestone it links to (and the goal likewise, and the two
when a direct motion joins them), exactly what a union-find over the roadmap plus the two ends holds.

The same answer as the plain implementation in ``tests/test_safe_prm.py`` (scipy's Dijkstra on an explicit
graph, repair by the definition), which the tests check; compiled when the module is imported.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .astar import search
from .kernels import k_s_nearest

#: edge kinds in the kernel's output
SAFE_EDGE, RISK_EDGE = 0, 1


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
def _ends_joined(n, labels, start_targets, start_use, goal_targets, goal_use, direct):
    if direct:
        return True
    for k in range(goal_targets.shape[0]):
        if goal_use[k] and _joins(labels, start_targets, start_use, labels[goal_targets[k]]):
            return True
    return False


@njit(cache=True, nogil=True)
def _is_safe(
    a, b, n, safe, ends_safe, safe_indptr, safe_indices, start_targets, start_safe, goal_targets, goal_safe, direct_safe
):
    """Both nodes safe and (a, b) an edge of R_safe (with the query's safe links and direct motion)."""
    for v in (a, b):
        if (v < n and not safe[v]) or (v == n and not ends_safe[0]) or (v == n + 1 and not ends_safe[1]):
            return False
    lo, hi = min(a, b), max(a, b)
    if hi < n:
        for e in range(safe_indptr[lo], safe_indptr[lo + 1]):
            if safe_indices[e] == hi:
                return True
        return False
    if lo == n:
        return direct_safe
    if hi == n:
        return _linked(start_targets, start_safe, lo)
    return _linked(goal_targets, goal_safe, lo)


@njit(cache=True, nogil=True)
def _kinds(
    path,
    count,
    kinds,
    n,
    safe,
    ends_safe,
    safe_indptr,
    safe_indices,
    start_targets,
    start_safe,
    goal_targets,
    goal_safe,
    direct_safe,
):
    risky = 0
    for k in range(count - 1):
        ok = _is_safe(
            path[k], path[k + 1], n, safe, ends_safe, safe_indptr, safe_indices, start_targets, start_safe,
            goal_targets, goal_safe, direct_safe,
        )  # fmt: skip
        kinds[k] = SAFE_EDGE if ok else RISK_EDGE
        risky += not ok
    return risky


@njit(cache=True, nogil=True)
def search_and_repair(
    free_indptr,
    free_indices,
    free_data,
    safe_indptr,
    safe_indices,
    safe_data,
    scaled,
    free_far,
    safe_far,
    safe_scaled,
    tolerance,
    delta,
    safe,
    free_labels,
    free_count,
    safe_labels,
    safe_count,
    start_targets,
    start_costs,
    start_safe,
    start_point,
    goal_targets,
    goal_costs,
    goal_safe,
    goal_point,
    ends_safe,
    direct_cost,
    direct_safe,
    source,
    target,
    work,
):
    """Algorithms 2-4 from ``source`` to ``target`` (the start n / goal n+1, or a milestone a risky end was
    projected to). Returns (status, nodes, edge kinds, repairs, settled, avoided nodes, avoided offsets):
    status 0 found, 1 start and goal in different components of R, 2 no path in R, 3 the workspace ran out of
    entries (grow it and ask again); the nodes of each risky stretch a repair replaced are
    ``avoided[offsets[i]:offsets[i + 1]]``. ``scaled``, ``free_far`` and ``safe_scaled``, ``safe_far``: the
    positions and landmark distances the searches in R and in R_safe read (:func:`.astar.search_records`: the
    same positions, each set side by side with its landmarks). ``delta``: :func:`.astar.search`'s; ``work``: a
    :class:`.astar.Workspace`'s arrays (:meth:`~.astar.Workspace.arrays`)."""
    n = scaled.shape[0]
    path = work[-1]
    every_start = np.ones(start_targets.shape[0], dtype=np.bool_)
    every_goal = np.ones(goal_targets.shape[0], dtype=np.bool_)
    direct = direct_cost < np.inf
    joined = _ends_joined(n, free_labels, start_targets, every_start, goal_targets, every_goal, direct)
    empty = np.empty(0, dtype=np.int64)
    nothing = np.empty(0, dtype=np.uint8)
    if _class(
        source, n, free_labels, free_count, start_targets, every_start, goal_targets, every_goal, joined
    ) != _class(target, n, free_labels, free_count, start_targets, every_start, goal_targets, every_goal, joined):
        return 1, empty, nothing, 0, 0, empty, np.zeros(1, dtype=np.int64)
    count, _, settled = search(
        free_indptr,
        free_indices,
        free_data,
        scaled,
        free_far,
        tolerance,
        delta,
        source,
        start_targets,
        start_costs,
        every_start,
        start_point,
        target,
        goal_targets,
        goal_costs,
        every_goal,
        goal_point,
        direct_cost,
        *work,
    )
    if count < 0:
        return 3, empty, nothing, 0, settled, empty, np.zeros(1, dtype=np.int64)
    if count == 0:
        return 2, empty, nothing, 0, settled, empty, np.zeros(1, dtype=np.int64)
    core = path[:count].copy()
    kinds = np.empty(max(count - 1, 0), dtype=np.uint8)
    # what deciding an edge's kind takes (:func:`_is_safe`)
    safety = (n, safe, ends_safe, safe_indptr, safe_indices, start_targets, start_safe, goal_targets, goal_safe)
    risky = _kinds(core, count, kinds, *safety, direct_safe)
    offsets = np.zeros(1, dtype=np.int64)
    if risky == 0:  # Algorithm 3: a path already safe is returned as it is
        return 0, core, kinds, 0, settled, empty, offsets

    # Algorithm 4: the R_safe component of every safe node of the path
    safe_direct = direct and direct_safe
    joined_safe = _ends_joined(n, safe_labels, start_targets, start_safe, goal_targets, goal_safe, safe_direct)
    label = np.full(count, -1, dtype=np.int64)
    for k in range(count):
        v = core[k]
        if (v < n and safe[v]) or (v == n and ends_safe[0]) or (v == n + 1 and ends_safe[1]):
            label[k] = _class(
                v, n, safe_labels, safe_count, start_targets, start_safe, goal_targets, goal_safe, joined_safe
            )
    out = np.empty(n + 2, dtype=np.int64)
    size = 0
    avoided = np.empty(count, dtype=np.int64)
    avoided_size = 0
    offsets = np.zeros(count + 1, dtype=np.int64)
    stretches = 0
    repaired = 0
    no_direct = np.inf if not safe_direct else direct_cost
    l = 0
    while l < count:
        m = l
        if label[l] >= 0:
            for k in range(count - 1, l, -1):
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
            sub, _, more = search(
                safe_indptr,
                safe_indices,
                safe_data,
                safe_scaled,
                safe_far,
                tolerance,
                delta,
                core[l],
                start_targets,
                start_costs,
                start_safe,
                start_point,
                core[m],
                goal_targets,
                goal_costs,
                goal_safe,
                goal_point,
                no_direct,
                *work,
            )
            settled += more
            if sub < 0:
                return 3, empty, nothing, 0, settled, empty, np.zeros(1, dtype=np.int64)
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
    _kinds(result, size, result_kinds, *safety, direct_safe)
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
def link_ends(ends, ends_slack, ends_safe, d_thresh, points, origin, dims, cell, first, order, k, s, slack, safe):
    """The start's and goal's K-S neighbours and how their links are certified, for a space whose motions are
    Euclidean (``Space.euclidean_motions``: the neighbour distance is the link's cost and speed bound).

    ``ends`` (2, d); ``ends_slack`` and ``slack`` (per milestone): the clearance, at most the workspace slack.
    Returns (targets, owner, cost, free, keeps d_thresh, direct cost, direct free, direct keeps d_thresh, how
    many of the entries are the start's, whether any decision is left to the space): the decisions as
    :func:`_covered` gives them (1, 0, or 2: ask the space), the neighbours a motion cannot reach (0) left out,
    the start's entries first; the direct start-goal motion only when within ``s`` (else its cost is inf)."""
    kk = max(k, 1)
    index = np.empty((2, kk), dtype=np.int64)
    distance = np.empty((2, kk))
    counts = np.zeros(2, dtype=np.int64)
    for i in range(2):
        counts[i] = k_s_nearest(ends[i], points, origin, dims, cell, first, order, k, s, -1, index[i], distance[i])
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


def _compile() -> None:
    """Load (or compile) both kernels for the types :mod:`.query` passes, when this module is imported: no query
    pays it (a fresh clone's first query included)."""
    from .astar import Workspace, search_records
    from .kernels import csr_rows, grid_build

    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    edges = np.array([[0, 1]], dtype=np.int64)
    every = np.ones(1, dtype=np.bool_)
    rows = csr_rows(2, edges, np.ones(1), every, 1e-15)
    labels = np.zeros(2, dtype=np.int64)
    safe = np.ones(2, dtype=np.bool_)
    origin, dims, first, order, ordered = grid_build(points, 1.0)
    ends = np.array([[0.0, 0.1, 0.0], [1.0, 0.1, 0.0]])
    targets, owner, cost, free, _, direct, _, _, _, _ = link_ends(
        ends, np.ones(2), safe, 0.0, ordered, origin, dims, 1.0, first, order, 2, 2.0, np.ones(2), safe
    )
    work = Workspace(2, 16)
    records = search_records(points, np.zeros((2, 1)))
    for source, target in ((2, 3), (0, 1)):
        search_and_repair(
            *rows,
            *rows,
            records[0],
            records[1],
            records[1],
            records[0],
            1e-9,
            0.1,
            safe,
            labels,
            1,
            labels,
            1,
            targets[owner == 0],
            cost[owner == 0],
            free[owner == 0] == 1,
            ends[0],
            targets[owner == 1],
            cost[owner == 1],
            free[owner == 1] == 1,
            ends[1],
            safe,
            float(direct),
            True,
            source,
            target,
            work.arrays(),
        )


_compile()
