"""Optimal paths on the roadmap: bottleneck and additive costs, searched lazily (paper 002 §IV-D, §IV-E).

Costs:

* **min-max energy / min-max stress**: an edge weighs the largest energy
  (stress) of the states along it; a path is worth its heaviest edge, the
  *bottleneck shortest path* problem (Ahuja, Magnanti & Orlin, the paper's
  ref. [3]). Solved exactly in two steps: the minimax value B* (the
  smallest threshold at which the start and a goal share a connected
  component, by bisection over the sorted weights), then the shortest path
  (roadmap distance) using only edges of weight <= B*. A single Dijkstra
  with lexicographic (bottleneck, length) labels is *not* exact: a label
  with a lower bottleneck but a longer way can shadow one that ties on the
  final bottleneck with a shorter way (the tests show such a graph).
* **control effort** C = sum d(q_i, q_i+1) (Π_i + Π_i+1) / 2 (ref. [20]):
  additive, Dijkstra.

Lazy search (Bohlin & Kavraki, ref. [7]): edge weights start as cheap
estimates that never exceed the true ones (an edge's endpoints are among its
states, so the endpoint maximum bounds the edge's maximum from below); the
best path is found, its unvalidated edges are validated (FEM along them),
invalid ones removed and weights updated, and the search repeats until the
best path is fully validated. It is then optimal for the true weights: the
same answer as validating every edge first.

Graphs are scipy.sparse matrices; searches are scipy.sparse.csgraph calls.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

BOTTLENECK = ("max_energy", "max_stress")


@dataclass
class Path:
    """Nodes from the source to a goal, the edges used (ids) and the path's value."""

    nodes: np.ndarray
    edges: np.ndarray
    value: float  # the bottleneck weight, or the summed cost
    length: float  # summed edge lengths


def _matrix(n: int, edges: np.ndarray, values: np.ndarray) -> csr_matrix:
    """Symmetric sparse matrix; zero values are nudged up (csgraph drops explicit zeros as non-edges)."""
    values = np.maximum(np.asarray(values, dtype=float), 1e-300)
    rows = np.concatenate([edges[:, 0], edges[:, 1]])
    cols = np.concatenate([edges[:, 1], edges[:, 0]])
    return csr_matrix((np.concatenate([values, values]), (rows, cols)), shape=(n, n))


def _walk(predecessors: np.ndarray, target: int) -> np.ndarray:
    nodes = [target]
    while predecessors[nodes[-1]] >= 0:  # path length, not graph size
        nodes.append(int(predecessors[nodes[-1]]))
    return np.array(nodes[::-1], dtype=np.int64)


def _edge_ids(n: int, edges: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    lookup = _matrix(n, edges, np.arange(1, len(edges) + 1, dtype=float))
    return np.asarray(lookup[nodes[:-1], nodes[1:]]).ravel().astype(np.int64) - 1


def shortest_path(n: int, edges: np.ndarray, costs: np.ndarray, source: int, goals: np.ndarray) -> Path | None:
    """The cheapest path (additive ``costs``) from ``source`` to any of ``goals``; None if none is reachable."""
    goals = np.asarray(goals, dtype=np.int64)
    if source in set(goals.tolist()):
        return Path(np.array([source]), np.empty(0, dtype=np.int64), 0.0, 0.0)
    if len(edges) == 0 or len(goals) == 0:
        return None
    distance, predecessors = dijkstra(_matrix(n, edges, costs), indices=source, return_predecessors=True)
    reach = distance[goals]
    if not np.isfinite(reach).any():
        return None
    target = int(goals[np.argmin(reach)])
    nodes = _walk(predecessors, target)
    ids = _edge_ids(n, edges, nodes)
    return Path(nodes, ids, float(np.sum(np.asarray(costs)[ids])), float("nan"))


def bottleneck_value(n: int, edges: np.ndarray, weights: np.ndarray, source: int, goals: np.ndarray) -> float | None:
    """The minimax weight B* over paths from ``source`` to any goal (None if unreachable; -inf if source is a goal)."""
    goals = np.asarray(goals, dtype=np.int64)
    if source in set(goals.tolist()):
        return -np.inf
    if len(edges) == 0 or len(goals) == 0:
        return None
    levels = np.unique(weights)

    def connected(level: float) -> bool:
        keep = weights <= level
        graph = _matrix(n, edges[keep], np.ones(int(keep.sum())))
        _, labels = connected_components(graph, directed=False)
        return bool(np.any(labels[goals] == labels[source]))

    if not connected(levels[-1]):
        return None
    lo, hi = 0, len(levels) - 1  # invariant: connected at levels[hi]
    while lo < hi:
        mid = (lo + hi) // 2
        if connected(levels[mid]):
            hi = mid
        else:
            lo = mid + 1
    return float(levels[hi])


def bottleneck_path(
    n: int, edges: np.ndarray, weights: np.ndarray, lengths: np.ndarray, source: int, goals: np.ndarray
) -> Path | None:
    """Exact bottleneck shortest path: B*, then the shortest path (``lengths``) over edges of weight <= B*."""
    value = bottleneck_value(n, edges, weights, source, goals)
    if value is None:
        return None
    keep = np.flatnonzero(weights <= value)
    path = shortest_path(n, edges[keep], np.asarray(lengths)[keep], source, goals)
    if path is None:  # cannot happen: B* connects the source to a goal
        return None
    ids = keep[path.edges]
    return Path(path.nodes, ids, value, float(np.sum(np.asarray(lengths)[ids])))


def best_path(metric: str, n, edges, weights, lengths, source, goals) -> Path | None:
    """``bottleneck_path`` for the min-max metrics, ``shortest_path`` on ``weights`` for control effort."""
    if metric in BOTTLENECK:
        return bottleneck_path(n, edges, weights, lengths, source, goals)
    path = shortest_path(n, edges, weights, source, goals)
    if path is not None:
        path.length = float(np.sum(np.asarray(lengths)[path.edges]))
    return path


@dataclass
class LazyState:
    """One roadmap's lazy search: weights (estimates until validated), which edges are checked or gone."""

    metric: str
    n: int
    edges: np.ndarray
    lengths: np.ndarray
    weights: np.ndarray
    source: int
    goals: np.ndarray
    validated: np.ndarray = field(init=False)
    alive: np.ndarray = field(init=False)
    iterations: int = 0
    path: Path | None = None
    done: bool = False

    def __post_init__(self) -> None:
        self.weights = np.asarray(self.weights, dtype=float).copy()
        self.validated = np.zeros(len(self.edges), dtype=bool)
        self.alive = np.ones(len(self.edges), dtype=bool)

    def step(self) -> np.ndarray:
        """Search once; returns the ids of the best path's edges still to validate (empty: finished)."""
        live = np.flatnonzero(self.alive)
        found = best_path(
            self.metric, self.n, self.edges[live], self.weights[live], self.lengths[live], self.source, self.goals
        )
        self.iterations += 1
        if found is None:
            self.path, self.done = None, True
            return np.empty(0, dtype=np.int64)
        found.edges = live[found.edges]
        self.path = found
        todo = found.edges[~self.validated[found.edges]]
        self.done = len(todo) == 0
        return todo

    def update(self, ids: np.ndarray, valid: np.ndarray, weights: np.ndarray | None) -> None:
        """Record validated edges: invalid ones are removed; true weights replace estimates."""
        self.validated[ids] = True
        self.alive[ids] &= np.asarray(valid, dtype=bool)
        if weights is not None:
            self.weights[ids] = np.maximum(self.weights[ids], weights)


def lazy_search(state: LazyState, validate: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray | None]]) -> LazyState:
    """Run one roadmap's lazy search to the end; ``validate(ids) -> (valid, true weights or None)``."""
    while not state.done:
        todo = state.step()
        if len(todo):
            state.update(todo, *validate(todo))
    return state


def eager_search(state: LazyState, validate) -> LazyState:
    """Validate every edge first, then search once (the reference lazy search must agree with)."""
    ids = np.arange(len(state.edges))
    state.update(ids, *validate(ids))
    state.step()
    state.done = True
    return state
