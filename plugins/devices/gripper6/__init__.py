"""``gripper6``: a 6-DOF gripper arm as a device (6 CiA 402 drives over CAN).

The generic 6-DOF gripper that executes paper 002's retraction plans
(Patil & Alterovitz) and any ``se3`` plan: a 6R arm with a spherical wrist.
Modules: :mod:`.device` (the :class:`Gripper6Device`: model, SE(3) inverse
kinematics, execution); ``urdf/gripper6.urdf`` (the model, package data).
"""

from __future__ import annotations

from surgiplan.hookspecs import PluginSpec, hookimpl

from .device import Gripper6Device, Gripper6Settings

__all__ = ["Gripper6Device", "Gripper6Settings"]


@hookimpl
def surgiplan_register_devices():
    return [
        PluginSpec("gripper6", Gripper6Device, "6R arm with a spherical wrist and a gripper: 6 CiA 402 drives over CAN")
    ]
