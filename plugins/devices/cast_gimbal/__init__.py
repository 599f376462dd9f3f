"""``cast_gimbal``: the CAST laparoscopic gimbal as a device (4 CiA 402 drives over CAN).

The Computer Assisted Surgical Trainer's instrument mount, the device papers
000 and 001 guide trainees on (Rozenblit et al., "The Computer Assisted
Surgical Trainer: design, models, and implementation", SummerSim 2014):
yaw and pitch about a fulcrum, insertion along the shaft, roll about it.
Modules: :mod:`.device` (the :class:`CastGimbalDevice`: model, closed-form
inverse kinematics check, execution); :mod:`.observe` (the gimbal as a pose
source for guide stages: observe mode, the drives never commanded); ``urdf/cast_gimbal.urdf`` (the model,
package data).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from surgiplan.hookspecs import PluginSpec, hookimpl
from surgiplan.lazy import lazy_exports

if TYPE_CHECKING:
    from .device import CastGimbalDevice, CastGimbalDeviceSettings
    from .observe import CastGimbalObserver, CastGimbalObserveSettings

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "CastGimbalDevice": ".device",
        "CastGimbalDeviceSettings": ".device",
        "CastGimbalObserver": ".observe",
        "CastGimbalObserveSettings": ".observe",
    },
)

__all__ = ["CastGimbalDevice", "CastGimbalDeviceSettings", "CastGimbalObserveSettings", "CastGimbalObserver"]


@hookimpl
def surgiplan_register_devices():
    return [
        PluginSpec(
            "cast_gimbal",
            "surgiplan.plugins.devices.cast_gimbal.device:CastGimbalDevice",
            "CAST laparoscopic gimbal (yaw, pitch, insertion, roll): 4 CiA 402 drives over CAN",
        )
    ]


@hookimpl
def surgiplan_register_sources():
    return [
        PluginSpec(
            "cast_gimbal",
            "surgiplan.plugins.devices.cast_gimbal.observe:CastGimbalObserver",
            "the CAST gimbal in observe mode: drives not commanded, encoder positions by TPDO (guide stages)",
        )
    ]
