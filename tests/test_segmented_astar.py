"""segmented_astar: A* on the pathmap (same cost as Dijkstra, admissible heuristic), links, replanning, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import assert_error_record
from helpers import coal_scene_segment_distance
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from surgiplan.plugins.planners.segmented_astar.search import ReplanSettings, SegmentedAStar, SegmentedAStarSettings
from test_optmis_support import (
    MM,
    POINTS_MM,
    SETTINGS,
    TIP_RADIUS,
    offline,
    pathmap_artifact,
    polyline_length,
    scene_yaml,
    small_world,
)


def planner(**settings) -> SegmentedAStar:
    return SegmentedAStar(SegmentedAStarSettings(**SETTINGS, **settings))


def reachable_pairs():
    repository = offline().repository
    return [(int(i), int(j)) for i, j in repository.pairs]


def assert_collision_free(path):
    scene = small_world()
    moving = np.any(path[1:] != path[:-1], axis=1)
    assert coal_scene_segment_distance(scene, path[:-1][moving], path[1:][moving], TIP_RADIUS).min() > 0
    assert np.all(scene.in_bounds(path))


def test_astar_cost_equals_dijkstra_on_the_same_graph():
    artifact = pathmap_artifact()
    graph, pois = artifact.graph, artifact.pathmap.pois
    p = planner()
    for i, j in reachable_pairs():
        result = p.query(artifact, pois[i], pois[j])
        assert result.solved
        reference = dijkstra(graph.graph, indices=artifact.poi_vertex[i])[artifact.poi_vertex[j]]
        assert result.metrics["path_cost_m"] == pytest.approx(reference, rel=1e-12, abs=1e-15)
        assert polyline_length(result.path) == pytest.approx(reference, rel=1e-12)
        np.testing.assert_array_equal(result.path[0], pois[i])
        np.testing.assert_array_equal(result.path[-1], pois[j])


def dijkstra_with_links(artifact, p, start, goal) -> float:
    """Independent reference: scipy's Dijkstra on the pathmap graph plus the coal-certified straight links."""
    graph = artifact.graph
    n = len(graph.points)
    rows, cols, weights = [], [], []
    for node, q in ((n, start), (n + 1, goal)):
        index = p.link_candidates(artifact, q)  # the planner's choice of candidates; certified here by coal
        distance = np.linalg.norm(graph.points[index] - q, axis=1)
        clear = (
            coal_scene_segment_distance(
                small_world(), np.repeat(q[None], len(index), 0), graph.points[index], TIP_RADIUS
            )
            > 0
        )
        rows += [np.full(clear.sum(), node), index[clear]]
        cols += [index[clear], np.full(clear.sum(), node)]
        weights += [distance[clear]] * 2
    base = graph.graph.tocoo()
    augmented = coo_matrix(
        (np.concatenate([base.data, *weights]), (np.concatenate([base.row, *rows]), np.concatenate([base.col, *cols]))),
        (n + 2, n + 2),
    ).tocsr()
    reference = dijkstra(augmented, indices=n)[n + 1]
    if coal_scene_segment_distance(small_world(), start, goal, TIP_RADIUS)[0] > 0:  # a straight line, if clear
        reference = min(reference, float(np.linalg.norm(goal - start)))
    return reference


def test_astar_from_arbitrary_points_equals_dijkstra_with_the_same_links():
    artifact = pathmap_artifact()
    p = planner()
    start, goal = np.array([6, 22, 12]) * MM, np.array([44, 30, 20]) * MM
    result = p.query(artifact, start, goal)
    assert result.solved and result.metrics["start_link"] == "straight" and result.metrics["goal_link"] == "straight"
    assert result.metrics["path_cost_m"] == pytest.approx(dijkstra_with_links(artifact, p, start, goal), rel=1e-12)
    assert_collision_free(result.path)
    # points just off the pathmap, often both beside the same chain (the route along that chain counts too)
    rng = np.random.default_rng(11)
    points = artifact.graph.points
    for _ in range(12):
        a, b = points[rng.choice(len(points), 2, replace=False)] + rng.normal(0, 0.2 * MM, (2, 3))
        if np.any(artifact.space.clearance(np.stack([a, b])) <= 0):
            continue
        result = p.query(artifact, a, b)
        assert result.solved
        assert result.metrics["path_cost_m"] == pytest.approx(dijkstra_with_links(artifact, p, a, b), rel=1e-9)
        assert polyline_length(result.path) == pytest.approx(result.metrics["path_cost_m"], rel=1e-9)


@pytest.mark.parametrize("margin", [0.0, 0.5 * MM])
def test_link_certification_decides_exactly_as_the_swept_check(margin):
    """Covering balls and interior samples only save swept checks: the decisions are the exact check's."""
    from surgiplan.plugins.planners.segmented_astar.graph import certify_motions

    space = pathmap_artifact().space
    scene = space.scene
    rng = np.random.default_rng(5)
    a = rng.uniform(scene.bounds_min, scene.bounds_max, (3000, 3))
    b = np.clip(a + rng.normal(0, 12 * MM, a.shape), scene.bounds_min, scene.bounds_max)
    keep = (space.clearance(a) > margin) & (space.clearance(b) > margin)
    a, b = a[keep], b[keep]
    decided = certify_motions(space, a, b, space.clearance(a) - margin, space.clearance(b) - margin, margin)
    np.testing.assert_array_equal(decided, space.motion_is_clear(a, b, margin))
    clearance = coal_scene_segment_distance(scene, a, b, TIP_RADIUS)
    assert np.all(clearance[decided] >= margin - 1e-12) and decided.sum() > 200 and (~decided).sum() > 100


def test_points_in_line_of_sight_get_the_straight_motion_without_linking():
    artifact = pathmap_artifact()
    p = planner()
    rng = np.random.default_rng(8)
    scene, space = small_world(), artifact.space
    free = rng.uniform(scene.bounds_min, scene.bounds_max, (600, 3))
    free = free[space.clearance(free) > 0][:200]
    seen = 0
    for start, goal in zip(free[::2], free[1::2], strict=True):
        clear = coal_scene_segment_distance(scene, start[None], goal[None], TIP_RADIUS)[0] > 0
        result = p.query(artifact, start, goal)
        if clear:
            seen += 1
            assert result.metrics["start_link"] == "direct" and result.metrics["link_checks"] == 0
            np.testing.assert_array_equal(result.path, np.stack([start, goal]))
            # the graph's answer with the same links is no shorter (it would be this motion)
            assert result.metrics["path_cost_m"] <= dijkstra_with_links(artifact, p, start, goal) + 1e-12
        else:
            assert result.metrics.get("start_link") != "direct"
    assert 10 < seen < 90


def test_euclidean_heuristic_is_admissible_and_consistent():
    artifact = pathmap_artifact()
    graph = artifact.graph
    points = graph.points
    goals = artifact.poi_vertex[artifact.poi_vertex >= 0]
    true = dijkstra(graph.graph, indices=goals)  # (goals, vertices): the true cost to each goal
    for g, row in zip(goals, true, strict=True):
        h = np.linalg.norm(points - points[g], axis=1)
        finite = np.isfinite(row)
        assert np.all(h[finite] <= row[finite] + 1e-12)  # never overestimates
        a, b = graph.edges[:, 0], graph.edges[:, 1]
        assert np.all(h[a] <= graph.length + h[b] + 1e-12) and np.all(h[b] <= graph.length + h[a] + 1e-12)
    # and on the contracted graph A* searches: every chain is at least as long as the line between its ends
    ends = np.array([[c[0], c[-1]] for c in graph.chains])
    assert np.all(graph.chain_cost + 1e-12 >= np.linalg.norm(points[ends[:, 0]] - points[ends[:, 1]], axis=1))


def test_online_paths_are_collision_free_and_no_longer_than_the_stored_ones():
    artifact = pathmap_artifact()
    pathmap, pois = artifact.pathmap, artifact.pathmap.pois
    p = planner()
    for k, (i, j) in enumerate(reachable_pairs()):
        result = p.query(artifact, pois[i], pois[j])
        assert_collision_free(result.path)
        # the pathmap holds the stored path (rebuilt within w_tip), so A* can only do better
        assert polyline_length(result.path) <= polyline_length(pathmap.path(k)) + 1e-12
    rng = np.random.default_rng(4)
    scene = small_world()
    free = rng.uniform(scene.bounds_min, scene.bounds_max, (400, 3))
    free = free[artifact.space.clearance(free) > 0.5 * MM][:24]
    for start, goal in zip(free[::2], free[1::2], strict=True):
        result = p.query(artifact, start, goal)
        if result.solved:
            assert_collision_free(result.path)
            np.testing.assert_array_equal(result.path[0], start)
            np.testing.assert_array_equal(result.path[-1], goal)
        else:  # only the sealed cup may be unreachable
            inside_cup = [
                bool(np.all((q >= np.array([50, 28, 0]) * MM) & (q <= np.array([58, 36, 10]) * MM)))
                for q in (start, goal)
            ]
            assert any(inside_cup), result.message


def test_start_that_no_straight_link_reaches_gets_a_local_plan():
    artifact = pathmap_artifact()
    # links of at most 0.05 mm: no pathmap point is that close, so the start is joined by a local plan
    p = planner(link_radius=0.05 * MM, local_radius=8 * MM)
    start, goal = np.array([12, 20, 8]) * MM, artifact.pathmap.pois[5]
    result = p.query(artifact, start, goal)
    assert result.solved, result.message
    assert result.metrics["start_link"] == "local" and result.metrics["local_plans"] == 1
    np.testing.assert_array_equal(result.path[0], start)
    assert_collision_free(result.path)


def test_points_no_stored_path_reaches_answer_no_path_with_the_reason():
    artifact = pathmap_artifact()
    names = artifact.pathmap.names
    cup = artifact.pathmap.pois[names.index("cup")]
    assert artifact.poi_vertex[names.index("cup")] == -1  # in no stored path
    p = planner()
    result = p.query(artifact, artifact.pathmap.pois[0], cup)
    assert result.status.value == "no_path"
    assert "cannot be joined to the pathmap" in result.message and "(54, 32, 4) mm" in result.message
    inside = np.array([52, 30, 6]) * MM  # in the cup, not a point of interest
    result = p.query(artifact, inside, artifact.pathmap.pois[2])
    assert result.status.value == "no_path" and "the start (52, 30, 6) mm cannot be joined" in result.message
    # a start inside an obstacle is refused before any search
    result = p.query(artifact, np.array([20, 10, 5]) * MM, artifact.pathmap.pois[2])
    assert result.status.value == "invalid_start"


def test_replanning_midway_gives_a_new_path_from_the_current_position(tmp_path):
    artifact = pathmap_artifact()
    pois, names = artifact.pathmap.pois, artifact.pathmap.names
    a, b, c = pois[names.index("a")], pois[names.index("d")], pois[names.index("c")]
    first = planner().query(artifact, a, b)
    p = planner(replan=ReplanSettings(goal="c", at=0.5, figure=str(tmp_path / "fig6.png")))
    result = p.query(artifact, a, b)
    assert result.solved
    assert (tmp_path / "fig6.png").read_bytes()[:4] == b"\x89PNG"
    replan = result.metrics["replan"]
    current = np.array(replan["position_m"])
    # the travelled part is the first path up to half its length ...
    arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(first.path, axis=0), axis=1))])
    travelled = result.path[: int(np.searchsorted(arc, arc[-1] / 2)) + 1]
    np.testing.assert_allclose(travelled[:-1], first.path[: len(travelled) - 1])
    assert polyline_length(np.vstack([travelled[:-1], current])) == pytest.approx(arc[-1] / 2, rel=1e-9)
    # ... and then a new path from there to C
    np.testing.assert_array_equal(result.path[-1], c)
    assert replan["status"] == "solved"
    again = p.replan(artifact, current, c)
    np.testing.assert_array_equal(again.path[0], current)
    assert polyline_length(again.path) == pytest.approx(replan["new_length_m"], rel=1e-12)
    assert polyline_length(result.path) == pytest.approx(arc[-1] / 2 + replan["new_length_m"], rel=1e-9)
    assert_collision_free(result.path)


def write_pipeline(tmp_path, extra="", points=POINTS_MM, report_dir=None):
    (tmp_path / "small.yaml").write_text(scene_yaml(points))
    out = tmp_path / "out"
    settings = (
        "{grid_spacing: 4, surface_spacing: 2, neighbours: 12, seed: 3, "
        f"report: {{dir: {report_dir or out / 'table1'}, segment_points: [2, 3]}}, "
        "replan: {goal: c, at: 0.5}}"
    )
    config = tmp_path / "pipeline.yaml"
    config.write_text(
        "name: small-offline-online\nlength_unit: mm\nscene: small.yaml\npipeline:\n"
        "  - {stage: plan, name: repository, plugin: optmis, space: {kind: r3, tip_radius: 0.2},\n"
        "     settings: {grid_spacing: 4, surface_spacing: 2, neighbours: 12, seed: 3},\n"
        f"     start: a, goal: h, artifact: {out}/repository.npz}}\n"
        "  - {stage: plan, name: pathmap, plugin: segmented_astar, space: {kind: r3, tip_radius: 0.2},\n"
        f"     settings: {settings},\n"
        f"     start: a, goal: d, artifact: {out}/pathmap.npz}}\n"
        f"{extra}"
        f"output: {{dir: {out}}}\n"
    )
    return config, out


@pytest.mark.slow
def test_offline_and_online_pipelines_from_the_command_line(tmp_path, cli):
    config, out = write_pipeline(tmp_path)
    code, _, err = cli("run", config, "--quiet")
    assert code == 0, err
    result = json.loads((out / "result.json").read_text())
    repository, pathmap = result["stages"]
    assert repository["status"] == pathmap["status"] == "solved"
    assert repository["metrics"]["unreachable_pairs"] == 8 and repository["metrics"]["paths"] == 28
    assert pathmap["metrics"]["replan"]["status"] == "solved"
    assert (out / "table1" / "table1.csv").is_file() and (out / "table1" / "table1.png").is_file()
    # the segmented_astar stage reused the optmis stage's all-pairs work
    work = list((out / ".work").glob("optmis-*"))
    from surgiplan.plugins.planners.optmis.repository import source_groups

    assert len(work) == 1 and len(list((work[0] / "paths").glob("*.npz"))) == len(source_groups(9, 4))
    # a second run loads both artifacts instead of building
    code, _, err = cli("run", config, "--quiet")
    assert code == 0, err
    again = json.loads((out / "result.json").read_text())
    assert [s["metrics"]["artifact"] for s in again["stages"]] == ["loaded", "loaded"]
    assert again["stages"][1]["path"] == pathmap["path"]


def test_point_of_interest_inside_an_obstacle_fails_cleanly_from_the_command_line(tmp_path, cli):
    config, out = write_pipeline(tmp_path, points={**POINTS_MM, "buried": (20, 10, 5)})
    code, _, err = cli("run", config, "--quiet")
    assert code == 2
    assert "point of interest 'buried' (20, 10, 5) mm is not free for the instrument tip" in err
    assert "Traceback" not in err
    assert_error_record(out, "point of interest 'buried' (20, 10, 5) mm is not free")
    assert not (out / "repository.npz").exists()


def test_report_directory_that_cannot_be_written_fails_before_any_work(tmp_path, cli):
    (tmp_path / "a-file").write_text("not a directory")
    config, out = write_pipeline(tmp_path, report_dir=tmp_path / "a-file" / "table1")
    # only the pathmap stage, so that nothing runs before the check
    text = config.read_text()
    start = text.index("  - {stage: plan, name: repository")
    config.write_text(text[:start] + text[text.index("  - {stage: plan, name: pathmap") :])
    code, _, err = cli("run", config, "--quiet")
    assert code == 2, err
    assert "settings.report.dir: cannot write to directory" in err and "a-file/table1" in err
    assert "Traceback" not in err
    assert_error_record(out, "cannot write to directory")
    assert not list(out.glob(".work/optmis-*"))


def test_a_thinned_pathmap_answers_queries_and_thinning_beyond_w_tip_is_refused():
    from surgiplan.errors import PlanningInputError
    from surgiplan.plugins.planners.segmented_astar.pathmap import build_pathmap
    from test_optmis_support import problem

    p = planner(thinning=0.1 * MM)
    space = pathmap_artifact().space
    artifact = SegmentedAStar._artifact(build_pathmap(offline().repository, space, n_s=3, thinning=0.1 * MM), space, [])
    stored = SegmentedAStar.load_artifact(p, p.save_artifact(artifact), problem())
    assert stored.pathmap.thinning == pytest.approx(0.1 * MM)
    pois = artifact.pathmap.pois
    for i, j in reachable_pairs()[::4]:
        result = p.query(stored, pois[i], pois[j])
        assert result.solved
        assert_collision_free(result.path)
    with pytest.raises(PlanningInputError, match="thinning") as caught:
        planner(thinning=1 * MM).build(problem())
    assert caught.value.location == "settings.thinning"
