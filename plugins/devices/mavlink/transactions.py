"""The command and parameter protocols, ground-station side, as requests re-sent until answered, without I/O.

mavlink.io services:

* *Command protocol*: :class:`CommandTransaction` sends COMMAND_LONG, again
  with ``confirmation`` increased when no COMMAND_ACK arrives within the
  timeout (default 1.5 s, 5 retries); MAV_RESULT_IN_PROGRESS extends the wait.
* *Parameter protocol*: :class:`ParamTransaction` reads one parameter by name
  (PARAM_REQUEST_READ) or sets it (PARAM_SET) and waits for the vehicle's
  PARAM_VALUE, re-sent after each timeout; INT32 values are decoded bytewise
  when the vehicle says it encodes them so (PX4), by a C cast otherwise
  (:func:`param_to_wire`, :func:`param_from_wire`); :class:`ParamDownload`
  fetches them all (PARAM_REQUEST_LIST, then what a lossy link lost by index).

Both are fed the vehicle's messages and the time (``on_message``,
``on_timer``) and return the messages to send;
:class:`~.gcs.GroundStation` runs them on its link.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

import numpy as np

from .link import enum_description, enum_name, mavlink

RESULT_ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
RESULT_IN_PROGRESS = mavlink.MAV_RESULT_IN_PROGRESS


def command_name(command: int) -> str:
    return enum_name("MAV_CMD", command)


def result_name(result: int) -> str:
    text = enum_name("MAV_RESULT", result)
    description = enum_description("MAV_RESULT", result)
    return f"{text} ({description})" if description else text


class _RetriedRequest:
    """A request sent again every ``timeout`` until answered, at most ``retries`` more times, without I/O.

    Subclasses set ``timeout``, ``retries`` and ``result`` and build the request in ``_message``; the
    count of retransmissions so far is ``retransmissions`` (the command protocol's confirmation).
    """

    timeout: float
    retries: int
    result: object | None
    retransmissions = 0
    deadline = math.inf
    timed_out = False

    @property
    def finished(self) -> bool:
        return self.result is not None or self.timed_out

    def _message(self):
        raise NotImplementedError

    def start(self, now: float) -> list:
        self.deadline = now + self.timeout
        return [self._message()]

    def on_timer(self, now: float) -> list:
        if self.finished or now < self.deadline:
            return []
        if self.retransmissions >= self.retries:
            self.timed_out = True
            self.deadline = math.inf
            return []
        self.retransmissions += 1
        self.deadline = now + self.timeout
        return [self._message()]


class CommandTransaction(_RetriedRequest):
    """One command of the command protocol, ground-station side, without I/O."""

    def __init__(
        self,
        command: int,
        params: Sequence[float],
        target: tuple[int, int],
        *,
        timeout: float = 1.5,
        retries: int = 5,
        in_progress_timeout: float = 10.0,
    ) -> None:
        self.command = int(command)
        self.params = [float(p) for p in params] + [0.0] * (7 - len(params))
        self.target = target
        self.timeout = timeout
        self.retries = retries
        self.in_progress_timeout = in_progress_timeout
        self.result: int | None = None
        self.progress: int | None = None

    def _message(self):
        return mavlink.MAVLink_command_long_message(*self.target, self.command, self.retransmissions, *self.params)

    def on_message(self, message, now: float) -> list:
        if message.get_type() != "COMMAND_ACK" or int(message.command) != self.command or self.finished:
            return []
        if int(message.result) == RESULT_IN_PROGRESS:
            self.progress = int(getattr(message, "progress", 255))
            self.deadline = now + self.in_progress_timeout
            return []
        self.result = int(message.result)
        self.deadline = math.inf
        return []


def param_to_wire(kind: int, value: float | int, bytewise: bool) -> float:
    """The float that carries ``value`` in PARAM_SET: bytewise (PX4) or cast (C) for an INT32."""
    if kind == mavlink.MAV_PARAM_TYPE_INT32 and bytewise:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return float(value)


def param_from_wire(kind: int, carried: float, bytewise: bool) -> float | int:
    """The value a PARAM_VALUE carries."""
    if kind == mavlink.MAV_PARAM_TYPE_INT32:
        return struct.unpack("<i", struct.pack("<f", carried))[0] if bytewise else round(carried)
    return float(np.float32(carried))


def _param_name(message) -> str:
    name = message.param_id
    return (name.decode("ascii", "replace") if isinstance(name, bytes) else str(name)).rstrip("\x00")


class ParamTransaction(_RetriedRequest):
    """Read (``value`` None) or set one parameter, ground-station side, without I/O.

    Finished when a PARAM_VALUE of that name arrives (for a set: the value it
    now has, which is the old one when the vehicle refused); re-sent after
    each ``timeout`` up to ``retries`` times.
    """

    def __init__(
        self,
        name: str,
        target: tuple[int, int],
        *,
        value: float | int | None = None,
        kind: int = mavlink.MAV_PARAM_TYPE_REAL32,
        bytewise: bool = True,
        timeout: float = 1.5,
        retries: int = 5,
    ) -> None:
        self.name = name
        self.target = target
        self.value = value
        self.kind = kind
        self.bytewise = bytewise
        self.timeout = timeout
        self.retries = retries
        self.result: float | int | None = None
        self.result_kind: int | None = None

    def _message(self):
        if self.value is None:
            return mavlink.MAVLink_param_request_read_message(*self.target, self.name.encode(), -1)
        wire = param_to_wire(self.kind, self.value, self.bytewise)
        return mavlink.MAVLink_param_set_message(*self.target, self.name.encode(), wire, self.kind)

    def on_message(self, message, now: float) -> list:
        if self.finished or message.get_type() != "PARAM_VALUE" or _param_name(message) != self.name:
            return []
        self.result_kind = int(message.param_type)
        self.result = param_from_wire(self.result_kind, message.param_value, self.bytewise)
        self.deadline = math.inf
        return []


class ParamDownload:
    """Every parameter of the vehicle, ground-station side, without I/O (what MAVSDK's get_all_params and
    MAVProxy's ``param fetch`` do).

    PARAM_REQUEST_LIST, sent again after ``timeout`` until a PARAM_VALUE
    arrives (at most ``retries`` more times); the vehicle then streams every
    parameter with its ``param_index`` and ``param_count``. Once the stream
    pauses for ``item_timeout``, the indices that did not arrive (a lossy
    link) are requested by index (PARAM_REQUEST_READ), ``batch`` at a time,
    each at most ``item_retries`` times; bounded in count by those retries
    and in time by ``timeout`` x (retries + 1) plus ``item_timeout`` x
    (item_retries + 1) for each parameter.
    """

    def __init__(
        self,
        target: tuple[int, int],
        *,
        bytewise: bool = True,
        timeout: float = 1.5,
        retries: int = 5,
        item_timeout: float = 0.5,
        item_retries: int = 17,
        batch: int = 10,
    ) -> None:
        self.target = target
        self.bytewise = bytewise
        self.timeout = timeout
        self.retries = retries
        self.item_timeout = item_timeout
        self.item_retries = item_retries
        self.batch = batch
        self.count: int | None = None
        #: index -> (name, value, MAV_PARAM_TYPE)
        self.received: dict[int, tuple[str, float | int, int]] = {}
        self.deadline = math.inf
        self.give_up_at = math.inf
        self.error = ""
        self.failed = False
        #: messages sent: PARAM_REQUEST_LIST, and PARAM_REQUEST_READ by index
        self.list_requests = 0
        self.read_requests = 0
        self._asked: dict[int, int] = {}
        self._list_attempts = 0
        self._started = 0.0

    @property
    def finished(self) -> bool:
        return self.failed or (self.count is not None and len(self.received) >= self.count)

    @property
    def values(self) -> dict[str, tuple[float | int, int]]:
        return {name: (value, kind) for name, value, kind in (self.received[i] for i in sorted(self.received))}

    def _list(self):
        self.list_requests += 1
        return mavlink.MAVLink_param_request_list_message(*self.target)

    def start(self, now: float) -> list:
        self._started = now
        self.deadline = now + self.timeout
        self.give_up_at = now + self.timeout * (self.retries + 1)
        return [self._list()]

    def on_message(self, message, now: float) -> list:
        if self.finished or message.get_type() != "PARAM_VALUE":
            return []
        count, index = int(message.param_count), int(message.param_index)
        if self.count is None and count > 0:
            self.count = count
            self.give_up_at = self._started + self.timeout * (self.retries + 1)
            self.give_up_at += self.item_timeout * (self.item_retries + 1) * count
        if self.count is None or not 0 <= index < self.count:
            return []
        kind = int(message.param_type)
        self.received[index] = (_param_name(message), param_from_wire(kind, message.param_value, self.bytewise), kind)
        self.deadline = now + self.item_timeout  # the stream flows: wait for the rest before asking again
        return []

    def on_timer(self, now: float) -> list:
        if self.finished:
            return []
        if now >= self.give_up_at:
            return self._fail(f"the download did not finish within {self.give_up_at - self._started:.0f} s")
        if now < self.deadline:
            return []
        if self.count is None:
            if self._list_attempts >= self.retries:
                return self._fail(f"no PARAM_VALUE after {self._list_attempts + 1} PARAM_REQUEST_LIST")
            self._list_attempts += 1
            self.deadline = now + self.timeout
            return [self._list()]
        missing = [i for i in range(self.count) if i not in self.received][: self.batch]
        out = []
        for index in missing:
            if self._asked.get(index, 0) > self.item_retries:
                return self._fail(f"parameter {index} did not arrive after {self._asked[index]} requests by index")
            self._asked[index] = self._asked.get(index, 0) + 1
            self.read_requests += 1
            out.append(mavlink.MAVLink_param_request_read_message(*self.target, b"", index))
        self.deadline = now + self.item_timeout
        return out

    def _fail(self, why: str) -> list:
        self.failed = True
        self.error = f"{why} ({len(self.received)} of {self.count if self.count is not None else '?'} received)"
        self.deadline = math.inf
        return []
