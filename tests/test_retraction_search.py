"""Roadmap searches of the retraction planner (paper 002 §IV-D, §IV-E) against brute force.

Every simple path of small random graphs is enumerated; the bottleneck
search must find the minimax value and, among paths achieving it, the
shortest; Dijkstra the cheapest additive path; the lazy search the same
path as validating every edge first. A hand-built graph shows why a single
Dijkstra with lexicographic (bottleneck, length) labels is wrong.
"""

from __future__ import annotations

import heapq

import numpy as np
import pytest
from surgiplan.plugins.planners.retraction.roadmap import all_pairs_disp, knn_edges
from surgiplan.plugins.planners.retraction.search import (
    LazyState,
    bottleneck_path,
    eager_search,
    lazy_search,
    shortest_path,
)


def random_graph(rng, n=8, p=0.45):
    pairs = np.array([(i, j) for i in range(n) for j in range(i + 1, n) if rng.random() < p], dtype=np.int64)
    return pairs.reshape(-1, 2), rng.uniform(1, 10, len(pairs)), rng.uniform(0.1, 5, len(pairs))


def simple_paths(n, edges, source, goals):
    """Every simple path source -> goal as a list of edge ids (depth-first)."""
    adjacency = {i: [] for i in range(n)}
    for e, (a, b) in enumerate(edges):
        adjacency[a].append((b, e))
        adjacency[b].append((a, e))
    out = []

    def walk(node, seen, used):
        if node in goals:
            out.append(list(used))
        for nxt, e in adjacency[node]:
            if nxt not in seen:
                walk(nxt, seen | {nxt}, [*used, e])

    walk(source, {source}, [])
    return out


def lexicographic_dijkstra(n, edges, weights, lengths, source, goals):
    """The tempting but inexact search: labels (bottleneck, length) compared lexicographically."""
    adjacency = {i: [] for i in range(n)}
    for e, (a, b) in enumerate(edges):
        adjacency[a].append((b, e))
        adjacency[b].append((a, e))
    best = {source: (-np.inf, 0.0)}
    heap = [(-np.inf, 0.0, source)]
    done = set()
    while heap:
        w, d, node = heapq.heappop(heap)
        if node in done:
            continue
        done.add(node)
        if node in goals:
            return w, d
        for nxt, e in adjacency[node]:
            label = (max(w, weights[e]), d + lengths[e])
            if nxt not in best or label < best[nxt]:
                best[nxt] = label
                heapq.heappush(heap, (*label, nxt))
    return None


@pytest.mark.parametrize("seed", range(40))
def test_bottleneck_path_is_minimax_then_shortest_like_brute_force(seed):
    rng = np.random.default_rng(seed)
    edges, weights, lengths = random_graph(rng)
    goals = np.array([6, 7])
    paths = simple_paths(8, edges, 0, set(goals.tolist()))
    found = bottleneck_path(8, edges, weights, lengths, 0, goals)
    if not paths:
        assert found is None
        return
    minimax = min(max(weights[p]) for p in paths)
    shortest = min(sum(lengths[p]) for p in paths if max(weights[p]) == minimax)
    assert found.value == pytest.approx(minimax)
    assert found.length == pytest.approx(shortest)
    assert max(weights[found.edges]) == pytest.approx(minimax)
    assert found.nodes[0] == 0 and found.nodes[-1] in goals
    # consecutive nodes are joined by the reported edges
    assert all(set(edges[e]) == {a, b} for e, a, b in zip(found.edges, found.nodes[:-1], found.nodes[1:], strict=True))


@pytest.mark.parametrize("seed", range(40))
def test_shortest_path_is_cheapest_like_brute_force(seed):
    rng = np.random.default_rng(100 + seed)
    edges, _, costs = random_graph(rng)
    paths = simple_paths(8, edges, 0, {5, 7})
    found = shortest_path(8, edges, costs, 0, np.array([5, 7]))
    if not paths:
        assert found is None
    else:
        assert found.value == pytest.approx(min(sum(costs[p]) for p in paths))


def test_lexicographic_dijkstra_fails_where_the_exact_bottleneck_search_does_not():
    # s=0 reaches v=3 by 0-1-3 (bottleneck 2, length 10) or 0-2-3 (bottleneck 3, length 1); v-t weighs 5.
    # Both routes tie at bottleneck 5 at t=4, so the shortest is through 2; lexicographic labels keep
    # the lower-bottleneck, longer label at v and never reconsider it.
    edges = np.array([[0, 1], [1, 3], [0, 2], [2, 3], [3, 4]])
    weights = np.array([2.0, 2.0, 3.0, 3.0, 5.0])
    lengths = np.array([5.0, 5.0, 0.5, 0.5, 1.0])
    exact = bottleneck_path(5, edges, weights, lengths, 0, np.array([4]))
    assert exact.value == 5.0 and exact.length == pytest.approx(2.0)
    assert exact.nodes.tolist() == [0, 2, 3, 4]
    wrong = lexicographic_dijkstra(5, edges, weights, lengths, 0, {4})
    assert wrong == (5.0, pytest.approx(11.0))  # same bottleneck, a path 5.5 times longer


def test_source_that_is_a_goal_needs_no_edge():
    edges = np.array([[0, 1]])
    assert bottleneck_path(2, edges, np.array([1.0]), np.array([1.0]), 0, np.array([0, 1])).nodes.tolist() == [0]


@pytest.mark.parametrize("metric", ["max_energy", "control_effort"])
@pytest.mark.parametrize("seed", range(30))
def test_lazy_search_returns_the_path_of_eager_validation(metric, seed):
    rng = np.random.default_rng(1000 + seed)
    n = 14
    edges, _, lengths = random_graph(rng, n, 0.35)
    node = rng.uniform(0, 10, n)
    if metric == "max_energy":
        estimate = np.maximum(node[edges[:, 0]], node[edges[:, 1]])
        true = estimate + rng.exponential(2.0, len(edges)) * (rng.random(len(edges)) < 0.5)
    else:
        estimate = lengths * 0.5 * (node[edges[:, 0]] + node[edges[:, 1]])
        true = None
    valid = rng.random(len(edges)) > 0.25
    calls = []

    def validate(ids):
        calls.append(len(ids))
        return valid[ids], (true[ids] if true is not None else None)

    goals = np.array([n - 2, n - 1])
    lazy = lazy_search(LazyState(metric, n, edges, lengths, estimate, 0, goals), validate)
    eager = eager_search(LazyState(metric, n, edges, lengths, estimate, 0, goals), lambda ids: validate(ids))
    if eager.path is None:
        assert lazy.path is None
        return
    assert lazy.path.nodes.tolist() == eager.path.nodes.tolist()
    assert lazy.path.value == pytest.approx(eager.path.value)
    assert np.all(valid[lazy.path.edges]) and np.all(lazy.validated[lazy.path.edges])
    assert lazy.validated.sum() <= len(edges)


def test_disp_nearest_neighbours_are_exact():
    rng = np.random.default_rng(5)
    # states: 60 random deformations of 200 surface nodes along a random walk (neighbours are close)
    base = rng.uniform(0, 0.05, (200, 3))
    states = base + np.cumsum(rng.normal(scale=1e-3, size=(60, 200, 3)), axis=0)
    edges, d = knn_edges(states, 5)
    full = all_pairs_disp(states)
    expected = set()
    for i in range(60):
        row = np.argsort(np.where(np.arange(60) == i, np.inf, full[i]))[:5]
        expected |= {(min(i, j), max(i, j)) for j in row}
    assert {tuple(e) for e in edges.tolist()} == expected
    assert np.allclose(d, full[edges[:, 0], edges[:, 1]], rtol=1e-5)
    # DISP is the largest node displacement, checked directly on one pair
    a, b = edges[0]
    assert d[0] == pytest.approx(np.max(np.linalg.norm(states[a] - states[b], axis=1)), rel=1e-5)  # float32 states
