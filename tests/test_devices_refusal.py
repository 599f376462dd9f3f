"""A device refuses, before any motion, a trajectory whose certified clearance is negative or below its
safety margin, whatever produced it (issue 14): the gimbal's whole shaft, the gripper's jaws and links,
certified along the whole timed motion the drives would interpolate, between the samples too.

The clearances in the messages are checked against coal (tests/helpers.py), the absence of motion on
the bus (no RPDO carries a new target) and in the simulated hardware's ground truth.
"""

from __future__ import annotations

import re
import struct

import numpy as np
import pytest
from devices_support import ARM_BASE, FULCRUM, active, gimbal_path, gimbal_space
from helpers import coal_scene_segment_distance
from surgiplan.devices import Trajectory
from surgiplan.plugins.devices.canopen.certify import certify
from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice
from surgiplan.plugins.devices.gripper6 import Gripper6Device
from surgiplan.spaces import R3Space

GIMBAL_START = [0.0, 0.6, 0.12, 0.0]
#: tip points in the block world: a waypoint 5 mm inside block B1 (y 15-44 mm), between clear ones
INTO_A_BLOCK = [[0.06, 0.05, 0.02], [0.075, 0.039, 0.02], [0.10, 0.05, 0.02]]
#: a straight line at x = 78 mm through blocks B1 (y 15-44) and B2 (y 56-85); both ends clear (the shaft too)
THROUGH_TWO_BLOCKS = [[0.078, 0.005, 0.02], [0.078, 0.095, 0.02]]
#: the blocks of configs/scenes/block_world.yaml (min, max), m: for the numpy reference below
BLOCKS = (
    np.array(
        [
            [35, 0, 0, 45, 47, 40],
            [35, 53, 0, 45, 100, 40],
            [70, 15, 0, 80, 44, 40],
            [70, 56, 0, 80, 85, 40],
            [105, 20, 0, 115, 46.5, 40],
            [105, 53.5, 0, 115, 80, 40],
        ]
    )
    / 1000
)


def block_distance(points: np.ndarray) -> np.ndarray:
    """Signed distance (m) of points to the nearest block, from the box formula (numpy; negative inside)."""
    lo, hi = BLOCKS[:, :3], BLOCKS[:, 3:]
    out = []
    for chunk in np.array_split(points, max(1, len(points) // 20000)):
        d = np.maximum(lo[None] - chunk[:, None], chunk[:, None] - hi[None])
        outside = np.linalg.norm(np.maximum(d, 0.0), axis=2)
        out.append((outside + np.minimum(d.max(axis=2), 0.0)).min(axis=1))
    return np.concatenate(out)


def deepest_shaft(space, tips: np.ndarray, step: float = 1e-4) -> float:
    """Lowest clearance (m) of the shaft capsule (fulcrum to tip, radius 2.5 mm) over the given tips: every
    shaft point sampled every ``step`` (an upper bound of the true minimum, within step / 2)."""
    lowest = np.inf
    for tip in tips:
        length = np.linalg.norm(tip - space.fulcrum)
        s = np.linspace(0.0, 1.0, int(length / step) + 2)[:, None]
        lowest = min(lowest, float(block_distance(space.fulcrum + s * (tip - space.fulcrum)).min()))
    return lowest - space.shaft_radius


def refused_execution(device_cls, settings, path, space, scene, tmp_path, start=None):
    """Execute on an active device (standing at ``start``, else where its drives power up); returns the report
    and what happened: the frames sent during execute, every RPDO's target, the hardware's positions."""
    if start is not None:
        settings = {**settings, "simulation": {"initial": start}}
    with active(device_cls, settings, scene, tmp_path) as device:
        start = device.simulator.positions()
        hold = np.round(np.asarray(start) * device.controller.cpu).astype(np.int64)
        before = len(device.bus.frames)
        report = device.execute(Trajectory(np.asarray(path, dtype=float), space, "a third-party planner"))
        sent = device.bus.frames[before:]
        ids = {0x200 + a.node_id: j for j, a in enumerate(device.master.axes)}
        rpdos = [(ids[i], struct.unpack("<Hl", d)[1]) for _, i, d in device.bus.frames if i in ids]
        truth = {
            "positions": device.simulator.positions(),
            "cpu": device.controller.cpu,
            "log": device.last_log,
            "sent": sent,
            "rpdo_targets": rpdos,
            "hold": hold,
            "rpdo_ids": set(ids),
            "start": start,
        }
    return report, truth


def clearance_in(message: str, body: str) -> float:
    match = re.search(rf"certified {body} clearance is (-?[\d.]+) mm", message)
    assert match, message
    return float(match.group(1)) / 1000


def assert_no_motion(report, truth):
    assert report.status == "refused" and report.metrics["refused"] is True
    assert report.message.startswith("refused before any motion: the timed motion's certified")
    assert report.metrics["cycles"] == 0 and truth["log"] is None
    # the stable metric names of an execute stage, even when nothing moved
    assert report.metrics["tracking_error_max_m"] is None and report.metrics["faults"] == []
    # on the bus: no RPDO during execute, and none ever carried a target other than the hold position
    assert not [f for f in truth["sent"] if f[1] in truth["rpdo_ids"]]
    assert all(target == truth["hold"][j] for j, target in truth["rpdo_targets"])
    # the hardware: every axis where it was (the position loop holds within an encoder count)
    assert np.all(np.abs(truth["positions"] - truth["start"]) <= 2.0 / truth["cpu"])


def test_gimbal_refuses_a_path_5_mm_into_a_block(block_world, tmp_path):
    space = gimbal_space(block_world)
    path = gimbal_path(space, INTO_A_BLOCK)
    report, truth = refused_execution(CastGimbalDevice, {"fulcrum": FULCRUM}, path, space, block_world, tmp_path,
                                      GIMBAL_START)  # fmt: skip
    assert_no_motion(report, truth)
    assert "a collision" in report.message and "tip at [75.0, 39.0, 20.0] mm" in report.message
    # the shaft (radius 2.5 mm) at the waypoint, measured with coal: its tip is 5 mm inside B1
    tip = space.tip(path[1:2])
    fulcrum = np.broadcast_to(space.fulcrum, tip.shape)
    shaft = coal_scene_segment_distance(block_world, fulcrum, tip, space.shaft_radius)[0]
    assert shaft == pytest.approx(-0.0075, abs=1e-6)
    measured = clearance_in(report.message, "shaft")
    assert shaft - 1e-5 - 5e-6 <= measured <= shaft + 5e-6  # certified: never above, within the tolerance
    assert report.metrics["certified_shaft_min_clearance_m"] == pytest.approx(measured, abs=5e-6)


def test_gimbal_refuses_a_straight_line_through_two_blocks_whose_ends_are_clear(block_world, tmp_path):
    scene = block_world
    space = R3Space(scene, tip_radius=0.001)
    ends = np.array(THROUGH_TWO_BLOCKS)
    gimbal = gimbal_space(scene)
    fulcrum = np.broadcast_to(gimbal.fulcrum, ends.shape)
    assert np.all(coal_scene_segment_distance(scene, fulcrum, ends, 0.0025) > 0.004)  # both ends clear, shaft too
    # the device stands where the path starts (no approach move)
    report, truth = refused_execution(CastGimbalDevice, {"fulcrum": FULCRUM}, ends, space, scene, tmp_path)
    assert_no_motion(report, truth)
    # the deepest the shaft goes along the line (numpy box distances): the tip 2 mm inside B1's x = 80 face
    deepest = deepest_shaft(gimbal, np.linspace(ends[0], ends[1], 901))
    assert deepest == pytest.approx(-0.0045, abs=1e-4)
    assert deepest - 5e-5 - 1e-5 <= clearance_in(report.message, "shaft") <= deepest + 1e-9


def test_the_safety_margin_refuses_a_clear_path_that_comes_too_close(block_world, tmp_path):
    space = gimbal_space(block_world)
    path = gimbal_path(space, [[0.06, 0.05, 0.02], [0.10, 0.05, 0.025], [0.14, 0.05, 0.02]])
    settings = {"fulcrum": FULCRUM, "safety_margin": "3 mm"}
    report, truth = refused_execution(CastGimbalDevice, settings, path, space, block_world, tmp_path, GIMBAL_START)
    assert_no_motion(report, truth)
    lowest = clearance_in(report.message, "shaft")
    assert 0 < lowest < 0.003 and "closer than the safety margin 3 mm" in report.message
    # below the margin at one sample at least, measured with coal (the gap of the right pair is 7 mm)
    dense = space.densify(path, 1e-4)
    tips = space.tip(dense)
    shaft = coal_scene_segment_distance(block_world, np.broadcast_to(space.fulcrum, tips.shape), tips, 0.0025)
    assert lowest <= shaft.min() + 1e-9 and shaft.min() - lowest < 1e-4
    # with a margin it keeps, the same path runs
    with active(CastGimbalDevice, {"fulcrum": FULCRUM, "safety_margin": 0.0005}, block_world, tmp_path) as device:
        report = device.execute(Trajectory(path, space, "test"))
    assert report.status == "completed", report.message
    assert report.metrics["certified_min_clearance_m"] >= 0.0005
    assert report.metrics["certified_min_clearance_m"] <= report.metrics["executed_shaft_min_clearance_m"] + 5e-5


def test_gripper6_refuses_a_straight_line_through_two_blocks(block_world, tmp_path):
    scene = block_world.with_bounds([0, 0, 0], [0.15, 0.1, 0.1])
    space = R3Space(scene)
    settings = {"base": ARM_BASE, "link_radius": 0.015}
    report, truth = refused_execution(Gripper6Device, settings, THROUGH_TWO_BLOCKS, space, block_world, tmp_path)
    assert_no_motion(report, truth)
    # the jaws, a 4 mm sphere, go through B1 and B2 at x = 78 mm: 2 mm inside their x = 80 face, + 4 mm
    jaws = clearance_in(report.message, "jaws")
    assert jaws == pytest.approx(-0.006, abs=2e-5)
    assert report.metrics["certified_jaws_min_clearance_m"] == pytest.approx(jaws, abs=5e-6)
    assert "certified_links_min_clearance_m" in report.metrics


def test_a_motion_clear_at_both_ends_through_a_block_is_caught_between_the_samples(block_world):
    """certify() on one joint-space segment: both configurations clear, the motion between them is not."""
    space = gimbal_space(block_world)
    # the tip 5 mm in front of B1 (y 15-44 mm) and 4 mm behind it, in the gap to B2: the tip sweeps through B1
    q = gimbal_path(space, [[0.078, 0.005, 0.02], [0.078, 0.048, 0.02]])
    ends = space.clearance(q)
    assert np.all(ends > 0.001)
    result = certify("shaft", space.clearance, space.motion_speed_bound, q, margin=0.0)
    dense = space.interpolate(q[:1].repeat(801, 0), q[1:].repeat(801, 0), np.linspace(0, 1, 801))
    truth = deepest_shaft(space, space.tip(dense))
    assert truth == pytest.approx(-0.0045, abs=1e-4)  # 2 mm inside B1 at x = 78 mm
    assert truth - 5e-5 - 1e-5 <= result.lowest <= truth + 1e-9
    assert result.segment == 0 and 0.3 < result.fraction < 0.7


def test_gripper6_refuses_a_path_5_mm_into_a_block(block_world, tmp_path):
    scene = block_world.with_bounds([0, 0, 0], [0.15, 0.1, 0.1])
    space = R3Space(scene)
    report, truth = refused_execution(Gripper6Device, {"base": ARM_BASE}, INTO_A_BLOCK, space, block_world, tmp_path)
    assert_no_motion(report, truth)
    # the jaws (a 4 mm sphere) at the waypoint 5 mm inside B1: -5 - 4 mm, measured with coal
    waypoint = np.array(INTO_A_BLOCK[1:2])
    jaws = coal_scene_segment_distance(block_world, waypoint, waypoint, 0.004)[0]
    assert jaws == pytest.approx(-0.009, abs=1e-6)
    assert jaws - 1e-5 - 5e-6 <= clearance_in(report.message, "jaws") <= jaws + 5e-6
