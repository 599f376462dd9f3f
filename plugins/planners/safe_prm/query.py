"""Query phase and path repair of the safe PRM (paper 000, Algorithms 2-4).

A query links the start and goal into both roadmaps (K-S neighbours,
certified motions), finds the shortest path P in R, and, unless every
milestone and edge of P is safe, repairs it (Algorithm 4): from each safe
milestone p_l, the last safe milestone p_m of P in the same R_safe component
is found (union-find), and P[l..m] is replaced by the shortest path between
them in R_safe. Stretches that cannot be repaired are *critical regions*: P
passes through them on R's edges.

Beyond the paper (its §5 proposal): a start or goal in the risk region is
*projected* into the safe region, to the nearest safe milestone it can reach
by a collision-free motion, searched in spheres of growing radius; the path
runs start → projection → ... and the link is reported like a critical
region (it cannot be avoided either).

For a space with Euclidean motions the whole query is one compiled call
(:mod:`.query_fused`: the links, the search and repair, the path's
configurations; for a point robot among primitives the ends' clearance too)
whenever the covering balls decide every link and no end is projected.
Otherwise the links are found here (K-S neighbours from the roadmap's grid,
certified by covering balls or the space's exact check) and the search and
the repair are one compiled call (:mod:`.query_kernel`, on :mod:`.astar`).
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field

import numpy as np
from surgiplan.paths import certify_edges

from .astar import Ends
from .query_fused import PROJECT, UNDECIDED, compiled_entry, link_search_repair, measure_link_search_repair
from .query_kernel import SAFE_EDGE, link_ends, search_and_repair
from .roadmap import RoadmapPair

__all__ = ["LINK", "RISK", "SAFE", "QueryOutcome", "query"]

#: edge kinds along a result path
SAFE, RISK, LINK = "safe", "risk", "link"


@dataclass
class Links:
    """A query point's certified links into the roadmaps: milestone indices, their costs, and whether each keeps
    d_thresh (an R_safe edge)."""

    targets: np.ndarray
    cost: np.ndarray
    safe: np.ndarray


@dataclass
class QueryOutcome:
    found: bool
    #: configurations of the path (n, d) and the kind of each of its n-1 motions
    path: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))
    kinds: list[str] = field(default_factory=list)
    repaired: int = 0
    message: str = ""
    timings: dict[str, float] = field(default_factory=dict)
    #: nodes the searches settled (R, then R_safe for each repair)
    settled: int = 0
    #: configurations (k, d) of each risky stretch of R's path that a repair replaced (a detour avoided it)
    detours: list[np.ndarray] = field(default_factory=list)


def _link_ends(
    ends: np.ndarray,
    roadmap: RoadmapPair,
    d_thresh: float,
    clearance: np.ndarray,
    workspace: np.ndarray,
    is_safe: np.ndarray,
) -> list[Links]:
    """The start's and goal's certified motions to their K-S neighbours (and which keep d_thresh).

    Both ends at once: one neighbour query, one batch of free-motion checks and one of safe-motion checks.
    """
    space = roadmap.space
    index, _, counts = roadmap.neighbours_of(ends)
    owner = np.repeat(np.arange(len(ends)), counts)
    targets = index[index >= 0]
    if not targets.size:
        return [Links(np.zeros(0, np.int64), np.zeros(0), np.zeros(0, dtype=bool)) for _ in ends]
    here = ends[owner]
    far = roadmap.milestones[targets]
    own = np.minimum(clearance, workspace)[owner]
    slack = np.minimum(roadmap.clearance[targets], roadmap.workspace[targets])
    free, _ = certify_edges(space, here, far, own, slack, 0.0)
    safe = free & is_safe[owner] & roadmap.safe[targets]
    if d_thresh > 0 and np.any(safe):
        safe[safe], _ = certify_edges(
            space, here[safe], far[safe], own[safe] - d_thresh, slack[safe] - d_thresh, d_thresh
        )
    cost = space.distance(here, far)
    out = []
    for i in range(len(ends)):
        mine = free & (owner == i)
        out.append(Links(targets[mine], cost[mine], safe[mine]))
    return out


def _link_euclidean(
    ends: np.ndarray, roadmap: RoadmapPair, d_thresh: float, ends_slack: np.ndarray, ends_safe: np.ndarray
) -> tuple[Links, Links, float, bool]:
    """:func:`_link_ends` and :func:`_direct` in one compiled call, for a space with Euclidean motions; the space's
    exact check decides only what the covering balls leave open."""
    space = roadmap.space
    targets, owner, cost, free, keeps, direct, direct_free, direct_keeps, split, undecided = link_ends(
        roadmap.arrays, ends, ends_slack, ends_safe
    )
    if not undecided:  # the covering balls decided every link (the common case): the entries are the links
        safe_ok = keeps == 1
        start = Links(targets[:split], cost[:split], safe_ok[:split])
        goal = Links(targets[split:], cost[split:], safe_ok[split:])
        return start, goal, (direct if direct_free else np.inf), bool(direct_free and direct_keeps)
    free_ok = free == 1
    open_free = free == 2
    if open_free.any():
        free_ok[open_free] = space.motion_is_clear(ends[owner[open_free]], roadmap.milestones[targets[open_free]], 0.0)
    safe_ok = keeps == 1
    open_safe = (keeps == 2) & free_ok
    if open_safe.any():
        safe_ok[open_safe] = space.motion_is_clear(
            ends[owner[open_safe]], roadmap.milestones[targets[open_safe]], d_thresh
        )
    safe_ok &= free_ok
    if direct_free == 2:
        direct_free = int(space.motion_is_clear(ends[:1], ends[1:], 0.0)[0])
    if direct_keeps == 2 and direct_free:
        direct_keeps = int(space.motion_is_clear(ends[:1], ends[1:], d_thresh)[0])
    links = []
    for i in (0, 1):
        mine = free_ok & (owner == i)
        links.append(Links(targets[mine], cost[mine], safe_ok[mine]))
    return links[0], links[1], (direct if direct_free else np.inf), bool(direct_free and direct_keeps)


def _project(roadmap: RoadmapPair, q: np.ndarray, clearance: float, workspace: float) -> tuple[int, float] | None:
    """The nearest safe milestone reachable from q by a collision-free motion (incremental spheres), and the
    motion's cost."""
    space = roadmap.space
    safe_index = np.flatnonzero(roadmap.safe)
    if not safe_index.size:
        return None
    radius = roadmap.s
    largest = float(np.max(space.distance(q, roadmap.milestones[safe_index])))
    tried: set[int] = set()
    while True:
        inside = [int(i) for i in roadmap.within(q, radius) if roadmap.safe[i] and int(i) not in tried]
        if inside:
            targets = roadmap.milestones[inside]
            here = np.repeat(q[None], len(inside), 0)
            slack = np.minimum(roadmap.clearance[inside], roadmap.workspace[inside])
            ok, _ = certify_edges(space, here, targets, np.full(len(inside), min(clearance, workspace)), slack, 0.0)
            if np.any(ok):
                best = inside[int(np.argmax(ok))]  # nearest first
                return best, float(space.distance(q, roadmap.milestones[best]))
            tried.update(inside)
        if radius > largest:
            return None
        radius *= 2.0


def _direct(space, start, goal, slack, ends_safe, d_thresh, reach) -> tuple[float, bool]:
    """The start-goal motion, if they are within reach of each other: (cost, keeps d_thresh); cost inf if none."""
    if space.distance(start, goal) > reach:
        return np.inf, False
    if not certify_edges(space, start[None], goal[None], slack[:1], slack[1:], 0.0)[0][0]:
        return np.inf, False
    safe = bool(ends_safe.all()) and (
        d_thresh <= 0
        or bool(
            certify_edges(space, start[None], goal[None], slack[:1] - d_thresh, slack[1:] - d_thresh, d_thresh)[0][0]
        )
    )
    return float(space.distance(start, goal)), safe


def _query_fused(roadmap: RoadmapPair, ends: np.ndarray, ends_slack, ends_safe, started: float):
    """The whole query in one compiled call (:mod:`.query_fused`): the ends measured in it too when the roadmap
    holds the scene's compiled obstacles (``ends_slack`` None), else with the slack and safety given. None when
    a link needs the space's exact check or an end is to be projected (the stepwise query then answers)."""
    work = roadmap.search_workspace
    with work.lock:
        while True:
            if ends_slack is None:
                obstacles, tip_radius = roadmap.point_obstacles
                answer = _ENTRIES[measure_link_search_repair](roadmap.arrays, obstacles, tip_radius, ends, work.arrays)
            else:
                answer = _ENTRIES[link_search_repair](roadmap.arrays, ends, ends_slack, ends_safe, work.arrays)
            if answer[0] != 3:
                break
            work.grow()  # more entries than the workspace holds: twice as many, and again
    status, path, kinds, repaired, settled, avoided, offsets = answer
    if status in (UNDECIDED, PROJECT):
        return None
    # one call: linking, search and repair are not told apart, all are search_s (link_s, when there is one, is the
    # ends' clearance measured before it)
    timings = {"search_s": time.perf_counter() - started}
    if status == 1:
        return QueryOutcome(False, message=_APART, timings=timings, settled=int(settled))
    if status == 2:
        return QueryOutcome(False, message="no path in R", timings=timings, settled=int(settled))
    names = [SAFE if k == SAFE_EDGE else RISK for k in kinds.tolist()]
    bounds = offsets.tolist()
    detours = [avoided[a:b] for a, b in itertools.pairwise(bounds) if b > a]
    return QueryOutcome(True, path, names, int(repaired), timings=timings, settled=int(settled), detours=detours)


_APART = "start and goal are in different components of the roadmap R (no collision-free path among the milestones)"
#: the one-call query's compiled functions for the argument types of every roadmap pair (all are made alike: the
#: same dtypes, contiguous, writable; :func:`_compile` resolves them on its small one, and the tests check that
#: others have its types), called without the dispatcher's type resolution (:func:`.query_fused.compiled_entry`)
_ENTRIES: dict = {}


def query(roadmap: RoadmapPair, start: np.ndarray, goal: np.ndarray) -> QueryOutcome:
    """Algorithms 2-4: the shortest path from start to goal in R, repaired through R_safe where possible."""
    space = roadmap.space
    d_thresh = roadmap.d_thresh
    started = time.perf_counter()
    ends = np.array((start, goal), dtype=float)
    if roadmap.point_obstacles is not None:  # the ends measured, linked, searched and repaired in one call
        fused = _query_fused(roadmap, ends, None, None, started)
        if fused is not None:
            return fused
    clearance = space.clearance(ends)
    workspace = space.workspace_slack(ends)
    ends_safe = clearance >= d_thresh if d_thresh > 0 else clearance > 0
    if space.euclidean_motions and roadmap.point_obstacles is None and (d_thresh <= 0 or ends_safe.all()):
        linked = time.perf_counter()
        fused = _query_fused(roadmap, ends, np.minimum(clearance, workspace), ends_safe, linked)
        if fused is not None:
            fused.timings = {"link_s": linked - started, **fused.timings}
            return fused
    return _query_stepwise(roadmap, ends, clearance, workspace, ends_safe, started)


def _query_stepwise(roadmap: RoadmapPair, ends, clearance, workspace, ends_safe, started: float) -> QueryOutcome:
    """The query step by step from Python: the links (the space's exact check where the covering balls leave one
    open), the projection of an end in the risk region, then the search and repair in one compiled call."""
    space = roadmap.space
    d_thresh = roadmap.d_thresh
    n = roadmap.n
    start, goal = ends
    timings: dict[str, float] = {}
    if space.euclidean_motions:
        start_links, goal_links, direct_cost, direct_safe = _link_euclidean(
            ends, roadmap, d_thresh, np.minimum(clearance, workspace), ends_safe
        )
    else:
        start_links, goal_links = _link_ends(ends, roadmap, d_thresh, clearance, workspace, ends_safe)
        direct_cost, direct_safe = _direct(
            space, start, goal, np.minimum(clearance, workspace), ends_safe, d_thresh, roadmap.s
        )
    # a start or goal in the risk region: project it into the safe region and link it back
    source, target = n, n + 1
    head: list[np.ndarray] = []
    tail: list[np.ndarray] = []
    if d_thresh > 0 and not ends_safe.all():
        for i, point in ((0, start), (1, goal)):
            if ends_safe[i]:
                continue
            projected = _project(roadmap, point, clearance[i], workspace[i])
            if projected is None:
                continue  # nothing safe reachable: plan from the point itself
            if i == 0:
                head, source = [start], projected[0]
            else:
                tail, target = [goal], projected[0]
    timings["link_s"] = time.perf_counter() - started

    started = time.perf_counter()
    scaled = ends * space.coordinate_weights  # the frame of the search (RoadmapPair.scaled, for both at once)
    every = [np.ones(len(links.targets), dtype=np.bool_) for links in (start_links, goal_links)]
    start_ends = Ends(start_links.targets, start_links.cost, every[0], scaled[0])
    goal_ends = Ends(goal_links.targets, goal_links.cost, every[1], scaled[1])
    work = roadmap.search_workspace
    with work.lock:
        while True:
            status, nodes, kinds, repaired, settled, avoided, offsets = search_and_repair(
                roadmap.arrays, start_ends, goal_ends, start_links.safe, goal_links.safe, ends_safe, direct_cost,
                direct_safe, source, target, work.arrays,
            )  # fmt: skip
            if status != 3:
                break
            work.grow()  # more entries than the workspace holds: twice as many, and again
    timings["search_s"] = time.perf_counter() - started
    if status == 1:
        return QueryOutcome(
            False,
            message=_APART,
            timings=timings,
            settled=int(settled),
        )
    if status == 2:
        return QueryOutcome(False, message="no path in R", timings=timings, settled=int(settled))

    def configurations(nodes: np.ndarray) -> np.ndarray:
        out = roadmap.milestones[np.minimum(nodes, n - 1)]
        out[nodes == n] = start
        out[nodes == n + 1] = goal
        return out

    path = configurations(nodes)
    if head or tail:
        path = np.concatenate(
            [np.asarray(head).reshape(-1, space.dimension), path, np.asarray(tail).reshape(-1, space.dimension)]
        )
    names = [SAFE if k == SAFE_EDGE else RISK for k in kinds.tolist()]
    names = ([LINK] if head else []) + names + ([LINK] if tail else [])
    detours = [configurations(avoided[a:b]) for a, b in itertools.pairwise(offsets.tolist()) if b > a]
    return QueryOutcome(True, path, names, int(repaired), timings=timings, settled=int(settled), detours=detours)


def _compile() -> None:
    """Load (or compile) the query's kernels, when this module is imported, for the types a roadmap pair holds: on
    a small roadmap pair made as every other is, queried in one call (the ends measured there, and given) and
    step by step. No query pays it, a fresh clone's first included."""
    from surgiplan.geometry.shapes import Box
    from surgiplan.geometry.transforms import Pose
    from surgiplan.scene import Scene
    from surgiplan.spaces import R3Space

    from .roadmap import build_roadmaps

    scene = Scene([0, 0, 0], [1, 1, 1], [Box("box", Pose.from_xyz_rpy([0.5, 0.5, 0.5]), size=(0.2, 0.2, 0.2))])
    space = R3Space(scene)
    roadmap = build_roadmaps(space, milestones=80, k=6, s=0.5, d_thresh=0.05, seed=0)
    ends = np.array([[0.1, 0.1, 0.1], [0.9, 0.9, 0.9]])
    clearance, workspace = space.clearance(ends), space.workspace_slack(ends)
    work = roadmap.search_workspace.arrays
    _ENTRIES[link_search_repair] = compiled_entry(
        link_search_repair, roadmap.arrays, ends, clearance, clearance >= 0.05, work
    )
    _ENTRIES[measure_link_search_repair] = compiled_entry(
        measure_link_search_repair, roadmap.arrays, *roadmap.point_obstacles, ends, work
    )
    query(roadmap, ends[0], ends[1])
    _query_fused(roadmap, ends, np.minimum(clearance, workspace), clearance >= 0.05, 0.0)
    _query_stepwise(roadmap, ends, clearance, workspace, clearance >= 0.05, 0.0)


_compile()
