"""A conformance session: canopen's master on the drives' bus, one ``canopen.RemoteNode`` per drive with its
EDS, every frame recorded, and the helpers the cases share (NMT with its boot-ups and heartbeats, SDO
requests whose abort code is the answer, raw frames where a case must break the protocol on purpose)."""

from __future__ import annotations

import queue
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import can
import canopen
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from . import standard as cia

#: the node-ID this master's heartbeat uses (the drives' heartbeat consumers watch it)
MASTER_ID = 0x7F


@dataclass(frozen=True)
class Frame:
    """A frame as the master received it: when (monotonic, here) and the interface's time stamp (``sent``: the
    kernel's reception time on SocketCAN, the receiving thread's on loopback; frames that wait in a busy
    receiver get the same stamp, so rates are judged by counts, :func:`.cases.periodic`)."""

    received: float
    sent: float
    can_id: int
    data: bytes
    remote: bool


class Recorder(can.Listener):
    """Every frame the master receives, in order, with a condition to wait on."""

    def __init__(self) -> None:
        self.frames: list[Frame] = []
        self.condition = threading.Condition()

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            return
        frame = Frame(time.monotonic(), msg.timestamp, msg.arbitration_id, bytes(msg.data), msg.is_remote_frame)
        with self.condition:
            self.frames.append(frame)
            self.condition.notify_all()

    def mark(self) -> int:
        with self.condition:
            return len(self.frames)

    def since(self, mark: int, can_id: int | None = None) -> list[Frame]:
        with self.condition:
            frames = self.frames[mark:]
        return frames if can_id is None else [f for f in frames if f.can_id == can_id]

    def wait(self, condition: Callable[[list[Frame]], bool], mark: int, timeout: float) -> bool:
        """Wait (at most ``timeout`` s) until ``condition(frames since mark)`` holds; returns whether it did."""
        deadline = time.monotonic() + timeout
        with self.condition:
            while True:
                if condition(self.frames[mark:]):
                    return True
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self.condition.wait(remaining)

    def on_error(self, exc: Exception) -> None:  # the bus went away: the cases waiting will time out
        pass


@dataclass
class Drive:
    """One drive under test: its joint, node-ID and EDS."""

    joint: str
    node_id: int
    eds: Path
    eds_text: str = ""
    dictionary: canopen.ObjectDictionary | None = None

    @property
    def label(self) -> str:
        return f"node {self.node_id} ({self.joint})"


@dataclass
class Timing:
    """How long the session waits (s): generous by default, for a loaded machine or a slow interface."""

    sdo: float = 1.0
    #: how long a node may take to answer or react when silence is the expected answer
    silence: float = 0.25
    boot: float = 3.0
    #: how long a fast scan step waits for an answer (its silence means a 1 bit: short, the scan has 132 steps)
    lss: float = 0.15


@dataclass
class Session:
    """canopen's master on the target's bus with the drives under test."""

    target: object
    drives: list[Drive]
    timing: Timing = field(default_factory=Timing)
    network: canopen.Network | None = None
    nodes: dict[int, canopen.RemoteNode] = field(default_factory=dict)
    recorder: Recorder = field(default_factory=Recorder)
    #: what the cases leave for later ones (the values stored before a power cycle, ...)
    notes: dict = field(default_factory=dict)
    #: the index ranges the object dictionary scan covers (every index the EDS lacks must be refused)
    scan: list[tuple[int, int]] = field(default_factory=lambda: [(0x1000, 0x1FFF), (0x6000, 0x67FF)])

    @property
    def ids(self) -> list[int]:
        return [drive.node_id for drive in self.drives]

    def drive(self, node_id: int) -> Drive:
        return next(d for d in self.drives if d.node_id == node_id)

    # ------------------------------------------------------------------ connection
    def open(self) -> None:
        """Join the bus, then power the drives up (the simulated ones: on the bus this master hosts, so that
        it hears everything they say from power-up on)."""
        for drive in self.drives:
            drive.eds_text = drive.eds.read_text(errors="replace")
            drive.dictionary = canopen.import_od(str(drive.eds), drive.node_id)
        network = canopen.Network()
        network.connect(**self.target.bus_arguments())
        network.notifier.add_listener(self.recorder)
        self.network = network
        self.target.start()
        self.nodes = {}
        for drive in self.drives:
            node = canopen.RemoteNode(drive.node_id, drive.dictionary)
            node.sdo.RESPONSE_TIMEOUT = self.timing.sdo
            network.add_node(node)
            self.nodes[drive.node_id] = node
        # LSS services that must be answered wait as long as an SDO answer may take; the fast scan, whose
        # silence is an answer, waits ``timing.lss`` (:meth:`fast_scan`)
        network.lss.RESPONSE_TIMEOUT = max(self.timing.sdo, self.timing.lss)

    def fast_scan(self) -> tuple[bool, list[int] | None]:
        """canopen's ``LssMaster.fast_scan``, each step waiting ``timing.lss`` (silence means a 1 bit)."""
        lss = self.network.lss
        patient, lss.RESPONSE_TIMEOUT = lss.RESPONSE_TIMEOUT, self.timing.lss
        try:
            return lss.fast_scan()
        finally:
            lss.RESPONSE_TIMEOUT = patient

    def close(self) -> None:
        if self.network is None:
            return
        network, self.network = self.network, None
        try:
            network.sync.stop()
            network.disconnect()
        except (can.CanError, OSError):  # the drives' side is gone already: nothing left to release
            pass

    def power_cycle(self) -> int:
        """Restart the drives (the target's power cycle), this master on the bus throughout; returns the
        recorder's mark from before the power-up."""
        mark = self.recorder.mark()
        self.target.restart()
        return mark

    # ------------------------------------------------------------------ NMT
    def nmt(self, command: int, node_id: int) -> None:
        self.network.send_message(0x000, bytes([command, node_id]))

    def reset(self, ids: list[int] | None = None, command: int = cia.RESET_NODE) -> dict[int, bool]:
        """NMT reset (node or communication) of ``ids``; returns whether each sent its boot-up message."""
        ids = self.ids if ids is None else ids
        mark = self.recorder.mark()
        for node_id in ids:
            self.nmt(command, node_id)
        wanted = {cia.heartbeat(node_id) for node_id in ids}

        def booted(frames: list[Frame]) -> bool:
            return wanted <= {f.can_id for f in frames if f.data == b"\x00"}

        self.recorder.wait(booted, mark, self.timing.boot)
        got = {f.can_id for f in self.recorder.since(mark) if f.can_id in wanted and f.data == b"\x00"}
        time.sleep(0.02)  # the node finishes its reset before the next request
        return {node_id: cia.heartbeat(node_id) in got for node_id in ids}

    def heartbeat_states(self, ids: list[int], mark: int, timeout: float) -> dict[int, int | None]:
        """The state byte of each node's first heartbeat after ``mark`` (None: none within ``timeout``)."""
        wanted = {cia.heartbeat(node_id): node_id for node_id in ids}

        def all_seen(frames: list[Frame]) -> bool:
            return set(wanted) <= {f.can_id for f in frames if len(f.data) == 1 and f.data != b"\x00"}

        self.recorder.wait(all_seen, mark, timeout)
        states: dict[int, int | None] = dict.fromkeys(ids)
        for frame in self.recorder.since(mark):
            node_id = wanted.get(frame.can_id)
            if node_id is not None and states[node_id] is None and len(frame.data) == 1 and frame.data != b"\x00":
                states[node_id] = frame.data[0]
        return states

    def set_heartbeat(self, period_ms: int, ids: list[int] | None = None) -> None:
        for node_id in self.ids if ids is None else ids:
            self.nodes[node_id].sdo[0x1017].raw = period_ms

    # ------------------------------------------------------------------ SDO
    def abort_code(self, action: Callable[[], object]) -> int | str | None:
        """Run an SDO ``action``: its abort code, None if it succeeded, "no answer" if the node was silent."""
        try:
            action()
        except SdoAbortedError as exc:
            return exc.code
        except SdoCommunicationError as exc:
            return f"no answer ({exc})"
        return None

    def upload(self, node_id: int, index: int, subindex: int) -> bytes | int:
        """The object's raw value, or the abort code."""
        try:
            return bytes(self.nodes[node_id].sdo.upload(index, subindex))
        except SdoAbortedError as exc:
            return exc.code

    def download(self, node_id: int, index: int, subindex: int, data: bytes, force_segment: bool = False) -> int | None:
        """Write raw bytes: None, or the abort code."""
        try:
            self.nodes[node_id].sdo.download(index, subindex, data, force_segment=force_segment)
        except SdoAbortedError as exc:
            return exc.code
        return None

    def request(self, node_id: int, frame: bytes, timeout: float | None = None) -> bytes | None:
        """A raw SDO request through canopen's client: the response frame (an abort included), or None if the
        node says nothing within ``timeout``."""
        client = self.nodes[node_id].sdo
        client.responses = queue.Queue()  # what an earlier exchange left
        client.send_request(bytes(frame))
        return self.read_frame(node_id, timeout)

    def read_frame(self, node_id: int, timeout: float | None = None) -> bytes | None:
        """The next frame from the node's SDO server (None: none within ``timeout``)."""
        try:
            return bytes(self.nodes[node_id].sdo.responses.get(timeout=timeout or self.timing.sdo))
        except queue.Empty:
            return None

    def upload_many(self, requests: dict[int, list[tuple[int, int]]]) -> dict[int, dict[tuple[int, int], bytes | int]]:
        """Expedited upload requests, one in flight per drive and every drive's at once (the drives' answers
        overlap the round trips): {node-ID: [(index, sub-index), ...]} -> the answers' data or abort codes
        (or -1: no answer). An answer counts only if it names the object asked for (a late answer to an
        earlier request is not taken for the next one); a request left unanswered is sent once more, as
        canopen's SDO client retries (``SdoClient.MAX_RETRIES``), with a longer wait."""
        out: dict[int, dict] = {node_id: {} for node_id in requests}
        self._upload_batches(requests, out, self.timing.sdo)
        silent = {node_id: [key for key, code in found.items() if code == -1] for node_id, found in out.items()}
        if any(silent.values()):
            self._upload_batches(silent, out, 4 * self.timing.sdo)
        return out

    def _upload_batches(self, requests: dict[int, list[tuple[int, int]]], out: dict[int, dict], timeout: float) -> None:
        queues = {node_id: list(items) for node_id, items in requests.items() if items}
        for _ in range(max((len(q) for q in queues.values()), default=0)):
            batch = {node_id: q.pop(0) for node_id, q in queues.items() if q}
            if not batch:
                break
            mark = self.recorder.mark()
            for node_id, (index, sub) in batch.items():
                self.network.send_message(cia.sdo_request(node_id), struct.pack("<BHB", 0x40, index, sub) + bytes(4))
            wanted = {cia.sdo_response(node_id): (node_id, struct.pack("<HB", *batch[node_id])) for node_id in batch}

            def matches(frame: Frame, wanted=wanted) -> bool:
                return frame.can_id in wanted and frame.data[1:4] == wanted[frame.can_id][1]

            def answered(frames: list[Frame], wanted=wanted) -> bool:
                return set(wanted) <= {f.can_id for f in frames if matches(f)}

            self.recorder.wait(answered, mark, timeout)
            for frame in self.recorder.since(mark):
                if not matches(frame):
                    continue
                node_id, _ = wanted.pop(frame.can_id)
                code = abort_of(frame.data)
                data = frame.data[4 : 8 - ((frame.data[0] >> 2) & 3)]
                out[node_id][batch[node_id]] = code if code is not None else data
            for node_id, _ in wanted.values():
                out[node_id][batch[node_id]] = -1

    def send_raw(self, node_id: int, frame: bytes) -> None:
        self.nodes[node_id].sdo.send_request(bytes(frame))


def abort_of(response: bytes | None) -> int | None:
    """The abort code an SDO response frame carries (None: not an abort)."""
    if response is None or len(response) < 8 or response[0] != 0x80:
        return None
    return int.from_bytes(response[4:8], "little")


def hexcode(code: int | str | bytes | None) -> str:
    """What an SDO exchange gave, in words: accepted, answered with data, an abort code, no answer."""
    if code is None:
        return "accepted"
    if isinstance(code, bytes):
        return f"answered {code.hex()}"
    if isinstance(code, str):
        return code
    return f"abort 0x{code:08X}"


def wait_until(condition: Callable[[], object], timeout: float, step: float = 0.01):
    """Poll ``condition()`` until truthy, at most ``timeout`` s; returns its last value."""
    deadline = time.monotonic() + timeout
    value = condition()
    while not value and time.monotonic() < deadline:
        time.sleep(step)
        value = condition()
    return value
