"""The ground station's side of the MAVLink mission protocol (:mod:`.mission`), as state machines without I/O.

:class:`MissionUpload`, :class:`MissionDownload` and :class:`MissionClear`
are fed the vehicle's messages and the time (``on_message``, ``on_timer``)
and return the messages to send; each sends its last message again after a
timeout, up to its retries (:class:`_Exchange`).

Bounded in count and in time: each wait by its timeout and retries, and each
whole transfer by the time those allow once for every message (an upload of
N items: timeout x (retries + 1) x (N + 1); a download likewise, with the
item timeout for its items), so that a vehicle that keeps asking for the same
item cannot hold the ground station for ever.

Robustness beyond the happy path, on purpose:

* the ground station answers *any* request in range, in any order and as
  often as asked (a vehicle that re-requests because an item was lost, or
  that requests out of order); a request out of range is ignored;
* MISSION_REQUEST (deprecated, float) is answered with MISSION_ITEM_INT, as
  the spec asks (or with MISSION_ITEM when the vehicle does not support
  MISSION_ITEM_INT: ``legacy``);
* a MISSION_ACK(ACCEPTED) that arrives before every item was requested is a
  stray acknowledgement (e.g. a repeated one from a previous transfer) and
  is ignored.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from .link import mavlink
from .mission import ACCEPTED, MISSION, MissionItem, result_text, type_name


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
        #: when the whole transfer is given up (wall s), whatever the vehicle keeps asking: see _limit
        self.give_up_at = math.inf
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

    _started = 0.0

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

    def _limit(self, now: float, seconds: float) -> None:
        """Give the whole transfer ``seconds`` from ``now``: every message's timeout and retries, once each.

        Each timeout bounds one wait, but a vehicle that keeps asking (the same item, for ever) would
        restart it for ever; this bounds the transfer in time as the retries bound it in count."""
        self.give_up_at = now + seconds + self.timeout  # one more wait: each message's own retries end first

    def on_timer(self, now: float) -> list:
        if self.state == "sending" and now >= self.give_up_at:
            progress = self._progress()
            return self._finish(
                "failed",
                f"the transfer did not finish within {self.give_up_at - self._started:g} s, the time its "
                f"timeouts and retries allow" + (f"; {progress}" if progress else ""),
            )
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
        self._started = now
        self._limit(now, self.timeout * (self.retries + 1) * (self.count + 1))
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
        self._started = now
        self._limit(now, self.timeout * (self.retries + 1))
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
            items = self.item_timeout * (self._retries_now() + 1) * self.count
            self._limit(self._started, self.timeout * (self.retries + 1) + items)
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
        self._started = now
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
