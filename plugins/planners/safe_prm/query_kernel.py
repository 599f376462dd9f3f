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
            path[k],
            path[k + 1],
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
        )
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
    """Algorithms 2-4 from ``source`` to ``target`` (the start n / goal n+1, or a milestone a risky end was
    projected to). Returns (status, nodes, edge kinds, repairs, settled, avoided nodes, avoided offsets):
    status 0 found, 1 start and goal in different components of R, 2 no path in R; the nodes of each risky
    stretch a repair replaced are ``avoided[offsets[i]:offsets[i + 1]]``."""
    n = scaled.shape[0]
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
    )
    if count == 0:
        return 2, empty, nothing, 0, settled, empty, np.zeros(1, dtype=np.int64)
    core = path[:count].copy()
    kinds = np.empty(max(count - 1, 0), dtype=np.uint8)
    risky = _kinds(
        core,
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
    )
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
                scaled,
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
            )
            settled += more
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
    _kinds(
        result,
        size,
        result_kinds,
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
    )
    return 0, result, result_kinds, repaired, settled, avoided[:avoided_size].copy(), offsets[: stretches + 1].copy()
