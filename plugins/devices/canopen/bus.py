"""The CAN transport: opening a python-can bus, fault injection, and bus load.

``bus: {interface: virtual}`` (the default) is python-can's in-process
virtual bus, shared by the master and the simulated drives;
``{interface: loopback, channel: PORT}`` reaches simulated drives in another
process (``surgiplan-sim-drives``) through a hub on 127.0.0.1
(:mod:`.sim.loopback`: nothing leaves the machine); any other
python-can interface (``{interface: socketcan, channel: can0}``,
``{interface: pcan, channel: PCAN_USBBUS1}``, ...) talks to real drives with
the same code. A bus that cannot be opened is a :class:`BusError` naming the
interface and channel, raised before anything moves.

Fault injection is a setting of the simulated bus (``faults:``), so failures
can be rehearsed from a pipeline file. Times ``at_s`` are seconds after the
start of the device's first trajectory; each fault happens once:

* ``{kind: heartbeat_loss, node: 2, at_s: 0.5}``: the node stops producing
  heartbeats (it keeps following its targets);
* ``{kind: frame_loss, rate: 0.01, seed: 0}``: every receiver (the master and
  each drive) independently loses each frame with this probability (a
  receive overrun; the frame was on the wire and counts in the bus load);
* ``{kind: following_error, node: 1, at_s: 1.0, load: 2.0, duration_s: 0.2}``:
  an external load of ``load`` times the drive's peak torque pushes the axis
  (a jam, a collision) for ``duration_s``: the drive cannot follow, detects
  a following error, sends an EMCY and faults;
* ``{kind: dead_node, node: 3}``: the drive never answers (with ``at_s``: it
  dies then, silencing heartbeats, PDOs and SDO);
* ``{kind: bus_off, at_s: 0.3}``: the master's CAN controller goes bus-off:
  every later send fails (without ``at_s``: from power-up, so configuring the
  device fails with a clear error before anything moves).

Bus load (:func:`frame_bits`): each classic CAN data frame with an 11-bit
identifier and n data bytes is 47 + 8n bits (SOF, identifier, RTR, IDE, r0,
DLC, data, CRC-15, CRC and ACK delimiters and slot, EOF, and the 3-bit
interframe space) plus its stuff bits, counted exactly from the frame's bits
and CRC. Without stuffing an 8-byte frame is 111 bits; the worst case
(:func:`worst_case_bits`, Davis et al. 2007, "Controller Area Network (CAN)
schedulability analysis: refuted, revisited and revised", Real-Time Systems
35(3), eq. 1) adds ``floor((34 + 8n - 1) / 4)``: 135 bits. The load is the
bits of every frame on the bus over the elapsed time, in percent of the
bit rate.
"""

from __future__ import annotations

import math
import threading
import uuid
from collections.abc import Callable, Sequence
from typing import Annotated, Any, Literal

import can
import numpy as np
from pydantic import Field, NonNegativeFloat, PositiveFloat, PositiveInt, field_validator
from surgiplan.errors import SurgiplanError
from surgiplan.models import StrictModel


class BusError(SurgiplanError):
    """The CAN bus cannot be opened, or a node on it does not answer."""


# ----------------------------------------------------------------------------- settings
class _Fault(StrictModel):
    """An injected fault; ``kind`` says which."""


class HeartbeatLoss(_Fault):
    kind: Literal["heartbeat_loss"]
    node: int = Field(ge=1, le=127)
    at_s: NonNegativeFloat = 0.0


class FrameLoss(_Fault):
    kind: Literal["frame_loss"]
    rate: float = Field(ge=0.0, lt=1.0)
    seed: int = 0
    at_s: NonNegativeFloat = 0.0


class FollowingErrorFault(_Fault):
    kind: Literal["following_error"]
    node: int = Field(ge=1, le=127)
    at_s: NonNegativeFloat = 0.0
    #: the external load, in units of the drive's peak torque (> 1 overpowers it)
    load: PositiveFloat = 2.0
    duration_s: PositiveFloat = 0.2


class DeadNode(_Fault):
    kind: Literal["dead_node"]
    node: int = Field(ge=1, le=127)
    #: None: the node never answers, not even at start-up
    at_s: NonNegativeFloat | None = None


class BusOff(_Fault):
    kind: Literal["bus_off"]
    #: None: bus-off from power-up
    at_s: NonNegativeFloat | None = None


Fault = Annotated[HeartbeatLoss | FrameLoss | FollowingErrorFault | DeadNode | BusOff, Field(discriminator="kind")]


class BusSettings(StrictModel):
    """Which CAN bus: python-can's ``interface`` and ``channel``, the bit rate, and injected faults."""

    #: python-can interface name: virtual (simulated drives), socketcan, pcan, kvaser, ...
    interface: str = "virtual"
    #: default for the virtual bus: a channel of its own per device, so parallel buses never meet;
    #: loopback: a port on 127.0.0.1 (a number is accepted)
    channel: str | None = None
    bitrate: PositiveInt = 1_000_000
    #: further keyword arguments for python-can's Bus (interface-specific)
    options: dict[str, Any] = Field(default_factory=dict)
    faults: list[Fault] = Field(default_factory=list)

    @field_validator("channel", mode="before")
    @classmethod
    def _channel_text(cls, value: Any) -> Any:
        return str(value) if isinstance(value, int) and not isinstance(value, bool) else value

    @field_validator("interface")
    @classmethod
    def _known_interface(cls, value: str) -> str:
        """An interface python-can does not know is an error at validation, before any stage runs."""
        from can.interfaces import VALID_INTERFACES

        if value not in VALID_INTERFACES:
            from surgiplan.errors import choices_hint

            raise ValueError(f"unknown python-can interface '{value}'; {choices_hint(value, VALID_INTERFACES)}")
        return value

    @property
    def simulated(self) -> bool:
        return self.interface == "virtual"


# ----------------------------------------------------------------------------- opening
def open_bus(settings: BusSettings) -> tuple[can.BusABC, str]:
    """Open the python-can bus; returns it and the channel used. Raises :class:`BusError`."""
    channel = settings.channel
    if channel is None:
        if not settings.simulated:
            raise BusError(f"bus interface '{settings.interface}' needs a channel (e.g. channel: can0)")
        channel = f"surgiplan-{uuid.uuid4().hex[:12]}"
    kwargs = dict(settings.options)
    if not settings.simulated:
        kwargs.setdefault("bitrate", settings.bitrate)
    try:
        bus = can.Bus(interface=settings.interface, channel=channel, **kwargs)
    except (can.CanError, OSError, ImportError, ValueError, TypeError, NotImplementedError) as exc:
        hint = ""
        if settings.interface == "socketcan":
            hint = f" (is it up? ip link set {channel} up type can bitrate {settings.bitrate})"
        raise BusError(
            f"cannot open CAN bus interface '{settings.interface}' channel '{channel}': {exc}{hint}"
        ) from None
    return bus, channel


# ----------------------------------------------------------------------------- fault injection
class ArmedFaults:
    """The fault list with its time origin: faults act only once armed (at the trajectory start)."""

    def __init__(self, faults: list, now: Callable[[], float]) -> None:
        self.faults = list(faults)
        self.now = now
        self.origin: float | None = None

    def arm(self, origin: float) -> None:
        self.origin = origin

    def elapsed(self) -> float | None:
        return None if self.origin is None else self.now() - self.origin

    def of(self, kind: str) -> list:
        return [f for f in self.faults if f.kind == kind]

    def frame_loss(self, stream: int) -> FrameDropper | None:
        losses = self.of("frame_loss")
        if not losses:
            return None
        loss = losses[0]
        return FrameDropper(loss.rate, np.random.default_rng([loss.seed, stream]), self, loss.at_s)

    def never_answers(self, node: int) -> bool:
        return any(f.node == node and f.at_s is None for f in self.of("dead_node"))


class FrameDropper:
    """Drops frames at random (seeded) at one receiver, once the faults are armed."""

    def __init__(self, rate: float, rng: np.random.Generator, armed: ArmedFaults, at_s: float) -> None:
        self.rate = rate
        self.rng = rng
        self.armed = armed
        self.at_s = at_s
        self.dropped: list[tuple[float, int]] = []

    def drop(self, can_id: int) -> bool:
        elapsed = self.armed.elapsed()
        if elapsed is None or elapsed < self.at_s:
            return False
        if self.rng.random() < self.rate:
            self.dropped.append((elapsed, can_id))
            return True
        return False


class FrameLog(Sequence):
    """The frames on the bus, (time s, arbitration id, data bytes), in chunks of a fixed size.

    A plain list of every frame of a long session (a 1 kHz loop logs some ten thousand frames a second) grows
    by reallocating: each time it copies the whole log, megabytes, with the GIL held, which stops a real-time
    loop for milliseconds. Here a full chunk is left as it is and a new one begun. A sequence: ``len``,
    indexing, slices (lists) and iteration as a list.
    """

    CHUNK = 8192

    def __init__(self) -> None:
        self._chunks: list[list[tuple[float, int, bytes]]] = [[]]
        self._full = 0  # frames in the full chunks

    def __len__(self) -> int:
        return self._full + len(self._chunks[-1])

    def append(self, frame: tuple[float, int, bytes]) -> None:
        last = self._chunks[-1]
        last.append(frame)
        if len(last) == self.CHUNK:
            self._full += self.CHUNK
            self._chunks.append([])

    def extend(self, frames) -> None:
        for frame in frames:
            self.append(frame)

    def clear(self) -> None:
        self._chunks = [[]]
        self._full = 0

    def __iter__(self):
        for chunk in self._chunks:
            yield from chunk

    def __getitem__(self, index):
        if isinstance(index, slice):
            start, stop, step = index.indices(len(self))
            if step != 1:
                return [self[i] for i in range(start, stop, step)]
            out: list[tuple[float, int, bytes]] = []
            while start < stop:
                chunk, at = divmod(start, self.CHUNK)
                piece = self._chunks[chunk][at : at + stop - start]
                out += piece
                start += len(piece)
            return out
        n = len(self)
        if index < 0:
            index += n
        if not 0 <= index < n:
            raise IndexError("frame index out of range")
        return self._chunks[index // self.CHUNK][index % self.CHUNK]


class MonitoredBus(can.BusABC):
    """The master's view of the bus: logs every frame on it and applies the receive-side faults.

    Every frame the master sends or receives is logged with the clock's time
    (the frames on the wire, for the bus load): a sent frame's taken as it is
    handed to the interface, before the send (a thread preempted in between must
    not log a SYNC after the drives' answers to it); received frames may then be
    dropped (``frame_loss``); after ``bus_off`` every send raises
    ``can.CanOperationError`` as a bus-off controller would.
    """

    def __init__(self, inner: can.BusABC, now: Callable[[], float], faults: ArmedFaults) -> None:
        self.inner = inner
        self.now = now
        self.faults = faults
        self.dropper = faults.frame_loss(stream=0)
        bus_off = faults.of("bus_off")
        self.bus_off: BusOff | None = bus_off[0] if bus_off else None
        self.log_lock = threading.Lock()
        #: COB-IDs only this master sends (NMT, SYNC, its RPDOs and SDO requests): received ones are
        #: echoes of its own frames (interfaces such as udp_multicast loop them back), not new traffic
        self.own_ids: set[int] = set()
        #: (time s, arbitration id, data bytes)
        self.frames = FrameLog()
        super().__init__(channel=getattr(inner, "channel_info", "can"))
        self.channel_info = f"monitored {inner.channel_info}"

    def _log(self, msg: can.Message, now: float | None = None) -> None:
        if msg.is_error_frame or msg.is_remote_frame:
            return
        with self.log_lock:
            self.frames.append((self.now() if now is None else now, msg.arbitration_id, bytes(msg.data)))

    def _check_bus_off(self) -> None:
        if self.bus_off is not None:
            if self.bus_off.at_s is None:
                raise can.CanOperationError("CAN controller is bus-off (injected fault, from power-up)")
            elapsed = self.faults.elapsed()
            if elapsed is not None and elapsed >= self.bus_off.at_s:
                raise can.CanOperationError("CAN controller is bus-off (injected fault)")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_bus_off()
        now = self.now()
        self.inner.send(msg, timeout)
        self._log(msg, now)

    @property
    def send_batch(self):
        """Send frames in order with one write, where the interface can (``LoopbackBus.send_batch``); None
        otherwise (then send them one by one)."""
        inner = getattr(self.inner, "send_batch", None)
        if inner is None:
            return None

        def send_batch(messages: list[can.Message]) -> None:
            self._check_bus_off()
            now = self.now()
            inner(messages)
            with self.log_lock:
                self.frames.extend((now, m.arbitration_id, bytes(m.data)) for m in messages)

        return send_batch

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        while True:
            msg = self.inner.recv(timeout)
            if msg is None:
                return None, False
            if msg.arbitration_id in self.own_ids:
                continue  # our own frame looped back: already logged when sent
            self._log(msg)
            if self.dropper is not None and self.dropper.drop(msg.arbitration_id):
                continue  # lost at this receiver; look for the next frame
            return msg, False

    def frames_between(self, start: float, end: float) -> list[tuple[float, int, bytes]]:
        with self.log_lock:
            return [f for f in self.frames if start <= f[0] < end]

    def shutdown(self) -> None:
        if not self._is_shutdown:
            self.inner.shutdown()
        super().shutdown()


# ----------------------------------------------------------------------------- bus load
_CRC15 = 0x4599


def crc15(bits: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """CAN's CRC-15 (polynomial 0x4599) of each row's first ``lengths[i]`` bits (MSB first)."""
    crc = np.zeros(len(bits), dtype=np.int64)
    for p in range(bits.shape[1]):
        active = p < lengths
        feedback = bits[:, p].astype(np.int64) ^ ((crc >> 14) & 1)
        new = ((crc << 1) & 0x7FFF) ^ np.where(feedback == 1, _CRC15, 0)
        crc = np.where(active, new, crc)
    return crc


def frame_bits(arbitration_ids, payloads: list[bytes]) -> np.ndarray:
    """Exact length in bits of classic CAN data frames (11-bit identifiers), stuff bits included.

    ``arbitration_ids``: (n,) identifiers; ``payloads``: n byte strings of 0-8 bytes. Vectorised
    over frames: the CRC and the stuffing walk the (at most 98) bit positions once.
    """
    ids = np.asarray(arbitration_ids, dtype=np.int64)
    n = len(ids)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    dlc = np.array([len(p) for p in payloads], dtype=np.int64)
    data = np.zeros((n, 8), dtype=np.uint8)
    for i, p in enumerate(payloads):  # copying the payloads; the bit work below is vectorised
        data[i, : len(p)] = np.frombuffer(p, dtype=np.uint8)
    header = np.zeros((n, 19), dtype=np.uint8)  # SOF, 11 id bits, RTR, IDE, r0, 4 DLC bits
    header[:, 1:12] = (ids[:, None] >> np.arange(10, -1, -1)) & 1
    header[:, 15:19] = (dlc[:, None] >> np.arange(3, -1, -1)) & 1
    data_bits = np.unpackbits(data, axis=1)  # MSB first
    body = np.concatenate([header, data_bits], axis=1)  # (n, 83)
    body_length = 19 + 8 * dlc
    crc = crc15(body, body_length)  # over SOF .. data
    crc_bits = ((crc[:, None] >> np.arange(14, -1, -1)) & 1).astype(np.uint8)
    # the stuffed region: SOF .. CRC, each frame's own length
    length = body_length + 15
    region = np.zeros((n, 98), dtype=np.uint8)
    region[:, :83] = body
    rows = np.arange(n)[:, None]
    region[rows, body_length[:, None] + np.arange(15)] = crc_bits
    last = np.full(n, -1, dtype=np.int64)
    run = np.zeros(n, dtype=np.int64)
    stuffed = np.zeros(n, dtype=np.int64)
    for p in range(98):
        active = p < length
        bit = region[:, p].astype(np.int64)
        same = bit == last
        run = np.where(active, np.where(same, run + 1, 1), run)
        last = np.where(active, bit, last)
        stuff = active & (run == 5)
        stuffed += stuff
        # the stuff bit is the complement and starts a new run
        last = np.where(stuff, 1 - bit, last)
        run = np.where(stuff, 1, run)
    return length + stuffed + 13  # CRC delimiter, ACK slot and delimiter, EOF (7), interframe space (3)


def worst_case_bits(data_bytes: int) -> int:
    """Davis et al. (2007) bound on a standard-identifier frame with ``data_bytes`` bytes."""
    return 47 + 8 * data_bytes + math.floor((34 + 8 * data_bytes - 1) / 4)


def bus_load_percent(frames: list[tuple[float, int, bytes]], duration: float, bitrate: int) -> tuple[float, float]:
    """(exact, worst-case) load in % of ``bitrate`` of ``frames`` over ``duration`` seconds."""
    if duration <= 0 or not frames:
        return 0.0, 0.0
    ids = [f[1] for f in frames]
    payloads = [f[2] for f in frames]
    exact = float(np.sum(frame_bits(ids, payloads)))
    worst = float(sum(worst_case_bits(len(p)) for p in payloads))
    scale = 100.0 / (duration * bitrate)
    return exact * scale, worst * scale
