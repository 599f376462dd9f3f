"""The roadmap pair of the safe PRM: R over C_free and R_safe over C_safe, built in one pass.

Paper 000 (Jain, Hong & Rozenblit 2019), §3.2-3.3, Algorithms 1 and 3: the
same milestones feed two roadmaps; a milestone is in R_safe when its
clearance is at least ``d_thresh``. Neighbours follow the K-S strategy
(at most ``k`` nearest within radius ``s``), and connected components are
kept with union-find.

Beyond the paper, every edge is *certified*: an edge of R never touches an
obstacle and an edge of R_safe never crosses a virtual boundary, anywhere
between its milestones (the paper admits PRM's visibility edges cut
corners). Most edges are certified for free by two covering balls: the
milestones' clearances, less the margin, bound how far the moving body may
go from each end before it could lose the margin, and if the two reaches add
up to the edge's length (the body's speed bound along it) the edge is
covered. The rest get the space's exact or certified motion check.

The learning phase runs vectorised over all milestones at once (a batch
PRM): the K-S neighbours of every milestone come from one KD-tree query, in
the space's metric, so the graph equals the one Algorithm 1 builds when
every milestone is offered to all its K-S neighbours regardless of insertion
order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from surgiplan.spaces.base import Space


class UnionFind:
    """Disjoint sets over milestone indices (union by size, path halving).

    Seeded from a batch labelling (``from_labels``) and kept up to date as
    query milestones are linked in (``union``), which is how the query phase
    of Algorithm 2 asks ``sameComponent`` without recomputing components.
    """

    def __init__(self, n: int) -> None:
        self.parent = np.arange(n)
        self.size = np.ones(n, dtype=np.int64)

    @classmethod
    def from_labels(cls, labels: np.ndarray) -> UnionFind:
        uf = cls(len(labels))
        # the first member of each component becomes its representative
        _, first = np.unique(labels, return_index=True)
        representative = np.empty(labels.max() + 1 if len(labels) else 0, dtype=np.int64)
        representative[labels[first]] = first
        uf.parent = representative[labels]
        uf.size = np.bincount(uf.parent, minlength=len(labels)).astype(np.int64)
        return uf

    def add(self, count: int = 1) -> np.ndarray:
        """New singleton elements; returns their indices."""
        start = len(self.parent)
        new = np.arange(start, start + count)
        self.parent = np.concatenate([self.parent, new])
        self.size = np.concatenate([self.size, np.ones(count, dtype=np.int64)])
        return new

    def find(self, i: int) -> int:
        parent = self.parent
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return int(i)

    def union(self, i: int, j: int) -> None:
        a, b = self.find(i), self.find(j)
        if a == b:
            return
        if self.size[a] < self.size[b]:
            a, b = b, a
        self.parent[b] = a
        self.size[a] += self.size[b]

    def same(self, i: int, j: int) -> bool:
        return self.find(i) == self.find(j)

    def copy(self) -> UnionFind:
        other = UnionFind(0)
        other.parent = self.parent.copy()
        other.size = self.size.copy()
        return other


@dataclass
class RoadmapPair:
    """Milestones, their clearances, and the edges of R and R_safe (a subset of R's).

    ``edges`` (E, 2) index pairs with ``i < j``; ``edge_cost`` the space's
    distance along each; ``edge_safe`` whether the edge is certified to keep
    ``d_thresh``; ``safe`` whether each milestone is in C_safe.
    """

    space: Space
    milestones: np.ndarray
    clearance: np.ndarray
    safe: np.ndarray
    edges: np.ndarray
    edge_cost: np.ndarray
    edge_safe: np.ndarray
    d_thresh: float
    k: int
    s: float
    #: edges certified by covering balls alone, for the record
    covered_edges: int = 0
    #: the KD-tree over the scaled milestones, when the caller has built it already
    tree: cKDTree | None = field(default=None, repr=False, compare=False)
    free_components: UnionFind = field(init=False, repr=False)
    safe_components: UnionFind = field(init=False, repr=False)

    def __post_init__(self) -> None:
        #: milestones times the space's coordinate weights: the frame of the metric (and of the search heuristic)
        self.scaled_milestones = np.ascontiguousarray(self.scaled(self.milestones).reshape(self.n, -1), dtype=float)
        if self.tree is None and self.n:
            self.tree = cKDTree(self.scaled_milestones)
        self._tree = self.tree if self.n else None
        #: how far each milestone's body may move before leaving the workspace (m)
        self.workspace = self.space.workspace_slack(self.milestones) if self.n else np.zeros(0)
        self.free_csr = self._graph(np.ones(len(self.edges), dtype=bool))
        self.safe_csr = self._graph(self.edge_safe)
        self.free_components = UnionFind.from_labels(self._labels(self.free_csr))
        self.safe_components = UnionFind.from_labels(self._labels(self.safe_csr))
        safe_edges = self.edges[self.edge_safe]
        # R_safe edges as sorted keys lo * (n + 2) + hi (room for the query's start and goal)
        self._safe_keys = np.sort(safe_edges[:, 0] * (self.n + 2) + safe_edges[:, 1])

    # ------------------------------------------------------------------ structure
    @property
    def n(self) -> int:
        return len(self.milestones)

    def scaled(self, q: np.ndarray) -> np.ndarray:
        return np.atleast_2d(q) * self.space.coordinate_weights

    def has_safe_edge(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Whether (lo[i], hi[i]) with lo < hi is an edge of R_safe (vectorised)."""
        keys = np.asarray(lo) * (self.n + 2) + np.asarray(hi)
        at = np.searchsorted(self._safe_keys, keys)
        at = np.minimum(at, max(len(self._safe_keys) - 1, 0))
        return self._safe_keys[at] == keys if len(self._safe_keys) else np.zeros(keys.shape, dtype=bool)

    def _graph(self, mask: np.ndarray) -> csr_matrix:
        """Both directions of the selected edges, so directed searches see an undirected roadmap.

        Built directly in CSR form (rows by a stable sort, no duplicate summing: the edges are distinct).
        """
        i, j = self.edges[mask, 0], self.edges[mask, 1]
        cost = np.maximum(self.edge_cost[mask], 1e-15)  # scipy's graph routines drop explicit zeros
        rows = np.concatenate([i, j])
        order = _stable_order(rows, self.n)
        indptr = np.zeros(self.n + 1, dtype=np.int64)
        np.cumsum(np.bincount(rows, minlength=self.n), out=indptr[1:])
        cols = np.concatenate([j, i])[order]
        index_type = np.int32 if self.n < 2**31 - 1 else np.int64
        return csr_matrix(
            (np.concatenate([cost, cost])[order], cols.astype(index_type), indptr.astype(index_type)),
            shape=(self.n, self.n),
        )

    @staticmethod
    def _labels(graph: csr_matrix) -> np.ndarray:
        if graph.shape[0] == 0:
            return np.zeros(0, dtype=np.int64)
        return connected_components(graph, directed=False)[1].astype(np.int64)

    def neighbours(self, q: np.ndarray, exclude: int | None = None) -> np.ndarray:
        """Indices of the K-S neighbours of configuration q (at most k within s), nearest first."""
        if self._tree is None:
            return np.zeros(0, dtype=np.int64)
        k = min(self.k + (exclude is not None), self.n)
        distance, index = self._tree.query(self.scaled(q)[0], k=k, distance_upper_bound=self.s)
        index = np.atleast_1d(index)[np.isfinite(np.atleast_1d(distance))]
        if exclude is not None:
            index = index[index != exclude]
        return index[: self.k]

    def within(self, q: np.ndarray, radius: float) -> np.ndarray:
        """Milestones within ``radius`` (space metric) of q, nearest first."""
        if self._tree is None:
            return np.zeros(0, dtype=np.int64)
        found = np.asarray(self._tree.query_ball_point(self.scaled(q)[0], radius), dtype=np.int64)
        if not found.size:
            return found
        d = self.space.distance(q, self.milestones[found])
        return found[np.argsort(d, kind="stable")]

    @property
    def stats(self) -> dict:
        return {
            "milestones": int(self.n),
            "safe_milestones": int(np.count_nonzero(self.safe)),
            "edges": len(self.edges),
            "safe_edges": int(np.count_nonzero(self.edge_safe)),
            "edges_certified_by_covering": int(self.covered_edges),
            "free_components": len(np.unique(self._labels(self.free_csr))) if self.n else 0,
            "safe_components": len(np.unique(self._labels(self.safe_csr)[self.safe])) if self.n else 0,
        }


def certify_roadmap_edges(
    space: Space,
    a: np.ndarray,
    b: np.ndarray,
    clear_a: np.ndarray,
    clear_b: np.ndarray,
    inside_a: np.ndarray,
    inside_b: np.ndarray,
    d_thresh: float,
    both_safe: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Which motions a[i] → b[i] are edges of R (clear) and of R_safe (keep d_thresh); certified.

    ``clear_*``: the milestones' clearances, ``inside_*`` their workspace
    slack. In order of cost: two covering balls at the ends (their slacks
    add up to the motion's speed bound, as :func:`surgiplan.paths.certify_edges`);
    for the rest one clearance query at the midpoint, shared by both
    roadmaps, which either fails the motion outright (the midpoint itself
    is too close) or covers it with three balls; what is still undecided
    gets the space's certified motion check. Returns the R decisions, the
    R_safe decisions (only ``both_safe`` motions can be R_safe edges) and
    how many R edges the balls alone certified.
    """
    reach = space.motion_speed_bound(a, b)
    free_a, free_b = np.minimum(clear_a, inside_a), np.minimum(clear_b, inside_b)
    free_ends = (free_a > 0) & (free_b > 0)
    free_ok = free_ends & (free_a + free_b > reach)
    covered = int(np.count_nonzero(free_ok))
    free_open = free_ends & ~free_ok
    if d_thresh > 0:
        safe_a, safe_b = np.minimum(clear_a - d_thresh, inside_a), np.minimum(clear_b - d_thresh, inside_b)
        safe_ends = both_safe & (safe_a >= 0) & (safe_b >= 0)
        safe_ok = safe_ends & (safe_a + safe_b > reach)
        safe_open = safe_ends & ~safe_ok
    else:
        safe_open = np.zeros(len(a), dtype=bool)
    need = np.flatnonzero(free_open | safe_open)
    if need.size:
        mid = space.interpolate(a[need], b[need], 0.5)
        clear_m = space.clearance(mid, cutoff=d_thresh + reach[need])
        inside_m = space.workspace_slack(mid)
        first = space.motion_speed_bound(a[need], mid)
        second = space.motion_speed_bound(mid, b[need])
        # R: margin 0, strict (touching is a collision)
        sel = free_open[need]
        at, m = need[sel], np.minimum(clear_m, inside_m)[sel]
        three = (m > 0) & (free_a[at] + m > first[sel]) & (m + free_b[at] > second[sel])
        free_ok[at[three]] = True
        covered += int(np.count_nonzero(three))
        exact = at[(m > 0) & ~three]
        if exact.size:
            free_ok[exact] = space.motion_is_clear(a[exact], b[exact], 0.0)
        if d_thresh > 0:
            sel = safe_open[need] & free_ok[need]
            at, m = need[sel], np.minimum(clear_m - d_thresh, inside_m)[sel]
            three = (m >= 0) & (safe_a[at] + m > first[sel]) & (m + safe_b[at] > second[sel])
            safe_ok[at[three]] = True
            exact = at[(m >= 0) & ~three]
            if exact.size:
                safe_ok[exact] = space.motion_is_clear(a[exact], b[exact], d_thresh)
    edge_safe = (safe_ok & free_ok) if d_thresh > 0 else free_ok.copy()
    return free_ok, edge_safe, covered


def _stable_order(values: np.ndarray, bound: int) -> np.ndarray:
    """np.argsort(values, kind="stable") for integers in [0, bound); a radix sort when they fit 16 bits."""
    if bound <= 1 << 16:
        return np.argsort(values.astype(np.uint16), kind="stable")
    return np.argsort(values, kind="stable")


def sample_milestones(
    space: Space, n: int, rng: np.random.Generator, progress_task=None, batch: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` milestones drawn uniformly from C_free (rejection sampling in batches) and their clearances."""
    found_q: list[np.ndarray] = []
    found_c: list[np.ndarray] = []
    total = 0
    batch = batch or max(256, n // 2)
    attempts = 0
    while total < n:
        q = space.sample(rng, batch)
        inside = space.within_limits(q) & space.in_workspace(q)
        q = q[inside]
        clearance = space.clearance(q)
        free = clearance > 0
        found_q.append(q[free])
        found_c.append(clearance[free])
        total += int(np.count_nonzero(free))
        attempts += batch
        if progress_task is not None:
            progress_task.update(min(total, n))
        if attempts > 200 * n + 10_000 and total < n:
            raise RuntimeError(
                f"only {total} of {attempts} samples were free: the free space is too small to sample {n} milestones"
            )
    return np.concatenate(found_q)[:n], np.concatenate(found_c)[:n]


def build_roadmaps(
    space: Space, *, milestones: int, k: int, s: float, d_thresh: float, seed: int, progress=None
) -> RoadmapPair:
    """The learning phase (Algorithm 1, for R and R_safe at once)."""
    from surgiplan.progress import NullProgress

    progress = progress or NullProgress()
    rng = np.random.default_rng(seed)
    with progress.task("sampling milestones", total=milestones) as task:
        q, clearance = sample_milestones(space, milestones, rng, task)
    safe = clearance >= d_thresh if d_thresh > 0 else clearance > 0
    # the body must also stay in the workspace along an edge (the gimbal's tip may leave the box)
    inside = space.workspace_slack(q)

    with progress.task("connecting milestones (K-S)", total=1) as task:
        tree = cKDTree(q * space.coordinate_weights)
        kk = min(k + 1, len(q))
        distance, index = tree.query(q * space.coordinate_weights, k=kk, distance_upper_bound=s)
        rows = np.repeat(np.arange(len(q), dtype=np.int64), kk)
        cols = index.ravel().astype(np.int64)
        keep = np.isfinite(distance.ravel()) & (cols != rows)
        # each undirected pair once, sorted (lo, hi): unique keys lo * n + hi (a 1-D sort, not a row sort)
        lo, hi = np.minimum(rows[keep], cols[keep]), np.maximum(rows[keep], cols[keep])
        keys = np.sort(lo * len(q) + hi)
        keys = keys[np.concatenate([[True], np.diff(keys) != 0])] if len(keys) else keys
        pairs = np.stack([keys // len(q), keys % len(q)], axis=1) if len(q) else np.zeros((0, 2), np.int64)
        i, j = pairs[:, 0], pairs[:, 1]
        both_safe = safe[i] & safe[j]
        free_ok, edge_safe, covered_free = certify_roadmap_edges(
            space, q[i], q[j], clearance[i], clearance[j], inside[i], inside[j], d_thresh, both_safe
        )
        pairs, edge_safe = pairs[free_ok], edge_safe[free_ok]
        a, b = q[pairs[:, 0]], q[pairs[:, 1]]
        cost = space.distance(a, b)
        task.advance(1)
    return RoadmapPair(
        space,
        q,
        clearance,
        safe,
        pairs.astype(np.int64),
        cost,
        edge_safe,
        float(d_thresh),
        int(k),
        float(s),
        covered_edges=covered_free,
        tree=tree,
    )
