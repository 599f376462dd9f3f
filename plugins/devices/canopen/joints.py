"""A CiA 402 device's settings per joint, checked against its kinematic model (SI joint units: rad or m).

One place turns the device's settings into per-joint values: the node ids,
encoder resolutions, following-error windows, the trajectories' velocity and
acceleration limits and where the axes stand at power-up in simulation
(:class:`Joints`). The master configures each drive from them
(:func:`axis_configs`); the simulated drives are built from them too
(:func:`.sim.drives.axis_hardware`). A setting that does not fit the model is
a :class:`~surgiplan.errors.ConfigError` naming it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from surgiplan.errors import ConfigError
from surgiplan.plugins.devices.kinematics.model import KinematicModel

from .bus import worst_case_bits
from .master import AxisConfig
from .settings import GENERIC_MOTOR, PRISMATIC_COUNTS, REVOLUTE_COUNTS, Cia402DeviceSettings


@dataclass(frozen=True)
class Joints:
    """The per-joint values of a device's settings (one entry per joint of its model)."""

    node_ids: list[int]
    counts_per_unit: np.ndarray
    following_error_window: np.ndarray
    #: the trajectories' velocity and acceleration limits
    velocity: np.ndarray
    acceleration: np.ndarray
    #: where the simulated axes stand at power-up: ``simulation.initial``, else the model's neutral configuration
    start: np.ndarray
    #: each joint's motor (:class:`.settings.MotorSettings`): name -> one value per joint
    motors: dict[str, np.ndarray] | None = None


def per_joint(model: KinematicModel, values, default, what: str) -> np.ndarray:
    """``values`` (one per joint; None: ``default``) as an array; a ConfigError naming ``what`` if miscounted."""
    nq = model.nq
    if values is None:
        return np.asarray(default, dtype=float)
    if len(values) != nq:
        raise ConfigError(f"{what}: give {nq} values, one per joint {model.joint_names}; got {len(values)}")
    return np.asarray(values, dtype=float)


def joint_limits(s: Cia402DeviceSettings, model: KinematicModel, default_acceleration) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and acceleration limits the trajectories use (SI per joint)."""
    velocity = model.velocity_limit * s.velocity_scale
    acceleration = per_joint(model, s.acceleration_limits, default_acceleration, "acceleration_limits")
    return velocity, acceleration


def resolve_motors(s: Cia402DeviceSettings, model: KinematicModel, defaults=None) -> dict[str, np.ndarray]:
    """Each joint's motor: ``motors`` settings, else the device's ``defaults`` (name -> per joint), else
    :data:`.settings.GENERIC_MOTOR`."""
    defaults = defaults or {}
    out = {}
    for name, generic in GENERIC_MOTOR.items():
        default = defaults.get(name, [generic] * model.nq)
        out[name] = per_joint(model, getattr(s.motors, name), default, f"motors.{name}")
    return out


def resolve_joints(s: Cia402DeviceSettings, model: KinematicModel, default_acceleration, default_motors=None) -> Joints:
    """The per-joint values of settings ``s`` on ``model`` (raises ConfigError)."""
    nq = model.nq
    ids = s.node_ids or list(range(1, nq + 1))
    if len(ids) != nq or len(set(ids)) != nq or not all(1 <= i <= 127 for i in ids):
        raise ConfigError(f"node_ids: give {nq} distinct CAN node ids (1-127), one per joint {model.joint_names}")
    if s.master_node_id in ids:
        raise ConfigError(f"master_node_id {s.master_node_id} is also a drive's node id (node_ids: {ids})")
    cpu = per_joint(
        model, s.counts_per_unit, np.where(model.prismatic, PRISMATIC_COUNTS, REVOLUTE_COUNTS), "counts_per_unit"
    )
    window = per_joint(
        model, s.following_error_window, np.where(model.prismatic, 0.001, 0.01), "following_error_window"
    )
    velocity, acceleration = joint_limits(s, model, default_acceleration)
    initial = s.simulation.initial
    if initial is not None:
        initial = per_joint(model, initial, None, "simulation.initial")
        if not model.within_limits(initial[None])[0]:
            raise ConfigError(f"simulation.initial {list(initial)} is outside the joint limits")
    start = initial if initial is not None else model.neutral()
    return Joints(ids, cpu, window, velocity, acceleration, start, resolve_motors(s, model, default_motors))


def axis_configs(s: Cia402DeviceSettings, model: KinematicModel, joints: Joints) -> list[AxisConfig]:
    """What the master configures on each joint's drive."""
    return [
        AxisConfig(
            model.joint_names[j],
            joints.node_ids[j],
            float(joints.counts_per_unit[j]),
            float(model.lower[j]),
            float(model.upper[j]),
            float(joints.following_error_window[j]),
            float(joints.velocity[j] * s.simulation.velocity_factor),
            float(joints.acceleration[j] * s.quick_stop_factor),
        )
        for j in range(model.nq)
    ]


def check_bus_load(s: Cia402DeviceSettings, axes: list[AxisConfig]) -> None:
    """Refuse a control rate whose cyclic frames alone cannot fit on the bus."""
    per_cycle = worst_case_bits(0) + len(axes) * 2 * worst_case_bits(6)
    load = per_cycle * s.control_rate / s.bus.bitrate
    if load > 1.0:
        raise ConfigError(
            f"control_rate {s.control_rate:g} Hz with {len(axes)} drives needs {100 * load:.0f}% of the "
            f"{s.bus.bitrate / 1e6:g} Mbit/s bus (SYNC + RPDO + TPDO per drive, worst-case stuffing); "
            f"lower control_rate to at most {s.control_rate / load:.0f} Hz"
        )
