"""Helpers for the CANopen conformance tests: drives in another process, canopen's own master here,
the traffic captured by python-can's logger and checked against CiA 301.

Nothing here uses surgiplan's master: the drives are reached only through CAN frames on the loopback
bus (a hub on 127.0.0.1 that the drives' process hosts), by ``canopen.Network`` and ``BaseNode402``.
The CiA 301 rules (COB-IDs of the predefined connection set, frame lengths, NMT and heartbeat values)
are written here from the standard, not taken from the code under test.
"""

from __future__ import annotations

import contextlib
import importlib.resources
import select
import socket
import subprocess
import sys
import time
from pathlib import Path

import can
import canopen
from canopen.profiles.p402 import BaseNode402

GIMBAL_JOINTS = ["yaw", "pitch", "insertion", "roll"]
#: where the simulated gimbal's axes stand at power-up (yaw, pitch rad; insertion m; roll rad)
GIMBAL_INITIAL = [0.0, 0.6, 0.12, 0.0]
#: the node id this test's master uses for its own heartbeat
MASTER_ID = 0x7F


def eds_path(device: str, joint: str) -> Path:
    """The EDS shipped with the installed device package (what a third-party tool would load)."""
    return Path(str(importlib.resources.files(f"surgiplan.plugins.devices.{device}"))) / "eds" / f"{device}_{joint}.eds"


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextlib.contextmanager
def drives_process(
    device: str = "cast_gimbal", initial=None, node_ids=None, start_timeout: float = 120.0, sync_timeout=None, extra=()
):
    """``surgiplan-sim-drives`` in a process of its own, hosting the loopback hub (``extra``: more arguments);
    yields the channel (port)."""
    port = free_port()
    command = [sys.executable, "-m", "surgiplan.plugins.devices.canopen.sim.process", "--device", device]
    command += ["--interface", "loopback", "--channel", str(port), "--option", "hub=host"]
    if initial is not None:
        command += ["--initial", *map(str, initial)]
    if node_ids is not None:
        command += ["--node-ids", *map(str, node_ids)]
    if sync_timeout is not None:  # the drives' SYNC watchdog (s): lenient where a loaded machine delays SYNCs
        command += ["--sync-timeout", str(sync_timeout)]
    command += list(extra)
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([process.stdout], [], [], start_timeout)
        line = process.stdout.readline().strip() if ready else ""
        if line != "ready":
            process.kill()
            raise RuntimeError(f"the drives did not start ({line!r}): {process.stderr.read()[-2000:]}")
        yield port
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=10)


@contextlib.contextmanager
def capture(port: int, path: Path):
    """Every frame on the bus, written by python-can's logger (BLF, ASC, ... by the file's suffix)."""
    bus = can.Bus(interface="loopback", channel=port, hub="join")
    logger = can.Logger(str(path))
    notifier = can.Notifier(bus, [logger], timeout=0.05)
    try:
        yield path
    finally:
        time.sleep(0.2)  # the last answers reach the logger
        try:
            notifier.stop(timeout=2.0)  # stops (flushes and closes) the logger too
        finally:
            bus.shutdown()


def read_log(path: Path) -> list[can.Message]:
    """The frames of a log file, decoded by python-can's reader for its format."""
    return [msg for msg in can.LogReader(str(path)) if not msg.is_error_frame]


@contextlib.contextmanager
def master(port: int):
    """canopen's own ``Network`` on the loopback bus (its Notifier thread receives)."""
    network = canopen.Network()
    network.connect(interface="loopback", channel=port, hub="join")
    try:
        yield network
    finally:
        network.sync.stop()
        network.disconnect()


def node402(network: canopen.Network, node_id: int, joint: str, device: str = "cast_gimbal") -> BaseNode402:
    """A canopen ``BaseNode402`` with the drive's EDS as its dictionary, with time-outs for a loaded machine."""
    node = BaseNode402(node_id, str(eds_path(device, joint)))
    node.sdo.RESPONSE_TIMEOUT = 1.0
    node.TIMEOUT_SWITCH_STATE_FINAL = 5.0
    node.TIMEOUT_SWITCH_STATE_SINGLE = 2.0
    node.TIMEOUT_CHECK_TPDO = 1.0
    node.TIMEOUT_SWITCH_OP_MODE = 2.0
    node.TIMEOUT_RESET_FAULT = 1.0
    network.add_node(node)
    return node


def wait_for(condition, timeout: float = 5.0, step: float = 0.01):
    """Poll ``condition()`` until it is truthy (bounded: ``timeout`` s); returns its last value."""
    deadline = time.monotonic() + timeout
    value = condition()
    while not value and time.monotonic() < deadline:
        time.sleep(step)
        value = condition()
    return value


# ----------------------------------------------------------------------------- CiA 301 from the standard
#: function codes of the predefined connection set (CiA 301 §7.3.3, Table 3): COB-ID = code << 7 | node
SERVICES = {
    0x0: "NMT",
    0x1: "SYNC/EMCY",
    0x2: "TIME",
    0x3: "TPDO1",
    0x4: "RPDO1",
    0x5: "TPDO2",
    0x6: "RPDO2",
    0x7: "TPDO3",
    0x8: "RPDO3",
    0x9: "TPDO4",
    0xA: "RPDO4",
    0xB: "SDO server->client",
    0xC: "SDO client->server",
    0xE: "NMT error control",
}
NMT_COMMANDS = {0x01, 0x02, 0x80, 0x81, 0x82}
HEARTBEAT_STATES = {0x00, 0x04, 0x05, 0x7F}  # boot-up, stopped, operational, pre-operational


def service(can_id: int) -> tuple[str, int]:
    """(service, node id) of an 11-bit COB-ID in the predefined connection set."""
    code, node = can_id >> 7, can_id & 0x7F
    name = SERVICES.get(code, "unknown")
    if code == 0x1:
        name = "SYNC" if node == 0 else "EMCY"
    return name, node


def cia301_violations(frames: list[can.Message], nodes: set[int], pdo_lengths: dict[int, int]) -> list[str]:
    """What in ``frames`` breaks CiA 301: unknown COB-IDs, wrong lengths, bad NMT/heartbeat values,
    a node talking between a reset command and its boot-up, an SDO request without an answer
    from a node that is not STOPPED. ``pdo_lengths``: the PDOs mapped, COB-ID -> bytes."""
    problems = []
    resetting: set[int] = set()
    stopped: set[int] = set()
    operational: set[int] = set()
    unanswered: dict[int, int] = {}
    for k, msg in enumerate(frames):
        can_id, data = msg.arbitration_id, bytes(msg.data)
        where = f"frame {k} (0x{can_id:03X} {data.hex()})"
        if msg.is_extended_id or msg.is_remote_frame:
            problems.append(f"{where}: extended or remote frame")
            continue
        name, node = service(can_id)
        if name in ("unknown", "TIME"):
            problems.append(f"{where}: COB-ID outside the predefined connection set")
            continue
        if name == "NMT":
            if len(data) != 2 or data[0] not in NMT_COMMANDS or data[1] > 127:
                problems.append(f"{where}: NMT command must be 2 bytes, a known command, node 0-127")
                continue
            targets = nodes if data[1] == 0 else {data[1]}
            if data[0] in (0x81, 0x82):
                resetting |= targets
                stopped -= targets
                operational -= targets
            elif data[0] == 0x02:
                stopped |= targets
                operational -= targets
            elif data[0] == 0x01:
                stopped -= targets
                operational |= targets
            else:
                stopped -= targets
                operational -= targets
            continue
        if name == "SYNC":
            if len(data) not in (0, 1):
                problems.append(f"{where}: SYNC carries 0 bytes (or a 1-byte counter)")
            continue
        if node in resetting and node in nodes and not (name == "NMT error control" and data == b"\x00"):
            problems.append(f"{where}: node {node} sent a frame between a reset command and its boot-up")
        if name == "EMCY":
            if len(data) != 8:
                problems.append(f"{where}: EMCY is 8 bytes")
            elif int.from_bytes(data[:2], "little") == 0 and data[2] != 0:
                problems.append(f"{where}: an error reset EMCY (0x0000) with error register {data[2]:#x}")
        elif name.startswith(("TPDO", "RPDO")):
            expected = pdo_lengths.get(can_id)
            if expected is None:
                problems.append(f"{where}: a PDO that was not mapped")
            elif len(data) != expected:
                problems.append(f"{where}: {name} of node {node} is mapped to {expected} bytes, carries {len(data)}")
            if name.startswith("TPDO") and node not in operational:
                problems.append(f"{where}: a TPDO from node {node}, which is not OPERATIONAL")
        elif name.startswith("SDO"):
            if len(data) != 8:
                problems.append(f"{where}: SDO frames are 8 bytes")
            elif name == "SDO client->server":
                if node not in stopped:  # a STOPPED node answers no SDO (checked below)
                    unanswered[node] = k
            else:
                unanswered.pop(node, None)
                if node in stopped:
                    problems.append(f"{where}: node {node} answered an SDO in STOPPED")
        elif name == "NMT error control":
            if len(data) != 1 or data[0] not in HEARTBEAT_STATES:
                problems.append(f"{where}: a heartbeat is 1 byte with state 0x00, 0x04, 0x05 or 0x7F")
            elif data[0] == 0x00:
                resetting.discard(node)
    for node, k in unanswered.items():
        if node in nodes and node not in stopped:
            problems.append(f"frame {k}: SDO request to node {node} never answered")
    return problems
