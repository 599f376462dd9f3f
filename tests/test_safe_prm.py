"""safe_prm (paper 000): certified roadmaps, repair, critical regions, projection, smoothing, persistence."""

from __future__ import annotations

import itertools
import json
import textwrap

import numpy as np
import pytest
from conftest import CONFIGS, ROOT
from helpers import coal_scene_segment_distance, dense_min_clearance
from surgiplan import PlanningProblem
from surgiplan.geometry.shapes import Box
from surgiplan.geometry.transforms import Pose
from surgiplan.plugins.planners.safe_prm.planner import SafePRM, SafePRMSettings
from surgiplan.scene import Scene
from surgiplan.spaces import CastGimbalSettings, CastGimbalSpace, R3Space

MM = 1e-3


def wall_scene(way_around: bool) -> Scene:
    """A wall across a 100 x 100 x 40 mm box at x = 50 with one 6 mm gap; optionally open at one end."""
    top = 80.0 if way_around else 100.0
    obstacles = [
        Box("lower", Pose.from_xyz_rpy([0.050, 0.0235, 0.020]), size=(0.010, 0.047, 0.040)),
        Box("upper", Pose.from_xyz_rpy([0.050, (53 + top) / 2 * MM, 0.020]), size=(0.010, (top - 53) * MM, 0.040)),
    ]
    return Scene([0, 0, 0], [0.1, 0.1, 0.04], obstacles, {"a": [0.015, 0.050, 0.020], "b": [0.085, 0.050, 0.020]})


def plan(space, start, goal, **settings):
    planner = SafePRM(SafePRMSettings(**{"milestones": 2500, "seed": 3, **settings}))
    artifact = planner.build(PlanningProblem(space.scene, space))
    return planner, artifact, planner.query(artifact, np.asarray(start, float), np.asarray(goal, float))


def outside_critical(path_tips, regions, spacing=5e-5):
    """Dense points of the path, as arc length and positions, with the critical regions cut out."""
    steps = np.linalg.norm(np.diff(path_tips, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    s = np.arange(0.0, arc[-1], spacing)
    points = np.stack([np.interp(s, arc, path_tips[:, k]) for k in range(3)], axis=1)
    keep = np.ones(len(s), dtype=bool)
    for r in regions:
        keep &= ~((s >= r["start_m"] - 1e-9) & (s <= r["end_m"] + 1e-9))
    return points[keep]


def test_a_wall_with_one_narrow_gap_is_a_critical_region():
    scene = wall_scene(way_around=False)
    space = R3Space(scene)
    _, _, result = plan(space, scene.points["a"], scene.points["b"], proficiency=4 * MM)
    assert result.solved
    regions = result.metrics["critical_regions"]
    assert len(regions) == 1
    region = regions[0]
    assert set(region["obstacles"]) <= {"lower", "upper"}
    # the gap is 6 mm wide: the best a path can do there is 3 mm, and it is centred
    assert region["min_clearance_m"] == pytest.approx(3 * MM, abs=0.05 * MM)
    # the region is where the wall is, give or take the 4 mm virtual boundary
    tips = result.path
    steps = np.linalg.norm(np.diff(tips, axis=0), axis=1)
    arc = np.concatenate([[0], np.cumsum(steps)])
    x_at = lambda s: np.interp(s, arc, tips[:, 0])  # noqa: E731
    assert 0.040 < x_at(region["start_m"]) < 0.046 and 0.054 < x_at(region["end_m"]) < 0.060
    # outside it, every point keeps 4 mm: re-measured with coal
    points = outside_critical(tips, regions)
    from helpers import coal_scene_point_distance

    assert coal_scene_point_distance(scene, points).min() >= 4 * MM - 1e-9
    assert coal_scene_segment_distance(scene, tips[:-1], tips[1:]).min() > 0


def test_a_way_around_removes_the_critical_region_and_the_path_detours():
    scene = wall_scene(way_around=True)
    space = R3Space(scene)
    _, _, result = plan(space, scene.points["a"], scene.points["b"], proficiency=4 * MM)
    assert result.solved
    assert result.metrics["critical_regions"] == []
    assert result.metrics["repaired"] >= 1  # R's shortest path went through the gap; repair detoured
    clearance = dense_min_clearance(scene, result.path[:-1], result.path[1:], spacing=5e-5)
    assert clearance.min() >= 4 * MM - 1e-9
    assert np.max(result.path[:, 1]) > 0.080, "the detour goes around the open end of the wall"


def test_start_and_goal_in_one_safe_component_are_not_repaired(block_world):
    space = R3Space(block_world)
    start, goal = np.array([0.055, 0.030, 0.020]), np.array([0.065, 0.080, 0.020])  # between pairs A and B
    _, _, smoothed = plan(space, start, goal, proficiency="intermediate")
    assert smoothed.solved and smoothed.metrics["repaired"] == 0
    assert smoothed.metrics["critical_regions"] == []
    # with smoothing off, the answer is R's own shortest path, every edge of it in R_safe
    raw = SafePRM(SafePRMSettings(proficiency="intermediate", milestones=2500, seed=3, smoothing={"enabled": False}))
    result = raw.query(raw.build(PlanningProblem(block_world, space)), start, goal)
    assert result.metrics["repaired"] == 0
    assert coal_scene_segment_distance(block_world, result.path[:-1], result.path[1:]).min() >= 4 * MM - 1e-9


def test_no_path_is_a_status_not_an_exception():
    sealed = Scene(
        [0, 0, 0], [0.1, 0.1, 0.04], [Box("wall", Pose.from_xyz_rpy([0.05, 0.05, 0.02]), size=(0.01, 0.1, 0.04))]
    )
    space = R3Space(sealed)
    _, _, result = plan(space, [0.02, 0.05, 0.02], [0.08, 0.05, 0.02], milestones=800)
    assert result.status.value == "no_path" and len(result.path) == 0
    assert "different components" in result.message


def test_invalid_start_is_a_status(block_world):
    _, _, result = plan(R3Space(block_world), [0.040, 0.020, 0.020], block_world.points["target"], milestones=500)
    assert result.status.value == "invalid_start"


def test_same_seed_same_path_and_reload_gives_the_same_answer(block_world):
    space = R3Space(block_world)
    problem = PlanningProblem(block_world, space)
    settings = SafePRMSettings(proficiency="intermediate", milestones=2000, seed=11)
    first = SafePRM(settings)
    artifact = first.build(problem)
    a = first.query(artifact, block_world.points["entry"], block_world.points["target"])
    b = SafePRM(settings).query(
        SafePRM(settings).build(problem), block_world.points["entry"], block_world.points["target"]
    )
    np.testing.assert_array_equal(a.path, b.path)
    stored = first.save_artifact(artifact)
    reloaded = first.load_artifact(stored, problem)
    c = first.query(reloaded, block_world.points["entry"], block_world.points["target"])
    np.testing.assert_array_equal(a.path, c.path)


@pytest.mark.parametrize("space_kind", ["r3", "gimbal"])
def test_the_build_is_the_same_on_one_thread_or_several(block_world, space_kind):
    """The neighbour search's slabs and the two roadmaps' landmarks run at once on several threads: the same
    edges, components, landmark marks and answer as on one (three threads: uneven slabs)."""
    space = (
        R3Space(block_world)
        if space_kind == "r3"
        else CastGimbalSpace(
            block_world,
            CastGimbalSettings.model_validate({"fulcrum": {"xyz": [0.075, -0.06, 0.12], "rpy": [0, 0, 1.5707963]}}),
        )
    )
    problem = PlanningProblem(block_world, space)
    built = {}
    for threads in (1, 2, 3):
        planner = SafePRM(SafePRMSettings(proficiency="intermediate", milestones=1500, seed=5, threads=threads))
        built[threads] = planner.build(problem).roadmap
    one = built[1]
    assert one.threads == 1 and built[2].threads == 2
    assert len(one.edges) > 5000 and 0 < np.count_nonzero(one.edge_safe) < len(one.edges)
    for threads in (2, 3):
        other = built[threads]
        np.testing.assert_array_equal(other.edges, one.edges)
        np.testing.assert_array_equal(other.edge_safe, one.edge_safe)
        np.testing.assert_array_equal(other.safe_labels, one.safe_labels)
        for mine, theirs in ((other.free_graph, one.free_graph), (other.safe_graph, one.safe_graph)):
            assert mine.landmarks == theirs.landmarks > 0
            np.testing.assert_array_equal(mine.marks, theirs.marks)
            np.testing.assert_array_equal(mine.indices, theirs.indices)


class _RefusingPool:
    """Stands in for :mod:`surgiplan.threads`' pool: any work handed to it fails the test."""

    def submit(self, *args, **kwargs):
        raise AssertionError("work went to the pool's threads")


def test_threads_1_keeps_the_whole_build_on_the_callers_thread(block_world, monkeypatch):
    """``threads: 1`` covers every split below the build, the scene's batched distances among them (a batch of
    1,500 sampled milestones is above the split size), not only the neighbour search and the landmarks."""
    from surgiplan import threads
    from surgiplan.geometry import compiled

    assert 1500 >= compiled.SPLIT_AT
    monkeypatch.setattr(threads, "_POOL", _RefusingPool())
    monkeypatch.setattr(threads, "_POOL_SIZE", 64)
    monkeypatch.setattr(threads.os, "sched_getaffinity", lambda pid: {0, 1})  # two CPUs, whatever this host has
    problem = PlanningProblem(block_world, R3Space(block_world))
    built = SafePRM(SafePRMSettings(proficiency="intermediate", milestones=1500, seed=5, threads=1)).build(problem)
    assert built.roadmap.threads == 1 and len(built.roadmap.edges) > 5000
    with pytest.raises(AssertionError, match="pool's threads"):  # two threads do use the pool
        SafePRM(SafePRMSettings(proficiency="intermediate", milestones=1500, seed=5, threads=2)).build(problem)


def test_every_edge_is_certified(block_world):
    """No R edge touches an obstacle, no R_safe edge crosses the 4 mm virtual boundary: re-measured with coal."""
    space = R3Space(block_world, tip_radius=0.5 * MM)
    planner = SafePRM(SafePRMSettings(proficiency="intermediate", milestones=1500, seed=5))
    roadmap = planner.build(PlanningProblem(block_world, space)).roadmap
    a = roadmap.milestones[roadmap.edges[:, 0]]
    b = roadmap.milestones[roadmap.edges[:, 1]]
    pick = np.random.default_rng(0).choice(len(a), size=min(3000, len(a)), replace=False)
    clearance = coal_scene_segment_distance(block_world, a[pick], b[pick], 0.5 * MM)
    assert clearance.min() > 0
    safe = roadmap.edge_safe[pick]
    assert safe.sum() > 100 and (~safe).sum() > 20
    assert clearance[safe].min() >= 4 * MM - 1e-9
    # covering balls certified most edges without a distance query
    assert roadmap.covered_edges > 0.5 * len(roadmap.edges)


def test_start_in_the_risk_region_is_projected_and_linked(block_world):
    space = R3Space(block_world)
    start = np.array([0.031, 0.020, 0.020])  # 4 mm from block A1: inside the 8 mm boundary
    _, _, result = plan(space, start, block_world.points["entry"], proficiency="beginner")
    assert result.solved
    regions = result.metrics["critical_regions"]
    assert len(regions) == 1 and regions[0]["start_m"] == 0.0  # only the link out of the risk region
    assert regions[0]["obstacles"] == ["A1"]
    # from 4 mm out to the nearest safe milestone, which lies beyond the 8 mm boundary
    assert 4 * MM <= regions[0]["length_m"] < 10 * MM


def test_gimbal_space_keeps_the_whole_shaft_clear(block_world):
    settings = CastGimbalSettings.model_validate(
        {
            "fulcrum": {"xyz": [0.075, -0.06, 0.12], "rpy": [0, 0, np.pi / 2]},
            "shaft_radius": 0.001,
            "roll": {"min": 0, "max": 0},
        }
    )
    space = CastGimbalSpace(block_world, settings)
    start = space.configuration(np.array([0.055, 0.030, 0.020]))
    goal = space.configuration(np.array([0.095, 0.030, 0.020]))
    _, _, result = plan(space, start, goal, proficiency=2 * MM, milestones=2000)
    assert result.solved, result.message
    dense = space.densify(result.path, 1e-4)
    fulcrum = np.broadcast_to(space.fulcrum, (len(dense), 3))
    shaft = coal_scene_segment_distance(block_world, fulcrum, space.tip(dense), 0.001)
    regions = result.metrics["critical_regions"]
    assert shaft.min() > 0
    if not regions:
        assert shaft.min() >= 2 * MM - 2e-5  # dense sampling between certified motions


def test_compiled_components_and_rows_match_scipy():
    """The roadmaps' component labels and CSR rows (compiled) against scipy's connected_components and CSR."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from surgiplan.plugins.planners.safe_prm.kernels import component_labels, csr_rows

    rng = np.random.default_rng(1)
    n = 300
    edges = np.unique(np.sort(rng.integers(0, n, size=(250, 2)), axis=1), axis=0)
    edges = edges[edges[:, 0] != edges[:, 1]]
    cost = rng.uniform(0.1, 1.0, len(edges))
    mask = rng.uniform(size=len(edges)) < 0.7
    labels, count = component_labels(n, edges, mask)
    expected_count, expected = connected_components(
        coo_matrix((np.ones(mask.sum()), edges[mask].T), shape=(n, n)), directed=False
    )
    assert count == expected_count
    for i, j in rng.integers(0, n, size=(2000, 2)):
        assert (labels[i] == labels[j]) == (expected[i] == expected[j])
    indptr, indices, data = csr_rows(n, edges, cost, mask, 1e-15)
    i, j = edges[mask, 0], edges[mask, 1]
    reference = coo_matrix((np.r_[cost[mask], cost[mask]], (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsr()
    reference.sort_indices()
    for row in range(n):
        span, theirs = slice(indptr[row], indptr[row + 1]), slice(reference.indptr[row], reference.indptr[row + 1])
        mine = sorted(zip(indices[span].tolist(), data[span].tolist(), strict=True))
        assert mine == list(zip(reference.indices[theirs].tolist(), reference.data[theirs].tolist(), strict=True))


def test_d_thresh_from_recorded_attempts(tmp_path):
    rng = np.random.default_rng(2)
    suggested = np.stack([np.linspace(0, 100, 21), np.full(21, 50.0), np.full(21, 20.0)], axis=1)
    rows = ["attempt,x_mm,y_mm,z_mm"] + [f"suggested,{x},{y},{z}" for x, y, z in suggested]
    deviations = []
    for attempt in range(3):
        offsets = rng.normal(0, 2.0, size=40)  # mm, sideways in y
        for x, dy in zip(np.linspace(2, 98, 40), offsets, strict=True):
            rows.append(f"{attempt},{x},{50 + dy},20")
            deviations.append(abs(dy))
    (tmp_path / "attempts.csv").write_text("\n".join(rows) + "\n")
    settings = SafePRMSettings.model_validate(
        {"proficiency": {"from_attempts": "attempts.csv", "percentile": 90}},
        context={"base_dir": tmp_path, "length_scale": 1e-3},
    )
    assert settings.d_thresh == pytest.approx(np.percentile(deviations, 90) * MM, rel=1e-9)
    assert settings.proficiency.attempts == 3 and settings.proficiency.points == 120


@pytest.mark.parametrize(
    ("proficiency", "message"),
    [
        ("intermediat", "unknown proficiency level 'intermediat'; did you mean 'intermediate'?"),
        ({"from_attempts": "missing.csv"}, "cannot read"),
        (-2, "non-negative"),
    ],
)
def test_bad_proficiency_settings_are_clear_errors(tmp_path, proficiency, message):
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match=message):
        SafePRMSettings.model_validate(
            {"proficiency": proficiency}, context={"base_dir": tmp_path, "length_scale": 1e-3}
        )


def test_paper_fig4_pipeline(cli, tmp_path, block_world):
    """configs/block_world_proficiency.yaml: the four panels of paper 000 Fig. 4."""
    config = (
        (CONFIGS / "block_world_proficiency.yaml")
        .read_text()
        .replace("out/block-world-proficiency", str(tmp_path / "out"))
    )
    config = config.replace("scene: scenes/block_world.yaml", f"scene: {ROOT}/configs/scenes/block_world.yaml")
    path = tmp_path / "fig4.yaml"
    path.write_text(config)
    code, _, err = cli("run", path, "--quiet")
    assert code == 0, err
    stages = {s["name"]: s for s in json.loads((tmp_path / "out" / "result.json").read_text())["stages"]}
    straight = 0.130
    expert = stages["expert"]
    assert expert["metrics"]["length_m"] <= 1.05 * straight and expert["metrics"]["critical_regions"] == []
    for name, around in (("intermediate", ("C1", "C2")), ("beginner", ("B1", "B2", "C1", "C2"))):
        stage = stages[name]
        regions = stage["metrics"]["critical_regions"]
        assert len(regions) == 1 and set(regions[0]["obstacles"]) <= {"A1", "A2"}, regions
        waypoints = np.array(stage["path"])
        # the passages of the pairs it detours around are not used: the path leaves y = 35..65 there
        for pair in {o[0] for o in around}:
            x = {"B": 0.075, "C": 0.110}[pair]
            y = np.interp(x, waypoints[:, 0], waypoints[:, 1])
            assert not 0.035 < y < 0.065, f"{name} goes through pair {pair}"
    assert np.interp(
        0.075, np.array(stages["intermediate"]["path"])[:, 0], np.array(stages["intermediate"]["path"])[:, 1]
    ) == pytest.approx(0.050, abs=0.004)
    tall = stages["beginner-tall-box"]
    assert tall["metrics"]["critical_regions"] == [] and tall["metrics"]["min_clearance_m"] >= 0.008 - 1e-9
    assert (tmp_path / "out" / "overview.png").is_file()
    # the roadmaps were stored; a second run loads them
    code, _, err = cli("run", path, "--quiet")
    assert code == 0, err
    again = json.loads((tmp_path / "out" / "result.json").read_text())["stages"]
    assert all(s["metrics"]["artifact"] == "loaded" for s in again)
    assert [s["path"] for s in again] == [stages[s["name"]]["path"] for s in again]


def test_pipeline_settings_accept_units_and_files(cli, tmp_path):
    (tmp_path / "attempts.csv").write_text(
        "attempt,x,y,z\nsuggested,10,50,20\nsuggested,140,50,20\n1,20,52,20\n1,40,53,20\n1,60,49,20\n"
    )
    path = tmp_path / "p.yaml"
    path.write_text(
        textwrap.dedent(f"""\
        name: units
        length_unit: mm
        scene: {ROOT}/configs/scenes/block_world.yaml
        pipeline:
          - {{stage: plan, name: custom, plugin: safe_prm, settings: {{proficiency: "0.5 cm", milestones: 800}},
             start: entry, goal: target}}
          - {{stage: plan, name: data, plugin: safe_prm,
             settings: {{proficiency: {{from_attempts: attempts.csv, percentile: 100}}, milestones: 800}},
             start: entry, goal: target}}
        output: {{dir: {tmp_path}/out, figures: false, gltf: false}}
        """)
    )
    code, _, err = cli("run", path, "--quiet")
    assert code == 0, err
    stages = json.loads((tmp_path / "out" / "result.json").read_text())["stages"]
    assert stages[0]["metrics"]["d_thresh_m"] == pytest.approx(0.005)
    assert stages[1]["metrics"]["d_thresh_m"] == pytest.approx(0.003)  # the largest deviation: 3 mm


# ----------------------------------------------------------------------------- the compiled search against scipy


def _random_roadmap_graph(rng, n=400, radius=0.18):
    """A random geometric graph in the unit cube: edge cost = Euclidean length (the A* heuristic's metric)."""
    from scipy.sparse import csr_matrix
    from scipy.spatial import cKDTree

    points = rng.uniform(0, 1, size=(n, 3))
    pairs = np.array(sorted(cKDTree(points).query_pairs(radius)), dtype=np.int64).reshape(-1, 2)
    keep = rng.uniform(size=len(pairs)) < 0.6  # thin it so that some nodes are unreachable
    pairs = pairs[keep]
    cost = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
    i, j = pairs[:, 0], pairs[:, 1]
    graph = csr_matrix((np.concatenate([cost, cost]), (np.concatenate([i, j]), np.concatenate([j, i]))), (n, n))
    return points, graph


def _path_cost(points, nodes):
    return float(np.linalg.norm(np.diff(points[nodes], axis=0), axis=1).sum())


def test_compiled_astar_finds_scipy_dijkstras_paths_and_costs():
    """Milestone to milestone, and between virtual start/goal points linked into the graph (with a direct motion)."""
    from scipy.sparse import bmat, csr_matrix
    from scipy.sparse.csgraph import connected_components, dijkstra
    from surgiplan.plugins.planners.safe_prm.astar import shortest_path
    from surgiplan.plugins.planners.safe_prm.landmarks import landmark_distances

    def rows(graph):
        return graph.indptr.astype(np.uint32), graph.indices.astype(np.uint32), graph.data.astype(float)

    rng = np.random.default_rng(7)
    for case in range(4):
        points, graph = _random_roadmap_graph(rng)
        n = len(points)
        distance, predecessors = dijkstra(graph, directed=False, return_predecessors=True)
        # the last graph with buckets so narrow that keys overflow the window and are re-bucketed as it moves
        delta = 1e-5 if case == 3 else None
        # the landmarks' bounds (ALT) on two graphs, the straight line alone on two
        far = landmark_distances(*rows(graph), points, connected_components(graph)[1].astype(np.int64), 4, 0.01)
        far = far if case % 2 else None
        for source, target in rng.integers(0, n, size=(60, 2)):
            nodes, cost, settled = shortest_path(graph, points, int(source), int(target), delta=delta, far=far)
            if not np.isfinite(distance[source, target]):
                assert len(nodes) == 0 and cost == np.inf
                continue
            expected = [int(target)]
            while expected[-1] != source:
                expected.append(int(predecessors[source, expected[-1]]))
            assert nodes.tolist() == expected[::-1]
            assert cost == pytest.approx(distance[source, target], rel=1e-12, abs=1e-15)
            assert settled <= n
        # virtual ends: the graph with two more nodes, searched by scipy from the start node
        for _ in range(30):
            ends = rng.uniform(0, 1, size=(2, 3))
            links = [np.flatnonzero(np.linalg.norm(points - p, axis=1) < 0.15) for p in ends]
            link_cost = [np.linalg.norm(points[t] - p, axis=1) for t, p in zip(links, ends, strict=True)]
            direct = float(np.linalg.norm(ends[1] - ends[0]))
            direct = direct if rng.uniform() < 0.3 else np.inf
            extra = np.zeros((2, n + 2))
            extra[0, links[0]] = link_cost[0]
            extra[1, links[1]] = link_cost[1]
            if np.isfinite(direct):
                extra[0, n + 1] = direct
            full = bmat([[graph, None], [None, csr_matrix((2, 2))]]).tolil()
            full[n:, :] = extra
            full = full.tocsr()
            full = full.maximum(full.T)
            d, pred = dijkstra(full, directed=False, indices=n, return_predecessors=True)
            nodes, cost, _ = shortest_path(
                graph,
                points,
                -1,
                -1,
                source_links=(links[0], link_cost[0], ends[0]),
                target_links=(links[1], link_cost[1], ends[1]),
                direct_cost=direct,
                delta=delta,
                far=far,
            )
            if not np.isfinite(d[n + 1]):
                assert len(nodes) == 0
                continue
            expected = [n + 1]
            while expected[-1] != n:
                expected.append(int(pred[expected[-1]]))
            expected = [-1 if v == n else -2 if v == n + 1 else v for v in expected[::-1]]
            assert nodes.tolist() == expected
            assert cost == pytest.approx(d[n + 1], rel=1e-12)


def _reference_query(roadmap, start, goal):
    """Algorithms 2-4 written plainly: scipy's Dijkstra on an explicit graph with the start and goal as nodes,
    links by the space's exact motion check (no covering balls), repair by the definition."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components, dijkstra

    space, n, d = roadmap.space, roadmap.n, roadmap.d_thresh
    ends = np.stack([start, goal])
    ends_safe = space.clearance(ends) >= d
    rows, cols, cost, safe = [roadmap.edges[:, 0]], [roadmap.edges[:, 1]], [roadmap.edge_cost], [roadmap.edge_safe]
    for node, q, q_safe in ((n, start, ends_safe[0]), (n + 1, goal, ends_safe[1])):
        targets = roadmap.neighbours(q)
        here = np.repeat(q[None], len(targets), 0)
        free = space.motion_is_clear(here, roadmap.milestones[targets], 0.0)
        kept = targets[free]
        link_safe = q_safe & roadmap.safe[kept] & space.motion_is_clear(here[free], roadmap.milestones[kept], d)
        rows.append(kept)
        cols.append(np.full(len(kept), node))
        cost.append(space.distance(q, roadmap.milestones[kept]))
        safe.append(link_safe)
    if space.distance(start, goal) <= roadmap.s and space.motion_is_clear(start[None], goal[None], 0.0)[0]:
        rows.append(np.array([n]))
        cols.append(np.array([n + 1]))
        cost.append(np.array([space.distance(start, goal)]))
        safe.append(np.array([bool(ends_safe.all() and space.motion_is_clear(start[None], goal[None], d)[0])]))
    rows, cols, cost, safe = map(np.concatenate, (rows, cols, cost, safe))

    def graph(mask):
        r, c, w = rows[mask], cols[mask], cost[mask]
        return coo_matrix((np.r_[w, w], (np.r_[r, c], np.r_[c, r])), (n + 2, n + 2)).tocsr()

    free_graph, safe_graph = graph(np.ones(len(rows), bool)), graph(safe)
    safe_node = np.concatenate([roadmap.safe, ends_safe])
    safe_pairs = {(min(a, b), max(a, b)) for a, b in zip(rows[safe], cols[safe], strict=True)}
    _, label = connected_components(safe_graph, directed=False)

    def shortest(g, a, b):
        _, pred = dijkstra(g, directed=False, indices=a, return_predecessors=True)
        out = [b]
        while out[-1] != a:
            out.append(int(pred[out[-1]]))
        return out[::-1]

    def is_safe(a, b):
        return safe_node[a] and safe_node[b] and (min(a, b), max(a, b)) in safe_pairs

    path = shortest(free_graph, n, n + 1)
    if all(is_safe(a, b) for a, b in itertools.pairwise(path)):
        return path
    out, l = [], 0
    while l < len(path):
        m = l
        if safe_node[path[l]]:
            m = max(k for k in range(l, len(path)) if safe_node[path[k]] and label[path[k]] == label[path[l]])
        if m == l:
            out.append(path[l])
            l += 1
            continue
        stretch = path[l : m + 1]
        if not all(is_safe(a, b) for a, b in itertools.pairwise(stretch)):
            stretch = shortest(safe_graph, path[l], path[m])
        out.extend(stretch[:-1])
        l = m
    return out


def query_as_the_reference(roadmap, start, goal):
    """The compiled query's outcome, checked to be :func:`_reference_query`'s path milestone for milestone."""
    from surgiplan.plugins.planners.safe_prm import query as prm_query

    outcome = prm_query.query(roadmap, start, goal)
    nodes = np.concatenate([roadmap.milestones, start[None], goal[None]])[_reference_query(roadmap, start, goal)]
    assert outcome.found
    np.testing.assert_array_equal(outcome.path, nodes)
    return outcome


@pytest.mark.parametrize("level", ["expert", "intermediate", "beginner"])
def test_query_and_repair_match_a_plain_scipy_implementation(block_world, level):
    """The compiled search, batched links and labelled repair give Algorithms 2-4's exact answer."""

    space = R3Space(block_world)
    rng = np.random.default_rng(3)
    for seed in (1, 2):
        roadmap = (
            SafePRM(SafePRMSettings(proficiency=level, milestones=1200, seed=seed))
            .build(PlanningProblem(block_world, space))
            .roadmap
        )
        pairs = [(block_world.points["entry"], block_world.points["target"])]
        while len(pairs) < 8:
            q = rng.uniform(block_world.bounds_min, block_world.bounds_max, size=(2, 3))
            if np.all(space.clearance(q) >= roadmap.d_thresh):  # the reference does not project
                pairs.append((q[0], q[1]))
        for start, goal in pairs:
            query_as_the_reference(roadmap, start, goal)


@pytest.mark.parametrize("tip_radius", [0.0, 0.5 * MM])
def test_roadmap_edges_are_exactly_the_k_s_pairs_the_exact_check_accepts(block_world, tip_radius):
    """Covering balls (two, then three with the midpoint) only save exact checks: the edge sets are the same."""
    from scipy.spatial import cKDTree

    space = R3Space(block_world, tip_radius=tip_radius)
    roadmap = (
        SafePRM(SafePRMSettings(proficiency="intermediate", milestones=1500, seed=4))
        .build(PlanningProblem(block_world, space))
        .roadmap
    )
    q = roadmap.milestones
    distance, index = cKDTree(q).query(q, k=roadmap.k + 1, distance_upper_bound=roadmap.s)
    candidates = {
        (min(i, int(j)), max(i, int(j)))
        for i in range(len(q))
        for dd, j in zip(distance[i], index[i], strict=True)
        if np.isfinite(dd) and j != i
    }
    pairs = np.array(sorted(candidates))
    free = space.motion_is_clear(q[pairs[:, 0]], q[pairs[:, 1]], 0.0)
    safe = free & roadmap.safe[pairs[:, 0]] & roadmap.safe[pairs[:, 1]]
    safe[safe] = space.motion_is_clear(q[pairs[safe, 0]], q[pairs[safe, 1]], roadmap.d_thresh)
    np.testing.assert_array_equal(roadmap.edges, pairs[free])
    np.testing.assert_array_equal(roadmap.edge_safe, safe[free])
    assert roadmap.covered_edges > 0.8 * len(roadmap.edges)
    # the edges' costs come from the neighbour search (R3's motions are Euclidean): the space's own distances, bit
    # for bit
    a, b = q[roadmap.edges[:, 0]], q[roadmap.edges[:, 1]]
    np.testing.assert_array_equal(roadmap.edge_cost, space.distance(a, b))
