"""What a ground station knows about its vehicle from the vehicle's messages (:class:`~.gcs.GroundStation` keeps it).

:class:`VehicleState` (heartbeat, mode, position, mission progress, capabilities), the
:class:`PositionSample` it records, and :func:`capability_names` for the AUTOPILOT_VERSION bits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from .link import mavlink


def capability_names(bits: int) -> list[str]:
    """MAV_PROTOCOL_CAPABILITY names of the bits set in ``bits``."""
    names = []
    for value, entry in sorted(mavlink.enums["MAV_PROTOCOL_CAPABILITY"].items()):
        if value and value & (value - 1) == 0 and bits & value and not entry.name.endswith("_ENUM_END"):
            names.append(entry.name.removeprefix("MAV_PROTOCOL_CAPABILITY_"))
    return names


@dataclass
class PositionSample:
    """One LOCAL_POSITION_NED: vehicle time (s), position (m) and velocity (m/s) in NED."""

    time: float
    position: tuple[float, float, float]
    velocity: tuple[float, float, float]


@dataclass
class VehicleState:
    """What the ground station knows about the vehicle, from its messages."""

    system_id: int = 0
    component_id: int = 0
    autopilot: int = 0
    vehicle_type: int = 0
    armed: bool = False
    mode: str = ""
    custom_mode: int = 0
    landed_state: int = mavlink.MAV_LANDED_STATE_UNDEFINED
    #: wall time (s, time.monotonic) of the last heartbeat
    last_heartbeat: float = -math.inf
    heartbeats: int = 0
    position: PositionSample | None = None
    mission_current: int = -1
    mission_state: int = 0
    #: (seq, vehicle time s) of every MISSION_ITEM_REACHED, in arrival order
    reached: list[tuple[int, float]] = field(default_factory=list)
    #: (seq, vehicle time s) whenever MISSION_CURRENT showed a new current item
    current_changes: list[tuple[int, float]] = field(default_factory=list)
    statustext: list[str] = field(default_factory=list)
    #: AUTOPILOT_VERSION.capabilities (None until read)
    capabilities: int | None = None
    #: (vehicle time s, messages lost, messages received) of the vehicle's stream, by its sequence numbers
    link: list[tuple[float, int, int]] = field(default_factory=list)
    #: SYS_STATUS's MAV_SYS_STATUS_GEOFENCE bits: (present, enabled, healthy); None before a SYS_STATUS
    fence: tuple[bool, bool, bool] | None = None
    #: (vehicle time s, what) of the vehicle's word on its geofence: STATUSTEXTs naming it, health lost
    fence_events: list[tuple[float, str]] = field(default_factory=list)

    @property
    def fence_breached(self) -> bool:
        """The vehicle says its geofence is breached (SYS_STATUS: present and enabled, not healthy)."""
        return self.fence is not None and self.fence[0] and self.fence[1] and not self.fence[2]

    @property
    def on_ground(self) -> bool:
        return self.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND

    @property
    def vehicle_time(self) -> float:
        return self.position.time if self.position is not None else 0.0

    def passed(self, seq: int) -> float:
        """Vehicle time (s) the mission got past item ``seq``: its MISSION_ITEM_REACHED, or (that message
        lost on a poor link) the first MISSION_CURRENT showing a later item; inf when neither came."""
        times = [t for s, t in self.reached if s == seq] + [t for s, t in self.current_changes if s > seq]
        return min(times, default=math.inf)
