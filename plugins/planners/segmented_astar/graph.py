"""The online planner's input graph, built from the segmented pathmap, and A* on it (paper 001 §5).

Paper 001 §5 makes each segment a node and its neighbour references the
edges. Here the graph is built at the level of points, which is the same
graph with each segment's points spelled out (so a start or goal can attach
to the middle of a segment): the vertices are the pathmap's distinct points
(identical points of different segments are one vertex, which is how the
pathmap "expands connectivity", paper 001 §3.2); the edges are the motions
between consecutive points of a segment and the junction motions between
referenced neighbours (all certified when the pathmap was built). Edge costs
are lengths (m): the rectifiable-curve approximation of paper 001 §5.

For speed the graph is *contracted*: runs of vertices with exactly two
neighbours become one weighted edge (a *chain*) between *junction* vertices
(degree other than two, and every point of interest). A* runs on the
junctions with the Euclidean heuristic of paper 001 §5,
h(v) = |x(v) - x_goal|. It is admissible, because every path from v to the
goal is at least as long as the straight line, and consistent, because every
edge (a chain) is at least as long as the straight line between its ends;
so A* returns a shortest path of the graph (Hart, Nilsson & Raphael 1968).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .astar import astar_junctions
from .pathmap import SegmentedPathmap


@dataclass
class Attachment:
    """How an endpoint joins the graph: ``cost`` (m) to reach ``junction``.

    ``link``/``link_cost``: the part from the endpoint to the graph vertex it
    joins (endpoint first), which is ``position`` along ``chain`` (-1: the
    vertex is a junction); from there the route runs along the chain towards
    its last vertex (``toward_end``) or its first. :meth:`points` spells the
    whole route out (only for the attachments a path uses).
    """

    junction: int
    cost: float
    chain: int = -1
    position: int = 0
    link: np.ndarray | None = None
    link_cost: float = 0.0
    toward_end: bool = True

    def points(self, graph: OnlineGraph) -> np.ndarray:
        """The route from the endpoint to ``junction`` (endpoint first)."""
        if self.chain < 0:
            return self.link
        chain, p = graph.chains[self.chain], self.position
        along = chain[p:] if self.toward_end else chain[p::-1]
        return np.concatenate([self.link, graph.points[along[1:]]])


@dataclass
class SearchOutcome:
    path: np.ndarray | None
    cost: float
    expanded: int
    junctions: list[int]


def pathmap_edges(pathmap: SegmentedPathmap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct points of the pathmap, the undirected edges between them (i < j) and their lengths (m)."""
    points, inverse = np.unique(pathmap.segment_points, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    starts, ends = pathmap.segment_start[:-1], pathmap.segment_start[1:] - 1
    # inside segments: consecutive points
    inner = np.ones(len(pathmap.segment_points) - 1, dtype=bool)
    inner[ends[:-1]] = False
    a = [inverse[:-1][inner]]
    b = [inverse[1:][inner]]
    # junctions: the end of each referenced segment (as used) to the start of the next one
    refs = pathmap.path_segments
    if len(refs) > 1:
        same_path = np.ones(len(refs) - 1, dtype=bool)
        same_path[pathmap.path_start[1:-1] - 1] = False
        u, v = refs[:-1][same_path], refs[1:][same_path]
        uid, vid = np.where(u >= 0, u, ~u), np.where(v >= 0, v, ~v)
        u_end = np.where(u >= 0, ends[uid], starts[uid])
        v_start = np.where(v >= 0, starts[vid], ends[vid])
        a.append(inverse[u_end])
        b.append(inverse[v_start])
    a, b = np.concatenate(a), np.concatenate(b)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    keep = lo != hi
    n = len(points)
    keys = np.unique(lo[keep].astype(np.int64) * n + hi[keep])
    edges = np.stack([keys // n, keys % n], axis=1)
    length = np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1)
    return points, edges, length


def vertex_graph(n: int, edges: np.ndarray, length: np.ndarray) -> csr_matrix:
    """Symmetric CSR matrix of the (uncontracted) pathmap graph."""
    w = np.maximum(length, 1e-15)
    i, j = edges[:, 0], edges[:, 1]
    return coo_matrix((np.concatenate([w, w]), (np.concatenate([i, j]), np.concatenate([j, i]))), (n, n)).tocsr()


class OnlineGraph:
    """The contracted pathmap graph with chain bookkeeping for attachments and path expansion."""

    def __init__(self, points: np.ndarray, edges: np.ndarray, length: np.ndarray, forced: np.ndarray) -> None:
        self.points = points
        self.edges = edges
        self.length = length
        n = len(points)
        self.graph = vertex_graph(n, edges, length)
        self.tree = cKDTree(points)
        degree = np.diff(self.graph.indptr)
        junction = degree != 2
        junction[forced] = True
        # a closed loop of degree-2 vertices has no junction: promote its first vertex
        interior = ~junction
        sub = self.graph[interior][:, interior]
        count, labels = connected_components(sub, directed=False)
        interior_index = np.flatnonzero(interior)
        if count:
            touches = np.zeros(count, dtype=bool)
            neighbours_junction = np.asarray(self.graph[interior][:, junction].sum(axis=1)).reshape(-1) > 0
            np.logical_or.at(touches, labels, neighbours_junction)
            for loop in np.flatnonzero(~touches):
                junction[interior_index[np.flatnonzero(labels == loop)[0]]] = True
        self.is_junction = junction
        self._build_chains()

    def _build_chains(self) -> None:
        """Walk from every junction along each incident edge to the next junction."""
        indptr, indices, data = self.graph.indptr, self.graph.indices, self.graph.data
        junction = self.is_junction
        chains: list[np.ndarray] = []
        costs: list[float] = []
        seen_edge = set()
        chain_of = np.full(len(self.points), -1, dtype=np.int64)
        position = np.zeros(len(self.points), dtype=np.int64)
        for j in np.flatnonzero(junction):
            for k in range(indptr[j], indptr[j + 1]):
                first = int(indices[k])
                if (j, first) in seen_edge:
                    continue
                walk = [int(j), first]
                cost = float(data[k])
                previous, current = int(j), first
                while not junction[current]:
                    a, b = indptr[current], indptr[current + 1]
                    nxt = int(indices[a]) if int(indices[a]) != previous else int(indices[a + 1])
                    cost += float(data[a] if int(indices[a]) == nxt else data[a + 1])
                    previous, current = current, nxt
                    walk.append(current)
                seen_edge.add((walk[-1], walk[-2]))
                seen_edge.add((j, first))
                c = len(chains)
                inner = np.asarray(walk[1:-1], dtype=np.int64)
                chain_of[inner] = c
                position[inner] = np.arange(1, len(walk) - 1)
                chains.append(np.asarray(walk, dtype=np.int64))
                costs.append(cost)
        self.chains = chains
        self.chain_cost = np.asarray(costs)
        self.chain_of = chain_of
        self.position = position
        # cumulative length along each chain, for attachments in its middle
        self.chain_cum = [
            np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.points[c], axis=0), axis=1))]) for c in chains
        ]
        # the junction graph for A*, on local indices 0..J-1 and plain Python lists (A* runs in pure Python)
        junctions = np.flatnonzero(junction)
        self.junction_vertex = junctions
        local = np.full(len(self.points), -1, dtype=np.int64)
        local[junctions] = np.arange(len(junctions))
        self.junction_local = local
        adjacency: list[list[tuple[int, float, int]]] = [[] for _ in range(len(junctions))]
        for c, (chain, cost) in enumerate(zip(chains, costs, strict=True)):
            a, b = int(local[chain[0]]), int(local[chain[-1]])
            adjacency[a].append((b, cost, c))
            if a != b:
                adjacency[b].append((a, cost, c))
        self.adjacency = adjacency
        self.junction_points = np.ascontiguousarray(self.points[junctions], dtype=float)
        # the same junction graph in CSR form for the compiled A* (entry -> chain)
        counts = np.array([len(a) for a in adjacency], dtype=np.int64)
        self.junction_indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        flat = [entry for a in adjacency for entry in a]
        self.junction_neighbour = np.array([e[0] for e in flat], dtype=np.int64)
        self.junction_cost = np.array([e[1] for e in flat], dtype=float)
        self.junction_chain = np.array([e[2] for e in flat], dtype=np.int64)

    @property
    def n_junctions(self) -> int:
        return len(self.adjacency)

    def stats(self) -> dict:
        return {
            "graph_vertices": len(self.points),
            "graph_edges": len(self.edges),
            "junctions": self.n_junctions,
            "chains": len(self.chains),
        }

    # ------------------------------------------------------------------ attachments
    def attachments_at_vertex(self, v: int, link: np.ndarray, link_cost: float) -> list[Attachment]:
        """Ways to a junction from graph vertex ``v`` reached by ``link`` (endpoint first, ending at v)."""
        if self.is_junction[v]:
            return [Attachment(int(v), link_cost, link=link, link_cost=link_cost)]
        c = int(self.chain_of[v])
        chain, cum, p = self.chains[c], self.chain_cum[c], int(self.position[v])
        return [
            Attachment(int(chain[0]), link_cost + cum[p], c, p, link, link_cost, toward_end=False),
            Attachment(int(chain[-1]), link_cost + cum[-1] - cum[p], c, p, link, link_cost, toward_end=True),
        ]

    def along_one_chain(self, starts: list[Attachment], goals: list[Attachment]) -> tuple[float, np.ndarray] | None:
        """The best route between a start and a goal attached to the same chain, along it (or None)."""
        start_chain = np.array([a.chain for a in starts], dtype=np.int64)
        goal_chain = np.array([b.chain for b in goals], dtype=np.int64)
        same = (start_chain[:, None] == goal_chain[None, :]) & (start_chain[:, None] >= 0)
        if not same.any():
            return None
        best, pick = None, None
        for i, j in zip(*np.nonzero(same), strict=True):  # starts first, as the nested loops would
            a, b = starts[i], goals[j]
            cum = self.chain_cum[a.chain]
            cost = a.link_cost + abs(cum[a.position] - cum[b.position]) + b.link_cost
            if best is None or cost < best:
                best, pick = cost, (a, b)
        a, b = pick
        step = 1 if b.position >= a.position else -1
        between = self.points[self.chains[a.chain][a.position : b.position + step : step]]
        return best, np.concatenate([a.link, between[1:], b.link[::-1][1:]])

    # ------------------------------------------------------------------ search
    def astar(
        self,
        starts: list[Attachment],
        goals: list[Attachment],
        goal_point: np.ndarray,
        direct: tuple[float, np.ndarray] | None = None,
    ) -> SearchOutcome:
        """Shortest path from any start attachment to any goal attachment (compiled A*, :mod:`.astar`).

        ``direct``: an optional (cost, points) candidate joining start and goal
        without the graph. Returns the path (start first), its cost (m), the
        number of expanded junctions and the junctions visited (vertex indices).
        """
        local = self.junction_local
        entries, first, last, cost, expanded = astar_junctions(
            self.junction_indptr,
            self.junction_neighbour,
            self.junction_cost,
            self.junction_points,
            np.array([local[a.junction] for a in starts], dtype=np.int64),
            np.array([a.cost for a in starts], dtype=float),
            np.array([local[b.junction] for b in goals], dtype=np.int64),
            np.array([b.cost for b in goals], dtype=float),
            np.asarray(goal_point, dtype=float),
            direct[0] if direct is not None else np.inf,
        )
        if last == -2:
            return SearchOutcome(None, math.inf, int(expanded), [])
        if last == -1:
            return SearchOutcome(direct[1], float(cost), int(expanded), [])
        start = starts[first]
        pieces = [start.points(self)]
        junctions = [int(start.junction)]
        u = start.junction
        for e in entries:
            chain = self.chains[int(self.junction_chain[e])]
            sequence = chain if chain[0] == u else chain[::-1]
            pieces.append(self.points[sequence[1:]])
            u = int(sequence[-1])
            junctions.append(u)
        pieces.append(goals[last].points(self)[::-1][1:])
        path = np.concatenate(pieces)
        keep = np.concatenate([[True], np.any(np.diff(path, axis=0) != 0, axis=1)])
        return SearchOutcome(path[keep], float(cost), int(expanded), junctions)


def certify_motions(
    space, a: np.ndarray, b: np.ndarray, slack_a: np.ndarray, slack_b: np.ndarray, margin: float, samples: int = 8
) -> np.ndarray:
    """Which straight motions a[i] → b[i] keep ``margin``: certified, with as few swept checks as possible.

    ``slack_*``: the clearance beyond the margin at the ends. Two covering
    balls at the ends (as :func:`surgiplan.paths.certify_edges`); then, in
    one clearance query, ``samples - 1`` points inside each remaining motion:
    a point that breaks the margin fails the motion, balls around all the
    points that cover it certify it; only what is still undecided gets the
    space's swept check (exact in R3, but slow near cylinders). The decisions
    are the swept check's: balls only certify clear motions, and a sample
    that breaks the margin proves the motion does too.
    """
    reach = space.motion_speed_bound(a, b)
    ends = (slack_a > 0) & (slack_b > 0) if margin <= 0 else (slack_a >= 0) & (slack_b >= 0)
    ok = ends & (slack_a + slack_b > reach)
    rest = np.flatnonzero(ends & ~ok)
    if rest.size:
        t = np.arange(1, samples) / samples
        inner = space.interpolate(a[rest][:, None, :], b[rest][:, None, :], t[None, :])  # (rest, samples-1, d)
        flat = inner.reshape(-1, a.shape[1])
        step = space.motion_speed_bound(a[rest], b[rest]) / samples  # travel between neighbouring samples
        m = space.motion_slack(flat, margin, np.repeat(step, samples - 1)).reshape(len(rest), samples - 1)
        m = np.concatenate([slack_a[rest][:, None], m, slack_b[rest][:, None]], axis=1)
        alive = np.all(m > 0 if margin <= 0 else m >= 0, axis=1)
        covered = alive & np.all(m[:, :-1] + m[:, 1:] > step[:, None], axis=1)
        ok[rest[covered]] = True
        exact = rest[alive & ~covered]
        if exact.size:
            ok[exact] = space.motion_is_clear(a[exact], b[exact], margin)
    return ok


def online_graph(pathmap: SegmentedPathmap) -> OnlineGraph:
    points, edges, length = pathmap_edges(pathmap)
    forced = cKDTree(points).query(pathmap.pois, distance_upper_bound=1e-12)[1]
    forced = forced[forced < len(points)]
    return OnlineGraph(points, edges, length, forced)
