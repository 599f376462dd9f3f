"""The roadmap search of a safe-PRM query (paper 000, Algorithms 2-3): Dijkstra over R or R_safe.

Node indices: milestones are 0..n-1, the start is n and the goal n+1. The
roadmaps are never copied for a query: the start's links become one extra
row of the graph searched from it, and the goal's links are looked up at the
end of the search (cost to a goal neighbour plus the link).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from .roadmap import RoadmapPair, UnionFind

#: edge kinds along a result path
SAFE, RISK, LINK = "safe", "risk", "link"


@dataclass
class Links:
    """A query point's certified links into the roadmaps."""

    node: int
    targets: np.ndarray  # milestone indices
    cost: np.ndarray
    safe: np.ndarray  # the link keeps d_thresh (it is an R_safe edge)


@dataclass
class Query:
    roadmap: RoadmapPair
    start: Links
    goal: Links
    #: the start-goal motion, if they are within reach of each other: (cost, safe)
    direct: tuple[float, bool] | None
    components: UnionFind
    free_components: UnionFind

    @property
    def n(self) -> int:
        return self.roadmap.n

    def links(self, node: int) -> Links | None:
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


def with_start_row(graph: csr_matrix, links: Links, safe: bool) -> csr_matrix:
    """The graph with one more row: the start's links (searched from, so one direction suffices)."""
    n = graph.shape[0]
    use = links.safe if safe else np.ones(len(links.targets), dtype=bool)
    cols, cost = links.targets[use], np.maximum(links.cost[use], 1e-15)
    indptr = np.concatenate([graph.indptr, [graph.indptr[-1] + len(cols)]])
    return csr_matrix(
        (np.concatenate([graph.data, cost]), np.concatenate([graph.indices, cols]), indptr), shape=(n + 1, n + 1)
    )


def search(graph: csr_matrix, source: int, q: Query, target: int, bound: float, safe: bool) -> list[int] | None:
    """Shortest path from ``source`` to ``target`` (milestones, or the start n / goal n+1).

    Searched in R_safe when ``safe``, else in R. The start's links become an
    extra row when it is the source; the goal is reached through its links.
    Dijkstra runs with a distance limit, starting at ``bound`` and doubling
    until the best route found is within it (then nothing beyond the limit
    can beat it), so a query explores only the part of the roadmap it needs.
    """
    n = q.n
    if source == n:
        graph = with_start_row(graph, q.start, safe)
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


def edge_kinds(path: list[int], safe_node: np.ndarray, q: Query) -> list[str]:
    if len(path) < 2:
        return []
    a = np.asarray(path[:-1])
    b = np.asarray(path[1:])
    safe = q.is_safe_edge(a, b) & safe_node[a] & safe_node[b]
    return [SAFE if s else RISK for s in safe]
