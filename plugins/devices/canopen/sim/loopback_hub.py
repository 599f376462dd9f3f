"""The loopback CAN bus's hub and wire format (:mod:`.loopback`): records on TCP streams on 127.0.0.1.

Wire format (little endian), one record per frame: ``<dIBB`` (time stamp,
s since the epoch: the sender's, then the bus's as the hub relays the frame;
arbitration id, flags, data length) then
the data bytes (0-64). Flags: 1 extended id, 2 remote, 4 error, 8 CAN FD, 16
bit-rate switch, 32 error-state indicator. Every socket operation has a time-out; a peer that does not read
its frames for ``send_timeout`` seconds is disconnected rather than allowed
to stall the bus.

:class:`Hub` is the wire: it accepts the buses that join, and relays every record from one to all the others
and to the bus that hosts it, stamped once (every bus sees the same frames in one order, at times that never go
back). It runs in a thread of its own, or is served by the hosting bus's receiver (:meth:`Hub.serve`).
"""

from __future__ import annotations

import selectors
import socket
import struct
import threading
import time
from typing import Any

import can

HEADER = struct.Struct("<dIBB")
#: a record's time stamp (its first field)
_STAMP = struct.Struct("<d")
#: what the hub sends a bus once it is on the bus: frames sent after the bus's constructor returned reach it
GREETING = b"SPCANHUB\x01"
_EXTENDED, _REMOTE, _ERROR, _FD, _BRS, _ESI = 1, 2, 4, 8, 16, 32
#: a record can never be longer than this; anything else on the socket is not this protocol
_MAX_DATA = 64


def encode(msg: can.Message) -> bytes:
    flags = (
        (_EXTENDED if msg.is_extended_id else 0)
        | (_REMOTE if msg.is_remote_frame else 0)
        | (_ERROR if msg.is_error_frame else 0)
        | (_FD if msg.is_fd else 0)
        | (_BRS if msg.bitrate_switch else 0)
        | (_ESI if msg.error_state_indicator else 0)
    )
    data = bytes(msg.data) if msg.data is not None else b""
    if len(data) > _MAX_DATA:
        raise can.CanOperationError(f"a CAN frame carries at most {_MAX_DATA} bytes, got {len(data)}")
    length = msg.dlc if msg.is_remote_frame else len(data)
    # the time it is sent (what a message carries in .timestamp is not: a replayed log's time, or nothing): the
    # hub puts it on the bus with it (or with the time of the frame before, if later)
    return HEADER.pack(time.time(), msg.arbitration_id, flags, length) + (b"" if msg.is_remote_frame else data)


class Reader:
    """Splits a byte stream into frame records."""

    def __init__(self) -> None:
        self.buffer = bytearray()

    def feed(self, chunk: bytes) -> None:
        self.buffer += chunk

    def records(self) -> list[bytes]:
        out = []
        buffer = self.buffer
        offset = 0
        while len(buffer) - offset >= HEADER.size:
            _, _, flags, length = HEADER.unpack_from(buffer, offset)
            if length > _MAX_DATA:
                raise can.CanOperationError("loopback CAN hub: malformed record (a peer that is not a CAN bus?)")
            size = HEADER.size + (0 if flags & _REMOTE else length)
            if len(buffer) - offset < size:
                break
            out.append(bytes(buffer[offset : offset + size]))
            offset += size
        if offset:
            del buffer[:offset]
        return out


def decode(record: bytes, channel: Any, is_rx: bool = True) -> can.Message:
    """A record as the :class:`can.Message` a bus on ``channel`` receives (``is_rx=False``: its own frame)."""
    timestamp, arbitration_id, flags, length = HEADER.unpack_from(record)
    remote = bool(flags & _REMOTE)
    return can.Message(
        timestamp=timestamp,  # when it went on the bus (own frames of a joined bus: when sent)
        arbitration_id=arbitration_id,
        is_extended_id=bool(flags & _EXTENDED),
        is_remote_frame=remote,
        is_error_frame=bool(flags & _ERROR),
        is_fd=bool(flags & _FD),
        bitrate_switch=bool(flags & _BRS),
        error_state_indicator=bool(flags & _ESI),
        dlc=length,
        data=None if remote else record[HEADER.size :],
        channel=channel,
        is_rx=is_rx,
    )


class Hub:
    """The hub a hosting bus runs: accepts the other buses and relays every record to every peer."""

    def __init__(self, listener: socket.socket, deliver, send_timeout: float, name: str, thread: bool = True) -> None:
        self.listener = listener
        self.deliver = deliver  # records to the hosting bus itself
        self.send_timeout = send_timeout
        self.lock = threading.Lock()
        #: one sender at a time: records from several threads must not interleave on a socket
        self.send_lock = threading.Lock()
        self.peers: dict[socket.socket, Reader] = {}
        self.selector = selectors.DefaultSelector()
        self.selector.register(listener, selectors.EVENT_READ)
        #: written to make :meth:`serve` return at once: by close(), and for a frame queued for the hosting bus
        #: (its own, received) while it waits in serve
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)  # a full pipe is already readable: a wake-up never blocks
        self.selector.register(self._wake_r, selectors.EVENT_READ)
        self.closed = threading.Event()
        self._last = 0.0  # the latest time stamp put on the bus
        #: the hub's own thread; None: the hosting bus's receiver serves it (``hub_thread=False``)
        self.thread: threading.Thread | None = None
        if thread:
            self.thread = threading.Thread(target=self._run, name=f"loopback-can-hub {name}", daemon=True)
            self.thread.start()

    def broadcast(self, records: list[bytes], source: socket.socket | None, own=None) -> None:
        """Put records on the bus: stamped with the time their sender sent them, never earlier than the record
        before (the hub is the wire: every bus sees them in one order, at times that never go back; a record that
        waited for the hub keeps its time), queued for the hosting bus (``own``: its own, when it receives them)
        and written to every peer but their ``source``, in one write each."""
        with self.lock:
            peers = [p for p in self.peers if p is not source]
        failed = []
        with self.send_lock:
            stamped = []
            for record in records:
                self._last = max(_STAMP.unpack_from(record)[0], self._last)
                stamped.append(_STAMP.pack(self._last) + record[_STAMP.size :])
            queue_to = self.deliver if source is not None else own
            if queue_to is not None:
                for record in stamped:
                    queue_to(record)
            data = b"".join(stamped)
            for peer in peers:
                try:
                    peer.sendall(data)
                except OSError:  # it hung up or stopped reading for send_timeout: it leaves the bus
                    failed.append(peer)
        for peer in failed:
            self._drop(peer)

    def _drop(self, peer: socket.socket) -> None:
        with self.lock:
            if self.peers.pop(peer, None) is None:
                return
        try:
            self.selector.unregister(peer)
        except (KeyError, ValueError):
            pass
        peer.close()

    def _run(self) -> None:
        while self.serve(0.1):
            pass

    def wake(self) -> None:
        """Make a :meth:`serve` under way return at once."""
        try:
            self._wake_w.send(b"\0")
        except OSError:
            pass

    def serve(self, timeout: float | None) -> bool:
        """One round of the hub: wait up to ``timeout`` s (None: until something happens) for a bus joining,
        frames to relay or a wake-up, and handle what came. False once the hub is closed."""
        try:
            events = self.selector.select(timeout=timeout)
        except (OSError, ValueError):  # closed under us
            return False
        for key, _ in events:
            if self.closed.is_set():
                return False
            sock = key.fileobj
            if sock is self._wake_r:
                try:
                    self._wake_r.recv(4096)
                except OSError:
                    pass
                continue
            if sock is self.listener:
                self._accept()
                continue
            try:
                chunk = sock.recv(65536)
            except (OSError, TimeoutError):
                chunk = b""
            if not chunk:
                self._drop(sock)
                continue
            reader = self.peers.get(sock)
            if reader is None:
                continue
            reader.feed(chunk)
            try:
                records = reader.records()
            except can.CanOperationError:
                self._drop(sock)
                continue
            if records:  # in order, with one write per peer for what arrived together
                self.broadcast(records, sock)
        return not self.closed.is_set()

    def _accept(self) -> None:
        try:
            peer, _ = self.listener.accept()
        except OSError:
            return
        peer.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        peer.settimeout(self.send_timeout)
        with self.send_lock:  # on the bus from here: no broadcast falls between the two
            with self.lock:
                self.peers[peer] = Reader()
            try:
                peer.sendall(GREETING)
            except OSError:
                pass
        self.selector.register(peer, selectors.EVENT_READ)

    def close(self) -> None:
        self.closed.set()
        self.wake()
        if self.thread is not None:
            self.thread.join(timeout=2.0)
        with self.lock:
            peers = list(self.peers)
            self.peers.clear()
        for peer in peers:
            try:
                peer.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            peer.close()
        self.selector.close()
        self.listener.close()
        self._wake_r.close()
        self._wake_w.close()
