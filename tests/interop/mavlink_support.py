"""Helpers of the MAVLink conformance suite: the simulated vehicle, third-party clients, loopback checks.

The clients are the ones users run: MAVSDK (the ``mavsdk`` package, 4.x: the
C++ library in-process through its C wrapper, no ``mavsdk_server``), MAVProxy
(``mavproxy.py``, a separate program driven through its command line) and
plain pymavlink. Each talks to the simulated vehicle (``surgiplan-sim-vehicle``
in a thread of the test, so that the test can read its ground truth) over UDP
on 127.0.0.1 only; MAVSDK's native sockets are invisible to the suite's
network guard, so :func:`inet_sockets` lists what the process has bound, from
``/proc``, and the tests check it.
"""

from __future__ import annotations

import contextlib
import math
import os
import queue
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from surgiplan.plugins.devices.mavlink.conventions import EARTH_RADIUS
from surgiplan.plugins.devices.mavlink.sim.settings import SimSettings
from surgiplan.plugins.devices.mavlink.sim.vehicle import SimulatedVehicle

#: the simulated vehicle of the suite: faster than real time, calm air
FAST = {"speed": 10.0}


def free_udp_port() -> int:
    """A UDP port free on 127.0.0.1 now (for a client that listens: ``udpin://127.0.0.1:PORT``)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextlib.contextmanager
def simulated(connection: str = "udpin:127.0.0.1:0", **settings):
    """The simulated vehicle in a thread (its ground truth readable by the test)."""
    vehicle = SimulatedVehicle(SimSettings(**{**FAST, **settings}), connection).start()
    try:
        yield vehicle
    finally:
        vehicle.stop()


def inet_sockets(pid: int | None = None) -> list[tuple[str, str, int]]:
    """Every IPv4/IPv6 UDP and TCP socket of a process: (protocol, local address, local port), from /proc."""
    pid = os.getpid() if pid is None else pid
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        with contextlib.suppress(OSError):
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    found = []
    for proto in ("udp", "udp6", "tcp", "tcp6"):
        path = Path(f"/proc/{pid}/net/{proto}")
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            if fields[9] not in inodes:
                continue
            address, port = fields[1].split(":")
            found.append((proto, _address(address), int(port, 16)))
    return found


def _address(hex_address: str) -> str:
    raw = bytes.fromhex(hex_address)
    if len(raw) == 4:
        return socket.inet_ntop(socket.AF_INET, raw[::-1])
    words = [raw[i : i + 4][::-1] for i in range(0, 16, 4)]
    return socket.inet_ntop(socket.AF_INET6, b"".join(words))


def not_loopback(sockets) -> list:
    """The sockets bound to anything but 127.0.0.0/8 or ::1 (the wildcard address included)."""
    import ipaddress

    return [s for s in sockets if not ipaddress.ip_address(s[1]).is_loopback]


def ground_distance(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Great-circle distance (m) on PX4's sphere (haversine): an independent measure of a position error."""
    p1, p2 = math.radians(lat1), math.radians(lat2)
    h = math.sin((p2 - p1) / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(math.radians(lon2 - lon1) / 2) ** 2
    return 2 * EARTH_RADIUS * math.asin(math.sqrt(h))


def offset(lat: float, lon: float, north: float, east: float) -> tuple[float, float]:
    """The point ``north``, ``east`` metres from lat/lon (small offsets, spherical Earth)."""
    return (
        lat + math.degrees(north / EARTH_RADIUS),
        lon + math.degrees(east / (EARTH_RADIUS * math.cos(math.radians(lat)))),
    )


# ----------------------------------------------------------------------------- MAVSDK


def mavsdk_or_skip():
    """The ``mavsdk`` package (4.x, asyncio API), or skip saying why."""
    mavsdk = pytest.importorskip("mavsdk", reason="MAVSDK is not installed (pip install '.[interop]')")
    version = getattr(mavsdk, "__version__", "0")
    if int(version.split(".")[0]) < 4:
        pytest.skip(f"mavsdk {version} is the gRPC MAVSDK-Python; the suite needs mavsdk>=4 (pip install '.[interop]')")
    return mavsdk


# ----------------------------------------------------------------------------- MAVProxy


def mavproxy_or_skip() -> str:
    """The ``mavproxy.py`` program, or skip saying why."""
    beside = Path(sys.executable).with_name("mavproxy.py")
    program = str(beside) if beside.exists() else shutil.which("mavproxy.py")
    if program is None:
        pytest.skip("MAVProxy is not installed (pip install '.[interop]')")
    return program


class MavproxySession:
    """``mavproxy.py`` as a user runs it, commands typed on its standard input, its output read line by line.

    Every wait is bounded (:meth:`expect` raises ``AssertionError`` with what was printed); the process is
    ended by :meth:`close` (its own ``exit``... MAVProxy has none on stdin: terminate, then kill).
    """

    def __init__(self, master: str, workdir: Path, modules: str = "param,wp,cmdlong,misc,mode,arm,fence,rally"):
        program = mavproxy_or_skip()
        command = [sys.executable, program, f"--master={master}", "--no-state", f"--default-modules={modules}"]
        self.process = subprocess.Popen(
            command,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=workdir,
        )
        self.lines: list[str] = []
        self._queue: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.process.stdout:
            self._queue.put(line.rstrip("\n"))

    def send(self, command: str) -> None:
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()

    def expect(self, pattern: str, timeout: float = 15.0) -> re.Match:
        """Wait for an output line matching ``pattern`` (a regex), at most ``timeout`` s."""
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                tail = "\n".join(self.lines[-25:])
                raise AssertionError(f"MAVProxy printed no line matching {pattern!r} within {timeout:g} s:\n{tail}")
            try:
                line = self._queue.get(timeout=min(remaining, 0.2))
            except queue.Empty:
                continue
            self.lines.append(line)
            match = regex.search(line)
            if match:
                return match

    def collect(self, pattern: str, count: int, timeout: float = 15.0) -> list[re.Match]:
        """The next ``count`` lines matching ``pattern``."""
        return [self.expect(pattern, timeout) for _ in range(count)]

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=5)
        if self.process.stdin:
            with contextlib.suppress(OSError):
                self.process.stdin.close()
        if self.process.stdout:
            self.process.stdout.close()

    def __enter__(self) -> MavproxySession:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
