"""The MAVLink mission protocol, both sides, as state machines without I/O.

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

:class:`MissionUpload`, :class:`MissionDownload` and :class:`MissionClear` are
the ground station's side, :class:`MissionReceiver` (uploads) and
:class:`MissionSender` (downloads) the vehicle's. All are fed messages and the
time (``on_message``, ``on_timer``) and return the messages to send; the
caller owns the link and the clock, so the same logic runs over UDP, a serial
radio, or in a unit test.

Robustness beyond the happy path, on purpose:

* the ground station answers *any* request in range, in any order and as
  often as asked (a vehicle that re-requests because an item was lost, or
  that requests out of order); a request out of range is ignored;
* MISSION_REQUEST (deprecated, float) is answered with MISSION_ITEM_INT, as
  the spec asks (or with MISSION_ITEM when the vehicle does not support
  MISSION_ITEM_INT: ``legacy``);
* a MISSION_ACK(ACCEPTED) that arrives before every item was requested is a
  stray acknowledgement (e.g. a repeated one from a previous transfer) and
  is ignored;
* the vehicle re-sends its ACCEPTED when the last item arrives again (its
  first acknowledgement was lost), and cancels with
  MAV_MISSION_OPERATION_CANCELLED when items arrive while it is idle or when
  it gives up waiting, so that the ground station learns at once;
* a vehicle that receives the deprecated MISSION_ITEM requests the rest with
  MISSION_REQUEST, as PX4 does (it switches out of its "int mode").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

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


# ----------------------------------------------------------------------------- ground station


@dataclass
class UploadStatistics:
    """How an upload went: what was (re)sent and what the vehicle asked for."""

    requests: int = 0
    #: requests for an item that had been sent before (the vehicle did not get it, or asked twice)
    repeated_requests: int = 0
    #: requests for another item than the next one
    out_of_order_requests: int = 0
    #: requests with seq outside [0, count)
    invalid_requests: int = 0
    #: messages re-sent after our own timeout
    retransmissions: int = 0
    stray_acks: int = 0


class _Exchange:
    """A ground-station transaction that re-sends its last message after a timeout (retries).

    ``state``: ``idle``, ``sending`` (waiting for the vehicle), ``done`` or ``failed``.
    """

    def __init__(self, target: tuple[int, int], timeout: float, retries: int, mission_type: int) -> None:
        self.target = target
        self.timeout = float(timeout)
        self.retries = int(retries)
        self.mission_type = mission_type
        self.state = "idle"
        self.error = ""
        self.result: int | None = None
        self.deadline = math.inf
        self.retransmissions = 0
        self._last = None
        self._waiting_for = ""
        self._attempts = 0

    @property
    def finished(self) -> bool:
        return self.state in ("done", "failed")

    def _send(self, message, now: float, waiting_for: str) -> list:
        self._last = message
        self._waiting_for = waiting_for
        self._attempts = 0
        self.deadline = now + self.timeout
        return [message]

    def _finish(self, state: str, error: str = "", result: int | None = None) -> list:
        self.state = state
        self.error = error
        self.result = result
        self.deadline = math.inf
        return []

    def _progress(self) -> str:
        return ""

    def on_timer(self, now: float) -> list:
        if self.state != "sending" or now < self.deadline:
            return []
        if self._attempts >= self._retries_now():
            progress = self._progress()
            return self._finish(
                "failed",
                f"the vehicle stopped answering: waited for {self._waiting_for} through {self._attempts + 1} "
                f"attempts, {self._timeout_now():g} s apart" + (f"; {progress}" if progress else ""),
            )
        self._attempts += 1
        self.retransmissions += 1
        self.deadline = now + self._timeout_now()
        return [self._last]

    def _timeout_now(self) -> float:
        return self.timeout

    def _retries_now(self) -> int:
        return self.retries

    def _mine(self, message) -> bool:
        return int(getattr(message, "mission_type", MISSION)) == self.mission_type


class MissionUpload(_Exchange):
    """Ground-station side of a mission upload.

    ``timeout`` (s) is how long to wait for the vehicle's next message before
    sending the last message again; after ``retries`` such resends the upload
    fails. ``state`` is ``idle``, ``sending``, ``done`` or ``failed`` (then
    :attr:`error` says why, and :attr:`result` holds the vehicle's
    MAV_MISSION_RESULT when it refused). ``legacy``: answer with the
    deprecated MISSION_ITEM (for a vehicle without MAV_PROTOCOL_CAPABILITY_MISSION_INT).
    """

    def __init__(
        self,
        items: Sequence[MissionItem],
        target_system: int,
        target_component: int,
        *,
        timeout: float = 1.5,
        retries: int = 5,
        mission_type: int = MISSION,
        legacy: bool = False,
    ) -> None:
        super().__init__((target_system, target_component), timeout, retries, mission_type)
        self.legacy = legacy
        self.items = list(items)
        self.stats = UploadStatistics()
        self.requested: set[int] = set()
        self._highest = -1

    @property
    def count(self) -> int:
        return len(self.items)

    def start(self, now: float) -> list:
        self.state = "sending"
        count = mavlink.MAVLink_mission_count_message(*self.target, self.count, self.mission_type)
        return self._send(count, now, "an answer to MISSION_COUNT")

    def on_message(self, message, now: float) -> list:
        if self.state != "sending":
            return []
        kind = message.get_type()
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            if not self._mine(message):
                return []
            return self._on_request(int(message.seq), now)
        if kind == "MISSION_ACK" and self._mine(message):
            return self._on_ack(int(message.type))
        return []

    def _on_request(self, seq: int, now: float) -> list:
        stats = self.stats
        stats.requests += 1
        if not 0 <= seq < self.count:
            stats.invalid_requests += 1
            return []
        if seq in self.requested:
            stats.repeated_requests += 1
        if seq != self._highest + 1 and seq not in self.requested:
            stats.out_of_order_requests += 1
        self.requested.add(seq)
        self._highest = max(self._highest, seq)
        item = self.items[seq].encode(seq, *self.target, self.mission_type, legacy=self.legacy)
        after = "MISSION_ACK" if len(self.requested) == self.count else f"the next MISSION_REQUEST_INT after item {seq}"
        return self._send(item, now, after)

    def _on_ack(self, result: int) -> list:
        if result == ACCEPTED:
            if len(self.requested) < self.count:
                self.stats.stray_acks += 1
                return []
            return self._finish("done")
        what = "mission" if self.mission_type == MISSION else type_name(self.mission_type)
        return self._finish("failed", f"the vehicle rejected the {what}: {result_text(result)}", result)

    def _progress(self) -> str:
        return f"{len(self.requested)} of {self.count} items had been requested"

    def on_timer(self, now: float) -> list:
        resent = super().on_timer(now)
        self.stats.retransmissions += len(resent)
        return resent


class MissionDownload(_Exchange):
    """Ground-station side of a mission download (MISSION_REQUEST_LIST, COUNT, REQUEST_INT..., ACK).

    ``items`` holds the mission once ``state`` is ``done``; a vehicle's MISSION_ACK with an error
    fails it (``result``)."""

    def __init__(
        self,
        target_system: int,
        target_component: int,
        *,
        timeout: float = 1.5,
        retries: int = 5,
        mission_type: int = MISSION,
        legacy: bool = False,
        item_timeout: float | None = None,
    ) -> None:
        super().__init__((target_system, target_component), timeout, retries, mission_type)
        self.legacy = legacy
        #: how long to wait for each item before requesting it again (the vehicle answers at once)
        self.item_timeout = timeout if item_timeout is None else float(item_timeout)
        self.count: int | None = None
        self.received: dict[int, MissionItem] = {}
        #: the deprecated frames (5, 6) the vehicle used on download, counted (PX4 answers in them)
        self.frames: dict[int, int] = {}

    @property
    def items(self) -> list[MissionItem]:
        return [self.received[i] for i in range(self.count or 0)]

    def start(self, now: float) -> list:
        self.state = "sending"
        request = mavlink.MAVLink_mission_request_list_message(*self.target, self.mission_type)
        return self._send(request, now, "MISSION_COUNT")

    def _request(self, seq: int, now: float) -> list:
        kind = mavlink.MAVLink_mission_request_message if self.legacy else mavlink.MAVLink_mission_request_int_message
        request = kind(*self.target, seq, self.mission_type)
        sent = self._send(request, now, f"{'MISSION_ITEM' if self.legacy else 'MISSION_ITEM_INT'} {seq}")
        self.deadline = now + self.item_timeout
        return sent

    def _progress(self) -> str:
        return "" if self.count is None else f"{len(self.received)} of {self.count} items had arrived"

    def _timeout_now(self) -> float:
        return self.timeout if self.count is None else self.item_timeout

    def _retries_now(self) -> int:
        """Items are asked for more often than the list: as many times as fit the list's patience (timeout x
        (retries + 1)), so that a poor link gets as long for an item as for the MISSION_COUNT."""
        if self.count is None:
            return self.retries
        return max(self.retries, math.ceil(self.timeout * (self.retries + 1) / self.item_timeout) - 1)

    def on_message(self, message, now: float) -> list:
        if self.state != "sending" or not self._mine(message):
            return []
        kind = message.get_type()
        if kind == "MISSION_COUNT" and self.count is None:
            self.count = int(message.count)
            if self.count == 0:
                ack = mavlink.MAVLink_mission_ack_message(*self.target, ACCEPTED, self.mission_type)
                self._finish("done")
                return [ack]
            return self._request(0, now)
        if kind in ("MISSION_ITEM_INT", "MISSION_ITEM") and self.count is not None:
            seq = int(message.seq)
            expected = len(self.received)
            if seq != expected:
                return []  # a late duplicate or out of sequence: the timeout asks again for the expected one
            self.received[seq] = MissionItem.decode(message)
            self.frames[int(message.frame)] = self.frames.get(int(message.frame), 0) + 1
            if len(self.received) == self.count:
                ack = mavlink.MAVLink_mission_ack_message(*self.target, ACCEPTED, self.mission_type)
                self._finish("done")
                return [ack]
            return self._request(seq + 1, now)
        if kind == "MISSION_ACK" and int(message.type) != ACCEPTED:
            return self._finish(
                "failed", f"the vehicle refused the download: {result_text(int(message.type))}", int(message.type)
            )
        return []


class MissionClear(_Exchange):
    """Ground-station side of MISSION_CLEAR_ALL (one mission type, or MAV_MISSION_TYPE_ALL): waits for MISSION_ACK."""

    def __init__(
        self, target_system: int, target_component: int, *, timeout: float = 1.5, retries: int = 5, mission_type=MISSION
    ) -> None:
        super().__init__((target_system, target_component), timeout, retries, mission_type)

    def start(self, now: float) -> list:
        self.state = "sending"
        clear = mavlink.MAVLink_mission_clear_all_message(*self.target, self.mission_type)
        return self._send(clear, now, "MISSION_ACK")

    def on_message(self, message, now: float) -> list:
        if self.state != "sending" or message.get_type() != "MISSION_ACK" or not self._mine(message):
            return []
        if int(message.type) == ACCEPTED:
            return self._finish("done")
        return self._finish(
            "failed", f"the vehicle refused to clear: {result_text(int(message.type))}", int(message.type)
        )


# ----------------------------------------------------------------------------- vehicle


@dataclass
class ReceiverFaults:
    """Ways to make the vehicle's side harder on the ground station (tests and rehearsals)."""

    #: refuse every upload with this MAV_MISSION_RESULT ...
    reject: int | None = None
    #: ... when this item arrives (None: at MISSION_COUNT)
    reject_at_item: int | None = None
    #: request the items in a random order instead of 0, 1, 2, ...
    shuffle: bool = False
    #: probability of requesting an item again after receiving it
    repeat: float = 0.0
    seed: int | None = None


@dataclass
class ReceiverStatistics:
    transfers: int = 0
    accepted: int = 0
    rerequests: int = 0
    duplicates: int = 0
    out_of_sequence: int = 0
    timeouts: int = 0


@dataclass
class _Transfer:
    source: tuple[int, int]
    count: int
    order: list[int]
    mission_type: int = MISSION
    items: dict[int, MissionItem] = field(default_factory=dict)
    position: int = 0
    attempts: int = 0
    deadline: float = math.inf
    #: a seq to request again before moving on (a deliberately repeated request)
    repeat: int | None = None
    #: request with MISSION_REQUEST_INT (False once the ground station answered with a MISSION_ITEM)
    int_mode: bool = True

    @property
    def expected(self) -> int:
        return self.repeat if self.repeat is not None else self.order[self.position]


#: validate(item, seq, mission_type, int_form) -> None (acceptable) or the MAV_MISSION_RESULT to refuse it with
Validator = Callable[[MissionItem, int, int, bool], "int | None"]


class MissionReceiver:
    """Vehicle side of a mission upload, for the mission types in ``types`` (others: MAV_MISSION_UNSUPPORTED).

    ``validate(item, seq, mission_type, int_form)`` returns None for an
    acceptable item or the MAV_MISSION_RESULT to refuse it with (``int_form``:
    it came as MISSION_ITEM_INT). ``on_accept(items, mission_type)`` is called
    with the complete list once it is accepted (the previous one stays in
    force until then); :attr:`stored` holds the accepted list of each type.
    """

    def __init__(
        self,
        system_id: int,
        component_id: int,
        *,
        capacity: int | dict[int, int] = 1000,
        timeout: float = 0.25,
        retries: int = 10,
        validate: Validator | None = None,
        on_accept: Callable[[list[MissionItem], int], None] | None = None,
        faults: ReceiverFaults | None = None,
        types: Sequence[int] = (MISSION,),
        int_requests: bool = True,
    ) -> None:
        #: request items with MISSION_REQUEST_INT (False: MISSION_REQUEST, a vehicle without MISSION_INT)
        self.int_requests = int_requests
        self.ids = (system_id, component_id)
        self.capacity = capacity
        self.timeout = timeout
        self.retries = retries
        self.validate = validate or (lambda item, seq, mission_type, int_form: None)
        self.on_accept = on_accept or (lambda items, mission_type: None)
        self.faults = faults or ReceiverFaults()
        self.types = tuple(types)
        self.stats = ReceiverStatistics()
        self.transfer: _Transfer | None = None
        self.stored: dict[int, list[MissionItem]] = {t: [] for t in self.types}
        #: the last accepted transfer's source, type and final item, to re-acknowledge a repeated last item
        self._last_accepted: tuple[tuple[int, int], int, int, MissionItem] | None = None
        self._rng = np.random.default_rng(self.faults.seed)

    @property
    def mission(self) -> list[MissionItem]:
        return self.stored.get(MISSION, [])

    @property
    def busy(self) -> bool:
        return self.transfer is not None

    def _ack(self, source: tuple[int, int], result: int, mission_type: int = MISSION):
        return mavlink.MAVLink_mission_ack_message(source[0], source[1], result, mission_type)

    def _request(self, transfer: _Transfer, now: float) -> list:
        transfer.deadline = now + self.timeout
        seq = transfer.expected
        kind = (
            mavlink.MAVLink_mission_request_int_message
            if transfer.int_mode
            else mavlink.MAVLink_mission_request_message
        )
        return [kind(*transfer.source, seq, transfer.mission_type)]

    def on_message(self, message, source: tuple[int, int], now: float) -> list:
        kind = message.get_type()
        mission_type = int(getattr(message, "mission_type", MISSION))
        if kind == "MISSION_COUNT":
            if mission_type not in self.types:
                return [self._ack(source, mavlink.MAV_MISSION_UNSUPPORTED, mission_type)]
            return self._on_count(int(message.count), mission_type, source, now)
        if kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            if mission_type not in self.types:
                return [self._ack(source, mavlink.MAV_MISSION_UNSUPPORTED, mission_type)]
            int_form = kind == "MISSION_ITEM_INT"
            return self._on_item(int(message.seq), MissionItem.decode(message), mission_type, int_form, source, now)
        return []

    def _on_count(self, count: int, mission_type: int, source: tuple[int, int], now: float) -> list:
        self.stats.transfers += 1
        self.transfer = None
        if self.faults.reject is not None and self.faults.reject_at_item is None:
            return [self._ack(source, self.faults.reject, mission_type)]
        capacity = self.capacity.get(mission_type, 0) if isinstance(self.capacity, dict) else self.capacity
        if count > capacity:
            return [self._ack(source, mavlink.MAV_MISSION_NO_SPACE, mission_type)]
        if count == 0:  # an empty upload clears the list (spec)
            self._accept(source, [], mission_type, None)
            return [self._ack(source, ACCEPTED, mission_type)]
        order = list(self._rng.permutation(count)) if self.faults.shuffle else list(range(count))
        self.transfer = _Transfer(source, count, [int(i) for i in order], mission_type, int_mode=self.int_requests)
        return self._request(self.transfer, now)

    def _on_item(
        self, seq: int, item: MissionItem, mission_type: int, int_form: bool, source: tuple[int, int], now: float
    ) -> list:
        transfer = self.transfer
        if transfer is None or transfer.source != source or transfer.mission_type != mission_type:
            last = self._last_accepted
            if last is not None and last[:3] == (source, mission_type, seq) and item.same_as(last[3]):
                return [self._ack(source, ACCEPTED, mission_type)]  # our ACCEPTED was lost; say it again
            return [self._ack(source, mavlink.MAV_MISSION_OPERATION_CANCELLED, mission_type)]
        if not int_form:
            transfer.int_mode = False  # as PX4: a MISSION_ITEM switches the rest of the transfer to MISSION_REQUEST
        if seq != transfer.expected:
            if seq in transfer.items:
                self.stats.duplicates += 1  # a late copy of an item we have: nothing to do
                return []
            self.stats.out_of_sequence += 1
            self.stats.rerequests += 1
            return self._request(transfer, now)  # spec: drop it, request the expected one again
        if self.faults.reject is not None and self.faults.reject_at_item == seq:
            self.transfer = None
            return [self._ack(source, self.faults.reject, mission_type)]
        refusal = self.validate(item, seq, mission_type, int_form)
        if refusal is not None:
            self.transfer = None
            return [self._ack(source, refusal, mission_type)]
        transfer.items[seq] = item
        transfer.attempts = 0
        if transfer.repeat is not None:
            transfer.repeat = None
        elif self.faults.repeat > 0 and self._rng.random() < self.faults.repeat:
            transfer.repeat = seq
            transfer.position += 1
            self.stats.rerequests += 1
            return self._request(transfer, now)
        else:
            transfer.position += 1
        if transfer.position >= transfer.count and transfer.repeat is None:
            items = [transfer.items[i] for i in range(transfer.count)]
            self.transfer = None
            self._accept(source, items, mission_type, (transfer.count - 1, items[-1]))
            return [self._ack(source, ACCEPTED, mission_type)]
        return self._request(transfer, now)

    def _accept(self, source, items: list[MissionItem], mission_type: int, last) -> None:
        self.stored[mission_type] = items
        self.stats.accepted += 1
        self._last_accepted = (source, mission_type, *last) if last is not None else None
        self.on_accept(items, mission_type)

    def clear(self, mission_type: int) -> None:
        """Empty one list (MISSION_CLEAR_ALL; :data:`ALL_TYPES` empties every one)."""
        for t in self.types if mission_type == ALL_TYPES else (mission_type,):
            if t in self.stored:
                self.stored[t] = []
                self.on_accept([], t)

    def on_timer(self, now: float) -> list:
        transfer = self.transfer
        if transfer is None or now < transfer.deadline:
            return []
        if transfer.attempts >= self.retries:
            self.stats.timeouts += 1
            self.transfer = None
            return [self._ack(transfer.source, mavlink.MAV_MISSION_OPERATION_CANCELLED, transfer.mission_type)]
        transfer.attempts += 1
        self.stats.rerequests += 1
        return self._request(transfer, now)

    @property
    def deadline(self) -> float:
        return self.transfer.deadline if self.transfer is not None else math.inf


class MissionSender:
    """Vehicle side of a mission download, as PX4 answers it.

    MISSION_REQUEST_LIST is answered with MISSION_COUNT; each request for the
    next item (or the last one again) with that item, as MISSION_ITEM_INT
    for a MISSION_REQUEST_INT and as MISSION_ITEM for the deprecated
    MISSION_REQUEST; ``provide(seq, mission_type, int_form)`` gives the
    item as the vehicle stores it. A request out of sequence ends the
    transfer with MISSION_ACK(MAV_MISSION_ERROR); the ground station's final
    MISSION_ACK, or ``timeout`` s without a request, ends it.
    """

    def __init__(
        self,
        count: Callable[[int], int],
        provide: Callable[[int, int, bool], MissionItem],
        *,
        current: Callable[[], int] = lambda: -1,
        timeout: float = 5.0,
    ) -> None:
        self.count = count
        self.provide = provide
        self.current = current
        self.timeout = timeout
        self.partner: tuple[int, int] | None = None
        self.mission_type = MISSION
        self.next_seq = 0
        self.total = 0
        self.deadline = math.inf
        self.transfers = 0
        self.completed = 0

    @property
    def busy(self) -> bool:
        return self.partner is not None

    def on_message(self, message, source: tuple[int, int], now: float) -> list:
        kind = message.get_type()
        mission_type = int(getattr(message, "mission_type", MISSION))
        if kind == "MISSION_REQUEST_LIST":
            if self.busy and (source != self.partner or mission_type != self.mission_type):
                if self.next_seq < self.total:
                    return []  # PX4: "Mission download request ignored, already active"
            self.partner, self.mission_type = source, mission_type
            self.next_seq, self.total = 0, self.count(mission_type)
            self.deadline = now + self.timeout
            self.transfers += 1
            return [mavlink.MAVLink_mission_count_message(*source, self.total, mission_type)]
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            if not self.busy or source != self.partner or mission_type != self.mission_type:
                return []  # no transfer: ignored (PX4 does so silently)
            seq = int(message.seq)
            self.deadline = now + self.timeout
            if seq == self.next_seq and seq < self.total:
                self.next_seq += 1
            elif seq != self.next_seq - 1 or seq >= self.total:
                error = mavlink.MAVLink_mission_ack_message(*source, mavlink.MAV_MISSION_ERROR, mission_type)
                self.partner = None
                return [error]
            int_form = kind == "MISSION_REQUEST_INT"
            item = self.provide(seq, mission_type, int_form)
            return [item.encode(seq, *source, mission_type, legacy=not int_form, current=seq == self.current())]
        if kind == "MISSION_ACK" and self.busy and source == self.partner and mission_type == self.mission_type:
            if int(message.type) == ACCEPTED and self.next_seq >= self.total:
                self.completed += 1
            self.partner = None
            self.deadline = math.inf
        return []

    def on_timer(self, now: float) -> list:
        if self.busy and now >= self.deadline:
            self.partner = None
            self.deadline = math.inf
        return []
