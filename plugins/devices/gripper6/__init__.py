"""``gripper6``: a 6-DOF gripper arm as a device (6 CiA 402 drives over CAN).

The generic 6-DOF gripper that executes paper 002's retraction plans
(Patil & Alterovitz) and any ``se3`` plan: a 6R arm with a spherical wrist.
Modules: :mod:`.device` (the :class:`Gripper6Device`: model, SE(3) inverse
kinematics, execution); ``urdf/gripper6.urdf`` (the model, package data).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from surgiplan.hookspecs import PluginSpec, hookimpl
from surgiplan.lazy import lazy_exports

if TYPE_CHECKING:
    from .device import Gripper6Device, Gripper6Settings

__getattr__, __dir__ = lazy_exports(
    __name__,
    {"Gripper6Device": ".device", "Gripper6Settings": ".device"},
)

__all__ = ["Gripper6Device", "Gripper6Settings"]


@hookimpl
def surgiplan_register_devices():
    return [
        PluginSpec(
            "gripper6",
            "surgiplan.plugins.devices.gripper6.device:Gripper6Device",
            "6R arm with a spherical wrist and a gripper: 6 CiA 402 drives over CAN",
        )
    ]
