"""Helpers for the device tests: scenes, spaces, a device lifecycle, and independent references.

The references here do not use the code under test: CAN frame lengths bit by bit from the
CAN 2.0 specification, and forward kinematics composed from the URDF text with numpy.
"""

from __future__ import annotations

import contextlib
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from surgiplan.devices import Trajectory
from surgiplan.results import StageContext
from surgiplan.spaces import CastGimbalSettings, CastGimbalSpace

#: the fulcrum of configs/gimbal_in_the_loop.yaml, in metres: above the box's right end, shaft down
FULCRUM = {"xyz": [0.15, 0.05, 0.13], "rpy": [0.0, math.pi / 2, 0.0]}
#: gripper6's mount of configs/gripper_in_the_loop.yaml
ARM_BASE = {"xyz": [0.075, -0.15, 0.0], "rpy": [0.0, 0.0, math.pi / 2]}


def gimbal_space(scene, fulcrum=None, **settings) -> CastGimbalSpace:
    return CastGimbalSpace(scene, CastGimbalSettings.model_validate({"fulcrum": fulcrum or FULCRUM, **settings}))


def gimbal_path(space: CastGimbalSpace, tips) -> np.ndarray:
    """Configurations reaching ``tips`` (closed form), roll 0."""
    return space.inverse(np.asarray(tips, dtype=float))


#: tip points in the gap plane y = 50 mm: a clear path through the middle and right pairs
GAP_TIPS = [[0.06, 0.05, 0.02], [0.10, 0.05, 0.025], [0.14, 0.05, 0.02]]


def context(scene, tmp_path: Path) -> StageContext:
    return StageContext("execute", scene, tmp_path, tmp_path)


def _settings(device_cls, settings: dict):
    # figures and CSV logs cost a second each: only the tests about them ask for them
    return device_cls.Settings.model_validate({"outputs": False, **settings})


@contextlib.contextmanager
def active(device_cls, settings: dict, scene, tmp_path: Path):
    """A configured and activated device; shut down on exit whatever happens."""
    device = device_cls(_settings(device_cls, settings))
    try:
        device.configure(context(scene, tmp_path))
        device.activate()
        yield device
    finally:
        device.shutdown()


@contextlib.contextmanager
def configured_gimbal(scene, tmp_path: Path, settings: dict | None = None):
    """A configured (inactive) cast_gimbal on the simulated bus, fulcrum FULCRUM."""
    from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice

    device = CastGimbalDevice(_settings(CastGimbalDevice, {"fulcrum": FULCRUM, **(settings or {})}))
    try:
        device.configure(context(scene, tmp_path))
        yield device
    finally:
        device.shutdown()


def execute(device_cls, settings: dict, path, space, scene, tmp_path: Path):
    """Configure, activate, execute one path, shut down; returns the report and ground truth.

    Ground truth (the simulated drives' true state when the run ended): ``positions``, ``velocities``,
    ``states`` (CiA 402 state names), ``transitions`` (time, node, from, to), ``frames`` (every frame
    the master saw: time, id, data), ``trajectory_start`` (clock time of the first cycle).
    """
    with active(device_cls, settings, scene, tmp_path) as device:
        report = device.execute(Trajectory(np.asarray(path, dtype=float), space, "test"))
        simulator = device.simulator
        truth = {
            "positions": simulator.pos.copy(),
            "velocities": simulator.vel.copy(),
            "states": [simulator_state(simulator, i) for i in range(len(simulator.pos))],
            "transitions": list(simulator.transitions),
            "frames": list(device.bus.frames),
            "emcy": list(device.master.emcy),
            "measured": _read_positions(device),
            "trajectory_start": device.faults.origin,
            "node_ids": [a.node_id for a in device.master.axes],
            "counts_per_unit": np.array([a.counts_per_unit for a in device.master.axes]),
            "period": device.master.period,
            "log": device.last_log,
            "model": device.model,
        }
    return report, truth


def _read_positions(device):
    from surgiplan.plugins.devices.canopen.bus import BusError

    try:
        return device.joint_positions()
    except BusError:  # a dead node or a bus-off controller cannot be read
        return None


def simulator_state(simulator, i: int) -> str:
    from surgiplan.plugins.devices.canopen.sim import statemachine

    return statemachine._STATES[simulator.state[i]]


# ----------------------------------------------------------------------------- CAN frames, bit by bit
def reference_frame_bits(can_id: int, data: bytes) -> int:
    """Length in bits of a classic CAN data frame with an 11-bit identifier (CAN 2.0 part A, §3.1).

    Built as a list of bits, the CRC-15 computed per the specification's shift-register
    pseudo-code, stuff bits counted by walking the bits after five equal ones.
    """
    bits = [0]  # SOF
    bits += [(can_id >> (10 - i)) & 1 for i in range(11)]
    bits += [0, 0, 0]  # RTR (data frame), IDE (standard), r0
    bits += [(len(data) >> (3 - i)) & 1 for i in range(4)]
    for byte in data:
        bits += [(byte >> (7 - i)) & 1 for i in range(8)]
    crc = [0] * 15
    for bit in bits:
        nxt = bit ^ crc[0]
        crc = [*crc[1:], 0]
        if nxt:
            poly = [(0x4599 >> (14 - i)) & 1 for i in range(15)]
            crc = [c ^ p for c, p in zip(crc, poly, strict=True)]
    stuffed_region = bits + crc
    stuff, run, last = 0, 0, None
    for bit in stuffed_region:
        if bit == last:
            run += 1
        else:
            run, last = 1, bit
        if run == 5:
            stuff += 1
            run, last = 1, 1 - bit
    # CRC delimiter, ACK slot, ACK delimiter, 7 EOF bits, 3 interframe bits
    return len(stuffed_region) + stuff + 1 + 2 + 7 + 3


# ----------------------------------------------------------------------------- kinematics from the URDF text
def urdf_chain(path: Path, tip: str) -> list[dict]:
    """The joints from the root to the link ``tip``, with origin, axis and type, from the XML."""
    root = ET.parse(path).getroot()
    joints = {j.find("child").get("link"): j for j in root.findall("joint")}
    chain = []
    link = tip
    while link in joints:
        joint = joints[link]
        origin = joint.find("origin")
        axis = joint.find("axis")
        chain.append(
            {
                "name": joint.get("name"),
                "type": joint.get("type"),
                "xyz": np.array([float(v) for v in (origin.get("xyz") or "0 0 0").split()]),
                "rpy": np.array([float(v) for v in (origin.get("rpy") or "0 0 0").split()]),
                "axis": np.array([float(v) for v in (axis.get("xyz") if axis is not None else "1 0 0").split()]),
            }
        )
        link = joint.find("parent").get("link")
    return chain[::-1]


def urdf_forward_kinematics(path: Path, tip: str, q, base_xyz, base_rpy) -> tuple[np.ndarray, np.ndarray]:
    """Tip position and rotation by composing the URDF's joint transforms (numpy, no Pinocchio)."""
    rotation = Rotation.from_euler("xyz", base_rpy).as_matrix()
    position = np.asarray(base_xyz, dtype=float)
    movable = iter(np.asarray(q, dtype=float))
    for joint in urdf_chain(path, tip):
        position = position + rotation @ joint["xyz"]
        rotation = rotation @ Rotation.from_euler("xyz", joint["rpy"]).as_matrix()
        if joint["type"] == "revolute":
            rotation = rotation @ Rotation.from_rotvec(joint["axis"] * next(movable)).as_matrix()
        elif joint["type"] == "prismatic":
            position = position + rotation @ (joint["axis"] * next(movable))
    return position, rotation
