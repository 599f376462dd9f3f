"""The MAVLink mission protocol's upload, both sides, as state machines without I/O.

mavlink.io, "Mission Protocol", *Upload a Mission to the Vehicle*: the ground
station sends MISSION_COUNT; the vehicle requests every item with
MISSION_REQUEST_INT (seq 0, 1, ...), the ground station answers each request
with MISSION_ITEM_INT; after the last item the vehicle sends MISSION_ACK
(MAV_MISSION_ACCEPTED, or an error code at any point, which cancels the
transfer). Every message that expects an answer has a timeout after which it
is sent again (the spec recommends 1500 ms, 250 ms for the vehicle waiting
on items, and at most 5 retries); an item that arrives out of sequence is
dropped and the expected one requested again.

:class:`MissionUpload` is the ground station's side, :class:`MissionReceiver`
the vehicle's. Both are fed messages and the time (``on_message``,
``on_timer``) and return the messages to send; the caller owns the link and
the clock, so the same logic runs over UDP, a serial radio, or in a unit test.

Robustness beyond the happy path, on purpose:

* the ground station answers *any* request in range, in any order and as
  often as asked (a vehicle that re-requests because an item was lost, or
  that requests out of order); a request out of range is ignored;
* MISSION_REQUEST (deprecated, float) is answered with MISSION_ITEM_INT, as
  the spec asks;
* a MISSION_ACK(ACCEPTED) that arrives before every item was requested is a
  stray acknowledgement (e.g. a repeated one from a previous transfer) and
  is ignored;
* the vehicle re-sends its ACCEPTED when the last item arrives again (its
  first acknowledgement was lost), and cancels with
  MAV_MISSION_OPERATION_CANCELLED when items arrive while it is idle or when
  it gives up waiting, so that the ground station learns at once.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from .link import enum_description, enum_name, mavlink

MISSION = mavlink.MAV_MISSION_TYPE_MISSION
ACCEPTED = mavlink.MAV_MISSION_ACCEPTED

#: frames whose x, y are latitude/longitude in degrees * 1e7 in MISSION_ITEM_INT
GLOBAL_INT_FRAMES = {
    mavlink.MAV_FRAME_GLOBAL_INT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
}
#: frames whose x, y are metres * 1e4 in MISSION_ITEM_INT
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


def _scale(frame: int) -> float:
    if frame in GLOBAL_INT_FRAMES:
        return 1e7
    if frame in LOCAL_FRAMES:
        return 1e4
    return 1.0  # global non-INT frames and MAV_FRAME_MISSION: sent as they are


def result_text(result: int) -> str:
    """``MAV_MISSION_NO_SPACE (4): Mission items exceed storage space``."""
    description = enum_description("MAV_MISSION_RESULT", result)
    text = f"{enum_name('MAV_MISSION_RESULT', result)} ({int(result)})"
    return f"{text}: {description}" if description else text


@dataclass(frozen=True)
class MissionItem:
    """One mission item (a MAV_CMD with its parameters); x, y, z in the frame's units (m or deg)."""

    command: int
    frame: int = mavlink.MAV_FRAME_LOCAL_NED
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    autocontinue: bool = True

    def encode(self, seq: int, target_system: int, target_component: int, mission_type: int = MISSION):
        """As a MISSION_ITEM_INT (local frames: m * 1e4, global ``_INT`` frames: deg * 1e7)."""
        k = _scale(self.frame)
        return mavlink.MAVLink_mission_item_int_message(
            target_system,
            target_component,
            seq,
            self.frame,
            self.command,
            0,
            int(self.autocontinue),
            self.param1,
            self.param2,
            self.param3,
            self.param4,
            round(self.x * k),
            round(self.y * k),
            float(self.z),
            mission_type,
        )

    @classmethod
    def decode(cls, message) -> MissionItem:
        """From a MISSION_ITEM_INT or (deprecated) MISSION_ITEM."""
        k = _scale(message.frame) if message.get_type() == "MISSION_ITEM_INT" else 1.0
        return cls(
            int(message.command),
            int(message.frame),
            message.x / k,
            message.y / k,
            float(message.z),
            float(message.param1),
            float(message.param2),
            float(message.param3),
            float(message.param4),
            bool(message.autocontinue),
        )

    def same_as(self, other: MissionItem) -> bool:
        """Equal after the MISSION_ITEM_INT quantisation (NaN equals NaN: NaN means 'default')."""
        k = _scale(self.frame)
        mine = (self.command, self.frame, round(self.x * k), round(self.y * k), self.autocontinue)
        theirs = (other.command, other.frame, round(other.x * k), round(other.y * k), other.autocontinue)
        floats = np.array([self.z, self.param1, self.param2, self.param3, self.param4], np.float32)
        others = np.array([other.z, other.param1, other.param2, other.param3, other.param4], np.float32)
        return mine == theirs and bool(np.all((floats == others) | (np.isnan(floats) & np.isnan(others))))


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


class MissionUpload:
    """Ground-station side of a mission upload.

    ``timeout`` (s) is how long to wait for the vehicle's next message before
    sending the last message again; after ``retries`` such resends the upload
    fails. ``state`` is ``idle``, ``sending``, ``done`` or ``failed`` (then
    :attr:`error` says why, and :attr:`result` holds the vehicle's
    MAV_MISSION_RESULT when it refused).
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
    ) -> None:
        self.items = list(items)
        self.target = (target_system, target_component)
        self.timeout = float(timeout)
        self.retries = int(retries)
        self.mission_type = mission_type
        self.state = "idle"
        self.error = ""
        self.result: int | None = None
        self.stats = UploadStatistics()
        self.requested: set[int] = set()
        self.deadline = math.inf
        self._last = None
        self._waiting_for = ""
        self._attempts = 0
        self._highest = -1

    @property
    def count(self) -> int:
        return len(self.items)

    @property
    def finished(self) -> bool:
        return self.state in ("done", "failed")

    def start(self, now: float) -> list:
        self.state = "sending"
        count = mavlink.MAVLink_mission_count_message(*self.target, self.count, self.mission_type)
        return self._send(count, now, "an answer to MISSION_COUNT")

    def _send(self, message, now: float, waiting_for: str) -> list:
        self._last = message
        self._waiting_for = waiting_for
        self._attempts = 0
        self.deadline = now + self.timeout
        return [message]

    def on_message(self, message, now: float) -> list:
        if self.state != "sending":
            return []
        kind = message.get_type()
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            if getattr(message, "mission_type", MISSION) != self.mission_type:
                return []
            return self._on_request(int(message.seq), now)
        if kind == "MISSION_ACK" and getattr(message, "mission_type", MISSION) == self.mission_type:
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
        item = self.items[seq].encode(seq, *self.target, self.mission_type)
        after = "MISSION_ACK" if len(self.requested) == self.count else f"the next MISSION_REQUEST_INT after item {seq}"
        return self._send(item, now, after)

    def _on_ack(self, result: int) -> list:
        if result == ACCEPTED:
            if len(self.requested) < self.count:
                self.stats.stray_acks += 1
                return []
            self.state = "done"
            self.deadline = math.inf
            return []
        self.state = "failed"
        self.result = result
        self.deadline = math.inf
        self.error = f"the vehicle rejected the mission: {result_text(result)}"
        return []

    def on_timer(self, now: float) -> list:
        if self.state != "sending" or now < self.deadline:
            return []
        if self._attempts >= self.retries:
            self.state = "failed"
            self.deadline = math.inf
            self.error = (
                f"the vehicle stopped answering: waited for {self._waiting_for} through {self._attempts + 1} "
                f"attempts, {self.timeout:g} s apart; {len(self.requested)} of {self.count} items had been requested"
            )
            return []
        self._attempts += 1
        self.stats.retransmissions += 1
        self.deadline = now + self.timeout
        return [self._last]


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
    items: dict[int, MissionItem] = field(default_factory=dict)
    position: int = 0
    attempts: int = 0
    deadline: float = math.inf
    #: a seq to request again before moving on (a deliberately repeated request)
    repeat: int | None = None

    @property
    def expected(self) -> int:
        return self.repeat if self.repeat is not None else self.order[self.position]


class MissionReceiver:
    """Vehicle side of a mission upload.

    ``validate(item, seq)`` returns None for an acceptable item or the
    MAV_MISSION_RESULT to refuse it with. ``on_accept(items)`` is called with
    the complete mission once it is accepted (the previous mission stays in
    force until then).
    """

    def __init__(
        self,
        system_id: int,
        component_id: int,
        *,
        capacity: int = 1000,
        timeout: float = 0.25,
        retries: int = 10,
        validate: Callable[[MissionItem, int], int | None] | None = None,
        on_accept: Callable[[list[MissionItem]], None] | None = None,
        faults: ReceiverFaults | None = None,
    ) -> None:
        self.ids = (system_id, component_id)
        self.capacity = capacity
        self.timeout = timeout
        self.retries = retries
        self.validate = validate or (lambda item, seq: None)
        self.on_accept = on_accept or (lambda items: None)
        self.faults = faults or ReceiverFaults()
        self.stats = ReceiverStatistics()
        self.transfer: _Transfer | None = None
        self.mission: list[MissionItem] = []
        #: the last accepted transfer's source and final item, to re-acknowledge a repeated last item
        self._last_accepted: tuple[tuple[int, int], int, MissionItem] | None = None
        self._rng = np.random.default_rng(self.faults.seed)

    @property
    def busy(self) -> bool:
        return self.transfer is not None

    def _ack(self, source: tuple[int, int], result: int):
        return mavlink.MAVLink_mission_ack_message(source[0], source[1], result, MISSION)

    def _request(self, transfer: _Transfer, now: float) -> list:
        transfer.deadline = now + self.timeout
        seq = transfer.expected
        return [mavlink.MAVLink_mission_request_int_message(*transfer.source, seq, MISSION)]

    def on_message(self, message, source: tuple[int, int], now: float) -> list:
        kind = message.get_type()
        if getattr(message, "mission_type", MISSION) != MISSION:
            return [self._ack(source, mavlink.MAV_MISSION_UNSUPPORTED)] if kind == "MISSION_COUNT" else []
        if kind == "MISSION_COUNT":
            return self._on_count(int(message.count), source, now)
        if kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            return self._on_item(int(message.seq), MissionItem.decode(message), source, now)
        return []

    def _on_count(self, count: int, source: tuple[int, int], now: float) -> list:
        self.stats.transfers += 1
        self.transfer = None
        if self.faults.reject is not None and self.faults.reject_at_item is None:
            return [self._ack(source, self.faults.reject)]
        if count > self.capacity:
            return [self._ack(source, mavlink.MAV_MISSION_NO_SPACE)]
        if count == 0:  # an empty upload clears the mission (spec)
            self._accept(source, [], None)
            return [self._ack(source, ACCEPTED)]
        order = list(self._rng.permutation(count)) if self.faults.shuffle else list(range(count))
        self.transfer = _Transfer(source, count, [int(i) for i in order])
        return self._request(self.transfer, now)

    def _on_item(self, seq: int, item: MissionItem, source: tuple[int, int], now: float) -> list:
        transfer = self.transfer
        if transfer is None or transfer.source != source:
            last = self._last_accepted
            if last is not None and last[0] == source and seq == last[1] and item.same_as(last[2]):
                return [self._ack(source, ACCEPTED)]  # our ACCEPTED was lost; say it again
            return [self._ack(source, mavlink.MAV_MISSION_OPERATION_CANCELLED)]
        if seq != transfer.expected:
            if seq in transfer.items:
                self.stats.duplicates += 1  # a late copy of an item we have: nothing to do
                return []
            self.stats.out_of_sequence += 1
            self.stats.rerequests += 1
            return self._request(transfer, now)  # spec: drop it, request the expected one again
        if self.faults.reject is not None and self.faults.reject_at_item == seq:
            self.transfer = None
            return [self._ack(source, self.faults.reject)]
        refusal = self.validate(item, seq)
        if refusal is not None:
            self.transfer = None
            return [self._ack(source, refusal)]
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
            self._accept(source, items, (transfer.count - 1, items[-1]))
            return [self._ack(source, ACCEPTED)]
        return self._request(transfer, now)

    def _accept(self, source, items: list[MissionItem], last) -> None:
        self.mission = items
        self.stats.accepted += 1
        self._last_accepted = (source, *last) if last is not None else None
        self.on_accept(items)

    def on_timer(self, now: float) -> list:
        transfer = self.transfer
        if transfer is None or now < transfer.deadline:
            return []
        if transfer.attempts >= self.retries:
            self.stats.timeouts += 1
            self.transfer = None
            return [self._ack(transfer.source, mavlink.MAV_MISSION_OPERATION_CANCELLED)]
        transfer.attempts += 1
        self.stats.rerequests += 1
        return self._request(transfer, now)

    @property
    def deadline(self) -> float:
        return self.transfer.deadline if self.transfer is not None else math.inf
