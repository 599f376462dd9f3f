"""The roadmap's neighbours: k nearest states by the DISP distance (paper 002 §IV-C).

DISP(M_i, M_j) is the largest displacement of a surface node between two
equilibrium states (Lamiraux & Kavraki, the paper's ref. [18]); the paper
found it alone a good distance for choosing neighbours. With thousands of
states of ~1,000 surface nodes, all-pairs DISP costs N^2 S; we get the
*exact* k nearest neighbours with far less work:

1. a lower bound: DISP over a subset of nodes (spread by farthest-point
   sampling) never exceeds DISP over all of them;
2. for each state, the exact DISP to its k + 1 lowest-bound candidates gives
   an upper bound U_i on its k-th neighbour's distance;
3. only pairs whose lower bound is at most U_i can be among the k nearest:
   their exact DISP is computed (vectorised, in blocks) and the k smallest kept.
"""

from __future__ import annotations

import numpy as np

#: surface nodes of the lower bound
SUBSET = 48
#: node-state pairs per vectorised block
BLOCK = 4_000_000


def farthest_points(points: np.ndarray, count: int) -> np.ndarray:
    """Indices of ``count`` points spread by greedy farthest-point sampling (deterministic)."""
    count = min(count, len(points))
    chosen = np.empty(count, dtype=np.int64)
    chosen[0] = int(np.argmin(points @ np.ones(points.shape[1])))
    gap = np.linalg.norm(points - points[chosen[0]], axis=1)
    for k in range(1, count):  # count is small and fixed
        chosen[k] = int(np.argmax(gap))
        gap = np.minimum(gap, np.linalg.norm(points - points[chosen[k]], axis=1))
    return chosen


def pair_disp(states: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """DISP (m) between states[i] and states[j] for index arrays i, j; states (N, S, 3) surface nodes."""
    out = np.empty(len(i))
    per = max(1, BLOCK // max(states.shape[1], 1))
    for s in range(0, len(i), per):
        diff = states[i[s : s + per]].astype(np.float64) - states[j[s : s + per]]
        out[s : s + per] = np.sqrt(np.max(np.sum(diff * diff, axis=2), axis=1))
    return out


def lower_bounds(states: np.ndarray, subset: np.ndarray) -> np.ndarray:
    """(N, N) DISP over the ``subset`` of surface nodes: a lower bound of DISP."""
    sub = states[:, subset].astype(np.float64)
    n = len(sub)
    bound = np.zeros((n, n))
    for k in range(sub.shape[1]):  # one node at a time keeps the memory at N^2
        p = sub[:, k]
        sq = np.sum(p * p, axis=1)
        d2 = sq[:, None] + sq[None, :] - 2.0 * (p @ p.T)
        np.maximum(bound, d2, out=bound)
    return np.sqrt(np.maximum(bound, 0.0))


def knn_edges(states: np.ndarray, k: int, max_distance: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Edges (E, 2) with i < j joining each state to its k nearest by DISP (symmetric union), and their DISP.

    ``states`` (N, S, 3): surface-node positions of each state. Pairs
    farther than ``max_distance`` are not joined.
    """
    states = np.asarray(states, dtype=np.float32)
    n = len(states)
    if n < 2:
        return np.empty((0, 2), dtype=np.int64), np.empty(0)
    k = min(k, n - 1)
    subset = farthest_points(states.mean(axis=0).astype(float), SUBSET)
    bound = lower_bounds(states, subset)
    np.fill_diagonal(bound, np.inf)
    # an upper bound of each state's k-th neighbour distance from its k lowest-bound candidates
    candidates = np.argpartition(bound, k - 1, axis=1)[:, :k]
    rows = np.repeat(np.arange(n), k)
    exact = pair_disp(states, rows, candidates.ravel()).reshape(n, k)
    upper = exact.max(axis=1)
    if max_distance is not None:
        upper = np.minimum(upper, max_distance)
    i, j = np.nonzero(bound <= upper[:, None] * (1 + 1e-9) + 1e-15)  # the tolerance only absorbs rounding
    d = pair_disp(states, i, j)
    # the k smallest of each row (the lower-bound candidates were among the pairs, so each row has >= k)
    order = np.lexsort((d, i))
    i, j, d = i[order], j[order], d[order]
    first = np.searchsorted(i, np.arange(n))
    rank = np.arange(len(i)) - first[i]
    keep = rank < k
    if max_distance is not None:
        keep &= d <= max_distance
    i, j, d = i[keep], j[keep], d[keep]
    pairs = np.column_stack([np.minimum(i, j), np.maximum(i, j)])
    pairs, index = np.unique(pairs, axis=0, return_index=True)
    return pairs, d[index]


def all_pairs_disp(states: np.ndarray) -> np.ndarray:
    """(N, N) DISP by brute force (tests and small sets)."""
    n = len(states)
    i, j = np.triu_indices(n, 1)
    out = np.zeros((n, n))
    out[i, j] = out[j, i] = pair_disp(np.asarray(states, dtype=np.float32), i, j)
    return out
