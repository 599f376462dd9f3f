"""The roadmap search of a safe-PRM query (paper 000, Algorithms 2-3): shortest paths in R or R_safe.

Node indices: milestones are 0..n-1, the start is n and the goal n+1. The
roadmaps are never copied for a query: the start's links are the search's
first edges and the goal's links end it (:mod:`.astar`, a compiled A*
with the space's distance to the target as its heuristic; the same paths
and costs as a Dijkstra search, checked against scipy's in the tests).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix

from .astar import shortest_path
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
    #: the query point's coordinates times the space's weights (the search heuristic's frame)
    scaled: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class Query:
    roadmap: RoadmapPair
    start: Links
    goal: Links
    #: the start-goal motion, if they are within reach of each other: (cost, safe)
    direct: tuple[float, bool] | None
    components: UnionFind
    free_components: UnionFind
    #: nodes settled by the searches of this query (for the record)
    settled: int = 0

    def __post_init__(self) -> None:
        self._safe_links = {
            self.n: {int(t) for t in self.start.targets[self.start.safe]},
            self.n + 1: {int(t) for t in self.goal.targets[self.goal.safe]},
        }

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
        for i in np.flatnonzero(hi >= n):  # edges of the start or the goal: a few per path
            low, high = int(lo[i]), int(hi[i])
            if low == n and high == n + 1:
                out[i] = self.direct is not None and self.direct[1]
            else:
                out[i] = low in self._safe_links[high]
        return out


def search(graph: csr_matrix, source: int, q: Query, target: int, safe: bool) -> list[int] | None:
    """Shortest path from ``source`` to ``target`` (milestones, or the start n / goal n+1).

    Searched in R_safe when ``safe`` (with the start's and goal's safe links
    only), else in R.
    """
    n = q.n
    source_links = target_links = None
    if source == n:
        use = q.start.safe if safe else slice(None)
        source_links = (q.start.targets[use], q.start.cost[use], q.start.scaled)
    if target == n + 1:
        use = q.goal.safe if safe else slice(None)
        target_links = (q.goal.targets[use], q.goal.cost[use], q.goal.scaled)
    direct = np.inf
    if source == n and target == n + 1 and q.direct is not None and (q.direct[1] or not safe):
        direct = q.direct[0]
    nodes, _, settled = shortest_path(
        graph,
        q.roadmap.scaled_milestones,
        source,
        target,
        source_links=source_links,
        target_links=target_links,
        direct_cost=direct,
    )
    q.settled += int(settled)
    if not len(nodes):
        return None
    return [n if v == -1 else n + 1 if v == -2 else int(v) for v in nodes]


def edge_kinds(path: list[int], safe_node: np.ndarray, q: Query) -> list[str]:
    if len(path) < 2:
        return []
    a = np.asarray(path[:-1])
    b = np.asarray(path[1:])
    safe = q.is_safe_edge(a, b) & safe_node[a] & safe_node[b]
    return [SAFE if s else RISK for s in safe]
