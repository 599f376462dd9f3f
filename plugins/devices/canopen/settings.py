"""Settings every CiA 402 device shares (``cast_gimbal``, ``gripper6``): bus, rates, limits, supervision.

Per-joint lists are in SI joint units (rad or m); lengths accept the pipeline's
``length_unit``. Device-specific settings extend :class:`Cia402DeviceSettings`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import Field, NonNegativeFloat, PositiveFloat, PositiveInt
from surgiplan.models import StrictModel
from surgiplan.units import Length, PositiveLength

from .bus import BusSettings
from .trace import RecordSettings

#: encoder resolution defaults: a 17-bit absolute encoder (revolute), 1 um per count (prismatic)
REVOLUTE_COUNTS = 2**17 / (2 * math.pi)
PRISMATIC_COUNTS = 1e6


class SimulationSettings(StrictModel):
    """The simulated drives (``bus.interface: virtual``)."""

    #: joint positions at power-up (SI); None: the first trajectory's start, as if placed there by hand
    initial: list[float] | None = None
    position_gain: PositiveFloat = 150.0
    velocity_gain: PositiveFloat = 1000.0
    #: each drive's current limit, as a multiple of the trajectory's acceleration limit
    peak_acceleration_factor: float = Field(default=3.0, gt=1.0)
    #: each motor's speed limit, as a multiple of the joint velocity limit
    velocity_factor: float = Field(default=1.5, ge=1.0)
    #: an enabled drive without SYNC for this long quick-stops by itself (s)
    sync_timeout: PositiveFloat = 0.05


#: the motor of a joint whose device gives none (:class:`MotorSettings`): rated torque (N·m at the motor), peak
#: torque (thousandths of the rated), gear ratio, inertia (kg·m² or kg), viscous (N·m·s/rad or N·s/m) and Coulomb
#: friction (N·m or N) at the joint
GENERIC_MOTOR = {
    "rated_torque": 0.1,
    "peak_torque": 3000,
    "gear_ratio": 10.0,
    "inertia": 0.005,
    "viscous_friction": 0.01,
    "coulomb_friction": 0.005,
}


class MotorSettings(StrictModel):
    """Each joint's motor and drive train (cyclic synchronous torque, the haptic ``assist`` mode), one value per
    joint; None: the device's defaults (``Cia402Device.default_motors``, else :data:`GENERIC_MOTOR`).

    The rated and peak torques are the drive's (0x6076, 0x6072's ceiling); the gear ratio turns a motor torque
    into a joint torque (N·m per N·m; a linear axis: N per N·m). Inertia and friction are the simulated axis'."""

    #: the motor's rated torque (N·m at the motor): 0x6076 of the simulated drive
    rated_torque: list[PositiveFloat] | None = None
    #: the drive's peak torque (thousandths of the rated torque): the highest max torque 0x6072 takes
    peak_torque: list[PositiveInt] | None = None
    #: joint torque per motor torque (a linear axis: N per N·m)
    gear_ratio: list[PositiveFloat] | None = None
    #: the axis' inertia at the joint (kg·m², a linear axis kg)
    inertia: list[PositiveFloat] | None = None
    #: viscous friction at the joint (N·m·s/rad or N·s/m)
    viscous_friction: list[NonNegativeFloat] | None = None
    #: Coulomb friction at the joint (N·m or N)
    coulomb_friction: list[NonNegativeFloat] | None = None


class IKSettings(StrictModel):
    #: position tolerance (m)
    tolerance: PositiveLength = 1e-7
    #: orientation tolerance (rad)
    rotation_tolerance: PositiveFloat = 1e-6
    max_iterations: PositiveInt = 100


class Cia402DeviceSettings(StrictModel):
    """Settings every CiA 402 device shares. Per-joint lists are in SI joint units (rad or m)."""

    bus: BusSettings = Field(default_factory=BusSettings)
    #: auto: simulated for the virtual bus, real time otherwise
    clock: Literal["auto", "simulated", "realtime"] = "auto"
    #: SYNC rate (Hz); its period must be a whole number of 1e-6 s steps (0x60C2)
    control_rate: PositiveFloat = 250.0
    #: real time: run the control loop's threads (and the simulated drives') under SCHED_FIFO at this priority
    #: (1-99; Linux, needs CAP_SYS_NICE), as a controller with real-time scheduling does; None: ordinary
    realtime_priority: int | None = Field(default=None, ge=1, le=99)
    #: CAN node ids per joint (default 1, 2, ...)
    node_ids: list[int] | None = None
    #: heartbeat producer period (s) of the drives and of the master; either side times out after 1.5 periods
    heartbeat_period: PositiveFloat = 0.1
    #: the master's own node id: its heartbeat (0x700 + id) is what the drives consume (0x1016)
    master_node_id: int = Field(default=127, ge=1, le=127)
    #: after the NMT reset communication, how long to wait for every node's boot-up message (s)
    boot_timeout: PositiveFloat = 1.0
    #: each joint's drive's EDS file (one file for all, or one per joint); default: the EDS of the simulated
    #: drives shipped with the device. Real drives: give their vendor's EDS (identity and objects are checked);
    #: relative paths are relative to the pipeline file
    eds: Path | list[Path] | None = None
    #: a trajectory whose certified clearance (over the whole timed motion) is below this is refused before
    #: any motion (m; 0: refuse only collisions)
    safety_margin: Length = 0.0
    #: fraction of the URDF velocity limits the trajectories use
    velocity_scale: float = Field(default=1.0, gt=0.0, le=1.0)
    #: per joint (rad/s^2 or m/s^2); default: the device's
    acceleration_limits: list[PositiveFloat] | None = None
    #: encoder counts per rad or per m, per joint; default 2^17 per turn, 1 per um
    counts_per_unit: list[PositiveFloat] | None = None
    #: following error window per joint (rad or m); default 0.01 rad, 1 mm
    following_error_window: list[PositiveFloat] | None = None
    following_error_timeout: PositiveFloat = 0.01
    #: quick-stop deceleration as a multiple of the acceleration limit
    quick_stop_factor: float = Field(default=2.0, ge=1.0)
    #: tip spacing (m) at which the path is resampled before inverse kinematics
    path_resolution: PositiveLength = 0.0005
    #: move from the current configuration to the path's start (checked clear) when they differ
    approach: bool = True
    sdo_timeout: PositiveFloat = 0.2
    pdo_timeout_cycles: PositiveInt = 5
    settle_time: PositiveFloat = 0.5
    stop_timeout: PositiveFloat = 1.0
    enable_timeout: PositiveFloat = 1.0
    #: after a stop, fault-reset and re-enable the drives and report whether they came back
    #: (``metrics.fault_reset``); the stage still ends "stopped"
    fault_reset: bool = False
    #: write <stage>.png (joints, tracking error, clearance over time, faults) and <stage>-execution.csv
    outputs: bool = True
    #: what else to record: ``can: blf | asc | log`` writes the bus traffic as ``<stage>.can.<format>`` (:mod:`.trace`)
    record: RecordSettings = Field(default_factory=RecordSettings)
    simulation: SimulationSettings = Field(default_factory=SimulationSettings)
    #: each joint's motor (torque mode): :class:`MotorSettings`
    motors: MotorSettings = Field(default_factory=MotorSettings)
    ik: IKSettings = Field(default_factory=IKSettings)
