"""A loopback-only inter-process CAN bus for python-can: ``interface: loopback``.

Processes on one machine share one CAN bus through a small TCP hub bound to
the loopback address: the master in a pipeline and simulated drives in a
process of their own (``surgiplan-sim-drives``) exchange frames exactly as
over a real interface, with nothing ever leaving the machine. It is a
python-can interface registered through python-can's ``can.interface`` entry
points, so any python-can program (canopen's ``Network``, ``can.logger``,
``can.viewer``) opens it by name::

    bus = can.Bus(interface="loopback", channel="43113")          # or "127.0.0.1:43113", "[::1]:43113"

The channel is a TCP port on 127.0.0.1 (or ``HOST:PORT`` with a loopback
host: 127.0.0.0/8, ::1 or ``localhost``); any other host is refused. The
first bus opened on a channel hosts the hub in a daemon thread of its process
(``hub="auto"``, the default; ``"host"`` insists on hosting, ``"join"`` on
joining one; ``hub_thread=False``: no thread, the hosting bus's receiver
relays while it waits in ``recv``); the buses opened later connect to it.
Every frame one bus sends reaches every other bus on the channel, in order;
a bus does not receive its
own frames unless ``receive_own_messages=True`` (as SocketCAN). When the
host's bus shuts down the hub closes and the other buses' ``recv`` raise
``can.CanOperationError`` saying so, as a bus whose cable was pulled.

As python-can's built-in interfaces: a received frame's ``channel`` is the
channel the bus was opened with (so ``can.logger`` writes files that
``can.LogReader`` and ``can.player`` read back); its ``timestamp`` is the
moment it went on the bus: its sender's time (one clock: the same machine),
never earlier than the frame before it, put on it once by the hub (every bus
sees the same frames in the same order at the same times, as the controllers
on a real bus do), not the moment the hub or the application reads it; a
bus's own frames (``receive_own_messages``) come back with ``is_rx=False``. Receiving on a
bus that is shut down raises ``can.CanOperationError``, and a thread
waiting in ``recv`` is woken with it when another thread shuts the bus
down. python-can's own interface tests run against this interface in
``tests/interop/pycan_tests/``.

Why not an existing transport: python-can's ``udp_multicast`` sends to a
239.x group on the default route, i.e. out of the machine's LAN interface;
``socketcand`` needs the socketcand daemon and SocketCAN (Linux kernel
modules); python-can-remote (0.3.0) targets python-can 3, carries its own
websocket implementation and listens on all interfaces by default.

The wire format and the hub: :mod:`.loopback_hub`.
"""

from __future__ import annotations

import errno
import ipaddress
import queue
import select
import socket
import threading
import time
from collections import deque
from typing import Any

import can

from ..bus import BusError
from .loopback_hub import GREETING, Hub, Reader, decode, encode


class LoopbackError(can.CanInitializationError, BusError):
    """The loopback channel is malformed, not on loopback, or cannot be hosted or joined.

    A ``can.CanInitializationError`` (python-can's contract for an interface that cannot be opened) and a
    :class:`..bus.BusError` (surgiplan's: the CAN bus cannot be opened, a user error).
    """


def parse_channel(channel: Any) -> tuple[str, int]:
    """``"43113"``, ``43113``, ``"127.0.0.1:43113"``, ``"[::1]:43113"``, ``"localhost:43113"`` -> (host, port).

    Raises :class:`LoopbackError` for a non-loopback host or a bad port.
    """
    text = str(channel).strip()
    host, port_text = "127.0.0.1", text
    if text.startswith("["):  # [v6]:port
        end = text.find("]")
        if end < 0 or text[end + 1 : end + 2] != ":":
            raise LoopbackError(f"loopback CAN channel '{text}': expected [ADDRESS]:PORT")
        host, port_text = text[1:end], text[end + 2 :]
    elif ":" in text:
        host, _, port_text = text.rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        raise LoopbackError(f"loopback CAN channel '{text}': the port '{port_text}' is not a number") from None
    if not 1 <= port <= 65535:
        raise LoopbackError(f"loopback CAN channel '{text}': port {port} is outside 1-65535")
    if host == "localhost":
        host = "127.0.0.1"
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        raise LoopbackError(
            f"loopback CAN channel '{text}': '{host}' is not an IP address (use 127.0.0.1 or ::1)"
        ) from None
    if not address.is_loopback:
        raise LoopbackError(
            f"loopback CAN channel '{text}': {host} is not a loopback address; this interface never "
            "sends a frame off the machine (use 127.0.0.1 or ::1)"
        )
    return str(address), port


def _family(host: str) -> int:
    return socket.AF_INET6 if ":" in host else socket.AF_INET


class LoopbackBus(can.BusABC):
    """A CAN bus shared by the processes of one machine through a hub on the loopback interface.

    :param channel: the hub's port on 127.0.0.1, or ``HOST:PORT`` with a loopback host.
    :param hub: ``"auto"`` (host the hub if nobody does, else join it), ``"host"`` or ``"join"``.
    :param receive_own_messages: also receive the frames this bus sends.
    :param connect_timeout: how long ``join`` waits for a hub to accept (s).
    :param send_timeout: a peer that does not take a frame within this time is disconnected (s).
    :param bitrate: the nominal bit rate (only reported: nothing is slowed down).
    :param hub_thread: a hosting bus relays in a thread of its own (the default); False: in the thread that
        receives on it, while it waits in ``recv`` (no thread of its own: a frame reaches a process whose one
        thread always receives, as the simulated drives' does, without a hand-over between threads; nobody
        receiving, nothing is relayed).
    """

    def __init__(
        self,
        channel: Any = None,
        can_filters=None,
        hub: str = "auto",
        receive_own_messages: bool = False,
        connect_timeout: float = 2.0,
        send_timeout: float = 1.0,
        bitrate: int = 1_000_000,
        hub_thread: bool = True,
        **kwargs: object,
    ) -> None:
        # first what shutdown() cleans up: it runs when the constructor fails half-way, too
        self._closing = threading.Event()
        self._hub: Hub | None = None
        self._sock: socket.socket | None = None
        #: the host's received records and (both roles) our own: (record, is_rx); None wakes a receiver to close
        self._rx: queue.SimpleQueue[tuple[bytes, bool] | None] = queue.SimpleQueue()
        #: one thread at a time reads the socket (joined) or serves the hub (hosted without its thread); shutdown()
        #: closes them once none is
        self._recv_lock = threading.Lock()
        #: a joined bus: written to wake a thread waiting in select (an own frame queued, or shutdown)
        self._wake_r: socket.socket | None = None
        self._wake_w: socket.socket | None = None
        self._send_lock = threading.Lock()
        self._reader = Reader()
        self._pending: deque[bytes] = deque()
        self._hub_closed = False
        if channel is None:
            raise LoopbackError("loopback CAN needs a channel: a port on 127.0.0.1, e.g. channel: 43113")
        if hub not in ("auto", "host", "join"):
            raise LoopbackError(f"loopback CAN: hub must be auto, host or join, not '{hub}'")
        self.host, self.port = parse_channel(channel)
        #: what received frames carry in ``Message.channel``: the channel as given, as python-can's interfaces do
        self.channel = channel
        self.bitrate = bitrate
        self.receive_own_messages = receive_own_messages
        self.send_timeout = float(send_timeout)
        self.channel_info = f"loopback CAN {self._address_text()}"
        try:
            listener = None
            if hub in ("auto", "host"):
                listener = self._try_listen(required=hub == "host")
            if listener is not None:
                rx = self._rx  # not self: the hub thread must not keep the bus alive (python-can's __del__ cleanup)
                self._hub = Hub(listener, lambda record: rx.put((record, True)), self.send_timeout,
                                 self._address_text(), thread=bool(hub_thread))  # fmt: skip
                self.role = "host"
            else:
                self._sock = self._join(float(connect_timeout))
                self._wake_r, self._wake_w = socket.socketpair()
                self._wake_r.setblocking(False)
                self._wake_w.setblocking(False)  # a full pipe is already readable: a wake-up never blocks
                self.role = "join"
            super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        except BaseException:
            self.shutdown()  # no hub thread nor socket outlives a constructor that failed
            raise

    def _address_text(self) -> str:
        return f"[{self.host}]:{self.port}" if ":" in self.host else f"{self.host}:{self.port}"

    def _try_listen(self, required: bool) -> socket.socket | None:
        sock = socket.socket(_family(self.host), socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((self.host, self.port))
            sock.listen(16)
        except OSError as exc:
            sock.close()
            if exc.errno == errno.EADDRINUSE and not required:
                return None
            raise LoopbackError(f"cannot host the loopback CAN hub on {self._address_text()}: {exc}") from None
        return sock

    def _join(self, connect_timeout: float) -> socket.socket:
        deadline = time.monotonic() + connect_timeout
        last: OSError | None = None
        for _ in range(1000):  # bounded: a hub that is still starting refuses for a moment
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            try:
                sock = socket.create_connection((self.host, self.port), timeout=remaining)
            except OSError as exc:
                last = exc
                time.sleep(min(0.02, max(0.0, deadline - time.monotonic())))
                continue
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            greeting = b""
            try:  # the hub greets a bus once it relays frames to it
                sock.settimeout(max(0.05, deadline - time.monotonic()))
                while len(greeting) < len(GREETING):
                    chunk = sock.recv(len(GREETING) - len(greeting))
                    if not chunk:
                        break
                    greeting += chunk
            except OSError as exc:
                last = exc
            if greeting != GREETING:
                sock.close()
                if last is None:
                    last = OSError(f"port {self.port} answered, but not as a loopback CAN hub")
                    break
                continue
            sock.settimeout(self.send_timeout)
            return sock
        raise LoopbackError(
            f"no loopback CAN hub answers on {self._address_text()} within {connect_timeout:g} s ({last}); "
            "start the other side first (e.g. surgiplan-sim-drives) or use hub: auto"
        )

    # ------------------------------------------------------------------ python-can interface
    def _closed_error(self) -> can.CanOperationError:
        return can.CanOperationError(f"{self.channel_info} is shut down")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._transmit([encode(msg)])

    def send_batch(self, messages: list[can.Message]) -> None:
        """Send frames in order with one write to the hub (a real-time loop's SYNC and RPDOs: one system call
        instead of one per frame); every other bus receives them as if sent one by one."""
        self._transmit([encode(msg) for msg in messages])

    def _transmit(self, records: list[bytes]) -> None:
        if self._closing.is_set():
            raise self._closed_error()
        if self._hub is not None:
            rx = self._rx
            # our own frames (receive_own_messages) are queued as the hub stamps them: transmitted, not received
            self._hub.broadcast(records, None, (lambda r: rx.put((r, False))) if self.receive_own_messages else None)
            if self.receive_own_messages and self._hub.thread is None:
                self._hub.wake()  # a receiver serving the hub waits in its select, not on the queue
            return
        with self._send_lock:
            try:
                self._sock.sendall(b"".join(records))
            except OSError as exc:
                if self._closing.is_set():
                    raise self._closed_error() from None
                raise can.CanOperationError(
                    f"{self.channel_info}: the hub is gone ({exc}); its host process ended or stopped reading"
                ) from None
        if self.receive_own_messages:
            for record in records:
                self._rx.put((record, False))  # our own frame: transmitted, not received (as virtual, socketcan)
            if self._wake_w is not None:  # a joined bus's receiver may be waiting in select, not on the queue
                try:
                    self._wake_w.send(b"\0")
                except OSError:
                    pass

    def _queued(self, item: tuple[bytes, bool] | None) -> can.Message:
        if item is None:  # shutdown's wake-up: pass it on to the next waiting thread
            self._rx.put(None)
            raise self._closed_error()
        record, is_rx = item
        return decode(record, self.channel, is_rx)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._closing.is_set():
            raise self._closed_error()
        if self._sock is None and self._hub.thread is None:  # the host without a hub thread: serve it here
            return self._recv_serving(timeout), False
        if self._sock is None:  # the host: the hub thread queues what the others send
            try:
                item = self._rx.get(timeout=timeout) if timeout is None or timeout > 0 else self._rx.get_nowait()
            except queue.Empty:
                return None, False
            return self._queued(item), False
        deadline = None if timeout is None else time.monotonic() + timeout
        if not self._recv_lock.acquire(timeout=-1 if deadline is None else max(0.0, timeout)):
            return None, False  # another thread is receiving for the whole time-out
        try:
            return self._recv_joined(deadline), False
        finally:
            self._recv_lock.release()

    def _recv_serving(self, timeout: float | None) -> can.Message | None:
        """The host without a hub thread: what is queued (frames of others the hub relayed, our own), else serve
        the hub (it queues what it relays) until a frame, the time-out or shutdown."""
        deadline = None if timeout is None else time.monotonic() + timeout
        if not self._recv_lock.acquire(timeout=-1 if deadline is None else max(0.0, timeout)):
            return None  # another thread is receiving (serving) for the whole time-out
        try:
            while True:  # until a frame, the deadline or shutdown: each turn is one round of the hub
                try:
                    return self._queued(self._rx.get_nowait())
                except queue.Empty:
                    pass
                if self._closing.is_set():
                    raise self._closed_error()
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining < 0:
                    return None
                if not self._hub.serve(remaining) and self._rx.empty():
                    raise self._closed_error()
        finally:
            self._recv_lock.release()

    def _recv_joined(self, deadline: float | None) -> can.Message | None:
        """A joined bus: frames of our own (receive_own_messages) first, then those read from the hub."""
        while True:  # until a frame, the deadline, the hub's end or shutdown: each turn waits in select
            if self._closing.is_set():
                raise self._closed_error()
            try:
                return self._queued(self._rx.get_nowait())
            except queue.Empty:
                pass
            if self._pending:
                return decode(self._pending.popleft(), self.channel)
            if self._hub_closed:
                raise can.CanOperationError(f"{self.channel_info}: the hub closed (its host's bus shut down)")
            remaining = None if deadline is None else max(0.0, deadline - time.monotonic())
            try:
                readable, _, _ = select.select([self._sock, self._wake_r], [], [], remaining)
            except (OSError, ValueError) as exc:
                if self._closing.is_set():
                    raise self._closed_error() from None
                raise can.CanOperationError(f"{self.channel_info}: {exc}") from None
            if self._closing.is_set():
                raise self._closed_error()
            if self._wake_r in readable:  # an own frame was queued: drain the wake-ups and look again
                try:
                    self._wake_r.recv(4096)
                except OSError:
                    pass
            if self._sock in readable:
                try:
                    chunk = self._sock.recv(65536)
                except (OSError, ValueError) as exc:
                    if self._closing.is_set():
                        raise self._closed_error() from None
                    raise can.CanOperationError(f"{self.channel_info}: {exc}") from None
                if not chunk:
                    if self._closing.is_set():
                        raise self._closed_error()
                    self._hub_closed = True
                    continue
                self._reader.feed(chunk)
                self._pending.extend(self._reader.records())
                continue
            if not readable or (deadline is not None and time.monotonic() >= deadline):
                if self._rx.empty():
                    return None

    def shutdown(self) -> None:
        """Close the bus: the hub (if this bus hosts it) or the connection to it. Any thread waiting in
        :meth:`recv` is woken with ``can.CanOperationError``, as is every later ``recv`` and ``send``."""
        super().shutdown()  # always (python-can's contract), even when the constructor did not finish
        closing = getattr(self, "_closing", None)
        if closing is None or closing.is_set():
            return
        closing.set()
        self._rx.put(None)  # wakes a thread waiting on the host's queue
        if self._wake_w is not None:
            try:
                self._wake_w.send(b"\0")  # wakes a thread waiting in a joined bus's select
            except OSError:
                pass
        hub = self._hub
        if hub is not None and hub.thread is not None:
            hub.close()
        elif hub is not None:  # a receiver serving it leaves at once; it closes below, once none does
            hub.closed.set()
            hub.wake()
        if self._sock is not None:
            try:
                self._sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        # close the sockets once no thread reads them (the wake-up above makes a reader leave at once)
        locked = self._recv_lock.acquire(timeout=2.0)
        try:
            if hub is not None and hub.thread is None:
                hub.close()
            for sock in (self._sock, self._wake_r, self._wake_w):
                if sock is not None:
                    sock.close()
        finally:
            if locked:
                self._recv_lock.release()

    @staticmethod
    def _detect_available_configs() -> list:
        return []
