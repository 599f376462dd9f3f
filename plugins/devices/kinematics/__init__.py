"""Kinematic models of the devices: Pinocchio models from URDF and QP inverse kinematics (:mod:`.model`).

Shared by the CiA 402 devices (:mod:`surgiplan.plugins.devices.cast_gimbal`,
:mod:`surgiplan.plugins.devices.gripper6`), each of which ships its own
URDF. Registers no plugin.
"""

from __future__ import annotations

from .model import DifferentialIK, IKResult, KinematicModel

__all__ = ["DifferentialIK", "IKResult", "KinematicModel"]
