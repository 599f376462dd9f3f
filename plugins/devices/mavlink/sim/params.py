"""The simulated vehicle's parameters: a subset of PX4's, each of which drives the simulation.

Parameter protocol (mavlink.io "Parameter Protocol", as PX4 speaks it):

* PARAM_REQUEST_LIST: every parameter as PARAM_VALUE, in index order, with
  ``param_count`` and ``param_index``;
* PARAM_REQUEST_READ by name (``param_index`` -1) or by index; an unknown
  name or index is ignored (a client times out, as with PX4);
* PARAM_SET: the value is set and the new PARAM_VALUE broadcast; a value of
  the wrong type or outside the parameter's range is refused: the unchanged
  value is sent back (the spec's "current value") with a STATUSTEXT saying
  why (PX4 checks neither; a simulation cannot fly a negative speed);
* values are typed (MAV_PARAM_TYPE_REAL32 or MAV_PARAM_TYPE_INT32); an INT32
  travels *bytewise* in the float field, as PX4 encodes it (MAVSDK decodes it
  so for a PX4 autopilot, QGroundControl and MAVProxy too), which is what
  AUTOPILOT_VERSION's MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE announces;
* values persist for the life of the process (PX4 keeps them on its SD card
  across reboots: a restarted simulator starts from its settings again).

Each parameter's default is the simulator's setting it stands for (the
airframe, the offboard timeout, ...), so a parameter read back is what the
simulation flies with, and setting it changes the simulation at once.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass

from pydantic import BaseModel
from surgiplan.plugins.devices.mavlink.link import mavlink

REAL32 = mavlink.MAV_PARAM_TYPE_REAL32
INT32 = mavlink.MAV_PARAM_TYPE_INT32

#: COM_OBL_RC_ACT (PX4): what the vehicle does when offboard setpoints stop
OFFBOARD_LOSS_ACTIONS = {
    0: "position",  # PX4 "Position mode": without sticks, it holds where it is
    1: "altitude",  # "Altitude mode": likewise
    2: "manual",  # "Manual": likewise (no pilot in the simulation)
    3: "return",
    4: "land",
    5: "hold",
}


@dataclass(frozen=True)
class Parameter:
    """One PX4 parameter: its name, type, unit, range and what it drives in the simulation."""

    name: str
    kind: int
    unit: str
    minimum: float
    maximum: float
    drives: str
    #: the setting it stands for: a path into SimSettings (``airframe.max_speed``)
    setting: str

    @property
    def type_name(self) -> str:
        return "INT32" if self.kind == INT32 else "REAL32"


def _p(name: str, unit: str, lo: float, hi: float, setting: str, drives: str, kind: int = REAL32) -> Parameter:
    return Parameter(name, kind, unit, lo, hi, drives, setting)


#: the parameters, in index order (alphabetical, as PX4 lists them)
PARAMETERS: tuple[Parameter, ...] = tuple(
    sorted(
        (
            _p("COM_DISARM_LAND", "s", 0.1, 20.0, "disarm_after_landing", "auto-disarm this long after landing"),
            _p("COM_DISARM_PRFLT", "s", 1.0, 600.0, "disarm_before_takeoff", "auto-disarm without take-off (wall s)"),
            _p(
                "COM_OBL_RC_ACT",
                "",
                0,
                5,
                "offboard_loss_action",
                "offboard loss: 0-2, 5 hold, 3 return, 4 land",
                INT32,
            ),
            _p("COM_OF_LOSS_T", "s", 0.1, 60.0, "offboard_timeout", "offboard loss after this long without setpoints"),
            _p(
                "GF_ACTION",
                "",
                0,
                5,
                "geofence_action",
                "fence breach: 0 none 1 warn 2 hold 3 return 4 end 5 land",
                INT32,
            ),
            _p("GF_MAX_HOR_DIST", "m", 0.0, 10000.0, "geofence_max_horizontal", "fence: farthest from home (0: none)"),
            _p("GF_MAX_VER_DIST", "m", 0.0, 10000.0, "geofence_max_vertical", "fence: highest above home (0: none)"),
            _p("GF_PREDICT", "", 0, 1, "geofence_predict", "act on the breach a braking distance ahead", INT32),
            _p("MIS_TAKEOFF_ALT", "m", 0.2, 100.0, "takeoff_altitude", "take-off altitude above home (NaN param7)"),
            _p("MPC_ACC_HOR", "m/s^2", 0.1, 20.0, "airframe.auto_acceleration", "acceleration of mission legs"),
            _p("MPC_ACC_HOR_MAX", "m/s^2", 0.5, 30.0, "airframe.max_acceleration", "thrust authority (all axes)"),
            _p("MPC_LAND_SPEED", "m/s", 0.05, 5.0, "airframe.landing_speed", "descent speed when landing"),
            _p("MPC_TKO_SPEED", "m/s", 0.1, 10.0, "airframe.takeoff_speed", "climb speed of a take-off"),
            _p("MPC_XY_CRUISE", "m/s", 0.1, 30.0, "airframe.cruise_speed", "mission and return speed"),
            _p("MPC_XY_P", "1/s", 0.05, 5.0, "airframe.position_gain", "horizontal position gain"),
            _p("MPC_XY_VEL_I_ACC", "1/s^2", 0.0, 60.0, "airframe.velocity_integral", "horizontal velocity I gain"),
            _p("MPC_XY_VEL_MAX", "m/s", 0.1, 30.0, "airframe.max_speed", "top horizontal speed"),
            _p("MPC_XY_VEL_P_ACC", "1/s", 0.1, 20.0, "airframe.velocity_gain", "horizontal velocity P gain"),
            _p("MPC_Z_P", "1/s", 0.05, 5.0, "airframe.position_gain_z", "vertical position gain"),
            _p("MPC_Z_VEL_I_ACC", "1/s^2", 0.0, 60.0, "airframe.velocity_integral_z", "vertical velocity I gain"),
            _p("MPC_Z_VEL_MAX_DN", "m/s", 0.1, 10.0, "airframe.max_descent", "top descent speed"),
            _p("MPC_Z_VEL_MAX_UP", "m/s", 0.1, 10.0, "airframe.max_climb", "top climb speed"),
            _p("MPC_Z_VEL_P_ACC", "1/s", 0.1, 20.0, "airframe.velocity_gain_z", "vertical velocity P gain"),
            _p("NAV_ACC_RAD", "m", 0.01, 200.0, "airframe.acceptance_radius", "default waypoint acceptance radius"),
            _p("RTL_RETURN_ALT", "m", 0.0, 500.0, "rtl_return_altitude", "return climbs to this above home first"),
            _p(
                "RTL_TYPE",
                "",
                0,
                1,
                "rtl_type",
                "return: 0 nearest of home, rally; 1 rally point",
                INT32,
            ),
        ),
        key=lambda p: p.name,
    )
)
BY_NAME = {p.name: p for p in PARAMETERS}


def _get(settings, path: str):
    value = settings
    for part in path.split("."):
        value = getattr(value, part)
    return value


def _set(settings, path: str, value) -> None:
    *parents, last = path.split(".")
    target = settings
    for part in parents:
        target = getattr(target, part)
    setattr(target, last, value)


def to_wire(kind: int, value: float | int) -> float:
    """The float that carries ``value`` in PARAM_VALUE/PARAM_SET: itself (REAL32) or its int32 bytes (INT32)."""
    if kind == INT32:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return float(value)


def from_wire(kind: int, carried: float) -> float | int:
    """The value a PARAM_VALUE/PARAM_SET float carries (bytewise for INT32)."""
    if kind == INT32:
        return struct.unpack("<i", struct.pack("<f", carried))[0]
    return float(struct.unpack("<f", struct.pack("<f", carried))[0])


def check_value(parameter: Parameter, value) -> str | None:
    """Why ``value`` cannot be set (None when it can)."""
    if parameter.kind == INT32:
        if int(value) != value:
            return f"{parameter.name} is an integer"
    elif not math.isfinite(value):
        return f"{parameter.name} must be a finite number"
    if not parameter.minimum <= value <= parameter.maximum:
        unit = f" {parameter.unit}" if parameter.unit else ""
        return f"{parameter.name} {value:g} outside [{parameter.minimum:g}, {parameter.maximum:g}]{unit}"
    return None


def validate_overrides(values: dict) -> dict:
    """Check initial parameter values given in the settings (name -> value); ``ValueError`` says what is wrong."""
    out = {}
    for name, value in values.items():
        parameter = BY_NAME.get(str(name).upper())
        if parameter is None:
            known = ", ".join(p.name for p in PARAMETERS)
            raise ValueError(f"unknown parameter '{name}'; the simulated vehicle has: {known}")
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"parameter {parameter.name}: {value!r} is not a number")
        problem = check_value(parameter, value)
        if problem is not None:
            raise ValueError(problem)
        out[parameter.name] = int(value) if parameter.kind == INT32 else float(value)
    return out


class ParameterStore:
    """The vehicle's parameters over ``settings`` (a :class:`~.settings.SimSettings`: a private, mutable copy the
    simulation reads; typed as its base, since that module imports this one's table)."""

    def __init__(self, settings: BaseModel, on_change: Callable[[Parameter, float | int], None] | None = None):
        self.settings = settings
        self.on_change = on_change or (lambda parameter, value: None)
        for name, value in settings.params.items():
            _set(settings, BY_NAME[name].setting, value)
        #: values set since start (name -> value), for tests and the log
        self.changes: list[tuple[str, float | int]] = []

    def value(self, name: str) -> float | int:
        parameter = BY_NAME[name]
        value = _get(self.settings, parameter.setting)
        return int(value) if parameter.kind == INT32 else float(value)

    def message(self, parameter: Parameter):
        index = PARAMETERS.index(parameter)
        return mavlink.MAVLink_param_value_message(
            parameter.name.encode(),
            to_wire(parameter.kind, self.value(parameter.name)),
            parameter.kind,
            len(PARAMETERS),
            index,
        )

    def set(self, name: str, value: float | int) -> str | None:
        """Set a parameter; the reason when refused."""
        parameter = BY_NAME.get(name)
        if parameter is None:
            return f"unknown parameter {name}"
        problem = check_value(parameter, value)
        if problem is not None:
            return problem
        value = int(value) if parameter.kind == INT32 else float(value)
        _set(self.settings, parameter.setting, value)
        self.changes.append((name, value))
        self.on_change(parameter, value)
        return None

    def handle(self, message) -> tuple[list, str | None]:
        """The answer to a PARAM_* message, and a refusal to announce (STATUSTEXT), if any."""
        kind = message.get_type()
        if kind == "PARAM_REQUEST_LIST":
            return [self.message(p) for p in PARAMETERS], None
        name = message.param_id
        name = (name.decode("ascii", "replace") if isinstance(name, bytes) else str(name)).rstrip("\x00")
        if kind == "PARAM_REQUEST_READ":
            index = int(message.param_index)
            if index >= 0:
                return ([self.message(PARAMETERS[index])] if index < len(PARAMETERS) else []), None
            parameter = BY_NAME.get(name)
            return ([self.message(parameter)] if parameter is not None else []), None
        if kind == "PARAM_SET":
            parameter = BY_NAME.get(name)
            if parameter is None:
                return [], f"unknown parameter: {name}"
            if int(message.param_type) != parameter.kind:
                wrong = f"MAV_PARAM_TYPE {int(message.param_type)}"
                return [self.message(parameter)], f"{name} is {parameter.type_name}, not {wrong}"
            problem = self.set(name, from_wire(parameter.kind, message.param_value))
            return [self.message(parameter)], problem
        return [], None
