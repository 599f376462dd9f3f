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

The search itself is :mod:`.search`, the repair :mod:`.repair`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from surgiplan.paths import certify_edges

from .repair import repair
from .roadmap import RoadmapPair
from .search import LINK, RISK, SAFE, Links, Query, edge_kinds, search

__all__ = ["LINK", "RISK", "SAFE", "QueryOutcome", "query"]


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
    nodes = (roadmap.n, roadmap.n + 1)
    per_end = [roadmap.neighbours(q) for q in ends]
    owner = np.concatenate([np.full(len(t), i) for i, t in enumerate(per_end)]).astype(np.int64)
    targets = np.concatenate(per_end).astype(np.int64)
    scaled_ends = roadmap.scaled(ends)
    if not targets.size:
        return [
            Links(node, np.zeros(0, np.int64), np.zeros(0), np.zeros(0, dtype=bool), scaled_ends[i])
            for i, node in enumerate(nodes)
        ]
    here = ends[owner]
    far = roadmap.milestones[targets]
    own = np.minimum(clearance, workspace)[owner]
    slack = np.minimum(roadmap.clearance[targets], roadmap.workspace[targets])
    free, _ = certify_edges(space, here, far, own, slack, 0.0)
    safe = np.zeros(len(targets), dtype=bool)
    sel = free & is_safe[owner] & roadmap.safe[targets]
    if d_thresh <= 0:
        safe = sel
    elif np.any(sel):
        safe[sel], _ = certify_edges(space, here[sel], far[sel], own[sel] - d_thresh, slack[sel] - d_thresh, d_thresh)
    cost = space.distance(here, far)
    out = []
    for i, node in enumerate(nodes):
        mine = free & (owner == i)
        out.append(Links(node, targets[mine], cost[mine], safe[mine], scaled_ends[i]))
    return out


def _project(roadmap: RoadmapPair, q: np.ndarray, clearance: float, workspace: float) -> tuple[int, float] | None:
    """The nearest safe milestone reachable from q by a collision-free motion (incremental spheres)."""
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


def query(roadmap: RoadmapPair, start: np.ndarray, goal: np.ndarray) -> QueryOutcome:
    """Algorithms 2-4: the shortest path from start to goal in R, repaired through R_safe where possible."""
    space = roadmap.space
    d_thresh = roadmap.d_thresh
    n = roadmap.n
    timings: dict[str, float] = {}
    started = time.perf_counter()
    ends = np.stack([start, goal])
    clearance = space.clearance(ends)
    workspace = space.workspace_slack(ends)
    ends_safe = clearance >= d_thresh if d_thresh > 0 else clearance > 0

    start_links, goal_links = _link_ends(ends, roadmap, d_thresh, clearance, workspace, ends_safe)
    direct = None
    if space.distance(start, goal) <= roadmap.s:
        slack = np.minimum(clearance, workspace)
        if certify_edges(space, start[None], goal[None], slack[:1], slack[1:], 0.0)[0][0]:
            safe = bool(ends_safe.all()) and (
                d_thresh <= 0
                or certify_edges(space, start[None], goal[None], slack[:1] - d_thresh, slack[1:] - d_thresh, d_thresh)[
                    0
                ][0]
            )
            direct = (float(space.distance(start, goal)), safe)

    components = roadmap.safe_components.copy()
    free_components = roadmap.free_components.copy()
    for uf in (components, free_components):
        uf.add(2)
    for links in (start_links, goal_links):
        for t, ok in zip(links.targets, links.safe, strict=True):
            free_components.union(links.node, int(t))
            if ok:
                components.union(links.node, int(t))
    if direct is not None:
        free_components.union(n, n + 1)
        if direct[1]:
            components.union(n, n + 1)
    q = Query(roadmap, start_links, goal_links, direct, components, free_components)

    # a start or goal in the risk region: project it into the safe region and link it back
    source, target = n, n + 1
    head: list[np.ndarray] = []
    tail: list[np.ndarray] = []
    if d_thresh > 0:
        for i, point in ((0, start), (1, goal)):
            if ends_safe[i]:
                continue
            projected = _project(roadmap, point, clearance[i], workspace[i])
            if projected is None:
                continue  # nothing safe reachable: plan from the point itself
            index, _ = projected
            if i == 0:
                head, source = [start], index
            else:
                tail, target = [goal], index
    timings["link_s"] = time.perf_counter() - started

    started = time.perf_counter()
    if not free_components.same(source, target):
        return QueryOutcome(
            False,
            message="start and goal are in different components of the roadmap R "
            "(no collision-free path among the milestones)",
            timings=timings,
        )
    core = search(roadmap.free_csr, source, q, target, safe=False)
    timings["search_s"] = time.perf_counter() - started
    if core is None:
        return QueryOutcome(False, message="no path in R", timings=timings)

    started = time.perf_counter()
    safe_node = np.concatenate([roadmap.safe, ends_safe])
    kinds = edge_kinds(core, safe_node, q)
    repaired = 0
    avoided: list[list[int]] = []
    if all(k == SAFE for k in kinds):
        result = core  # Algorithm 3: a path already safe is returned as it is
    else:
        result, kinds, repaired = repair(core, safe_node, q, kinds, avoided)
    timings["repair_s"] = time.perf_counter() - started

    result = np.asarray(result)
    on_path = roadmap.milestones[np.minimum(result, n - 1)]
    on_path[result == n] = start
    on_path[result == n + 1] = goal
    path = np.concatenate(
        [np.asarray(head).reshape(-1, space.dimension), on_path, np.asarray(tail).reshape(-1, space.dimension)]
    )
    kinds = ([LINK] if head else []) + kinds + ([LINK] if tail else [])

    def configurations(nodes: list[int]) -> np.ndarray:
        nodes = np.asarray(nodes)
        out = roadmap.milestones[np.minimum(nodes, n - 1)]
        out[nodes == n] = start
        out[nodes == n + 1] = goal
        return out

    detours = [configurations(stretch) for stretch in avoided if stretch]
    return QueryOutcome(True, path, kinds, repaired, timings=timings, settled=q.settled, detours=detours)
