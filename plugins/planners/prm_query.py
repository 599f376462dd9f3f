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

Node indices: milestones are 0..n-1, the start is n and the goal n+1. The
roadmaps are never copied for a query: the start's links become one extra
row of the graph searched from it, and the goal's links are looked up at the
end of the search (cost to a goal neighbour plus the link).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from .prm_roadmap import RoadmapPair, UnionFind, certify_edges

#: edge kinds along a result path
SAFE, RISK, LINK = "safe", "risk", "link"


@dataclass
class QueryOutcome:
    found: bool
    #: configurations of the path (n, d) and the kind of each of its n-1 motions
    path: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))
    kinds: list[str] = field(default_factory=list)
    repaired: int = 0
    message: str = ""
    timings: dict[str, float] = field(default_factory=dict)


@dataclass
class _Links:
    """A query point's certified links into the roadmaps."""

    node: int
    targets: np.ndarray  # milestone indices
    cost: np.ndarray
    safe: np.ndarray  # the link keeps d_thresh (it is an R_safe edge)


@dataclass
class _Query:
    roadmap: RoadmapPair
    start: _Links
    goal: _Links
    #: the start-goal motion, if they are within reach of each other: (cost, safe)
    direct: tuple[float, bool] | None
    components: UnionFind
    free_components: UnionFind

    @property
    def n(self) -> int:
        return self.roadmap.n

    def links(self, node: int) -> _Links | None:
        return self.start if node == self.n else self.goal if node == self.n + 1 else None

    def is_safe_edge(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Vectorised: is (a[i], b[i]) an edge of R_safe (including the query's own safe links)?"""
        a = np.asarray(a)
        b = np.asarray(b)
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        out = self.roadmap.has_safe_edge(lo, hi)
        n = self.n
        for links in (self.start, self.goal):
            at = (lo == links.node) | (hi == links.node)
            if np.any(at):
                other = np.where(lo == links.node, hi, lo)
                safe_targets = links.targets[links.safe]
                out |= at & np.isin(other, safe_targets)
        if self.direct is not None and self.direct[1]:
            out |= (lo == n) & (hi == n + 1)
        return out


def _with_start_row(graph: csr_matrix, links: _Links, safe: bool) -> csr_matrix:
    """The graph with one more row: the start's links (searched from, so one direction suffices)."""
    n = graph.shape[0]
    use = links.safe if safe else np.ones(len(links.targets), dtype=bool)
    cols, cost = links.targets[use], np.maximum(links.cost[use], 1e-15)
    indptr = np.concatenate([graph.indptr, [graph.indptr[-1] + len(cols)]])
    return csr_matrix(
        (np.concatenate([graph.data, cost]), np.concatenate([graph.indices, cols]), indptr), shape=(n + 1, n + 1)
    )


def _search(graph: csr_matrix, source: int, q: _Query, target: int, bound: float, safe: bool) -> list[int] | None:
    """Shortest path from ``source`` to ``target`` (milestones, or the start n / goal n+1).

    Searched in R_safe when ``safe``, else in R. The start's links become an
    extra row when it is the source; the goal is reached through its links.
    Dijkstra runs with a distance limit, starting at ``bound`` and doubling
    until the best route found is within it (then nothing beyond the limit
    can beat it), so a query explores only the part of the roadmap it needs.
    """
    n = q.n
    if source == n:
        graph = _with_start_row(graph, q.start, safe)
    if target == n + 1:
        use = q.goal.safe if safe else np.ones(len(q.goal.targets), dtype=bool)
        end_cols, end_cost = q.goal.targets[use], q.goal.cost[use]
    else:
        end_cols, end_cost = np.array([target]), np.zeros(1)
    direct = np.inf
    if source == n and target == n + 1 and q.direct is not None and (q.direct[1] or not safe):
        direct = q.direct[0]
    limit = max(bound, 1e-9)
    reached_before = -1
    while True:
        distance, predecessors = dijkstra(graph, directed=True, indices=source, return_predecessors=True, limit=limit)
        total = distance[end_cols] + end_cost if end_cols.size else np.full(1, np.inf)
        best = min(float(total.min()), direct)
        if best <= limit:
            break
        reached = int(np.count_nonzero(np.isfinite(distance)))
        if reached == reached_before:
            # nothing new within the larger limit: one unlimited search settles it
            distance, predecessors = dijkstra(graph, directed=True, indices=source, return_predecessors=True)
            total = distance[end_cols] + end_cost if end_cols.size else np.full(1, np.inf)
            best = min(float(total.min()), direct)
            if not np.isfinite(best):
                return None
            break
        reached_before = reached
        limit *= 2.0
    if direct <= float(total.min()):
        return [n, n + 1]
    path = [int(end_cols[int(np.argmin(total))])]
    while path[-1] != source:
        path.append(int(predecessors[path[-1]]))
    path.reverse()
    if target == n + 1:
        path.append(n + 1)
    return path


def _link(
    q: np.ndarray, node: int, roadmap: RoadmapPair, d_thresh: float, clearance: float, workspace: float, is_safe: bool
) -> _Links:
    """A start or goal's certified motions to its K-S neighbours (and which keep d_thresh)."""
    space = roadmap.space
    targets = roadmap.neighbours(q)
    if not targets.size:
        return _Links(node, targets, np.zeros(0), np.zeros(0, dtype=bool))
    ends = roadmap.milestones[targets]
    here = np.repeat(q[None], len(targets), 0)
    own = np.full(len(targets), min(clearance, workspace))
    slack = np.minimum(roadmap.clearance[targets], roadmap.workspace[targets])
    free, _ = certify_edges(space, here, ends, own, slack, 0.0)
    targets, ends, here, own, slack = targets[free], ends[free], here[free], own[free], slack[free]
    cost = space.distance(here, ends)
    safe = np.zeros(len(targets), dtype=bool)
    if is_safe:
        sel = roadmap.safe[targets]
        if d_thresh <= 0:
            safe = sel
        elif np.any(sel):
            safe[sel], _ = certify_edges(
                space, here[sel], ends[sel], own[sel] - d_thresh, slack[sel] - d_thresh, d_thresh
            )
    return _Links(node, targets, cost, safe)


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

    start_links = _link(start, n, roadmap, d_thresh, clearance[0], workspace[0], bool(ends_safe[0]))
    goal_links = _link(goal, n + 1, roadmap, d_thresh, clearance[1], workspace[1], bool(ends_safe[1]))
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
    q = _Query(roadmap, start_links, goal_links, direct, components, free_components)

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
    nodes = np.concatenate([roadmap.milestones, ends])
    bound = 1.5 * float(space.distance(nodes[source], nodes[target]))
    core = _search(roadmap.free_csr, source, q, target, bound, safe=False)
    timings["search_s"] = time.perf_counter() - started
    if core is None:
        return QueryOutcome(False, message="no path in R", timings=timings)

    started = time.perf_counter()
    safe_node = np.concatenate([roadmap.safe, ends_safe])
    kinds = _edge_kinds(core, safe_node, q)
    repaired = 0
    if all(k == SAFE for k in kinds):
        result = core  # Algorithm 3: a path already safe is returned as it is
    else:
        result, kinds, repaired = _repair(core, safe_node, q, nodes)
    timings["repair_s"] = time.perf_counter() - started

    path = np.concatenate(
        [np.asarray(head).reshape(-1, space.dimension), nodes[result], np.asarray(tail).reshape(-1, space.dimension)]
    )
    kinds = ([LINK] if head else []) + kinds + ([LINK] if tail else [])
    return QueryOutcome(True, path, kinds, repaired, timings=timings)


def _edge_kinds(path: list[int], safe_node: np.ndarray, q: _Query) -> list[str]:
    if len(path) < 2:
        return []
    a = np.asarray(path[:-1])
    b = np.asarray(path[1:])
    safe = q.is_safe_edge(a, b) & safe_node[a] & safe_node[b]
    return [SAFE if s else RISK for s in safe]


def _repair(path: list[int], safe_node: np.ndarray, q: _Query, nodes: np.ndarray) -> tuple[list[int], list[str], int]:
    """Algorithm 4 (PathRepair) on node indices; returns the path, its edge kinds, repairs made.

    From each safe milestone p_l, the last safe milestone p_m of the path in
    the same R_safe component is found; unless P[l..m] is already safe it is
    replaced by the shortest R_safe path from p_l to p_m. Risk milestones
    that no repair spans stay: they are the critical regions.
    """
    space = q.roadmap.space
    n_path = len(path)
    out: list[int] = []
    repaired = 0
    l = 0
    while l < n_path:
        p_l = path[l]
        m = l
        if safe_node[p_l]:
            for k in range(n_path - 1, l, -1):
                if safe_node[path[k]] and q.components.same(p_l, path[k]):
                    m = k
                    break
        if m == l:
            out.append(p_l)
            l += 1
            continue
        original = path[l : m + 1]
        if all(kind == SAFE for kind in _edge_kinds(original, safe_node, q)):
            sub = original
        else:
            stretch = float(np.sum(space.distance(nodes[original[:-1]], nodes[original[1:]])))
            sub = _search(q.roadmap.safe_csr, p_l, q, path[m], 1.5 * stretch, safe=True)
            if sub is None:  # pragma: no cover - same component guarantees a path
                sub = original
            else:
                repaired += 1
        out.extend(sub[:-1])
        l = m  # p_m is the last of its component on the path: the next round appends it and moves on
    return out, _edge_kinds(out, safe_node, q), repaired
