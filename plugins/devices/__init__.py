"""surgiplan's device plugins, one package per device family.

* :mod:`.canopen` — the CANopen layer (CiA 301/402): the master, the
  supervised control loop, timing; the base class of devices whose joints
  are CiA 402 drives; :mod:`.canopen.sim` the simulated drives and the
  loopback bus interface for drives in another process. Registers no plugin.
* :mod:`.kinematics` — Pinocchio models from URDF and QP inverse kinematics.
* :mod:`.cast_gimbal` — the CAST laparoscopic gimbal (``cast_gimbal``).
* :mod:`.gripper6` — a 6-DOF gripper arm (``gripper6``).
* :mod:`.mavlink` — a MAVLink 2 vehicle (``mavlink_vehicle``, the ground
  station side); :mod:`.mavlink.sim` the simulated PX4-like vehicle.

Layers (the import contracts in ``pyproject.toml``): cast_gimbal and
gripper6 build on canopen, which builds on kinematics; mavlink stands alone.
"""
