"""optmis: the search space, the all-pairs repository, smoothing, resumption, executors, bad input.

Clearances are re-measured with coal (tests/helpers.py), shortest lengths
against closed forms, and resumption by counting the tasks that run.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import coal_scene_point_distance, coal_scene_segment_distance
from surgiplan import InlineExecutor, LocalExecutor, PlanningProblem
from surgiplan.errors import PlanningInputError
from surgiplan.paths.splines import CHORD, GLOBAL, smooth_paths
from surgiplan.plugins.planners.optmis import repository as optmis_repository
from surgiplan.plugins.planners.optmis import search_space as optmis_graph
from surgiplan.plugins.planners.optmis.offline import OptMISSettings, run_offline
from surgiplan.plugins.planners.optmis.planner import OptMIS
from surgiplan.scene import Scene
from surgiplan.spaces import R3Space
from test_optmis_support import MM, SETTINGS, TIP_RADIUS, box, offline, polyline_length, problem, small_world, space


def optmis_planner():
    """The optmis planner and its artifact for the small world (the cached offline build)."""
    from surgiplan.plugins.planners.optmis.planner import OptMISArtifact

    result = offline()
    return OptMIS(OptMISSettings(**SETTINGS)), OptMISArtifact(result.graph, result.repository, space())


def test_search_space_vertices_and_edges_are_free_for_the_tip_by_coal():
    graph = offline().graph
    scene = small_world()
    rng = np.random.default_rng(0)
    some = rng.choice(graph.n, 400, replace=False)
    clearance = coal_scene_point_distance(scene, graph.vertices[some]) - TIP_RADIUS
    np.testing.assert_allclose(graph.clearance[some], clearance, atol=1e-9)
    assert np.all(clearance > 0)
    edges = graph.edges[rng.choice(len(graph.edges), 1500, replace=False)]
    swept = coal_scene_segment_distance(scene, graph.vertices[edges[:, 0]], graph.vertices[edges[:, 1]], TIP_RADIUS)
    assert swept.min() > 0
    # the points of interest are vertices, exactly
    np.testing.assert_array_equal(graph.vertices[graph.poi_vertex], offline().repository.pois)


def test_search_space_is_denser_where_space_is_tight():
    graph = offline().graph
    near = graph.clearance < SETTINGS["grid_spacing"]
    # vertex density (per mm^3) close to obstacles against far from them, both measured on the vertices
    tree_d, _ = graph.tree.query(graph.vertices, k=2)
    spacing_near = np.median(tree_d[near, 1])
    spacing_far = np.median(tree_d[~near, 1])
    assert spacing_near < 0.75 * spacing_far


def test_every_stored_path_is_collision_free_for_the_tip_by_coal():
    repository = offline().repository
    scene = small_world()
    for k in range(repository.n_paths):
        path = repository.path(k)
        i, j = repository.pairs[k]
        np.testing.assert_array_equal(path[0], repository.pois[i])
        np.testing.assert_array_equal(path[-1], repository.pois[j])
        assert np.all(scene.in_bounds(path))
        assert coal_scene_segment_distance(scene, path[:-1], path[1:], TIP_RADIUS).min() > 0
        assert np.linalg.norm(np.diff(path, axis=0), axis=1).max() <= 2 * MM + 1e-12  # the stored resolution


def test_unreachable_pairs_are_reported_not_dropped():
    repository = offline().repository
    names = repository.names
    cup = names.index("cup")
    listed = {tuple(sorted((names[i], names[j]))) for i, j in repository.unreachable}
    assert listed == {tuple(sorted((n, "cup"))) for n in names if n != "cup"}
    stored = {tuple(sorted((names[i], names[j]))) for i, j in repository.pairs}
    assert len(stored) + len(listed) == math.comb(len(names), 2)
    assert repository.summary()["unreachable_pairs"] == len(names) - 1
    planner, artifact = optmis_planner()
    result = planner.query(artifact, repository.pois[0], repository.pois[cup])
    assert result.status.value == "no_path"
    assert "'a' and 'cup' are not connected" in result.message


def test_line_of_sight_pairs_get_the_straight_line():
    repository = offline().repository
    s = space()
    a, b = repository.pois[repository.pairs[:, 0]], repository.pois[repository.pairs[:, 1]]
    visible = s.motion_is_clear(a, b)
    assert visible.sum() >= 5
    straight = np.linalg.norm(b - a, axis=1)
    np.testing.assert_allclose(repository.length[visible], straight[visible], rtol=1e-9)


def _around_a_corner(a, b, corner, radius):
    """Shortest 2-D path from a to b wrapping round a disc of ``radius`` at ``corner`` (tangent, arc, tangent).

    The path goes round the far side of the disc, so the arc spans the reflex
    angle less the two tangent angles.
    """
    da, db = np.linalg.norm(a - corner), np.linalg.norm(b - corner)
    angle = math.acos(np.dot(a - corner, b - corner) / (da * db))
    arc = 2 * math.pi - angle - math.acos(radius / da) - math.acos(radius / db)
    assert arc > 0
    return math.sqrt(da**2 - radius**2) + math.sqrt(db**2 - radius**2) + radius * arc


def test_path_around_a_wall_is_within_half_a_percent_of_the_closed_form_shortest_path():
    # a wall as tall as the workspace: the only way is round its end, bending at one vertical edge
    scene = Scene(
        np.zeros(3),
        np.array([40, 40, 10]) * MM,
        [box("wall", (18, 0, 0), (22, 30, 10))],
        {"west": np.array([8, 12, 5]) * MM, "east": np.array([33, 20, 5]) * MM},
    )
    s = R3Space(scene, TIP_RADIUS)
    result = run_offline(PlanningProblem(scene, s), OptMISSettings(**SETTINGS))
    path = result.repository.between(0, 1)
    west_corner, east_corner = np.array([18, 30]) * MM, np.array([22, 30]) * MM
    # unfold: west -> around the west corner -> along the wall's end -> around the east corner -> east
    a, b = scene.points["west"][:2], scene.points["east"][:2]
    # the optimum touches both rounded corners (radius = tip radius): tangent lines and arcs
    via = np.array([20, 30 + 0.2]) * MM
    shortest = _around_a_corner(a, via, west_corner, TIP_RADIUS) + _around_a_corner(via, b, east_corner, TIP_RADIUS)
    length = polyline_length(path)
    assert length >= shortest * (1 - 1e-6)
    assert length <= shortest * 1.005, (length, shortest)
    assert coal_scene_segment_distance(scene, path[:-1], path[1:], TIP_RADIUS).min() > 0


def test_spline_that_would_touch_an_obstacle_falls_back_and_stays_clear():
    # a path 0.05 mm off a face that turns away from it: the natural spline dips into the face before the turn
    scene = Scene(np.array([-5, -5, -5]) * MM, np.array([30, 20, 5]) * MM, [box("slab", (-5, -5, -5), (30, 0, 5))])
    s = R3Space(scene, TIP_RADIUS)
    y = TIP_RADIUS + 0.05 * MM
    knots = np.array([[0, y, 0], [6 * MM, y, 0], [12 * MM, y, 0], [14 * MM, 10 * MM, 0], [16 * MM, 18 * MM, 0]])
    assert np.all(s.motion_is_clear(knots[:-1], knots[1:]))
    spline = np.array([0.0])
    from scipy.interpolate import CubicSpline

    t = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(knots, axis=0), axis=1))])
    spline = CubicSpline(t, knots, bc_type="natural")(np.linspace(0, t[-1], 400))
    assert coal_scene_point_distance(scene, spline).min() - TIP_RADIUS < 0  # the plain spline collides
    (smoothed,) = smooth_paths(s, [knots], resolution=1 * MM)
    assert np.any(smoothed.kinds != GLOBAL) and np.any(smoothed.kinds == CHORD)
    np.testing.assert_array_equal(smoothed.points[smoothed.knot_index], knots)
    swept = coal_scene_segment_distance(scene, smoothed.points[:-1], smoothed.points[1:], TIP_RADIUS)
    assert swept.min() > 0


def test_smoothing_rounds_turns_but_keeps_paths_nearly_as_short_as_the_taut_path():
    repository = offline().repository
    ratio = repository.length / repository.taut_length
    assert ratio.min() >= 1 - 1e-9  # a curve through the knots is never shorter than their polyline
    assert ratio.mean() < 1.01
    # tautening removed the search space's zig-zag
    assert np.mean(repository.graph_length / repository.taut_length) > 1.01


class Interrupt(BaseException):
    """Stands for Ctrl-C half-way through the all-pairs build."""


class InterruptingExecutor(InlineExecutor):
    def __init__(self, after: int) -> None:
        self.after = after

    def imap_unordered(self, fn, items):
        for count, result in enumerate(super().imap_unordered(fn, items)):
            if count == self.after:
                raise Interrupt
            yield result


def test_interrupted_build_resumes_without_recomputing_finished_sources(tmp_path, monkeypatch):
    computed: list[tuple[int, ...]] = []
    real_task = optmis_repository.sources_task

    def counting_task(item):
        computed.append(tuple(item["source_pois"]))
        return real_task(item)

    graph_builds = []
    real_build = optmis_repository.build_search_graph
    monkeypatch.setattr(optmis_repository, "sources_task", counting_task)
    monkeypatch.setattr(
        optmis_repository, "build_search_graph", lambda *a, **k: graph_builds.append(1) or real_build(*a, **k)
    )
    # one source per task, so that there are eight tasks to interrupt
    monkeypatch.setattr(optmis_repository, "source_groups", lambda n, group: [[i] for i in range(n - 1)])
    settings = OptMISSettings(**SETTINGS)
    workdir = tmp_path / "out" / ".work" / "stage"
    with pytest.raises(Interrupt):
        run_offline(problem(workdir, InterruptingExecutor(after=3)), settings)
    # three results were delivered and stored; Ctrl-C came while the fourth was being handed over
    finished = computed[:3]
    assert len(computed) == 4
    computed.clear()
    resumed = run_offline(problem(workdir), settings)
    tasks = len(resumed.repository.names) - 1
    assert len(computed) == tasks - 3 and not set(computed) & set(finished)
    assert len(graph_builds) == 1  # the search space was stored once and loaded on resumption
    assert resumed.repository.stats["resumed_tasks"] == 3
    # the same repository as an uninterrupted build
    fresh = offline().repository
    for name in ("pairs", "path_start", "points", "unreachable", "length"):
        np.testing.assert_array_equal(getattr(resumed.repository, name), getattr(fresh, name))
    # a third run computes nothing at all
    computed.clear()
    run_offline(problem(workdir), settings)
    assert computed == []


def test_sources_are_grouped_by_equal_work():
    groups = optmis_repository.source_groups(80, 4)
    assert [s for g in groups for s in g] == list(range(79))
    assert max(len(g) for g in groups) <= 4
    work = [sum(79 - s for s in g) for g in groups]  # paths per task
    assert sum(work) == 80 * 79 // 2
    # no task much heavier than an equal share of 20 tasks (the first sources have the most paths)
    assert max(work) <= sum(work) / 20 + 79


def test_process_pool_builds_the_same_repository_as_inline():
    s = space()
    graph = offline().graph
    fresh = offline().repository
    with LocalExecutor(workers=2) as executor:
        pooled = optmis_repository.build_repository(
            s, graph, fresh.names, fresh.pois, OptMISSettings(**SETTINGS).path_options(), executor=executor
        )
    for name in ("pairs", "path_start", "points", "corner", "unreachable", "length"):
        np.testing.assert_array_equal(getattr(pooled, name), getattr(fresh, name))


@pytest.mark.slow
@pytest.mark.dask
def test_dask_executor_builds_the_same_repository_as_the_local_one():
    distributed = pytest.importorskip("distributed")
    from surgiplan import DaskExecutor

    s = space()
    graph = offline().graph
    fresh = offline().repository
    options = OptMISSettings(**SETTINGS).path_options()
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with DaskExecutor(cluster.scheduler_address) as executor:
            remote = optmis_repository.build_repository(s, graph, fresh.names, fresh.pois, options, executor=executor)
    assert remote.stats["executor"].startswith("dask")
    for name in ("pairs", "path_start", "points", "corner", "unreachable", "length"):
        np.testing.assert_array_equal(getattr(remote, name), getattr(fresh, name))


def test_query_between_arbitrary_points_searches_the_space_and_stays_clear():
    planner, artifact = optmis_planner()
    start, goal = np.array([3, 3, 3]) * MM, np.array([34, 22, 8]) * MM
    result = planner.query(artifact, start, goal)
    assert result.solved and result.metrics["source"] == "search"
    np.testing.assert_array_equal(result.path[0], start)
    np.testing.assert_array_equal(result.path[-1], goal)
    scene = small_world()
    assert coal_scene_segment_distance(scene, result.path[:-1], result.path[1:], TIP_RADIUS).min() > 0
    # a stored pair comes straight from the repository
    repository = artifact.repository
    stored = planner.query(artifact, repository.pois[0], repository.pois[3])
    assert stored.metrics["source"] == "repository"
    np.testing.assert_array_equal(stored.path, repository.between(0, 3))
    backwards = planner.query(artifact, repository.pois[3], repository.pois[0])
    np.testing.assert_array_equal(backwards.path, stored.path[::-1])


def test_artifact_round_trip_answers_the_same():
    planner, artifact = optmis_planner()
    p = problem()
    from surgiplan.storage import to_jsonable

    data = planner.save_artifact(artifact)
    arrays = {k: v for k, v in data.items() if isinstance(v, np.ndarray)}
    values = to_jsonable({k: v for k, v in data.items() if not isinstance(v, np.ndarray)})
    loaded = planner.load_artifact({**values, **arrays}, p)
    pois = artifact.repository.pois
    np.testing.assert_array_equal(
        planner.query(loaded, pois[1], pois[6]).path, planner.query(artifact, pois[1], pois[6]).path
    )
    damaged = {**values, **arrays, "path_start": arrays["path_start"][:-3]}
    with pytest.raises(ValueError, match="path offsets"):
        planner.load_artifact(damaged, p)


def test_point_of_interest_inside_an_obstacle_is_named():
    points = {"ok": (5, 10, 5), "buried": (20, 10, 5), "outside": (5, 10, 45)}
    scene = small_world(points)
    with pytest.raises(PlanningInputError) as caught:
        optmis_graph.build_search_graph(
            space(scene),
            np.array(list(scene.points.values())),
            grid_spacing=4 * MM,
            surface_spacing=2 * MM,
            surface_gap=0.3 * MM,
            neighbours=8,
            names=list(scene.points),
        )
    message = str(caught.value)
    assert "'buried' (20, 10, 5) mm is not free for the instrument tip" in message
    assert "obstacle 'W1'" in message
    assert "'outside' (5, 10, 45) mm is outside the scene bounds" in message
    assert "'ok'" not in message


def test_unknown_point_names_and_other_spaces_are_clear_errors():
    with pytest.raises(PlanningInputError, match=r"no scene point named 'hh'; did you mean 'h'\?"):
        run_offline(problem(), OptMISSettings(points=["a", "hh"], **SETTINGS))
    from surgiplan.spaces import CastGimbalSpace

    scene = small_world()
    gimbal = CastGimbalSpace.from_settings(CastGimbalSpace.Settings(fulcrum={"xyz": [0.03, 0.02, 0.05]}), scene)
    with pytest.raises(PlanningInputError, match=r"optMIS plans for the instrument tip.*'cast_gimbal'"):
        run_offline(PlanningProblem(scene, gimbal), OptMISSettings(**SETTINGS))
    with pytest.raises(ValueError, match="at least two points of interest"):
        OptMISSettings(points=["a"])


def test_repository_figure_draws_every_path_and_counts_paths_per_cell(tmp_path):
    from surgiplan.plugins.planners.optmis.figures import paths_per_cell
    from surgiplan.plugins.planners.optmis.planner import OptMISPlanSettings

    _, artifact = optmis_planner()
    repository = artifact.repository
    figure = tmp_path / "figures" / "repository.png"
    planner = OptMIS(OptMISPlanSettings(**SETTINGS, figure=str(figure)))
    result = planner.query(artifact, repository.pois[0], repository.pois[3])
    assert result.solved and result.metrics["figure"] == str(figure)
    assert figure.read_bytes()[:4] == b"\x89PNG"
    # the density counts each path once per 1 mm cell it passes: a straight path along x through 10 cells
    points = np.array([[0.5, 0.5], [9.5, 0.5], [0.5, 2.5], [0.6, 2.6]])
    counts = paths_per_cell(points, np.array([0, 2, 4]), np.zeros(2), 1.0, (10, 4))
    assert counts[:, 0].tolist() == [1] * 10 and counts[0, 2] == 1 and counts.sum() == 11


def test_repository_figure_in_a_directory_that_cannot_be_written_fails_before_the_work(tmp_path):
    from surgiplan.errors import OutputError
    from surgiplan.plugins.planners.optmis.planner import OptMISPlanSettings

    (tmp_path / "a-file").write_text("not a directory")
    planner = OptMIS(OptMISPlanSettings(**SETTINGS, figure=str(tmp_path / "a-file" / "repository.png")))
    with pytest.raises(OutputError, match="cannot write to directory") as caught:
        planner.build(problem())
    assert caught.value.location == "settings.figure"
