"""Built-in device plugins: ``cast_gimbal`` and ``gripper6``, CiA 402 drives over CAN.

Modules: :mod:`.kinematics` (Pinocchio models, QP inverse kinematics),
:mod:`.timing` (time-optimal parameterisation), :mod:`.cia402` (the drive
profile), :mod:`.bus` (transport, fault injection, bus load),
:mod:`.network` and :mod:`.clock` (simulated clock), :mod:`.drives`
(simulated drives; :mod:`.sim_drives` runs them in a process of their own),
:mod:`.master` (CANopen master), :mod:`.control` (the supervised control
loop), :mod:`.settings` and :mod:`.device` (settings, lifecycle and
execution), :mod:`.execution_report` (metrics, figure, log),
:mod:`.cast_gimbal` and :mod:`.gripper6` (the devices).
"""

from surgiplan.hookspecs import PluginSpec, hookimpl

from .cast_gimbal import CastGimbalDevice
from .gripper6 import Gripper6Device

__all__ = ["CastGimbalDevice", "Gripper6Device"]


@hookimpl
def surgiplan_register_devices():
    return [
        PluginSpec(
            "cast_gimbal",
            CastGimbalDevice,
            "CAST laparoscopic gimbal (yaw, pitch, insertion, roll): 4 CiA 402 drives over CAN",
        ),
        PluginSpec(
            "gripper6", Gripper6Device, "6R arm with a spherical wrist and a gripper: 6 CiA 402 drives over CAN"
        ),
    ]
