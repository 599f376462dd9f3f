"""``mavlink_vehicle``: fly safe paths on a MAVLink 2 vehicle (PX4's conventions); simulated by default.

Paper 000 (Jain, Hong & Rozenblit, SpringSim-MSM 2019) ends (§5) by
proposing its safe planner for an autonomous quadrotor that must keep a
distance from obstacles except in critical regions. The ground-station side:

* :mod:`.link` — connections, MAVLink 2, signing, enum names;
* :mod:`.conventions` — PX4's modes and frames, the local/global projection;
* :mod:`.mission` — the mission protocol's items, frames and comparison;
  :mod:`.mission_gcs` and :mod:`.mission_vehicle` — its two sides as state
  machines without I/O (the vehicle's serves the simulator);
* :mod:`.gcs` — the ground station: heartbeats, commands, uploads;
  :mod:`.transactions` — its command and parameter protocols without I/O;
  :mod:`.vehicle_state` — what it knows of the vehicle;
* :mod:`.profile`, :mod:`.stream` — the timed offboard path and its stream;
* :mod:`.zones` — PX4's geofence zones and their items (both ends);
  :mod:`.scene_fence` — the scene's safety as a geofence; :mod:`.safety` —
  the fence and rally points uploaded and verified before the mission;
* :mod:`.flight` — the route, the flight and its watch (failsafes);
* :mod:`.report` — what was flown, re-measured against the scene;
* :mod:`.device` — the :class:`MavlinkVehicle` plugin, its :mod:`.settings`,
  and :mod:`.local_simulator`, which starts the simulated vehicle for it.

:mod:`.sim` is the simulated PX4-like vehicle (``surgiplan-sim-vehicle``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from surgiplan.hookspecs import PluginSpec, hookimpl
from surgiplan.lazy import lazy_exports

if TYPE_CHECKING:
    from .device import MavlinkVehicle, MavlinkVehicleSettings

__getattr__, __dir__ = lazy_exports(
    __name__,
    {"MavlinkVehicle": ".device", "MavlinkVehicleSettings": ".device"},
)

__all__ = ["MavlinkVehicle", "MavlinkVehicleSettings"]


@hookimpl
def surgiplan_register_devices():
    return [
        PluginSpec(
            "mavlink_vehicle",
            "surgiplan.plugins.devices.mavlink.device:MavlinkVehicle",
            "a MAVLink 2 vehicle (PX4) flying R3 paths by mission or offboard setpoints; simulated by default",
        )
    ]
