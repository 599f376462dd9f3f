"""The loopback CAN interface judged against python-can itself, beyond python-can's vendored tests
(``tests/interop/pycan_tests``): its back-to-back tests again with ``receive_own_messages=True`` (the flag
the loopback docstring promises); the direction flag, time stamps and shutdown compared with python-can's
reference interface ``virtual``; and ``python -m can.logger`` -> ``can.LogReader`` / ``python -m
can.player`` round trips through ``.log``, ``.asc`` and ``.blf`` files."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import threading
import time

import can
import pytest
from pycan_tests import back2back_test as b2b
from pycan_tests import free_port, free_ports
from pycan_tests.config import TEST_CAN_FD


class TestBackToBackReceivingOwnMessages(b2b.Back2BackTestCase):
    """python-can's back-to-back tests, both buses opened with ``receive_own_messages=True``."""

    def setUp(self):
        self.CHANNEL_1 = self.CHANNEL_2 = free_port()
        kw = {"interface": "loopback", "bitrate": self.BITRATE, "fd": TEST_CAN_FD, "receive_own_messages": True}
        self.bus1 = can.Bus(channel=self.CHANNEL_1, **kw)
        self.bus2 = can.Bus(channel=self.CHANNEL_2, **kw)


def _exchange(interface: str, channel) -> list[tuple[str, bool, object]]:
    """Who receives what, with which direction flag and channel: a sends one frame, b and a (own) receive it."""
    with (
        can.Bus(channel, interface=interface, receive_own_messages=True) as a,
        can.Bus(channel, interface=interface) as b,
    ):
        a.send(can.Message(arbitration_id=0x55, data=b"\x01", is_extended_id=False))
        got_b, got_a = b.recv(2.0), a.recv(2.0)
        a.send(can.Message(arbitration_id=0x56, data=b"\x02", is_extended_id=False))
        b.send(can.Message(arbitration_id=0x57, data=b"\x03", is_extended_id=False))
        rest = [a.recv(2.0), a.recv(2.0)]
        return [("b", got_b.is_rx, got_b.channel), ("a", got_a.is_rx, got_a.channel)] + [
            (hex(m.arbitration_id), m.is_rx, m.channel) for m in rest
        ]


def test_direction_flag_and_channel_as_virtual_sets_them():
    """is_rx: False on a bus's own frames, True on the others' (python-can's virtual, the reference); the
    channel: the one the bus was opened with."""
    port = free_port()
    loopback = _exchange("loopback", port)
    virtual = _exchange("virtual", port)  # virtual's channel is any object: the same port number
    assert loopback == virtual
    assert loopback == [("b", True, port), ("a", False, port), ("0x56", False, port), ("0x57", True, port)]


@pytest.mark.parametrize("reader", ["host", "join"])
def test_a_frame_read_late_carries_the_time_it_was_sent(reader):
    """A frame is stamped with the time it went on the bus (its sender's), not when the hub relayed it or the
    application got round to reading it."""
    port = free_port()
    with can.Bus(port, interface="loopback") as host, can.Bus(port, interface="loopback") as joined:
        sender, receiver = (joined, host) if reader == "host" else (host, joined)
        before = time.time()
        sender.send(can.Message(arbitration_id=0x10, timestamp=12.5))  # what a message carries is not sent
        after = time.time()
        time.sleep(0.5)
        msg = receiver.recv(2.0)
        read = time.time()
    assert before <= msg.timestamp <= after  # its sender's time, whoever relayed it when
    assert read - msg.timestamp >= 0.3


def test_every_bus_sees_one_order_and_times_that_never_go_back():
    """As on a real bus: three buses sending at once from three threads; every bus receives the others'
    frames with time stamps that never decrease, and a frame carries the same stamp on every bus."""
    port = free_port()
    buses = [can.Bus(port, interface="loopback") for _ in range(3)]
    try:

        def send(k: int) -> None:
            for i in range(200):
                buses[k].send(can.Message(arbitration_id=0x100 + k, data=i.to_bytes(2, "little"), is_extended_id=False))

        threads = [threading.Thread(target=send, args=(k,)) for k in range(3)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(30)
        seen = [[bus.recv(5.0) for _ in range(400)] for bus in buses]
        stamps: dict[tuple[int, bytes], set[float]] = {}
        for k, got in enumerate(seen):
            assert all(m is not None for m in got) and buses[k].recv(0.1) is None
            assert sorted(m.arbitration_id - 0x100 for m in got).count(k) == 0  # not its own
            times = [m.timestamp for m in got]
            assert times == sorted(times), f"bus {k}: a time stamp went back"
            for m in got:
                stamps.setdefault((m.arbitration_id, bytes(m.data)), set()).add(m.timestamp)
        assert len(stamps) == 600 and all(len(t) == 1 for t in stamps.values())
    finally:
        for bus in reversed(buses):
            bus.shutdown()


@pytest.mark.parametrize("role", ["host", "join"])
def test_a_thread_waiting_in_recv_is_woken_by_shutdown(role):
    """python-can's contract (virtual): receiving on a closed bus raises CanOperationError, a thread already
    waiting included; and it does so at once, not after spinning."""
    port = free_port()
    host = can.Bus(port, interface="loopback")
    joined = can.Bus(port, interface="loopback")
    bus, other = (host, joined) if role == "host" else (joined, host)
    outcome: list[BaseException | can.Message | None] = []

    def wait() -> None:
        try:
            outcome.append(bus.recv())  # no time-out: only a frame or the shutdown ends it
        except BaseException as exc:
            outcome.append(exc)

    thread = threading.Thread(target=wait, daemon=True)
    thread.start()
    time.sleep(0.2)
    cpu = time.process_time()
    time.sleep(0.3)
    waiting_cpu = time.process_time() - cpu
    bus.shutdown()
    thread.join(5.0)
    try:
        assert not thread.is_alive()
        assert len(outcome) == 1 and isinstance(outcome[0], can.CanOperationError), outcome
        assert "shut down" in str(outcome[0])
        assert waiting_cpu < 0.15  # blocked, not spinning (a spinning thread takes ~0.3 s of 0.3 s)
        for _ in range(3):  # and every later call, without waiting
            with pytest.raises(can.CanOperationError, match="shut down"):
                bus.recv(1.0)
        with pytest.raises(can.CanOperationError, match="shut down"):
            bus.send(can.Message())
    finally:
        other.shutdown()
        bus.shutdown()


def test_a_constructor_that_fails_after_the_hub_started_leaves_nothing_behind(monkeypatch):
    """python-can's BusABC.__init__ runs last; should it fail, the hub this bus started is closed again."""
    port = free_port()

    def refuse(self, *args, **kwargs):
        raise can.CanInitializationError("refused (injected)")

    with monkeypatch.context() as patch:
        patch.setattr(can.BusABC, "__init__", refuse)
        with pytest.raises(can.CanInitializationError, match="injected"):
            can.Bus(port, interface="loopback", hub="host")
    with can.Bus(port, interface="loopback", hub="host") as bus:  # the port is free: nobody hosts it
        assert bus.role == "host"


FRAMES = [
    can.Message(arbitration_id=0x123, data=bytes(range(8)), is_extended_id=False),
    can.Message(arbitration_id=0x1ABCDEF0, data=b"\x01\x02", is_extended_id=True),
    can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False),
    can.Message(arbitration_id=0x200, is_remote_frame=True, dlc=4, is_extended_id=False),
    can.Message(arbitration_id=0x456, data=bytes(range(64)), is_fd=True, bitrate_switch=True, is_extended_id=False),
    can.Message(arbitration_id=0x18FF00AA, data=bytes(range(12)), is_fd=True, is_extended_id=True),
]


def _same_frame(got: can.Message, sent: can.Message, remote_dlc: bool = True) -> bool:
    """Equal but for the time stamp, direction and channel (and a remote frame's length where the file format
    has no place for it: python-can's canutils ``.log`` writes ``ID#R``)."""
    return (
        got.arbitration_id == sent.arbitration_id
        and got.is_extended_id == sent.is_extended_id
        and got.is_remote_frame == sent.is_remote_frame
        and (got.dlc == sent.dlc or (sent.is_remote_frame and not remote_dlc))
        and (sent.is_remote_frame or bytes(got.data) == bytes(sent.data))
        and got.is_fd == sent.is_fd
        and got.bitrate_switch == sent.bitrate_switch
    )


def _run_module(module: str, *args: str) -> subprocess.Popen:
    """``python -m module args`` with Ctrl-C (SIGINT) raising KeyboardInterrupt, as in a terminal.

    A process started in the background by a non-interactive shell (``cmd &``, as CI runners may) inherits SIGINT
    ignored, and Python then installs no handler: can.logger would never see the Ctrl-C it stops on. -u: its lines
    reach us as printed; -X faulthandler: a process that does not end in time is asked (SIGABRT) where it is stuck.
    """
    code = (
        "import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
        f"sys.argv[0] = {module!r}; runpy.run_module({module!r}, run_name='__main__', alter_sys=True)"
    )
    return subprocess.Popen(
        [sys.executable, "-u", "-X", "faulthandler", "-c", code, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _started(process: subprocess.Popen, marker: str, timeout: float = 60.0) -> str:
    """What ``process`` printed up to the line with ``marker`` (bounded in time); "" if it never came."""
    seen = ""
    deadline = time.monotonic() + timeout
    while marker not in seen and time.monotonic() < deadline and process.poll() is None:
        ready, _, _ = select.select([process.stdout], [], [], 0.1)
        if ready:  # from the descriptor: the file object's buffer would hide lines from select
            seen += os.read(process.stdout.fileno(), 4096).decode()
    return seen


def _ended(process: subprocess.Popen, timeout: float) -> tuple[str, str]:
    """Its output once it ends; if it does not within ``timeout`` s, where it is stuck (faulthandler's dump)."""
    try:
        return process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.send_signal(signal.SIGABRT)
        _, err = process.communicate(timeout=30)
        raise AssertionError(f"{process.args} did not end within {timeout:g} s of SIGINT; its stacks:\n{err}") from None


SUFFIXES = (".log", ".asc", ".blf")


def test_can_logger_writes_what_can_logreader_and_can_player_read_back(tmp_path):
    """Three ``can.logger`` processes (one per format) on one bus, then three ``can.player`` processes, each
    on a bus of its own (the processes start together: each takes seconds to import python-can and us)."""
    port = free_port()
    paths = {suffix: tmp_path / f"capture{suffix}" for suffix in SUFFIXES}
    with can.Bus(port, interface="loopback", hub="host") as host:
        loggers = {
            s: _run_module("can.logger", "-i", "loopback", "-c", str(port), "-f", str(paths[s])) for s in SUFFIXES
        }
        try:
            # each logger has connected, made its file and is about to receive (it says so)
            started = {s: _started(logger, "Can Logger (Started") for s, logger in loggers.items()}
            assert all("Can Logger (Started" in text for text in started.values()), started
            deadline = time.monotonic() + 60
            while len(host._hub.peers) < len(loggers) and time.monotonic() < deadline:
                if any(logger.poll() is not None for logger in loggers.values()):
                    break
                time.sleep(0.02)
            assert len(host._hub.peers) == len(loggers)
            sent = []  # (frame, time just before, time just after sending it)
            for msg in FRAMES:
                before = time.time()
                host.send(msg)
                sent.append((msg, before, time.time()))
                time.sleep(0.02)
            time.sleep(0.3)  # the loggers have them (they write what they received when stopped)
        finally:
            for logger in loggers.values():
                logger.send_signal(signal.SIGINT)
            outputs = {s: _ended(logger, 60) for s, logger in loggers.items()}
    for suffix, logger in loggers.items():
        out, err = outputs[suffix]
        out = started[suffix] + out
        assert logger.returncode == 0, out + err
        assert f"Connected to LoopbackBus: loopback CAN 127.0.0.1:{port}" in out

    for suffix, path in paths.items():
        read = list(can.LogReader(str(path)))
        assert len(read) == len(FRAMES), suffix
        remote_dlc = suffix != ".log"
        assert all(_same_frame(got, msg, remote_dlc) for got, (msg, _, _) in zip(read, sent, strict=True)), suffix
        if suffix == ".log":  # canutils names a numeric channel canN; absolute times to the microsecond
            assert {m.channel for m in read} == {f"can{port}"}
            assert all(b - 1e-6 <= m.timestamp <= a + 1e-6 for m, (_, b, a) in zip(read, sent, strict=True))
        else:  # .asc and .blf: the gaps between frames are those between sending them
            for i in range(1, len(read)):
                gap = read[i].timestamp - read[i - 1].timestamp
                assert sent[i][1] - sent[i - 1][2] - 2e-5 <= gap <= sent[i][2] - sent[i - 1][1] + 2e-5, suffix

    ports = dict(zip(SUFFIXES, free_ports(len(SUFFIXES)), strict=True))
    hosts = {s: can.Bus(ports[s], interface="loopback", hub="host") for s in SUFFIXES}
    try:
        players = {s: _run_module("can.player", "-i", "loopback", "-c", str(ports[s]), str(paths[s])) for s in SUFFIXES}
        for player in players.values():
            out, err = player.communicate(timeout=120)  # it plays the file and ends; its frames wait in our queue
            assert player.returncode == 0, out + err
        for suffix, bus in hosts.items():
            played = [bus.recv(5.0) for _ in FRAMES]
            remote_dlc = suffix != ".log"
            assert all(m is not None and _same_frame(m, f, remote_dlc) for m, f in zip(played, FRAMES, strict=True))
            assert all(m.is_rx and m.channel == ports[suffix] for m in played)
            assert bus.recv(0.2) is None  # nothing twice
    finally:
        for bus in hosts.values():
            bus.shutdown()
