"""The OMPL bridge: every planner through our interface, in every space, on our certified checks."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import coal_scene_segment_distance
from surgiplan import PlanningProblem
from surgiplan.geometry.shapes import Box
from surgiplan.geometry.transforms import Pose
from surgiplan.scene import Scene
from surgiplan.spaces import CastGimbalSettings, CastGimbalSpace, R3Space, SE3Settings, SE3Space

pytest.importorskip("ompl")
pytestmark = pytest.mark.ompl

from surgiplan.plugins.planners.ompl_bridge.bridge import OmplPlanner, OmplSettings  # noqa: E402


def plan(space, start, goal, **settings):
    planner = OmplPlanner(OmplSettings(**{"milestones": 300, "time_limit": 3.0, "seed": 1, **settings}))
    artifact = planner.build(PlanningProblem(space.scene, space))
    return planner.query(artifact, np.asarray(start, float), np.asarray(goal, float))


@pytest.mark.parametrize("name", ["PRM", "PRMstar", "RRTConnect", "RRTstar"])
def test_every_ompl_planner_finds_a_clear_path(block_world, name):
    space = R3Space(block_world, tip_radius=0.0005)
    # around block B1, from between the left and middle pairs to between the middle and right ones
    start, goal = np.array([0.055, 0.030, 0.020]), np.array([0.095, 0.030, 0.020])
    result = plan(space, start, goal, planner=name, margin=0.001, time_limit=3.0)
    assert result.solved, result.message
    path = result.path
    np.testing.assert_allclose(path[[0, -1]], [start, goal], atol=1e-12)
    clearance = coal_scene_segment_distance(block_world, path[:-1], path[1:], 0.0005)
    assert clearance.min() >= 0.001 - 1e-9, "the margin holds along every segment (re-measured with coal)"


def test_gimbal_space_keeps_the_whole_shaft_clear(block_world):
    space = CastGimbalSpace(
        block_world,
        CastGimbalSettings.model_validate(
            {"fulcrum": {"xyz": [0.075, -0.06, 0.12], "rpy": [0, 0, np.pi / 2]}, "shaft_radius": 0.001}
        ),
    )
    start = space.configuration(np.array([0.055, 0.030, 0.020]))
    goal = space.configuration(np.array([0.095, 0.030, 0.020]))
    result = plan(space, start, goal, planner="RRTConnect", time_limit=10.0)
    assert result.solved, result.message
    dense = space.densify(result.path, 2e-4)
    fulcrum = np.broadcast_to(space.fulcrum, (len(dense), 3))
    shaft = coal_scene_segment_distance(block_world, fulcrum, space.tip(dense), 0.001)
    assert shaft.min() > 0


def test_se3_body_plans_around_a_wall():
    wall = Box("wall", Pose.from_xyz_rpy([0.05, 0.05, 0.05]), size=(0.01, 0.06, 0.1))
    scene = Scene([0, 0, 0], [0.1, 0.1, 0.1], [wall])
    space = SE3Space(
        scene,
        SE3Settings.model_validate({"body": [{"capsule": {"a": [-0.01, 0, 0], "b": [0.01, 0, 0], "radius": 0.003}}]}),
    )
    start = space.configuration(np.array([0.02, 0.05, 0.05]))
    goal = space.configuration(np.array([0.08, 0.05, 0.05]))
    result = plan(space, start, goal, planner="RRTConnect")
    assert result.solved
    assert space.motion_is_clear(result.path[:-1], result.path[1:]).all()


def test_discrete_motion_checking_can_clip_and_is_reported():
    """OMPL's own checker samples states; a thin wall between samples goes unseen. We measure it."""
    wall = Box("foil", Pose.from_xyz_rpy([0.05, 0.05, 0.05]), size=(0.0004, 0.1, 0.1))
    scene = Scene([0, 0, 0], [0.1, 0.1, 0.1], [wall])
    space = R3Space(scene)
    start, goal = np.array([0.02, 0.05, 0.05]), np.array([0.08, 0.05, 0.05])
    clipped = plan(space, start, goal, planner="RRTConnect", motion_check="discrete", resolution=0.2)
    assert clipped.solved and clipped.metrics["clipped_segments"] >= 1
    certified = plan(space, start, goal, planner="RRTConnect", time_limit=1.0)
    assert not certified.solved  # the foil spans the box: there is no way through
    assert certified.status.value in ("timeout", "no_path")


def test_invalid_start_is_a_status(block_world):
    space = R3Space(block_world)
    result = plan(space, [0.040, 0.020, 0.020], block_world.points["target"], planner="RRTConnect")
    assert result.status.value == "invalid_start" and "clearance" in result.message
