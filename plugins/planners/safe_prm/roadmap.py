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

The learning phase runs over all milestones at once (a batch PRM): the K-S
neighbours of every milestone come from one compiled query of a uniform grid
(:mod:`.kernels`; the answers a KD-tree gives), in the space's metric, so the
graph equals the one Algorithm 1 builds when every milestone is offered to
all its K-S neighbours regardless of insertion order. The milestones are
numbered in the grid's cell order, so that milestones close in space (and in
the roadmap) are close in memory: the neighbour search reads runs of points,
and a query's search reads few cache lines. The roadmaps' CSR rows,
connected components and landmark distances are compiled too; the
certification is the space's (its scene queries compiled for scenes of
primitives, :mod:`surgiplan.geometry.compiled`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree
from surgiplan.spaces.base import Space
from surgiplan.threads import in_parallel, thread_budget, threads_or_default

from .astar import Workspace, bucket_width, search_graph
from .kernels import (
    component_labels,
    cover_by_midpoint,
    cover_pairs,
    csr_rows,
    grid_build,
    grid_cell,
    k_s_neighbours,
    k_s_pairs,
)
from .landmarks import BUCKET_FRACTION, FREE_LANDMARKS, ONLY_LANDMARKS, SAFE_LANDMARKS, landmark_distances
from .query_fused import point_obstacles
from .query_kernel import Roadmap


class Grid(NamedTuple):
    """Points (a roadmap's milestones, scaled) sorted into uniform cells: what :mod:`.kernels` searches for K-S
    neighbours. The points of a cell are consecutive, the cells in order (x, then y, then z)."""

    cell: float
    origin: np.ndarray
    dims: np.ndarray
    #: the first point of each cell (and, last, the number of points)
    first: np.ndarray
    points: np.ndarray

    @classmethod
    def sorting(cls, scaled: np.ndarray, s: float) -> tuple[Grid, np.ndarray]:
        """The grid of the points ``scaled`` and the order that sorts them into it (``points[i]`` is
        ``scaled[order[i]]``)."""
        cell = grid_cell(scaled, s)
        origin, dims, first, order = grid_build(scaled, cell)
        # np.take along the rows: an index array on a 2-D array takes numpy's general path (3x)
        return cls(cell, origin, dims, first, np.take(np.asarray(scaled, dtype=float), order, axis=0)), order


@dataclass
class RoadmapPair:
    """Milestones, their clearances, and the edges of R and R_safe (a subset of R's).

    ``edges`` (E, 2) index pairs with ``i < j``, sorted; ``edge_cost`` the space's distance along each;
    ``edge_safe`` whether the edge is certified to keep ``d_thresh``; ``safe`` whether each milestone is in
    C_safe. The milestones are numbered in the order of their :class:`Grid` (given in another order, as a stored
    roadmap of an earlier version may be, they are renumbered).
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
    #: the grid over the scaled milestones, when the caller has built it already (milestones in its order)
    grid: Grid | None = field(default=None, repr=False, compare=False)
    #: threads for the landmarks' Dijkstras (R's and R_safe's at once); None: :func:`surgiplan.threads.cpu_threads`
    threads: int | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.threads = threads_or_default(self.threads)
        with thread_budget(self.threads):
            self._prepare()

    def _prepare(self) -> None:
        """The grid, the slack and the searches' arrays (on :attr:`threads` threads where the work divides)."""
        if self.grid is None:
            self.grid, order = Grid.sorting(self.scaled(self.milestones).reshape(len(self.milestones), -1), self.s)
            if np.any(order != np.arange(len(order))):
                self._renumber(order)
        #: milestones times the space's coordinate weights: the frame of the metric (and of the search heuristic)
        self.scaled_milestones = self.grid.points
        self._tree: cKDTree | None = None
        #: how far each milestone's body may move before leaving the workspace (m)
        self.workspace = self.space.workspace_slack(self.milestones) if self.n else np.zeros(0)
        #: each milestone's clearance, at most its workspace slack (what a motion from it may use); safe as booleans
        self.slack = np.ascontiguousarray(np.minimum(self.clearance, self.workspace), dtype=float)
        self.safe_flags = np.ascontiguousarray(self.safe, dtype=np.bool_)
        edges = np.ascontiguousarray(self.edges, dtype=np.int64).reshape(-1, 2)
        cost = np.ascontiguousarray(self.edge_cost, dtype=float)
        every = np.ones(len(edges), dtype=np.bool_)
        edge_safe = np.ascontiguousarray(self.edge_safe, dtype=np.bool_)
        #: the connected component of every milestone in R and in R_safe, and how many there are; R and R_safe as
        #: the searches read them (:class:`.astar.Graph`): CSR rows, both directions of every edge, the milestones'
        #: positions and their distances to each roadmap's landmarks (:mod:`.landmarks`)
        if edge_safe.all() and self.safe_flags.all():  # R_safe is R (d_thresh 0: every free motion is safe)
            self.free_labels, self.free_count, self.free_graph = self._graph(edges, cost, every, ONLY_LANDMARKS)
            self.safe_labels, self.safe_count, self.safe_graph = self.free_labels, self.free_count, self.free_graph
        else:  # the two at once where the build has two threads (most of each is its landmarks' Dijkstras)
            calls = [
                (self._graph, (edges, cost, edge_safe, SAFE_LANDMARKS)),
                (self._graph, (edges, cost, every, FREE_LANDMARKS)),
            ]
            safe, free = in_parallel(calls)
            self.free_labels, self.free_count, self.free_graph = free
            self.safe_labels, self.safe_count, self.safe_graph = safe
        grid = self.grid
        #: what the query's kernels take of the roadmap (:mod:`.query_kernel`)
        self.arrays = Roadmap(
            self.free_graph, self.safe_graph, self.safe_flags, self.slack, self.free_labels, int(self.free_count),
            self.safe_labels, int(self.safe_count), grid.points, grid.origin, grid.dims, float(grid.cell), grid.first,
            int(self.k), float(self.s), float(self.d_thresh), np.ascontiguousarray(self.milestones, dtype=float),
        )  # fmt: skip
        #: the scene's compiled obstacles and the tip radius when the query measures the ends itself, else None
        self.point_obstacles = point_obstacles(self.space)
        self._workspace = Workspace(self.n, len(self.free_graph.indices) + self.n + 64)

    def _renumber(self, order: np.ndarray) -> None:
        """The milestones in the grid's ``order``; the edges renamed and sorted again."""
        rank = np.empty(len(order), dtype=np.int64)
        rank[order] = np.arange(len(order))
        self.milestones, self.clearance, self.safe = self.milestones[order], self.clearance[order], self.safe[order]
        edges = rank[np.asarray(self.edges, dtype=np.int64).reshape(-1, 2)]
        edges = np.sort(edges, axis=1)
        by = np.lexsort((edges[:, 1], edges[:, 0]))
        self.edges, self.edge_cost, self.edge_safe = edges[by], self.edge_cost[by], self.edge_safe[by]

    def _graph(self, edges: np.ndarray, cost: np.ndarray, mask: np.ndarray, landmarks: int) -> tuple:
        """The roadmap of ``edges[mask]``: its components (a label per milestone, how many) and its
        :class:`.astar.Graph` with that many ``landmarks``."""
        labels, count = component_labels(self.n, edges, mask)
        rows = csr_rows(self.n, edges, cost, mask, 1e-15)
        points = self.grid.points
        far = landmark_distances(*rows, points, labels, landmarks, bucket_width(cost, BUCKET_FRACTION))
        return labels, count, search_graph(*rows, points, far, bucket_width(cost))

    # ------------------------------------------------------------------ structure
    @property
    def n(self) -> int:
        return len(self.milestones)

    def scaled(self, q: np.ndarray) -> np.ndarray:
        return np.atleast_2d(q) * self.space.coordinate_weights

    @property
    def search_workspace(self) -> Workspace:
        """The searches' arrays (hold its ``lock``: one query at a time)."""
        return self._workspace

    def neighbours_of(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The K-S neighbours (at most k within s) of each configuration q[i]: (indices, distances, counts), rows
        nearest first, padded with -1 and inf."""
        grid = self.grid
        return k_s_neighbours(
            np.ascontiguousarray(self.scaled(q), dtype=float),
            grid.points,
            grid.origin,
            grid.dims,
            grid.cell,
            grid.first,
            self.k,
            self.s,
        )

    def neighbours(self, q: np.ndarray) -> np.ndarray:
        """Indices of the K-S neighbours of configuration q (at most k within s), nearest first."""
        index, _, counts = self.neighbours_of(np.asarray(q, dtype=float).reshape(1, -1))
        return index[0, : counts[0]].copy()

    def within(self, q: np.ndarray, radius: float) -> np.ndarray:
        """Milestones within ``radius`` (space metric) of q, nearest first."""
        if not self.n:
            return np.zeros(0, dtype=np.int64)
        if self._tree is None:  # only a projection asks: built on first use
            self._tree = cKDTree(self.scaled_milestones)
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
            "free_components": int(self.free_count),
            "safe_components": len(np.unique(self.safe_labels[self.safe])) if self.n else 0,
        }


#: half a straight motion's length, rounded up past round-off: the speed bound of each of its halves
_HALF = 0.5 * (1 + 1e-12)


def certify_roadmap_edges(
    space: Space,
    q: np.ndarray,
    pairs: np.ndarray,
    clearance: np.ndarray,
    inside: np.ndarray,
    safe: np.ndarray,
    d_thresh: float,
    reach: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Which motions q[i] → q[j], (i, j) in ``pairs``, are edges of R (clear) and of R_safe (keep d_thresh);
    certified.

    ``clearance``, ``inside``: the milestones' clearances and workspace slack; ``safe``: which are in C_safe
    (only motions between two can be R_safe edges); ``reach``: the motions' speed bounds when the caller has
    them (a space with Euclidean motions: their lengths), else the space's. In order of cost: two covering
    balls at the ends (their slacks add up to the motion's speed bound, as :func:`surgiplan.paths.certify_edges`;
    compiled, :func:`.kernels.cover_pairs`); for the rest one clearance query at the midpoint, shared by both
    roadmaps, which either fails the motion outright (the midpoint itself is too close) or covers it with three
    balls; what is still undecided gets the space's certified motion check. Returns the R decisions, the R_safe
    decisions and how many R edges the balls alone certified.
    """
    if reach is None:
        reach = space.motion_speed_bound(q[pairs[:, 0]], q[pairs[:, 1]])
    free_state, safe_state, covered = cover_pairs(
        pairs, np.ascontiguousarray(reach, dtype=float), clearance, inside, safe, float(d_thresh)
    )
    free_ok = free_state == 1
    safe_ok = safe_state == 1
    need = np.flatnonzero((free_state == 2) | (safe_state == 2))
    if need.size:
        needed = np.take(pairs, need, axis=0)  # rows by index: np.take is numpy's fast path (3x here)
        a, b = np.take(q, needed[:, 0], axis=0), np.take(q, needed[:, 1], axis=0)
        mid = space.interpolate(a, b, 0.5)
        clear_m = np.ascontiguousarray(space.clearance(mid, cutoff=d_thresh + reach[need]), dtype=float)
        inside_m = np.ascontiguousarray(space.workspace_slack(mid), dtype=float)
        if space.euclidean_motions:  # each half of a straight motion is half its length (and round-off)
            first = second = np.ascontiguousarray(reach[need], dtype=float) * _HALF
        else:
            first = np.ascontiguousarray(space.motion_speed_bound(a, mid), dtype=float)
            second = np.ascontiguousarray(space.motion_speed_bound(mid, b), dtype=float)
        ends = (clear_m, inside_m, first, second, clearance, inside)
        # R: margin 0, strict (touching is a collision)
        more, exact = cover_by_midpoint(need, pairs, free_state, free_ok, *ends, 0.0, np.ones_like(free_ok))  # no gate
        covered += more
        if exact.size:
            free_ok[need[exact]] = space.motion_is_clear(a[exact], b[exact], 0.0)
        if d_thresh > 0:  # R_safe: only what R kept
            _, exact = cover_by_midpoint(need, pairs, safe_state, safe_ok, *ends, float(d_thresh), free_ok)
            if exact.size:
                safe_ok[need[exact]] = space.motion_is_clear(a[exact], b[exact], d_thresh)
    edge_safe = (safe_ok & free_ok) if d_thresh > 0 else free_ok.copy()
    return free_ok, edge_safe, covered


def sample_milestones(
    space: Space, n: int, rng: np.random.Generator, progress_task=None
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` milestones drawn uniformly from C_free (rejection sampling in batches) and their clearances: the first
    n free samples of ``rng``'s stream, whatever the batches (each draws the next numbers of the stream). The first
    batch is n / 2; each next one what the free fraction so far says is still missing, and a twentieth more, so
    that few samples are measured for nothing."""
    found_q: list[np.ndarray] = []
    found_c: list[np.ndarray] = []
    total = 0
    batch = max(256, n // 2)
    attempts = 0
    while total < n:
        q = space.sample(rng, batch)
        inside = space.within_limits(q) & space.in_workspace(q)
        q = np.compress(inside, q, axis=0)  # rows by a mask: np.compress is the fast path (3x here)
        clearance = space.clearance(q)
        free = clearance > 0
        found_q.append(np.compress(free, q, axis=0))
        found_c.append(clearance[free])
        total += int(np.count_nonzero(free))
        attempts += batch
        if progress_task is not None:
            progress_task.update(min(total, n))
        if attempts > 200 * n + 10_000 and total < n:
            raise RuntimeError(
                f"only {total} of {attempts} samples were free: the free space is too small to sample {n} milestones"
            )
        batch = max(256, min(int(1.05 * (n - total) * attempts / max(total, 1)), 8 * n))
    return np.concatenate(found_q)[:n], np.concatenate(found_c)[:n]


def build_roadmaps(
    space: Space,
    *,
    milestones: int,
    k: int,
    s: float,
    d_thresh: float,
    seed: int,
    progress=None,
    threads: int | None = None,
) -> RoadmapPair:
    """The learning phase (Algorithm 1, for R and R_safe at once), on ``threads`` threads where it divides (the
    neighbour search's slabs, the two roadmaps' landmarks; None: :func:`surgiplan.threads.cpu_threads`). The roadmaps
    are the same whatever the threads."""
    with thread_budget(threads) as budget:
        return _build_roadmaps(space, milestones, k, s, d_thresh, seed, progress, budget)


def _build_roadmaps(space, milestones, k, s, d_thresh, seed, progress, threads: int) -> RoadmapPair:
    """:func:`build_roadmaps` within its thread budget."""
    from surgiplan.progress import NullProgress

    progress = progress or NullProgress()
    rng = np.random.default_rng(seed)
    with progress.task("sampling milestones", total=milestones) as task:
        q, clearance = sample_milestones(space, milestones, rng, task)

    with progress.task("connecting milestones (K-S)", total=1) as task:
        # the milestones numbered in the grid's order (see the module docstring)
        grid, order = Grid.sorting(q * space.coordinate_weights, s)
        q, clearance = np.take(q, order, axis=0), clearance[order]
        safe = clearance >= d_thresh if d_thresh > 0 else clearance > 0
        # the body must also stay in the workspace along an edge (the gimbal's tip may leave the box)
        inside = space.workspace_slack(q)
        pairs, length = k_s_pairs(grid.points, grid.origin, grid.dims, grid.cell, grid.first, int(k), float(s), threads)
        # a space with Euclidean motions: the pairs' lengths (measured by the neighbour search, the same numbers
        # space.distance gives) are the motions' speed bounds and the edges' costs
        euclidean = space.euclidean_motions
        free_ok, edge_safe, covered_free = certify_roadmap_edges(
            space, q, pairs, clearance, inside, safe, d_thresh, length if euclidean else None
        )
        # np.compress along the rows: a boolean mask on a 2-D array takes numpy's general path (0.6-0.8 ms
        # for the 43,000 pairs at 5,000 milestones against 0.07)
        pairs, edge_safe = np.compress(free_ok, pairs, axis=0), edge_safe[free_ok]
        cost = length[free_ok] if euclidean else space.distance(q[pairs[:, 0]], q[pairs[:, 1]])
        task.advance(1)
    return RoadmapPair(
        space,
        q,
        clearance,
        safe,
        pairs.astype(np.int64, copy=False),
        cost,
        edge_safe,
        float(d_thresh),
        int(k),
        float(s),
        covered_edges=covered_free,
        grid=grid,
        threads=threads,
    )
