"""The MAVLink mission protocol's vocabulary: mission items, their frames and wire coordinates, comparison.

mavlink.io, "Mission Protocol". *Upload*: the ground station sends
MISSION_COUNT; the vehicle requests every item with MISSION_REQUEST_INT (seq
0, 1, ...), the ground station answers each request with MISSION_ITEM_INT;
after the last item the vehicle sends MISSION_ACK (MAV_MISSION_ACCEPTED, or
an error code at any point, which cancels the transfer). *Download*: the
ground station sends MISSION_REQUEST_LIST, the vehicle answers MISSION_COUNT,
the ground station requests each item and ends with MISSION_ACK. *Clear*:
MISSION_CLEAR_ALL, answered by MISSION_ACK. Every message has a mission type
(mission, geofence, rally points; MAV_MISSION_TYPE_ALL for a clear). Every
message that expects an answer has a timeout after which it is sent again
(the spec recommends 1500 ms, 250 ms for the vehicle waiting on items, and
at most 5 retries); an item that arrives out of sequence is dropped and the
expected one requested again.

Coordinates (mavlink.io "MISSION_ITEM_INT"): in MISSION_ITEM_INT, x and y are
latitude/longitude in degrees * 1e7 for *every* global frame (MAV_FRAME_GLOBAL
(0) and MAV_FRAME_GLOBAL_RELATIVE_ALT (3), the current ones, as much as their
deprecated ``_INT`` twins 5 and 6) and metres * 1e4 for local frames; in the
deprecated MISSION_ITEM they are plain floats. The scale follows the
*message*, not the frame's name.

This module holds what both sides share: :class:`MissionItem` (encoded and
decoded either way), the mission types and frames, and the comparison of a
mission sent with the one downloaded back (:func:`compare_missions`). The
transfers are state machines without I/O, the ground station's side in
:mod:`.mission_gcs` (:class:`~.mission_gcs.MissionUpload`,
:class:`~.mission_gcs.MissionDownload` and :class:`~.mission_gcs.MissionClear`),
the vehicle's in :mod:`.mission_vehicle` (:class:`~.mission_vehicle.MissionReceiver`
for uploads, :class:`~.mission_vehicle.MissionSender` for downloads). All are
fed messages and the time (``on_message``, ``on_timer``) and return the
messages to send; the caller owns the link and the clock, so the same logic
runs over UDP, a serial radio, or in a unit test.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .link import enum_description, enum_name, mavlink

MISSION = mavlink.MAV_MISSION_TYPE_MISSION
ACCEPTED = mavlink.MAV_MISSION_ACCEPTED

FENCE = mavlink.MAV_MISSION_TYPE_FENCE
RALLY = mavlink.MAV_MISSION_TYPE_RALLY
ALL_TYPES = mavlink.MAV_MISSION_TYPE_ALL

#: frames whose x, y are latitude/longitude: degrees * 1e7 in MISSION_ITEM_INT, degrees in MISSION_ITEM
GLOBAL_FRAMES = {
    mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
    mavlink.MAV_FRAME_GLOBAL_INT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
}
#: the deprecated ``_INT`` frames (2024) -> the current frame they mean
CURRENT_FRAME = {
    mavlink.MAV_FRAME_GLOBAL_INT: mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT: mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
}
#: frames whose x, y are metres: * 1e4 in MISSION_ITEM_INT
LOCAL_FRAMES = {
    mavlink.MAV_FRAME_LOCAL_NED,
    mavlink.MAV_FRAME_LOCAL_ENU,
    mavlink.MAV_FRAME_LOCAL_OFFSET_NED,
    mavlink.MAV_FRAME_BODY_NED,
    mavlink.MAV_FRAME_BODY_OFFSET_NED,
    mavlink.MAV_FRAME_BODY_FRD,
    mavlink.MAV_FRAME_LOCAL_FRD,
    mavlink.MAV_FRAME_LOCAL_FLU,
}


def int_scale(frame: int) -> float:
    """What x and y are multiplied by in MISSION_ITEM_INT: 1e7 (global), 1e4 (local), 1 (MAV_FRAME_MISSION)."""
    if frame in GLOBAL_FRAMES:
        return 1e7
    if frame in LOCAL_FRAMES:
        return 1e4
    return 1.0  # MAV_FRAME_MISSION: x, y are plain parameters (integers on the wire)


def current_frame(frame: int) -> int:
    """The current frame a deprecated ``_INT`` frame stands for (the frame itself otherwise)."""
    return CURRENT_FRAME.get(int(frame), int(frame))


def type_name(mission_type: int) -> str:
    return enum_name("MAV_MISSION_TYPE", mission_type)


#: per command, the parameters (1-4) a vehicle keeps and sends back on download (PX4's mission storage
#: keeps only these for position items; a MAV_FRAME_MISSION item keeps all four); yaw (param4) modulo 360
KEPT_PARAMS = {
    mavlink.MAV_CMD_NAV_WAYPOINT: (1, 2, 4),
    mavlink.MAV_CMD_NAV_TAKEOFF: (4,),
    mavlink.MAV_CMD_NAV_LAND: (2, 4),
    mavlink.MAV_CMD_NAV_LOITER_UNLIM: (3, 4),
    mavlink.MAV_CMD_NAV_LOITER_TIME: (1, 3),
    mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION: (1,),
    mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION: (1,),
    mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION: (1,),
    mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION: (1,),
    mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT: (),
    mavlink.MAV_CMD_NAV_RALLY_POINT: (),
}
#: commands whose param4 is a yaw angle (deg): compared modulo 360
YAW_PARAM4 = {
    mavlink.MAV_CMD_NAV_WAYPOINT,
    mavlink.MAV_CMD_NAV_TAKEOFF,
    mavlink.MAV_CMD_NAV_LAND,
    mavlink.MAV_CMD_NAV_LOITER_UNLIM,
}


def result_text(result: int) -> str:
    """``MAV_MISSION_NO_SPACE (4): Mission items exceed storage space``."""
    description = enum_description("MAV_MISSION_RESULT", result)
    text = f"{enum_name('MAV_MISSION_RESULT', result)} ({int(result)})"
    return f"{text}: {description}" if description else text


@dataclass(frozen=True)
class MissionItem:
    """One mission item (a MAV_CMD with its parameters); x, y, z in the frame's units (m or deg)."""

    command: int
    frame: int = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    autocontinue: bool = True

    def encode(
        self,
        seq: int,
        target_system: int,
        target_component: int,
        mission_type: int = MISSION,
        *,
        legacy: bool = False,
        current: bool = False,
    ):
        """As a MISSION_ITEM_INT (global frames: deg * 1e7, local frames: m * 1e4) or, ``legacy``, as the
        deprecated MISSION_ITEM (floats)."""
        fields = (self.param1, self.param2, self.param3, self.param4)
        if legacy:
            return mavlink.MAVLink_mission_item_message(
                target_system, target_component, seq, self.frame, self.command, int(current),
                int(self.autocontinue), *fields, float(self.x), float(self.y), float(self.z), mission_type,
            )  # fmt: skip
        k = int_scale(self.frame)
        return mavlink.MAVLink_mission_item_int_message(
            target_system, target_component, seq, self.frame, self.command, int(current), int(self.autocontinue),
            *fields, _to_int(self.x, k), _to_int(self.y, k), float(self.z), mission_type,
        )  # fmt: skip

    @classmethod
    def decode(cls, message) -> MissionItem:
        """From a MISSION_ITEM_INT (scaled by the frame's class) or a deprecated MISSION_ITEM (floats)."""
        if message.get_type() == "MISSION_ITEM_INT":
            k = int_scale(message.frame)
            x, y = _from_int(message.x, k), _from_int(message.y, k)
        else:
            x, y = float(message.x), float(message.y)
        return cls(
            int(message.command),
            int(message.frame),
            x,
            y,
            float(message.z),
            float(message.param1),
            float(message.param2),
            float(message.param3),
            float(message.param4),
            bool(message.autocontinue),
        )

    @property
    def params(self) -> tuple[float, float, float, float]:
        return (self.param1, self.param2, self.param3, self.param4)

    def same_as(self, other: MissionItem) -> bool:
        """Equal after the MISSION_ITEM_INT quantisation (NaN equals NaN: NaN means 'default')."""
        k = int_scale(self.frame)
        mine = (self.command, self.frame, _to_int(self.x, k), _to_int(self.y, k), self.autocontinue)
        theirs = (other.command, other.frame, _to_int(other.x, k), _to_int(other.y, k), other.autocontinue)
        floats = np.array([self.z, *self.params], np.float32)
        others = np.array([other.z, *other.params], np.float32)
        return mine == theirs and bool(np.all((floats == others) | (np.isnan(floats) & np.isnan(others))))

    def difference(self, other: MissionItem, legacy: bool = False) -> str | None:
        """What differs between the item sent (self) and the one a vehicle sent back on download, or None.

        Compared as a vehicle keeps them: the deprecated ``_INT`` frames as the current frame they stand
        for (PX4 answers a MISSION_REQUEST_INT with frame 6 for an item uploaded in frame 3), positions
        after the MISSION_ITEM_INT quantisation, altitudes and parameters as float32 (NaN equals NaN);
        of a position item's parameters only those the vehicle keeps (:data:`KEPT_PARAMS`), yaw modulo
        360 degrees.
        """
        if self.command != other.command:
            return f"command {enum_name('MAV_CMD', self.command)} came back as {enum_name('MAV_CMD', other.command)}"
        if current_frame(self.frame) != current_frame(other.frame):
            return f"frame {enum_name('MAV_FRAME', self.frame)} came back as {enum_name('MAV_FRAME', other.frame)}"
        if bool(self.autocontinue) != bool(other.autocontinue):
            return f"autocontinue {int(self.autocontinue)} came back as {int(other.autocontinue)}"
        k = int_scale(self.frame)
        for name, a, b in (("x", self.x, other.x), ("y", self.y, other.y)):
            same = _same_float(a, b) if legacy else _to_int(a, k) == _to_int(b, k)  # legacy: float32 on the wire
            if not same:
                return f"{name} {a!r} came back as {b!r}"
        if not _same_float(self.z, other.z):
            return f"z {self.z!r} came back as {other.z!r}"
        kept = KEPT_PARAMS.get(self.command, (1, 2, 3, 4)) if self.frame != mavlink.MAV_FRAME_MISSION else (1, 2, 3, 4)
        for i in kept:
            a, b = self.params[i - 1], other.params[i - 1]
            if i == 4 and self.command in YAW_PARAM4 and math.isfinite(a) and math.isfinite(b):
                if abs((a - b + 180.0) % 360.0 - 180.0) < 1e-3:  # a vehicle may keep it in radians
                    continue
            if not _same_float(a, b):
                return f"param{i} {a!r} came back as {b!r}"
        return None


#: MISSION_ITEM_INT's "unused" x or y (the spec's stand-in for NaN: "use the current position")
INT_UNUSED = 2**31 - 1


def _to_int(value: float, scale: float) -> int:
    return INT_UNUSED if math.isnan(value) else round(value * scale)


def _from_int(value: int, scale: float) -> float:
    return math.nan if int(value) == INT_UNUSED else value / scale


def _same_float(a: float, b: float) -> bool:
    a32, b32 = np.float32(a), np.float32(b)
    return bool(a32 == b32 or (np.isnan(a32) and np.isnan(b32)))


def compare_missions(sent: Sequence[MissionItem], received: Sequence[MissionItem], legacy: bool = False) -> str | None:
    """The first difference between a mission sent and the one downloaded back, in words; None if equal.

    ``legacy``: both ways as MISSION_ITEM (positions compared as the float32 they travelled as)."""
    if len(sent) != len(received):
        return f"{len(sent)} items were uploaded, the vehicle holds {len(received)}"
    for seq, (a, b) in enumerate(zip(sent, received, strict=True)):
        why = a.difference(b, legacy)
        if why is not None:
            return f"item {seq} ({enum_name('MAV_CMD', a.command)}): {why}"
    return None
