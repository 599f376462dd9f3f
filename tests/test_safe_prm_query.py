"""The safe PRM's query with landmark bounds (ALT) gives the answers of a plain implementation, on hundreds of
queries: scipy's Dijkstra is the independent measure (of the landmarks' distances and of the paths)."""

from __future__ import annotations

import numpy as np
import pytest
from surgiplan import PlanningProblem
from surgiplan.plugins.planners.safe_prm.planner import SafePRM, SafePRMSettings
from surgiplan.spaces import R3Space
from test_safe_prm import _random_roadmap_graph, query_as_the_reference


def test_landmark_distances_are_scipys_dijkstra():
    """Every column: the roadmap distances from one milestone of the largest component (scipy's Dijkstra from
    it), inf in the other components; the landmarks are distinct and spread (each the farthest from the former)."""
    from scipy.sparse.csgraph import connected_components, dijkstra
    from surgiplan.plugins.planners.safe_prm.landmarks import landmark_distances

    rng = np.random.default_rng(11)
    for _ in range(3):
        points, graph = _random_roadmap_graph(rng, n=300)
        _, labels = connected_components(graph, directed=False)
        far = landmark_distances(
            graph.indptr.astype(np.int32),
            graph.indices.astype(np.int32),
            graph.data.astype(float),
            points,
            labels.astype(np.int64),
            6,
            0.002,
        )
        largest = np.argmax(np.bincount(labels))
        assert far.shape == (300, min(6, np.count_nonzero(labels == largest)))
        chosen = [int(np.flatnonzero(far[:, j] == 0.0)[0]) for j in range(far.shape[1])]
        assert len(set(chosen)) == len(chosen)
        assert all(labels[c] == largest for c in chosen)
        expected = dijkstra(graph, directed=False, indices=chosen).T
        np.testing.assert_allclose(far, expected, rtol=1e-12, atol=0)
        # the farthest strategy: each landmark is the node farthest from the ones before it (within the component)
        inside = labels == largest
        for j in range(1, far.shape[1]):
            nearest = far[:, :j].min(axis=1)
            assert nearest[chosen[j]] == pytest.approx(nearest[inside].max(), rel=1e-12)


@pytest.mark.parametrize("level", ["expert", "beginner"])
def test_hundreds_of_queries_match_the_plain_implementation(block_world, level):
    """150 random queries a level (both ends safe: the reference does not project) on a 1,500-milestone roadmap:
    the same milestones in the same order as scipy's Dijkstra on an explicit graph and the repair by its
    definition, so the same cost; and the landmarks make the search settle fewer nodes than the straight-line
    bound alone does on the same queries."""
    from surgiplan.plugins.planners.safe_prm import query as prm_query

    space = R3Space(block_world)
    roadmap = (
        SafePRM(SafePRMSettings(proficiency=level, milestones=1500, seed=5))
        .build(PlanningProblem(block_world, space))
        .roadmap
    )
    rng = np.random.default_rng(17)
    pairs = []
    while len(pairs) < 150:
        q = rng.uniform(block_world.bounds_min, block_world.bounds_max, size=(2, 3))
        if np.all(space.clearance(q) >= max(roadmap.d_thresh, 1e-4)):
            pairs.append(q)
    settled = []
    repaired = 0
    for start, goal in pairs:
        outcome = query_as_the_reference(roadmap, start, goal)
        settled.append(outcome.settled)
        repaired += outcome.repaired
    if level == "beginner":
        assert repaired >= 10  # the repair is exercised, not only the search in R
    # the same queries with the landmarks dropped: the straight-line bound alone
    with_landmarks = roadmap.kernel_arrays
    roadmap.kernel_arrays = (
        *with_landmarks[:7],
        np.empty((roadmap.n, 0)),
        np.empty((roadmap.n, 0)),
        *with_landmarks[9:],
    )
    plain = [prm_query.query(roadmap, start, goal).settled for start, goal in pairs]
    assert np.sum(settled) < 0.8 * np.sum(plain)
