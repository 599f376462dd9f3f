"""``cast_gimbal``: the CAST laparoscopic gimbal as a device (4 CiA 402 drives over CAN).

The Computer Assisted Surgical Trainer's instrument mount, the device papers
000 and 001 guide trainees on (Rozenblit et al., "The Computer Assisted
Surgical Trainer: design, models, and implementation", SummerSim 2014):
yaw and pitch about a fulcrum, insertion along the shaft, roll about it.
Modules: :mod:`.device` (the :class:`CastGimbalDevice`: model, closed-form
inverse kinematics check, execution); ``urdf/cast_gimbal.urdf`` (the model,
package data).
"""

from __future__ import annotations

from surgiplan.hookspecs import PluginSpec, hookimpl

from .device import CastGimbalDevice, CastGimbalDeviceSettings

__all__ = ["CastGimbalDevice", "CastGimbalDeviceSettings"]


@hookimpl
def surgiplan_register_devices():
    return [
        PluginSpec(
            "cast_gimbal",
            CastGimbalDevice,
            "CAST laparoscopic gimbal (yaw, pitch, insertion, roll): 4 CiA 402 drives over CAN",
        )
    ]
