"""The loopback CAN transport (``interface: loopback``): frames between buses and processes, in order,
never off the machine; canopen's own classes over it; and the suite's loopback-only guard."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import can
import canopen
import pytest
from surgiplan.plugins.devices.canopen.sim.loopback import LoopbackError, parse_channel

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def frame(can_id: int, data: bytes = b"", **kw) -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=kw.pop("is_extended_id", False), **kw)


def test_every_bus_on_a_channel_receives_every_other_buss_frames_in_order_and_not_its_own():
    port = free_port()
    buses = [can.Bus(interface="loopback", channel=port) for _ in range(3)]
    try:
        assert [b.role for b in buses] == ["host", "join", "join"]
        for sender, bus in enumerate(buses):
            for i in range(50):
                bus.send(frame(0x100 + sender, bytes([i, sender])))
            for receiver, other in enumerate(buses):
                if receiver == sender:
                    continue
                got = [other.recv(2.0) for _ in range(50)]
                assert [m.arbitration_id for m in got] == [0x100 + sender] * 50
                assert [bytes(m.data) for m in got] == [bytes([i, sender]) for i in range(50)]
            assert all(b.recv(0.05) is None for b in buses)  # nobody got a frame twice, nor their own
    finally:
        for b in reversed(buses):
            b.shutdown()


def test_frame_fields_survive_the_trip():
    port = free_port()
    with (
        can.Bus(interface="loopback", channel=f"127.0.0.1:{port}") as a,
        can.Bus(interface="loopback", channel=str(port), receive_own_messages=True) as b,
    ):
        sent = [
            frame(0x7FF, bytes(range(8))),
            frame(0x1ABCDEF0, b"\x01", is_extended_id=True),
            frame(0x123, is_remote_frame=True, dlc=4),
            frame(0x456, bytes(range(64)), is_fd=True, bitrate_switch=True),
            frame(0x000, b""),
        ]
        for m in sent:
            b.send(m)
        for m in sent:
            for bus in (a, b):  # b receives its own frames as asked
                got = bus.recv(2.0)
                assert got.arbitration_id == m.arbitration_id and got.is_extended_id == m.is_extended_id
                assert got.is_remote_frame == m.is_remote_frame and got.is_fd == m.is_fd
                assert got.bitrate_switch == m.bitrate_switch and got.dlc == m.dlc
                assert bytes(got.data) == (b"" if m.is_remote_frame else bytes(m.data))


@pytest.mark.parametrize(
    "channel, message",
    [
        ("192.168.1.10:43113", "not a loopback address"),
        ("239.74.163.2:43113", "not a loopback address"),
        ("[ff02::1]:43113", "not a loopback address"),
        ("example.org:43113", "not an IP address"),
        ("70000", "outside 1-65535"),
        ("port", "is not a number"),
    ],
)
def test_a_channel_off_the_loopback_interface_is_refused(channel, message):
    with pytest.raises(LoopbackError, match=message):
        can.Bus(interface="loopback", channel=channel)


def test_loopback_hosts_are_accepted():
    assert parse_channel("43113") == ("127.0.0.1", 43113)
    assert parse_channel("localhost:5") == ("127.0.0.1", 5)
    assert parse_channel("127.9.9.9:5") == ("127.9.9.9", 5)
    assert parse_channel("[::1]:5") == ("::1", 5)


def test_joining_a_channel_nobody_hosts_is_a_clear_error():
    with pytest.raises(LoopbackError, match=r"no loopback CAN hub answers on 127\.0\.0\.1:\d+ within 0\.3 s"):
        can.Bus(interface="loopback", channel=free_port(), hub="join", connect_timeout=0.3)


def test_the_hosts_shutdown_is_a_bus_error_on_the_others():
    port = free_port()
    host = can.Bus(interface="loopback", channel=port)
    peer = can.Bus(interface="loopback", channel=port)
    host.shutdown()
    with pytest.raises(can.CanOperationError, match="the hub closed"):
        peer.recv(2.0)
    peer.shutdown()


class Receiving:
    """A thread receiving on ``bus`` until stopped (as the simulated drives' thread does): what it got, in order."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.got: list[can.Message] = []
        self.error: Exception | None = None
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        for _ in range(100_000):  # bounded: 0.05 s a turn at most, a few minutes in all
            if self.stop.is_set():
                return
            try:
                msg = self.bus.recv(0.05)
            except can.CanOperationError as exc:
                self.error = exc
                return
            if msg is not None:
                self.got.append(msg)

    def wait_for(self, count: int, timeout: float = 5.0) -> list[can.Message]:
        deadline = time.monotonic() + timeout
        while len(self.got) < count and time.monotonic() < deadline:
            time.sleep(0.01)
        return list(self.got)


def test_a_host_without_a_hub_thread_relays_every_frame_while_it_receives():
    """``hub_thread=False``: no thread of the hub's own; the thread receiving on the hosting bus accepts the others
    and relays their frames (to itself and to each other, in order), and its own frames go out from send()."""
    port = free_port()
    host = can.Bus(interface="loopback", channel=port, hub_thread=False)
    receiving = Receiving(host)
    joined = []
    try:
        assert host.role == "host" and host._hub.thread is None
        assert not [t for t in threading.enumerate() if t.name.startswith("loopback-can-hub")]
        joined = [can.Bus(interface="loopback", channel=port, hub="join", connect_timeout=2.0) for _ in range(2)]
        before = time.time()
        for i in range(50):
            joined[0].send(frame(0x181, bytes([i])))
        after = time.time()
        got = receiving.wait_for(50)
        assert [bytes(m.data) for m in got] == [bytes([i]) for i in range(50)]
        assert all(before <= m.timestamp <= after for m in got)  # the time each was sent
        assert [bytes(joined[1].recv(2.0).data) for _ in range(50)] == [bytes([i]) for i in range(50)]
        host.send(frame(0x80))
        assert [joined[k].recv(2.0).arbitration_id for k in (0, 1)] == [0x80, 0x80]
        assert joined[0].recv(0.05) is None and len(receiving.got) == 50  # nobody got a frame twice, nor its own
    finally:
        started = time.monotonic()
        host.shutdown()  # wakes the receiving thread at once, with the bus error
        receiving.thread.join(2.0)
        assert not receiving.thread.is_alive() and time.monotonic() - started < 1.0
        assert isinstance(receiving.error, can.CanOperationError)
        for bus in joined:
            bus.shutdown()


def test_a_host_without_a_hub_thread_receives_its_own_frames_while_it_waits():
    port = free_port()
    with can.Bus(interface="loopback", channel=port, hub_thread=False, receive_own_messages=True) as host:
        receiving = Receiving(host)
        try:
            time.sleep(0.05)  # waiting in the hub's select, not on the queue its own frames go to
            host.send(frame(0x80))
            got = receiving.wait_for(1, timeout=1.0)
            assert [(m.arbitration_id, m.is_rx) for m in got] == [(0x80, False)]
        finally:
            receiving.stop.set()
            receiving.thread.join(2.0)


DRIVE = textwrap.dedent(
    """
    import sys, threading, signal
    import canopen
    network = canopen.Network()
    network.connect(interface="loopback", channel=sys.argv[1], hub="host")
    node = canopen.LocalNode(5, canopen.ObjectDictionary())
    od = node.object_dictionary
    var = canopen.objectdictionary.ODVariable("Device type", 0x1000, 0)
    var.data_type = canopen.objectdictionary.UNSIGNED32
    var.default = 0x00020192
    od.add_object(var)
    network.add_node(node)
    print("ready", flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    stop.wait(20)
    network.disconnect()
    """
)


def test_canopen_sdo_between_two_processes_over_the_loopback_bus():
    """canopen's own Network and SDO client (not surgiplan's master) reach a node in another process."""
    port = free_port()
    process = subprocess.Popen([sys.executable, "-c", DRIVE, str(port)], stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline().strip() == "ready"
        network = canopen.Network()
        network.connect(interface="loopback", channel=port, hub="join")
        try:
            node = network.add_node(5, canopen.ObjectDictionary())
            assert int.from_bytes(node.sdo.upload(0x1000, 0), "little") == 0x00020192
        finally:
            network.disconnect()
    finally:
        process.terminate()
        process.wait(timeout=10)


def test_the_guard_refuses_and_reports_a_non_loopback_send(tmp_path, monkeypatch):
    """The suite's guard (tests/netguard) is live: a multicast send, as python-can's udp_multicast makes,
    is refused before it leaves, in this process and in a subprocess."""
    import surgiplan_netguard as guard

    monkeypatch.setenv("SURGIPLAN_NETGUARD_LOG", str(tmp_path / "log"))
    # every attempt is made on a socket already closed: the audit hook sees the call (and refuses it) before
    # the descriptor is used, and should the guard ever fail the call ends in EBADF, so nothing can leave
    # this host or listen on it whatever happens (the refusal is still asserted: OSError is not it)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.close()
    with pytest.raises(guard.NetworkPolicyError):
        sock.sendto(b"x", ("239.74.163.2", 43113))
    code = (
        "import socket; s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.close(); "
        "s.sendto(b'x', ('239.74.163.2', 43113))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert result.returncode != 0 and "network guard" in result.stderr
    log = (tmp_path / "log").read_text()
    assert log.count("socket.sendto to ('239.74.163.2', 43113)") == 2
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.close()
    with pytest.raises(guard.NetworkPolicyError):
        sock.bind(("0.0.0.0", 0))  # listening on every interface is refused too


@pytest.mark.slow
def test_device_tests_pass_in_a_network_namespace_with_only_loopback():
    """The device tests that start drives in other processes, run where only ``lo`` exists
    (``unshare --net``): anything sent off the machine would fail with 'network unreachable'."""
    unshare = shutil.which("unshare")
    if unshare is None:
        pytest.skip("no unshare(1) on this machine (util-linux)")
    probe = subprocess.run([unshare, "-rn", "true"], capture_output=True, text=True, timeout=30)
    if probe.returncode != 0:
        pytest.skip(f"cannot create a network namespace here: {probe.stderr.strip()}")
    script = (
        "ip link set lo up 2>/dev/null || true; "
        "test $(ip -o link | wc -l) -eq 1 || exit 97; "
        f"exec {sys.executable} -m pytest -q -p no:cacheprovider "
        "tests/test_devices_realtime.py tests/test_can_loopback.py -k 'not namespace'"
    )
    result = subprocess.run([unshare, "-rn", "sh", "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert result.returncode != 97, "the namespace has an interface besides lo"
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert " passed" in result.stdout and "failed" not in result.stdout
