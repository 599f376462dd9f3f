"""Device in the loop: paths executed on the simulated drives, measured independently.

Clearances are re-measured with coal (tests/helpers.py), tracking against the planned geometry,
bus load from the frames on the wire bit by bit; nothing is taken from the report on trust.
"""

from __future__ import annotations

import numpy as np
import pytest
from devices_support import (
    ARM_BASE,
    FULCRUM,
    GAP_TIPS,
    execute,
    gimbal_path,
    gimbal_space,
    reference_frame_bits,
)
from helpers import coal_scene_segment_distance
from scipy.spatial.transform import Rotation
from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice
from surgiplan.plugins.devices.gripper6 import Gripper6Device
from surgiplan.spaces import R3Space, SE3Settings, SE3Space

GIMBAL = {"fulcrum": FULCRUM}
ARM = {"base": ARM_BASE}
#: the jaws of configs/gripper_in_the_loop.yaml: a capsule reaching back 60 mm from the jaws' tip
JAWS_BODY = [{"name": "jaws", "capsule": {"a": [0, 0, 0], "b": [0, 0, -0.06], "radius": 0.004}}]


def polyline_distance(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance of each point to a polyline (numpy, exact)."""
    a, b = polyline[:-1], polyline[1:]
    d = b - a
    t = np.clip(np.einsum("pij,ij->pi", points[:, None] - a[None], d) / np.sum(d * d, axis=1), 0.0, 1.0)
    nearest = a[None] + t[..., None] * d[None]
    return np.min(np.linalg.norm(points[:, None] - nearest, axis=2), axis=1)


def bus_load_from_frames(truth, report) -> float:
    start = truth["trajectory_start"]
    end = start + report.metrics["duration_s"]
    bits = sum(reference_frame_bits(i, d) for t, i, d in truth["frames"] if start <= t <= end + 1e-12)
    return 100.0 * bits / (report.metrics["duration_s"] * 1e6)


def test_gimbal_executes_a_gimbal_space_path_within_tolerance_and_deterministically(block_world, tmp_path):
    space = gimbal_space(block_world)
    path = gimbal_path(space, GAP_TIPS)
    report, truth = execute(CastGimbalDevice, GIMBAL, path, space, block_world, tmp_path)
    m = report.metrics
    # the simulated clock makes a run reproducible to the bit
    again, _ = execute(CastGimbalDevice, GIMBAL, path, space, block_world, tmp_path)
    np.testing.assert_array_equal(again.executed_tip_path, report.executed_tip_path)
    assert again.metrics == m
    assert report.status == "completed", report.message
    assert report.faults == [] and m["faults"] == []
    # the hardware ends where the path ends (ground truth, within two encoder counts)
    assert np.all(np.abs(truth["positions"] - path[-1]) <= 2.0 / truth["counts_per_unit"])
    # tracking: every executed tip lies near the planned tip curve, and the report agrees
    planned_tips = space.tip(space.densify(path, 1e-4))
    deviation = polyline_distance(report.executed_tip_path, planned_tips)
    assert deviation.max() < 5e-5
    # the timed path rounds the waypoints' corners (reported), the servo adds its tracking error
    assert m["path_deviation_max_m"] < 5e-5
    assert deviation.max() <= m["tracking_error_max_m"] + m["path_deviation_max_m"] + 2e-6
    assert m["tracking_error_rms_m"] <= m["tracking_error_max_m"] < 5e-5
    assert set(m["joint_tracking_error_max"]) == {"yaw", "pitch", "insertion", "roll"}
    # executed clearance re-measured with coal: the tip sphere swept between samples, and the shaft
    tips = report.executed_tip_path
    radius = m["shaft_radius_m"]
    swept = coal_scene_segment_distance(block_world, tips[:-1], tips[1:], radius)
    assert m["executed_min_clearance_m"] == pytest.approx(swept.min(), abs=1e-9)
    fulcrum = np.broadcast_to(space.fulcrum, tips.shape)
    shaft = coal_scene_segment_distance(block_world, fulcrum, tips, radius)
    step = np.max(np.linalg.norm(np.diff(tips, axis=0), axis=1))
    assert shaft.min() - step <= m["executed_shaft_min_clearance_m"] <= shaft.min() + 1e-9
    assert m["executed_shaft_min_clearance_m"] > 0
    # cycles and bus load, from the frames on the wire
    assert m["cycles"] == pytest.approx(m["planned_duration_s"] / truth["period"], abs=20)
    assert m["bus_load_percent"] == pytest.approx(bus_load_from_frames(truth, report), rel=1e-9)
    # per second: 250 x (SYNC + 4 RPDO + 4 TPDO of 6 bytes) and 40 heartbeats (1 byte): between the
    # frames' unstuffed lengths and their worst-case stuffing
    unstuffed = 250 * (47 + 8 * (47 + 48)) + 40 * (47 + 8)
    worst = 250 * (55 + 8 * 115) + 40 * 65
    assert 100 * unstuffed / 1e6 < m["bus_load_percent"] < 100 * worst / 1e6
    assert m["bus_load_percent"] < m["bus_load_worst_case_percent"] < 100
    # the measured joint speeds: the trajectory uses the limits fully, the servo follows within a few %
    velocity = np.diff(truth["log"].measured, axis=0) / truth["period"]
    ratio = np.max(np.abs(velocity) / truth["model"].velocity_limit, axis=0)
    assert np.max(ratio) == pytest.approx(1.0, abs=0.05)
    assert m["max_joint_velocity_ratio"] <= 1.0 and m["max_joint_acceleration_ratio"] <= 1.0


def test_gimbal_executes_an_r3_tip_path_through_the_qp_inverse_kinematics(block_world, tmp_path):
    space = R3Space(block_world, tip_radius=0.001)
    tips = np.array(GAP_TIPS)
    report, _ = execute(CastGimbalDevice, GIMBAL, tips, space, block_world, tmp_path)
    m = report.metrics
    assert report.status == "completed", report.message
    # the QP solutions agree with the gimbal's closed form, and the tip follows the straight segments
    assert m["ik_max_residual_m"] < 1e-6
    assert m["ik_closed_form_deviation_m"] < 1e-6
    assert polyline_distance(report.executed_tip_path, tips).max() < 5e-5
    swept = coal_scene_segment_distance(block_world, report.executed_tip_path[:-1], report.executed_tip_path[1:], 0.001)
    assert m["executed_min_clearance_m"] == pytest.approx(swept.min(), abs=1e-9)
    assert m["tip_radius_m"] == 0.001


def test_device_approaches_the_path_start_from_where_it_stands(block_world, tmp_path):
    space = gimbal_space(block_world)
    path = gimbal_path(space, GAP_TIPS)
    initial = path[0] + np.array([0.0, 0.0, -0.01, 0.3])  # drawn back 10 mm and rolled: clear
    assert space.motion_is_clear(initial[None], path[:1])[0]
    settings = {**GIMBAL, "simulation": {"initial": initial.tolist()}}
    report, truth = execute(CastGimbalDevice, settings, path, space, block_world, tmp_path)
    assert report.status == "completed", report.message
    assert report.metrics["approach"] is True
    np.testing.assert_allclose(truth["log"].measured[0], initial, atol=1e-4)
    np.testing.assert_allclose(truth["positions"], path[-1], atol=1e-4)


# ----------------------------------------------------------------------------- refused before motion
def refused(report, truth, initial, match):
    assert report.status == "refused"
    assert report.metrics["refused"] is True and report.metrics["cycles"] == 0
    assert report.message.startswith("refused before any motion")
    assert match in report.message
    # ground truth: no axis moved (the holding position loop settles on the nearest encoder count)
    assert np.all(np.abs(truth["positions"] - initial) <= 2.0 / truth["counts_per_unit"])
    assert truth["log"] is None


@pytest.mark.parametrize(
    ("tip", "match"),
    [
        ([0.15, 0.05, -0.25], "out of the gimbal's reach"),  # 380 mm below the fulcrum: insertion <= 300 mm
        ([0.15, 0.05, 0.125], "out of the gimbal's reach"),  # 5 mm from the fulcrum: insertion >= 20 mm
    ],
)
def test_an_unreachable_tip_path_is_refused_before_any_motion(block_world, tmp_path, tip, match):
    space = R3Space(block_world.with_bounds([0, 0, -0.3], [0.15, 0.1, 0.2]))
    initial = [0.0, 0.6, 0.12, 0.0]
    settings = {**GIMBAL, "simulation": {"initial": initial}}
    report, truth = execute(CastGimbalDevice, settings, [GAP_TIPS[0], tip], space, block_world, tmp_path)
    refused(report, truth, initial, match)


def test_a_configuration_outside_the_joint_limits_is_refused(block_world, tmp_path):
    space = gimbal_space(block_world, yaw={"min": -1.4, "max": 1.4})  # the space is wider than the device
    path = gimbal_path(space, GAP_TIPS)
    path[1, 0] = 1.2  # yaw 69 deg: the URDF allows +-60 deg
    initial = [0.0, 0.6, 0.12, 0.0]
    settings = {**GIMBAL, "simulation": {"initial": initial}}
    report, truth = execute(CastGimbalDevice, settings, path, space, block_world, tmp_path)
    refused(report, truth, initial, "needs joint 'yaw' at 1.0")
    assert "outside its limits [-1.047, 1.047]" in report.message


def test_a_tip_leaving_the_workspace_bounds_is_refused(block_world, tmp_path):
    space = gimbal_space(block_world)
    path = gimbal_path(space, GAP_TIPS)
    path[1, 2] = 0.05  # insertion 50 mm: the tip 80 mm above the box's floor, above its 40 mm lid
    initial = [0.0, 0.6, 0.12, 0.0]
    settings = {**GIMBAL, "simulation": {"initial": initial}}
    report, truth = execute(CastGimbalDevice, settings, path, space, block_world, tmp_path)
    refused(report, truth, initial, "outside the workspace bounds")


def test_a_plan_with_another_fulcrum_than_the_device_is_refused(block_world, tmp_path):
    space = gimbal_space(block_world)
    path = gimbal_path(space, GAP_TIPS)
    moved = {"xyz": [0.14, 0.05, 0.13], "rpy": FULCRUM["rpy"]}
    initial = [0.0, 0.6, 0.12, 0.0]
    report, truth = execute(
        CastGimbalDevice, {"fulcrum": moved, "simulation": {"initial": initial}}, path, space, block_world, tmp_path
    )
    refused(report, truth, initial, "fulcrum")


def test_an_approach_through_an_obstacle_is_refused(block_world, tmp_path):
    space = gimbal_space(block_world)
    path = gimbal_path(space, GAP_TIPS)
    # from beside block B1 (between the B and C pairs): the straight joint move sweeps the tip through B1
    initial = gimbal_path(space, [[0.09, 0.01, 0.03]])[0]
    assert space.clearance(initial[None])[0] > 0
    assert not space.motion_is_clear(initial[None], path[:1])[0]
    settings = {**GIMBAL, "simulation": {"initial": initial.tolist()}}
    report, truth = execute(CastGimbalDevice, settings, path, space, block_world, tmp_path)
    refused(report, truth, initial, "not clear of the obstacles")


# ----------------------------------------------------------------------------- gripper6
def se3_space(scene) -> SE3Space:
    return SE3Space(scene.with_bounds([0, 0, 0], [0.15, 0.1, 0.1]), SE3Settings.model_validate({"body": JAWS_BODY}))


def jaws_down_path() -> np.ndarray:
    """Jaws pointing down 20 mm above the blocks, turning 90 deg about the vertical on the way."""
    xyz = np.array([[0.02, 0.05, 0.06], [0.075, 0.05, 0.07], [0.13, 0.05, 0.06]])
    quaternion = Rotation.from_euler("xyz", [[np.pi, 0, 0], [np.pi, 0, np.pi / 4], [np.pi, 0, np.pi / 2]]).as_quat()
    return np.concatenate([xyz, quaternion], axis=1)


def jaws_capsules(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The jaws capsule's end points in the world, from poses (numpy, independent of the space)."""
    back = Rotation.from_quat(poses[:, 3:]).apply([0.0, 0.0, -0.06])
    return poses[:, :3], poses[:, :3] + back


def test_gripper6_executes_an_se3_path(block_world, tmp_path):
    space = se3_space(block_world)
    path = jaws_down_path()
    report, truth = execute(Gripper6Device, ARM, path, space, block_world, tmp_path)
    m = report.metrics
    assert report.status == "completed", report.message
    assert m["ik_max_residual_m"] < 1e-6 and m["ik_max_rotation_residual_rad"] < 1e-5
    # the executed jaws poses (forward kinematics of what the drives reported) follow the planned ones
    poses = truth["model"].tip_poses(truth["log"].measured)
    assert polyline_distance(poses[:, :3], path[:, :3]).max() < 5e-5
    assert m["tracking_error_max_m"] < 5e-5
    # the jaws keep pointing down (z of the jaws along -z of the world) all the way
    approach = Rotation.from_quat(poses[:, 3:]).apply([0.0, 0.0, 1.0])
    assert np.max(np.degrees(np.arccos(np.clip(-approach[:, 2], -1, 1)))) < 0.05
    np.testing.assert_allclose(
        Rotation.from_quat(poses[-1, 3:]).as_matrix(), Rotation.from_quat(path[-1, 3:]).as_matrix(), atol=1e-4
    )
    # the jaws body's clearance re-measured with coal at the samples
    a, b = jaws_capsules(poses)
    coal_body = coal_scene_segment_distance(block_world, a, b, 0.004)
    step = np.max(np.linalg.norm(np.diff(poses[:, :3], axis=0), axis=1)) + 0.06 * np.max(
        Rotation.from_quat(poses[:-1, 3:]).inv().__mul__(Rotation.from_quat(poses[1:, 3:])).magnitude()
    )
    assert coal_body.min() - step <= m["executed_body_min_clearance_m"] <= coal_body.min() + 1e-9
    tip_swept = coal_scene_segment_distance(block_world, poses[:-1, :3], poses[1:, :3], 0.0)
    assert m["executed_min_clearance_m"] == pytest.approx(tip_swept.min(), abs=1e-9)


def test_gripper6_takes_a_planner_frame_through_tool_frame(block_world, tmp_path):
    """A planner (e.g. retraction) whose grasp frame is 15 mm beyond the jaws and turned 90 deg."""
    space = se3_space(block_world)
    tool = {"xyz": [0.0, 0.0, 0.015], "rpy": [0.0, 0.0, np.pi / 2]}
    jaws_path = jaws_down_path()[:2]  # the first stretch: a 45 deg turn on the way
    offset = Rotation.from_euler("xyz", tool["rpy"])
    planned = np.concatenate(
        [
            jaws_path[:, :3] + Rotation.from_quat(jaws_path[:, 3:]).apply(tool["xyz"]),
            (Rotation.from_quat(jaws_path[:, 3:]) * offset).as_quat(),
        ],
        axis=1,
    )
    settings = {**ARM, "tool_frame": tool}
    report, truth = execute(Gripper6Device, settings, planned, space, block_world, tmp_path)
    assert report.status == "completed", report.message
    # the jaws went where the planned frame says they must be
    poses = truth["model"].tip_poses(truth["log"].measured)
    np.testing.assert_allclose(poses[-1, :3], jaws_path[-1, :3], atol=2e-5)
    assert polyline_distance(poses[:, :3], jaws_path[:, :3]).max() < 5e-5


def test_gripper6_executes_an_r3_path_with_the_jaws_pointing_down(block_world, tmp_path):
    scene = block_world.with_bounds([0, 0, 0], [0.15, 0.1, 0.1])
    space = R3Space(scene)
    path = np.array([[0.02, 0.05, 0.06], [0.13, 0.05, 0.06]])
    report, _ = execute(Gripper6Device, {**ARM, "link_radius": 0.015}, path, space, block_world, tmp_path)
    m = report.metrics
    assert report.status == "completed", report.message
    assert polyline_distance(report.executed_tip_path, path).max() < 5e-5
    # the tool sphere (4 mm) at the jaws, and the arm's links, clear of the blocks
    swept = coal_scene_segment_distance(block_world, report.executed_tip_path[:-1], report.executed_tip_path[1:], 0.004)
    assert m["executed_body_min_clearance_m"] == pytest.approx(swept.min(), abs=1e-9)
    assert m["arm_min_clearance_m"] > 0


def test_an_unreachable_pose_is_refused_before_any_motion(block_world, tmp_path):
    space = se3_space(block_world.with_bounds([0, 0, 0], [0.15, 0.1, 0.6]))
    path = jaws_down_path()
    path[1, :3] = [0.075, 0.05, 0.55]  # 0.55 m above the table: the arm reaches about 0.5 m
    initial = [0.3, 0.2, 0.9, 0.0, 0.5, 0.0]
    settings = {**ARM, "simulation": {"initial": initial}}
    report, truth = execute(Gripper6Device, settings, path, space, block_world, tmp_path)
    refused(report, truth, initial, "out of the arm's reach")


# ----------------------------------------------------------------------------- the pipeline
def test_gimbal_in_the_loop_pipeline_plans_with_safe_prm_and_reports_what_the_hardware_did(tmp_path, block_world):
    import json

    from conftest import CONFIGS
    from surgiplan import load_pipeline, run_pipeline

    out = tmp_path / "out"
    pipeline = load_pipeline(CONFIGS / "gimbal_in_the_loop.yaml", output_dir=out)
    pipeline.model.output.figures = pipeline.model.output.gltf = False  # the plan's figures are not tested here
    run_pipeline(pipeline)
    plan, stage = json.loads((out / "result.json").read_text())["stages"]
    assert (plan["plugin"], plan["status"], plan["space"]) == ("safe_prm", "solved", "cast_gimbal")
    assert (stage["plugin"], stage["status"]) == ("cast_gimbal", "completed")
    m = stage["metrics"]
    # the metric names, in SI
    assert m["tracking_error_max_m"] < 5e-5 and m["tracking_error_rms_m"] <= m["tracking_error_max_m"]
    assert (
        set(m["joint_tracking_error_max"])
        == set(m["joint_tracking_error_rms"])
        == {"yaw", "pitch", "insertion", "roll"}
    )
    assert 15 < m["bus_load_percent"] < 30 and m["cycles"] > 100 and m["faults"] == []
    # the executed tip path is the stage's path; its clearance re-measured with coal from result.json
    tips = np.array(stage["path"])
    assert tips.shape == (m["cycles"] - 1, 3)
    swept = coal_scene_segment_distance(block_world, tips[:-1], tips[1:], m["tip_radius_m"])
    assert m["executed_min_clearance_m"] == pytest.approx(swept.min(), abs=1e-9)
    assert m["executed_min_clearance_m"] > 0 and m["executed_shaft_min_clearance_m"] > 0
    # the executed path stays within tracking and corner rounding of the planned one
    assert np.linalg.norm(tips[-1] - np.array(plan["tip_path"])[-1]) < 5e-5
    # what a user looks at: the figure and the log
    # (and the bus traffic the config records: record: {can: blf})
    assert set(stage["files"]) == {"gimbal.png", "gimbal-execution.csv", "gimbal.can.blf"}
    log = np.genfromtxt(out / "gimbal-execution.csv", delimiter=",", names=True)
    np.testing.assert_allclose(np.column_stack([log["tip_x_m"], log["tip_y_m"], log["tip_z_m"]]), tips, atol=1e-8)


@pytest.mark.slow
@pytest.mark.ompl
def test_gripper6_executes_the_se3_path_of_a_plan_stage(tmp_path, block_world):
    """configs/gripper_in_the_loop.yaml: OMPL plans the jaws in se3, gripper6 executes the plan's path
    (any se3 planner's, e.g. retraction's, is taken the same way: path_from, no code change)."""
    import json

    pytest.importorskip("ompl")
    from conftest import CONFIGS
    from surgiplan import load_pipeline, run_pipeline

    out = tmp_path / "out"
    pipeline = load_pipeline(CONFIGS / "gripper_in_the_loop.yaml", output_dir=out)
    pipeline.model.output.figures = pipeline.model.output.gltf = False
    run_pipeline(pipeline)
    plan, stage = json.loads((out / "result.json").read_text())["stages"]
    assert (plan["space"], plan["status"], stage["plugin"], stage["status"]) == (
        "se3",
        "solved",
        "gripper6",
        "completed",
    )
    m = stage["metrics"]
    assert m["tracking_error_max_m"] < 5e-5 and m["faults"] == []
    assert m["executed_body_min_clearance_m"] > 0 and m["arm_min_clearance_m"] > 0
    # the jaws end at the plan's goal
    np.testing.assert_allclose(np.array(stage["path"])[-1], np.array(plan["path"])[-1][:3], atol=5e-5)
    tips = np.array(stage["path"])
    swept = coal_scene_segment_distance(block_world, tips[:-1], tips[1:], 0.0)
    assert m["executed_min_clearance_m"] == pytest.approx(swept.min(), abs=1e-9)
