"""A whole safe-PRM query in one compiled call, for a space whose motions are Euclidean.

The query in steps (:func:`.query.query`) is the ends' links (:func:`.query_kernel.link_ends`), their
bookkeeping, the search and repair (:func:`.query_kernel.search_and_repair`), then the path's configurations,
each a call from Python, each paying numba's argument checks and allocating. :func:`link_search_repair` is those
same steps in one call: the links, the search and repair on them, and the configurations of the path and of
every avoided stretch. It answers only when the covering balls decide every link (the common case); otherwise it
says so (status 4) and the query takes the general path, which asks the space's exact check. The answer is the
stepwise one, by construction: the same kernels on the same arrays. The roadmap comes as one
:class:`.query_kernel.Roadmap` and the workspace as one :class:`.astar.Work`, so a call unpacks two arguments
where it unpacked forty. Compiled when the module is imported.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from surgiplan.geometry.compiled import nearest

from .astar import Ends
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
def _unanswered(status, ends):
    none = np.empty((0, ends.shape[1]))
    return status, none, np.empty(0, np.uint8), 0, 0, none, np.zeros(1, np.int64)


@njit(cache=True, nogil=True)
def link_search_repair(roadmap, ends, ends_slack, ends_safe, work):
    """:func:`.query_kernel.link_ends` then :func:`.query_kernel.search_and_repair` from the start to the goal
    (``ends`` (2, d), unit coordinate weights; ``ends_slack``: their clearance, at most their workspace slack;
    ``ends_safe``: whether each is in C_safe). Returns (status, path configurations, edge kinds, repairs, settled,
    configurations of the avoided stretches, their offsets): status as :func:`~.query_kernel.search_and_repair`'s,
    or :data:`UNDECIDED` (nothing else set) when a link needs the space's exact check."""
    targets, _, cost, _, keeps, direct, direct_free, direct_keeps, split, undecided = link_ends(
        roadmap, ends, ends_slack, ends_safe
    )
    if undecided:
        return _unanswered(UNDECIDED, ends)
    every = np.ones(targets.shape[0], dtype=np.bool_)
    keep = keeps == 1
    start = Ends(targets[:split], cost[:split], every[:split], ends[0])
    goal = Ends(targets[split:], cost[split:], every[split:], ends[1])
    n = roadmap.points.shape[0]
    status, nodes, kinds, repaired, settled, avoided, offsets = search_and_repair(
        roadmap, start, goal, keep[:split], keep[split:], ends_safe, direct if direct_free != 0 else np.inf,
        direct_free != 0 and direct_keeps != 0, n, n + 1, work,
    )  # fmt: skip
    if status != 0:
        return status, np.empty((0, ends.shape[1])), kinds, repaired, settled, np.empty((0, ends.shape[1])), offsets
    milestones = roadmap.milestones
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
def measure_link_search_repair(roadmap, obstacles, tip_radius, ends, work):
    """:func:`link_search_repair` with the ends' clearance measured in the same call, for a point robot of radius
    ``tip_radius`` among a scene's compiled primitives (``obstacles``: the scene's packed form, what
    :func:`surgiplan.geometry.compiled.nearest` takes first): the scene's signed distance less the radius, the
    number ``R3Space.clearance`` gives, is the ends' slack (no workspace limit). Status :data:`PROJECT` (nothing
    else set) when an end is in the risk region: the query projects it, in Python."""
    distance = np.empty(2)
    index = np.empty(2, dtype=np.int64)
    nearest(*obstacles, ends, ends, False, np.full(2, np.inf), distance, index)
    clearance = distance - tip_radius
    d_thresh = roadmap.d_thresh
    ends_safe = clearance >= d_thresh if d_thresh > 0 else clearance > 0
    if d_thresh > 0 and not (ends_safe[0] and ends_safe[1]):
        return _unanswered(PROJECT, ends)
    return link_search_repair(roadmap, ends, clearance, ends_safe, work)


def compiled_entry(dispatcher, *example):
    """``dispatcher``'s compiled function for the argument types of ``example``, to be called directly: the
    dispatcher works out every argument's type at every call, which for a query's bundles of forty arrays was most
    of the call's cost (about 10 us of 13, against 2.5 us to unpack them). The caller passes arguments of exactly
    those types (the query's always are: the roadmap's own arrays, its workspace, float64 ends). Loaded from
    numba's cache (compiled at import) when a roadmap is made, never in a query."""
    key = tuple(dispatcher.typeof_pyval(value) for value in example)
    if key not in dispatcher.overloads:
        dispatcher.compile(key)
    return dispatcher.overloads[key].entry_point


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
