"""The compiled kernels: the same answers as the numpy and scipy code they replace, compiled before use.

* the scene's distances for primitives (``surgiplan.geometry.compiled``) against the vectorised groups;
* safe_prm's K-S grid against scipy's KD-tree, in three and four coordinates, for points outside the grid too;
* no build or query compiles anything: every kernel is compiled when its module is imported (checked in a
  fresh process, where numba's dispatchers show what they hold).
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from surgiplan.geometry.shapes import Box, Capsule, Cylinder, Sphere
from surgiplan.geometry.transforms import Pose
from surgiplan.scene import Scene


def primitive_scene(seed: int) -> Scene:
    rng = np.random.default_rng(seed)
    obstacles = []
    for i in range(12):
        pose = Pose.from_xyz_rpy(rng.uniform(0, 0.1, 3), rng.uniform(-3, 3, 3))
        kind = i % 4
        if kind == 0:
            obstacles.append(Box(f"b{i}", pose, size=tuple(rng.uniform(0.005, 0.03, 3))))
        elif kind == 1:
            obstacles.append(Sphere(f"s{i}", pose, radius=float(rng.uniform(0.003, 0.02))))
        elif kind == 2:
            r, length = float(rng.uniform(0.003, 0.02)), float(rng.uniform(0.01, 0.05))
            obstacles.append(Cylinder(f"c{i}", pose, radius=r, length=length))
        else:
            r, length = float(rng.uniform(0.003, 0.02)), float(rng.uniform(0.01, 0.05))
            obstacles.append(Capsule(f"p{i}", pose, radius=r, length=length))
    return Scene([0, 0, 0], [0.1, 0.1, 0.1], obstacles)


@pytest.mark.parametrize("cutoff", [np.inf, 0.004])
def test_compiled_scene_distances_equal_the_vectorised_groups(cutoff):
    """Points and segments near and inside rotated boxes, spheres, cylinders and capsules: below the cutoff the
    same exact distance and nearest obstacle; above it, both at least the cutoff."""
    scene = primitive_scene(0)
    rng = np.random.default_rng(1)
    a = rng.uniform(-0.01, 0.11, (3000, 3))
    b = a + rng.normal(0, 0.01, (3000, 3))
    scene._prepare()
    packed = scene._packed
    assert packed is not None  # primitives only: the compiled path
    compiled = scene.signed_distance(a, cutoff), scene.segment_distance(a, b, cutoff)
    scene._packed = None  # the vectorised groups
    try:
        numpy = scene.signed_distance(a, cutoff), scene.segment_distance(a, b, cutoff)
    finally:
        scene._packed = packed
    for (d1, i1), (d0, i0), tolerance in zip(compiled, numpy, (1e-15, 2e-10), strict=True):
        exact = d0 < cutoff
        assert exact.sum() > 500 and (d0 < 0).sum() > 50  # near, and inside, obstacles
        np.testing.assert_allclose(d1[exact], d0[exact], rtol=0, atol=tolerance)  # cylinders: golden section
        assert np.array_equal(i1[exact], i0[exact])
        assert np.all(d1[~exact] >= cutoff) and np.all(d0[~exact] >= cutoff)


@pytest.mark.parametrize("dimension, threads", [(3, 1), (4, 1), (3, 2), (4, 3)])
def test_k_s_grid_finds_the_kd_trees_neighbours(dimension, threads):
    """At most k nearest within s, for the milestones themselves (pairs, on one thread or slabs on several) and
    for any points (links)."""
    from scipy.spatial import cKDTree
    from surgiplan.plugins.planners.safe_prm.kernels import k_s_neighbours, k_s_pairs
    from surgiplan.plugins.planners.safe_prm.roadmap import Grid

    rng = np.random.default_rng(dimension)
    points = rng.uniform(0, 1, (1500, dimension)) * rng.uniform(0.5, 2.0, dimension)
    points[:200] *= 0.2  # a dense corner: uneven cells
    k, s = 12, 0.25
    grid, order = Grid.sorting(points, s)
    np.testing.assert_array_equal(grid.points, points[order])  # the points numbered in the grid's order
    points = grid.points
    tree = cKDTree(points)
    pairs, lengths = k_s_pairs(grid.points, grid.origin, grid.dims, grid.cell, grid.first, k, s, threads)
    distance, index = tree.query(points, k=k + 1, distance_upper_bound=s)
    expected = {
        (min(i, int(j)), max(i, int(j)))
        for i in range(len(points))
        for d, j in zip(distance[i], index[i], strict=True)
        if np.isfinite(d) and j != i
    }
    assert [tuple(p) for p in pairs.tolist()] == sorted(expected)
    np.testing.assert_allclose(lengths, np.linalg.norm(points[pairs[:, 1]] - points[pairs[:, 0]], axis=1), rtol=1e-12)
    queries = rng.uniform(-0.5, 2.5, (300, dimension))  # inside the grid and far outside it
    found, found_distance, counts = k_s_neighbours(
        queries, grid.points, grid.origin, grid.dims, grid.cell, grid.first, k, s
    )
    distance, index = tree.query(queries, k=k, distance_upper_bound=s)
    for row in range(len(queries)):
        keep = np.isfinite(distance[row])
        assert counts[row] == keep.sum()
        assert found[row, : counts[row]].tolist() == index[row][keep].tolist()  # nearest first
        np.testing.assert_allclose(found_distance[row, : counts[row]], distance[row][keep], rtol=1e-12)


def test_builds_and_queries_compile_nothing():
    """In a fresh process: after the imports, a safe_prm build and query (R3 and the gimbal space), a
    segmented_astar query's search and a scene's distances add no compiled specialisation to any kernel (they
    were all compiled, or loaded from numba's cache, when their modules were imported)."""
    script = textwrap.dedent(
        """
        import json
        import numpy as np
        from numba.core.registry import CPUDispatcher
        from surgiplan import PlanningProblem, load_scene
        from surgiplan.geometry import compiled
        from surgiplan.plugins.planners.safe_prm import astar, kernels, landmarks, query, query_fused, query_kernel
        from surgiplan.plugins.planners.safe_prm.planner import SafePRM, SafePRMSettings
        from surgiplan.plugins.planners.segmented_astar import astar as pathmap_astar
        from surgiplan.spaces import CastGimbalSettings, CastGimbalSpace, R3Space

        modules = (compiled, astar, kernels, landmarks, query_fused, query_kernel, pathmap_astar)
        def counts():
            return {f"{m.__name__}.{name}": len(f.signatures) for m in modules for name, f in vars(m).items()
                    if isinstance(f, CPUDispatcher)}
        scene = load_scene("configs/scenes/block_world.yaml")
        scene.signed_distance(np.zeros((1, 3)))  # the scene prepares (imports its kernels) on its first query
        before = counts()
        for space in (R3Space(scene), CastGimbalSpace(scene, CastGimbalSettings.model_validate(
                {"fulcrum": {"xyz": [0.075, -0.06, 0.12], "rpy": [0, 0, 1.5707963]}}))):
            planner = SafePRM(SafePRMSettings(proficiency="intermediate", milestones=600, seed=1,
                                              smoothing={"enabled": False}))
            artifact = planner.build(PlanningProblem(scene, space))
            start = space.configuration(scene.points["entry"])
            goal = space.configuration(np.array([0.095, 0.03, 0.02]))
            planner.query(artifact, start, goal)
        print(json.dumps({"before": before, "after": counts()}))
        """
    )
    from conftest import ROOT

    done = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=600, check=True
    )
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["before"] == result["after"]
    called_from_python = [
        "surgiplan.geometry.compiled.nearest",
        "surgiplan.plugins.planners.safe_prm.astar.search",
        "surgiplan.plugins.planners.safe_prm.kernels.grid_build",
        "surgiplan.plugins.planners.safe_prm.kernels.neighbour_rows",
        "surgiplan.plugins.planners.safe_prm.kernels.unique_pairs",
        "surgiplan.plugins.planners.safe_prm.kernels.k_s_neighbours",
        "surgiplan.plugins.planners.safe_prm.kernels.cover_pairs",
        "surgiplan.plugins.planners.safe_prm.kernels.cover_by_midpoint",
        "surgiplan.plugins.planners.safe_prm.kernels.csr_rows",
        "surgiplan.plugins.planners.safe_prm.kernels.component_labels",
        "surgiplan.plugins.planners.safe_prm.landmarks._landmark_distances",
        "surgiplan.plugins.planners.safe_prm.query_fused.link_search_repair",
        "surgiplan.plugins.planners.safe_prm.query_kernel.link_ends",
        "surgiplan.plugins.planners.safe_prm.query_kernel.search_and_repair",
        "surgiplan.plugins.planners.segmented_astar.astar.astar_junctions",
    ]
    assert all(result["before"][name] >= 1 for name in called_from_python), result["before"]


def test_a_large_batch_of_distances_in_halves_on_two_threads_is_the_batch_on_one(block_world, monkeypatch):
    """compiled.distances splits a batch of SPLIT_AT or more between the process's threads: the same distances
    and nearest obstacles, to the bit, as one thread's, for points and for segments."""
    from surgiplan.geometry import compiled

    rng = np.random.default_rng(7)
    lo, hi = np.asarray(block_world.bounds_min), np.asarray(block_world.bounds_max)
    a = rng.uniform(lo, hi, (compiled.SPLIT_AT * 3 + 17, 3))
    b = rng.uniform(lo, hi, a.shape)
    block_world.signed_distance(a[:2])
    block_world.prepare()
    packed = block_world._packed
    answers = {}
    for threads in (1, 2):
        monkeypatch.setattr(compiled, "cpu_threads", lambda threads=threads: threads)
        answers[threads] = compiled.distances(packed, a, None, np.inf), compiled.distances(packed, a, b, 0.01)
    for one, two in zip(answers[1], answers[2], strict=True):
        np.testing.assert_array_equal(one[0], two[0])
        np.testing.assert_array_equal(one[1], two[1])
    assert np.any(answers[1][0][0] < 0) and np.any(answers[1][1][0] >= 0.01)  # inside obstacles, and cut off


def test_in_parallel_returns_every_result_in_order_and_raises_a_calls_error():
    from surgiplan.threads import in_parallel

    assert in_parallel([(pow, (2, k)) for k in range(5)]) == [1, 2, 4, 8, 16]
    assert in_parallel([]) == []

    def fail(message):
        raise ValueError(message)

    with pytest.raises(ValueError, match="second"):
        in_parallel([(pow, (2, 3)), (fail, ("second",)), (pow, (3, 2))])


def test_a_real_time_caller_or_a_budget_of_one_runs_every_call_itself(monkeypatch):
    """The pool's threads run at ordinary priority: a SCHED_FIFO caller waiting on them would wait on whatever
    preempts them, so it runs its calls itself, as under ``thread_budget(1)``; the results are the same."""
    import os
    import threading

    from surgiplan import threads

    def where(k):
        return threading.get_ident(), k * k

    calls = [(where, (k,)) for k in range(3)]
    me = threading.get_ident()
    monkeypatch.setattr(threads.os, "sched_getaffinity", lambda pid: {0, 1})
    spread = threads.in_parallel(calls)
    assert [k for _, k in spread] == [0, 1, 4] and {ident for ident, _ in spread[:-1]}.isdisjoint({me})
    with threads.thread_budget(1) as budget:
        assert budget == 1 and threads.cpu_threads() == 1
        assert threads.in_parallel(calls) == [(me, 0), (me, 1), (me, 4)]
    assert threads.cpu_threads() == 2  # the budget ends with its block
    with threads.thread_budget(None) as budget:
        assert budget == 2
    monkeypatch.setattr(threads.os, "sched_getscheduler", lambda pid: os.SCHED_FIFO)
    assert threads.cpu_threads() == 1
    assert threads.in_parallel(calls) == [(me, 0), (me, 1), (me, 4)]
    with threads.thread_budget(2):
        assert threads.cpu_threads() == 1  # a budget does not override the policy


def test_a_thread_really_under_sched_fifo_runs_its_calls_itself():
    """The same on a thread that the kernel runs under SCHED_FIFO (where this host lets a test set it)."""
    import os
    import threading

    from surgiplan import threads

    seen: dict = {}

    def body():
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        except PermissionError:
            seen["refused"] = True
            return
        try:
            me = threading.get_ident()
            seen["idents"] = {ident for ident in threads.in_parallel([(threading.get_ident, ())] * 3)}
            seen["me"] = me
        finally:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))

    worker = threading.Thread(target=body)
    worker.start()
    worker.join(30)
    if seen.get("refused"):
        pytest.skip("this host does not let a test set SCHED_FIFO")
    assert seen["idents"] == {seen["me"]}


def test_a_child_forked_after_the_pool_started_runs_in_parallel_too():
    """fork copies only the calling thread: a child must not hand work to the parent's pool, whose threads it has
    not got (the crash walk forks a child per run after a build used the pool; it waited forever)."""
    import multiprocessing

    from surgiplan.threads import in_parallel

    assert in_parallel([(pow, (2, 3)), (pow, (3, 2))]) == [8, 9]  # the pool exists in this process now
    context = multiprocessing.get_context("fork")
    with context.Pool(1) as pool:
        result = pool.apply_async(in_parallel, ([(pow, (2, 5)), (pow, (5, 2))],))
        assert result.get(timeout=60) == [32, 25]
