"""The vehicle's side of the MAVLink mission protocol (:mod:`.mission`), as state machines without I/O.

:class:`MissionReceiver` takes uploads and :class:`MissionSender` answers
downloads, as PX4 does; both are fed the ground station's messages with
their source and the time (``on_message``, ``on_timer``) and return the
messages to send. :class:`ReceiverFaults` makes the receiver harder on a
ground station (tests and rehearsals).

Robustness beyond the happy path, on purpose:

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

from .link import mavlink
from .mission import ACCEPTED, ALL_TYPES, MISSION, MissionItem


@dataclass
class ReceiverFaults:
    """Ways to make the vehicle's side harder on the ground station (tests and rehearsals)."""

    #: refuse every upload with this MAV_MISSION_RESULT ...
    reject: int | None = None
    #: ... when this item arrives (None: at MISSION_COUNT)
    reject_at_item: int | None = None
    #: ... of the lists of this mission type (the mission, by default; fence and rally lists are accepted)
    reject_type: int = MISSION
    #: request the items in a random order instead of 0, 1, 2, ...
    shuffle: bool = False
    #: probability of requesting an item again after receiving it
    repeat: float = 0.0
    seed: int | None = None


def rejecting(faults: ReceiverFaults, mission_type: int) -> bool:
    """Whether the injected refusal applies to a list of this type."""
    return faults.reject is not None and mission_type == faults.reject_type


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
#: check(items, mission_type) -> None (acceptable) or the MAV_MISSION_RESULT to refuse the whole list with
ListCheck = Callable[[list[MissionItem], int], "int | None"]


class MissionReceiver:
    """Vehicle side of a mission upload, for the mission types in ``types`` (others: MAV_MISSION_UNSUPPORTED).

    ``validate(item, seq, mission_type, int_form)`` returns None for an
    acceptable item or the MAV_MISSION_RESULT to refuse it with (``int_form``:
    it came as MISSION_ITEM_INT); ``check(items, mission_type)`` judges the
    complete list before it is accepted (PX4's feasibility check: a mission
    that leaves the geofence), answered with its MAV_MISSION_RESULT in the
    final MISSION_ACK. ``on_accept(items, mission_type)`` is called
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
        check: ListCheck | None = None,
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
        self.check = check or (lambda items, mission_type: None)
        self.on_accept = on_accept or (lambda items, mission_type: None)
        self.faults = faults or ReceiverFaults()
        self.types = tuple(types)
        self.stats = ReceiverStatistics()
        self.transfer: _Transfer | None = None
        self.stored: dict[int, list[MissionItem]] = {t: [] for t in self.types}
        #: the last accepted transfer's source, type and final item, to re-acknowledge a repeated last item
        self._last_accepted: tuple[tuple[int, int], int, int, MissionItem] | None = None
        #: likewise the last list refused by ``check`` (with the MAV_MISSION_RESULT), to refuse it again
        self._last_refused: tuple[tuple[int, int], int, int, MissionItem, int] | None = None
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
        self._last_refused = None
        if rejecting(self.faults, mission_type) and self.faults.reject_at_item is None:
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
            refused = self._last_refused
            if refused is not None and refused[:3] == (source, mission_type, seq) and item.same_as(refused[3]):
                return [self._ack(source, refused[4], mission_type)]  # our refusal was lost; say it again
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
        if rejecting(self.faults, mission_type) and self.faults.reject_at_item == seq:
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
            refusal = self.check(items, mission_type)
            if refusal is not None:
                self._last_refused = (source, mission_type, transfer.count - 1, items[-1], refusal)
                return [self._ack(source, refusal, mission_type)]
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
            current = mission_type == MISSION and seq == self.current()  # fence and rally items are never current
            return [item.encode(seq, *source, mission_type, legacy=not int_form, current=current)]
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
