"""A whole safe-PRM query in one compiled call, for a space whose motions are Euclidean.

:func:`.query.query` did the query in steps: the ends' links (:func:`.query_kernel.link_ends`), their
bookkeeping in numpy, the search and repair (:func:`.query_kernel.search_and_repair`), then the path's
configurations, each a call from Python. At 5,000 milestones that glue was as long as the search itself
(about 100 µs of a 200 µs query, each call paying numba's argument checks and each step allocating).
:func:`link_search_repair` is those same steps in one call: the links, the search and repair on them, and the
configurations of the path and of every avoided stretch. It answers only when the covering balls decide every
link (the common case); otherwise it says so (status 4) and the query takes the general path, which asks the
space's exact check. The answer is the stepwise one, by construction: the same kernels on the same arrays.
Compiled when the module is imported.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from surgiplan.geometry.compiled import nearest

from .query_kernel import link_ends, search_and_repair

#: :func:`link_search_repair`'s status when a link is left to the space's exact check
UNDECIDED = 4
#: :func:`measure_link_search_repair`'s status when an end is in the risk region (it is projected)
PROJECT = 5


@njit(cache=True, nogil=True)
def _configurations(nodes, milestones, ends):
    """The configurations of search nodes: milestones, the start (n) and the goal (n + 1)."""
    n = milestones.shape[0]
    out = np.empty((nodes.shape[0], milestones.shape[1]))
    for i in range(nodes.shape[0]):
        v = nodes[i]
        for d in range(milestones.shape[1]):
            out[i, d] = ends[v - n, d] if v >= n else milestones[v, d]
    return out


@njit(cache=True, nogil=True)
def link_search_repair(
    ends,
    ends_slack,
    ends_safe,
    d_thresh,
    points,
    origin,
    dims,
    cell,
    first,
    order,
    k,
    s,
    slack,
    safe,
    milestones,
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
    search_safe,
    free_labels,
    free_count,
    safe_labels,
    safe_count,
    work,
):
    """:func:`.query_kernel.link_ends` then :func:`.query_kernel.search_and_repair` from the start to the goal
    (``ends`` (2, d), unit coordinate weights), the roadmap's arrays as :attr:`.roadmap.RoadmapPair.kernel_arrays`
    and its grid hold them. Returns (status, path configurations, edge kinds, repairs, settled, configurations of
    the avoided stretches, their offsets): status as :func:`~.query_kernel.search_and_repair`'s, or
    :data:`UNDECIDED` (nothing else set) when a link needs the space's exact check."""
    targets, _, cost, _, keeps, direct, direct_free, direct_keeps, split, undecided = link_ends(
        ends, ends_slack, ends_safe, d_thresh, points, origin, dims, cell, first, order, k, s, slack, safe
    )
    none = np.empty((0, ends.shape[1]))
    if undecided:
        return UNDECIDED, none, np.empty(0, np.uint8), 0, 0, none, np.zeros(1, np.int64)
    keep = keeps == 1
    direct_cost = direct if direct_free != 0 else np.inf
    direct_safe = direct_free != 0 and direct_keeps != 0
    n = scaled.shape[0]
    status, nodes, kinds, repaired, settled, avoided, offsets = search_and_repair(
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
        search_safe,
        free_labels,
        free_count,
        safe_labels,
        safe_count,
        targets[:split],
        cost[:split],
        keep[:split],
        ends[0],
        targets[split:],
        cost[split:],
        keep[split:],
        ends[1],
        ends_safe,
        direct_cost,
        direct_safe,
        n,
        n + 1,
        work,
    )
    if status != 0:
        return status, none, kinds, repaired, settled, none, offsets
    return (
        status,
        _configurations(nodes, milestones, ends),
        kinds,
        repaired,
        settled,
        _configurations(avoided, milestones, ends),
        offsets,
    )


@njit(cache=True, nogil=True)
def measure_link_search_repair(ends, obstacles, tip_radius, d_thresh, linking, kernel, work):
    """:func:`link_search_repair` with the ends' clearance measured in the same call, for a point robot of radius
    ``tip_radius`` among a scene's compiled primitives (``obstacles``: the scene's packed form, what
    :func:`surgiplan.geometry.compiled.nearest` takes first): the scene's signed distance less the radius, the
    number ``R3Space.clearance`` gives, is the ends' slack (no workspace limit). ``linking``: the arguments of
    :func:`link_search_repair` from ``points`` to ``milestones``; ``kernel``: the roadmap's
    :attr:`~.roadmap.RoadmapPair.kernel_arrays`. Status :data:`PROJECT` (nothing else set) when an end is in the
    risk region: the query projects it, in Python."""
    distance = np.empty(2)
    index = np.empty(2, dtype=np.int64)
    cutoff = np.full(2, np.inf)
    nearest(*obstacles, ends, ends, False, cutoff, distance, index)
    clearance = distance - tip_radius
    ends_safe = clearance >= d_thresh if d_thresh > 0 else clearance > 0
    if d_thresh > 0 and not (ends_safe[0] and ends_safe[1]):
        none = np.empty((0, ends.shape[1]))
        return PROJECT, none, np.empty(0, np.uint8), 0, 0, none, np.zeros(1, np.int64)
    return link_search_repair(ends, clearance, ends_safe, d_thresh, *linking, *kernel, work)


def point_obstacles(space) -> tuple | None:
    """What :func:`measure_link_search_repair` needs of a space to measure the ends itself: (the scene's packed
    primitives, the tip radius) for an :class:`~surgiplan.spaces.R3Space` (its clearance is the scene's signed
    distance less the radius, no workspace slack) whose scene answers in one compiled call; None otherwise."""
    from surgiplan.spaces import R3Space

    if type(space) is not R3Space or not space.scene.obstacles:
        return None
    scene = space.scene
    scene.prepare()  # the scene's own compiled form, built once (its first large distance query does the same)
    packed, tree = getattr(scene, "_packed", None), getattr(scene, "_tree", None)
    if packed is None or tree is not None:
        return None
    return tuple(packed), float(space.tip_radius)


def _compile() -> None:
    """Load (or compile) the kernel for the types :mod:`.query` passes, when this module is imported: no query
    pays it."""
    from .astar import Workspace, search_records
    from .kernels import csr_rows, grid_build
    from .landmarks import landmark_distances

    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    rows = csr_rows(2, np.array([[0, 1]], dtype=np.int64), np.ones(1), np.ones(1, dtype=np.bool_), 1e-15)
    labels = np.zeros(2, dtype=np.int64)
    safe = np.ones(2, dtype=np.bool_)
    scaled, far = search_records(points, landmark_distances(*rows, points, labels, 1, 0.1))
    origin, dims, first, _, ordered = grid_build(points, 1.0)
    ends = np.array([[0.0, 0.1, 0.0], [1.0, 0.1, 0.0]])
    linking = (ordered, origin, dims, 1.0, first, np.arange(2, dtype=np.int64), 2, 2.0, np.ones(2), safe, points)
    kernel = (*rows, *rows, scaled, far, far, scaled, 1e-9, 0.1, safe, labels, 1, labels, 1)
    link_search_repair(ends, np.ones(2), safe, 0.0, *linking, *kernel, Workspace(2, 16).arrays())
    vectors = np.full((1, 3), 5.0)  # one obstacle, as the scene packs it (geometry.compiled.compile_all)
    obstacles = (np.zeros(1, np.int64), np.eye(3)[None].copy(), vectors, np.ones((1, 3)), vectors, np.ones(1),
                 vectors - 1.0, vectors + 1.0)  # fmt: skip
    for d_thresh in (0.0, 0.5):
        measure_link_search_repair(ends, obstacles, 0.0, d_thresh, linking, kernel, Workspace(2, 16).arrays())


_compile()
