"""The safe PRM's query with landmark bounds (ALT) gives the answers of a plain implementation, on hundreds of
queries: scipy's Dijkstra is the independent measure (of the landmarks' distances and of the paths)."""

from __future__ import annotations

import numpy as np
import pytest
from surgiplan import PlanningProblem
from surgiplan.plugins.planners.safe_prm.planner import SafePRM, SafePRMSettings
from surgiplan.spaces import R3Space
from test_safe_prm import _random_roadmap_graph, query_as_the_reference


@pytest.mark.parametrize("bits", [16, 32])
def test_landmark_distances_are_scipys_dijkstra(bits):
    """Every column, with each edge's far node packed in 16 bits and in 32: the roadmap distances from one
    milestone of the largest component (scipy's Dijkstra from it), inf in the other components, never above scipy's
    and below it by less than a unit (a bucket's width over 2**shift, the finest shift whose weights fit the
    packing) an edge of a path; across every edge they change by no more than its cost (what keeps the landmarks'
    bounds admissible); the landmarks are distinct and spread (each the farthest from the former)."""
    from scipy.sparse.csgraph import connected_components, dijkstra
    from surgiplan.plugins.planners.safe_prm.landmarks import _SHIFTS, landmark_distances

    rng = np.random.default_rng(11)
    for _ in range(3):
        points, graph = _random_roadmap_graph(rng, n=300)
        _, labels = connected_components(graph, directed=False)
        far = landmark_distances(
            graph.indptr.astype(np.uint32),
            graph.indices.astype(np.uint32),
            graph.data.astype(float),
            points,
            labels.astype(np.int64),
            6,
            0.002,
            bits,
        )
        largest = np.argmax(np.bincount(labels))
        assert far.shape == (300, min(6, np.count_nonzero(labels == largest)))
        chosen = [int(np.flatnonzero(far[:, j] == 0.0)[0]) for j in range(far.shape[1])]
        assert len(set(chosen)) == len(chosen)
        assert all(labels[c] == largest for c in chosen)
        expected = dijkstra(graph, directed=False, indices=chosen).T
        finite = np.isfinite(expected)
        assert np.array_equal(np.isfinite(far), finite)
        heaviest = graph.data.max() / 0.002  # the longest edge in buckets
        shift = next(s for s in _SHIFTS if np.floor(heaviest * 2**s) < min(2**bits - 1, 2**32 - 1))
        assert shift == (16 if bits == 32 else 8)  # both packings and a shift past the first are what is tested
        unit = 0.002 / 2**shift
        shortfall = expected[finite] - far[finite]
        assert shortfall.min() >= -1e-12 * expected[finite].max()
        assert shortfall.max() < (np.count_nonzero(labels == largest) - 1) * unit  # < a unit an edge of a path
        assert shortfall.max() > 0  # the rounding is there (so the bound above is what is tested)
        rows, cols = graph.nonzero()
        inside = finite[rows, 0]
        step = far[cols[inside]] - far[rows[inside]]
        assert np.all(step <= np.asarray(graph[rows[inside], cols[inside]]).reshape(-1, 1) * (1 + 1e-12))
        # the farthest strategy: each landmark is the node farthest from the ones before it (within the component)
        inside = labels == largest
        for j in range(1, far.shape[1]):
            nearest = far[:, :j].min(axis=1)
            assert nearest[chosen[j]] == pytest.approx(nearest[inside].max(), rel=1e-12)


def test_landmark_distances_pack_edges_in_32_bits_when_a_weight_does_not_fit_16():
    """A chain whose middle edge is 100,000 buckets long: no shift gives it a 16-bit weight, so the distances come
    from the 32-bit packing (the same as asking for it), exact to a unit an edge; asking for 16 bits gives none."""
    from surgiplan.plugins.planners.safe_prm.landmarks import landmark_distances

    delta = 1e-3
    cost = np.array([1.0, 100_000.0, 2.0]) * delta  # the chain 0 - 1 - 2 - 3
    indptr = np.array([0, 1, 3, 5, 6], dtype=np.uint32)
    indices = np.array([1, 0, 2, 1, 3, 2], dtype=np.uint32)
    data = np.array([cost[0], cost[0], cost[1], cost[1], cost[2], cost[2]])
    points = np.zeros((4, 3))
    labels = np.zeros(4, dtype=np.int64)
    args = (indptr, indices, data, points, labels, 2, delta)
    assert landmark_distances(*args, 16).shape == (4, 0)
    far = landmark_distances(*args)
    np.testing.assert_array_equal(far, landmark_distances(*args, 32))
    expected = np.array([[0.0, 100_003.0], [1.0, 100_002.0], [100_001.0, 2.0], [100_003.0, 0.0]]) * delta
    assert far.shape == (4, 2)
    assert np.all(far <= expected) and np.all(expected - far < 3 * delta / 2**16)
    with pytest.raises(ValueError, match="70000 milestones cannot pack its edges in 16 bits"):
        landmark_distances(indptr, indices, data, np.zeros((70_000, 3)), labels, 2, delta, 16)


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
    arrays = roadmap.arrays
    roadmap.arrays = arrays._replace(free=arrays.free._replace(landmarks=0), safe=arrays.safe._replace(landmarks=0))
    plain = [prm_query.query(roadmap, start, goal).settled for start, goal in pairs]
    assert np.sum(settled) < 0.8 * np.sum(plain)


def test_the_one_call_query_is_the_stepwise_query(block_world, monkeypatch):
    """The query in one compiled call (query_fused: the ends measured, linked, searched and repaired there) gives
    the stepwise query's answer (the space's clearance, the kernels called one by one) on 200 random pairs at
    each level: the same path, edge kinds, repairs, settled nodes and avoided stretches, found or not, ends in
    the risk region (projected) and in collision included; the clearance it measures is R3Space.clearance's."""
    from surgiplan.plugins.planners.safe_prm import query as prm_query
    from surgiplan.plugins.planners.safe_prm.query_fused import point_obstacles

    space = R3Space(block_world, tip_radius=0.001)
    assert point_obstacles(space) is not None
    rng = np.random.default_rng(23)
    pairs = [np.array([block_world.points["entry"], block_world.points["target"]])]
    pairs += list(rng.uniform(block_world.bounds_min, block_world.bounds_max, size=(200, 2, 3)))
    fused = 0
    for level in ("expert", "beginner"):
        roadmap = (
            SafePRM(SafePRMSettings(proficiency=level, milestones=400, seed=3))
            .build(PlanningProblem(block_world, space))
            .roadmap
        )
        one_call = [prm_query.query(roadmap, start, goal) for start, goal in pairs]
        with monkeypatch.context() as patched:
            patched.setattr(prm_query, "_query_fused", lambda *args: None)
            stepwise = [prm_query.query(roadmap, start, goal) for start, goal in pairs]
        for a, b in zip(one_call, stepwise, strict=True):
            fused += "link_s" not in a.timings  # answered in the one call (linking not timed apart)
            assert (a.found, a.message, a.kinds, a.repaired, a.settled) == (
                b.found,
                b.message,
                b.kinds,
                b.repaired,
                b.settled,
            )
            np.testing.assert_array_equal(a.path, b.path)
            assert len(a.detours) == len(b.detours)
            for x, y in zip(a.detours, b.detours, strict=True):
                np.testing.assert_array_equal(x, y)
    # both ways exercised: the one call, and the stepwise query it hands over to (a projected end, or a link the
    # covering balls leave open: most at this sparse roadmap's long links)
    assert 40 <= fused <= 2 * len(pairs) - 40, fused
    # the clearance the one call measures: the scene's signed distance less the tip radius, exactly
    from surgiplan.geometry.compiled import nearest

    obstacles, tip = point_obstacles(space)
    ends = np.ascontiguousarray(np.concatenate(pairs[:50]))
    distance, index = np.empty(len(ends)), np.empty(len(ends), dtype=np.int64)
    nearest(*obstacles, ends, ends, False, np.full(len(ends), np.inf), distance, index)
    np.testing.assert_array_equal(distance - tip, space.clearance(ends))


def test_every_roadmap_pair_has_the_types_the_one_call_query_was_compiled_for(block_world):
    """The one-call query calls its compiled function directly, resolved once for a small roadmap's argument types
    (query._ENTRIES): every roadmap pair, in R3 and the gimbal space, built or stored and reloaded, has those types."""
    from surgiplan.plugins.planners.safe_prm import query as prm_query
    from surgiplan.plugins.planners.safe_prm.query_fused import link_search_repair
    from surgiplan.spaces import CastGimbalSettings, CastGimbalSpace

    entry = prm_query._ENTRIES[link_search_repair]
    (key,) = [k for k, compiled in link_search_repair.overloads.items() if compiled.entry_point is entry]
    gimbal = CastGimbalSpace(
        block_world,
        CastGimbalSettings.model_validate({"fulcrum": {"xyz": [0.075, -0.06, 0.12], "rpy": [0, 0, 1.5707963]}}),
    )
    for space, level in ((R3Space(block_world), "expert"), (R3Space(block_world), "beginner"), (gimbal, "beginner")):
        planner = SafePRM(SafePRMSettings(proficiency=level, milestones=300, seed=2))
        artifact = planner.build(PlanningProblem(block_world, space))
        reloaded = planner.load_artifact(planner.save_artifact(artifact), PlanningProblem(block_world, space))
        for roadmap in (artifact.roadmap, reloaded.roadmap):
            ends = np.zeros((2, space.dimension))
            arguments = (roadmap.arrays, ends, np.zeros(2), np.ones(2, dtype=bool), roadmap.search_workspace.arrays)
            assert tuple(link_search_repair.typeof_pyval(a) for a in arguments) == key
