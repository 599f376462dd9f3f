"""CANopen traffic by name: a CAN trace (any format python-can reads) decoded with the nodes' EDS files.

What ``surgiplan can-decode TRACE`` prints. Every frame is classified by CiA 301's predefined connection
set (NMT, SYNC, EMCY, TPDO/RPDO 1-4, SDO, heartbeat, LSS) and decoded:

- **NMT** commands and **heartbeats** with the state names (boot-up, pre-operational, operational, stopped);
- **SDO** transfers with the object's name from the node's EDS, the value of an expedited transfer decoded
  with the object's data type, segmented and block transfers by phase, aborts with CiA 301's abort text;
- **PDOs** as the values of their mapped objects. The mapping starts as the EDS's defaults and then follows
  the trace: the SDO writes to the PDO communication (0x1400-0x15FF, 0x1800-0x19FF) and mapping
  (0x1600-0x17FF, 0x1A00-0x1BFF) parameters that a node confirms are applied, as CiA 301's dynamic mapping
  procedure makes them take effect, so a master that remaps at start-up (surgiplan's does) is followed;
- **CiA 402**: a statusword is shown with the drive's state (canopen's ``State402`` masks), a controlword
  with the command it carries; every change of a node's NMT or CiA 402 state is an *event*.

The decoder trusts nothing in the trace: a frame it cannot place, an SDO for an object the EDS does not know
or a PDO shorter than its mapping is shown raw with what is missing, never an error.
"""

from __future__ import annotations

import struct
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ConfigError

NMT_COMMANDS = {
    0x01: "start",
    0x02: "stop",
    0x80: "enter pre-operational",
    0x81: "reset node",
    0x82: "reset communication",
}
NMT_STATES = {0x00: "boot-up", 0x04: "stopped", 0x05: "operational", 0x7F: "pre-operational"}
#: function code (COB-ID & 0x780) -> name, for node-ids 1-127
FUNCTIONS = {
    0x080: "EMCY",
    0x180: "TPDO1",
    0x200: "RPDO1",
    0x280: "TPDO2",
    0x300: "RPDO2",
    0x380: "TPDO3",
    0x400: "RPDO3",
    0x480: "TPDO4",
    0x500: "RPDO4",
    0x580: "SDO response",
    0x600: "SDO request",
    0x700: "heartbeat",
}
_CONTROLWORD = {
    0x00: "disable voltage",
    0x02: "quick stop",
    0x06: "shutdown",
    0x07: "switch on",
    0x0F: "enable operation",
}
STATUSWORD, CONTROLWORD = 0x6041, 0x6040


def state_402(statusword: int) -> str:
    """The CiA 402 state a statusword shows (canopen's ``State402`` masks)."""
    from canopen.profiles.p402 import State402

    for state, (mask, value) in State402.SW_MASK.items():
        if statusword & mask == value:
            return state
    return "UNKNOWN"


def controlword_command(word: int) -> str:
    if word & 0x80:
        return "fault reset"
    return _CONTROLWORD.get(word & 0x0F, _CONTROLWORD.get(word & 0x07, "")) or f"bits 0x{word:04X}"


def abort_text(code: int) -> str:
    from canopen.sdo.exceptions import SdoAbortedError

    return SdoAbortedError.CODES.get(code, "unknown abort code")


def emcy_text(code: int) -> str:
    from canopen.emcy import EmcyError

    return EmcyError(code, 0, b"", 0.0).get_desc()


@dataclass
class Node:
    """A node the trace is decoded for: its node-id, a name (the joint) and its object dictionary (or None)."""

    node_id: int
    name: str = ""
    od: Any = None
    #: PDO name (RPDO1 ... TPDO4) -> [COB-ID, valid, [(index, subindex, bits)]] as the trace has configured it
    pdos: dict[str, list] = field(default_factory=dict)
    #: SDO download the node has not confirmed yet: (index, subindex, raw value)
    pending: tuple[int, int, int] | None = None
    nmt: str = ""
    cia402: str = ""

    @property
    def label(self) -> str:
        return f"node {self.node_id}" + (f" ({self.name})" if self.name else "")


@dataclass
class Frame:
    """One decoded frame: time (s, from the trace's start), direction, node, what it is, and its text."""

    t: float
    direction: str
    node: int | None
    kind: str
    text: str
    #: a change of state (NMT or CiA 402), an NMT command, an EMCY or an SDO abort
    event: bool = False


def load_nodes(eds: dict[int, Path], names: dict[int, str] | None = None) -> dict[int, Node]:
    """Nodes from EDS files (node-id -> path): the object dictionary through canopen's EDS importer, the
    PDO mapping from the EDS's defaults. A file canopen cannot read is a :class:`ConfigError` naming it."""
    import canopen

    nodes = {}
    for node_id, path in sorted(eds.items()):
        try:
            od = canopen.import_od(str(path), node_id)
        except Exception as exc:  # canopen raises what its parsers raise
            raise ConfigError(f"cannot read the EDS {path}: {type(exc).__name__}: {exc}", location=str(path)) from None
        node = Node(node_id, (names or {}).get(node_id, ""), od)
        _default_pdos(node)
        nodes[node_id] = node
    return nodes


def _default(od, index: int, sub: int) -> int | None:
    try:
        entry = od[index]
        value = (entry[sub] if hasattr(entry, "subindices") else entry).default
    except (KeyError, TypeError):
        return None
    return int(value) if isinstance(value, int) else None


def _default_pdos(node: Node) -> None:
    for kind, communication, mapping in (("RPDO", 0x1400, 0x1600), ("TPDO", 0x1800, 0x1A00)):
        for k in range(4):
            cob = _default(node.od, communication + k, 1)
            count = _default(node.od, mapping + k, 0)
            if cob is None or count is None:
                continue
            entries = [_default(node.od, mapping + k, s) or 0 for s in range(1, count + 1)]
            valid = not cob & 0x80000000
            node.pdos[f"{kind}{k + 1}"] = [cob & 0x7FF, valid, [(e >> 16, (e >> 8) & 0xFF, e & 0xFF) for e in entries]]


class Decoder:
    """Decodes frames one by one, following the nodes' PDO mapping and states (see the module)."""

    def __init__(self, nodes: dict[int, Node] | None = None) -> None:
        self.nodes: dict[int, Node] = dict(nodes or {})
        self.counts: Counter[str] = Counter()

    def node(self, node_id: int) -> Node:
        if node_id not in self.nodes:
            self.nodes[node_id] = Node(node_id)
        return self.nodes[node_id]

    # ------------------------------------------------------------------ names and values
    def _variable(self, node: Node, index: int, sub: int):
        if node.od is None:
            return None
        try:
            entry = node.od[index]
            return entry[sub] if hasattr(entry, "subindices") else entry
        except (KeyError, TypeError):
            return None

    def _name(self, node: Node, index: int, sub: int) -> str:
        var = self._variable(node, index, sub)
        if var is None:
            return f"0x{index:04X}.{sub}"
        parent = getattr(var, "parent", None)
        if parent is not None and hasattr(parent, "subindices") and parent is not var:
            return f"{parent.name}.{var.name}"
        return var.name

    def _value(self, node: Node, index: int, sub: int, data: bytes) -> str:
        var = self._variable(node, index, sub)
        raw: Any
        try:
            raw = var.decode_raw(data) if var is not None else int.from_bytes(data, "little")
        except Exception:  # a value of the wrong size for its type: shown raw
            return data.hex(" ")
        if isinstance(raw, int) and index == STATUSWORD:
            state = state_402(raw)
            if state != node.cia402:
                node.cia402 = state
                self._state_changed = True
            return f"0x{raw:04X} ({state})"
        if isinstance(raw, int) and index == CONTROLWORD:
            return f"0x{raw:04X} ({controlword_command(raw)})"
        if isinstance(raw, int) and (index >> 8) in (0x14, 0x15, 0x16, 0x17, 0x18, 0x19, 0x1A, 0x1B, 0x10):
            return f"0x{raw:X}"
        if isinstance(raw, bytes | bytearray):
            return bytes(raw).hex(" ")
        return f"{raw:.6g}" if isinstance(raw, float) else str(raw)

    # ------------------------------------------------------------------ frames
    def decode(self, msg, t: float) -> Frame:
        """The frame of a python-can message ``msg`` at ``t`` s."""
        self._state_changed = False
        cob, data = msg.arbitration_id, bytes(msg.data)
        direction = "Rx" if getattr(msg, "is_rx", True) else "Tx"
        kind, node_id, text, event = self._classify(cob, data)
        self.counts[kind] += 1
        return Frame(t, direction, node_id, kind, text, event or self._state_changed)

    def _classify(self, cob: int, data: bytes) -> tuple[str, int | None, str, bool]:
        if cob == 0x000 and len(data) >= 2:
            target = "all nodes" if data[1] == 0 else self.node(data[1]).label
            return "NMT", data[1] or None, f"{NMT_COMMANDS.get(data[0], f'command 0x{data[0]:02X}')} -> {target}", True
        if cob == 0x080:
            return "SYNC", None, f"counter {data[0]}" if data else "", False
        if cob in (0x7E4, 0x7E5):
            return (
                "LSS",
                None,
                f"{'slave' if cob == 0x7E4 else 'master'} command 0x{data[0]:02X}" if data else "",
                False,
            )
        for node in self.nodes.values():  # a PDO as the trace configured it
            for pdo_name, (pdo_cob, valid, entries) in node.pdos.items():
                if valid and pdo_cob == cob:
                    return self._pdo(node, pdo_name, entries, data)
        function, node_id = cob & 0x780, cob & 0x7F
        if node_id == 0 or function not in FUNCTIONS:
            return "other", None, data.hex(" "), False
        node = self.node(node_id)
        name = FUNCTIONS[function]
        if name == "heartbeat":
            state = NMT_STATES.get(data[0] & 0x7F, f"state 0x{data[0]:02X}") if data else "?"
            changed = state != node.nmt
            node.nmt = state
            return name, node_id, f"{node.label}: {state}", changed
        if name == "EMCY":
            if len(data) < 3:
                return name, node_id, f"{node.label}: {data.hex(' ')} (short)", True
            code, register = struct.unpack_from("<HB", data)
            return name, node_id, f"{node.label}: 0x{code:04X} {emcy_text(code)}, error register 0x{register:02X}", True
        if name.startswith("SDO"):
            return self._sdo(node, name, data)
        return name, node_id, f"{node.label}: {data.hex(' ')} (not mapped)", False

    def _pdo(self, node: Node, name: str, entries: list, data: bytes) -> tuple[str, int, str, bool]:
        parts, bit = [], 0
        for index, sub, bits in entries:
            if bits % 8 or bit % 8:
                parts.append(f"{self._name(node, index, sub)}=(not byte-aligned)")
                bit += bits
                continue
            chunk = data[bit // 8 : (bit + bits) // 8]
            bit += bits
            if len(chunk) * 8 < bits:
                parts.append(f"{self._name(node, index, sub)}=(missing: frame of {len(data)} bytes)")
                continue
            parts.append(f"{self._name(node, index, sub)}={self._value(node, index, sub, chunk)}")
        return name, node.node_id, f"{node.label}: " + (" ".join(parts) or data.hex(" ")), False

    def _sdo(self, node: Node, name: str, data: bytes) -> tuple[str, int, str, bool]:
        if len(data) < 8:
            return name, node.node_id, f"{node.label}: {data.hex(' ')} (not 8 bytes)", False
        command = data[0] >> 5
        index, sub = struct.unpack_from("<HB", data, 1)
        what = f"{self._name(node, index, sub)} [0x{index:04X}.{sub}]"
        request = name == "SDO request"
        if command == 4:  # abort, either way
            code = struct.unpack_from("<I", data, 4)[0]
            node.pending = None
            return name, node.node_id, f"{node.label}: abort {what}: 0x{code:08X} {abort_text(code)}", True
        if request and command == 1:  # initiate download
            if data[0] & 0x02:  # expedited
                size = 4 - ((data[0] >> 2) & 3) if data[0] & 0x01 else 4
                value = data[4 : 4 + size]
                node.pending = (index, sub, int.from_bytes(value, "little"))
                return name, node.node_id, f"{node.label}: write {what} = {self._value(node, index, sub, value)}", False
            node.pending = None
            return name, node.node_id, f"{node.label}: write {what} (segmented)", False
        if request and command == 2:
            return name, node.node_id, f"{node.label}: read {what}", False
        if not request and command == 3:  # download confirmed
            if node.pending is not None and node.pending[:2] == (index, sub):
                self._apply(node, *node.pending)
            node.pending = None
            return name, node.node_id, f"{node.label}: written {what}", False
        if not request and command == 2:  # initiate upload response
            if data[0] & 0x02:
                size = 4 - ((data[0] >> 2) & 3) if data[0] & 0x01 else 4
                value = self._value(node, index, sub, data[4 : 4 + size])
                return name, node.node_id, f"{node.label}: {what} = {value}", False
            return (
                name,
                node.node_id,
                f"{node.label}: {what} (segmented, {int.from_bytes(data[4:], 'little')} bytes)",
                False,
            )
        phase = {0: "segment", 1: "segment", 3: "segment", 5: "block", 6: "block"}.get(command, f"command {command}")
        return name, node.node_id, f"{node.label}: {phase} {data.hex(' ')}", False

    def _apply(self, node: Node, index: int, sub: int, value: int) -> None:
        """A confirmed write to a PDO parameter: the mapping the node now uses (CiA 301 7.5.2.35-36)."""
        group, k = index & 0xFE00, index & 0x01FF
        if group not in (0x1400, 0x1600, 0x1800, 0x1A00) or k > 3:
            return
        kind = "RPDO" if group in (0x1400, 0x1600) else "TPDO"
        pdo = node.pdos.setdefault(f"{kind}{k + 1}", [0, False, []])
        if group in (0x1400, 0x1800):
            if sub == 1:
                pdo[0], pdo[1] = value & 0x7FF, not value & 0x80000000
            return
        entries = pdo[2]
        if sub == 0:
            del entries[value:]
        elif 1 <= sub <= 8:
            entries.extend([(0, 0, 0)] * max(0, sub - len(entries)))
            entries[sub - 1] = (value >> 16, (value >> 8) & 0xFF, value & 0xFF)


def decode_trace(path: Path, nodes: dict[int, Node] | None = None):
    """The frames of the trace at ``path`` (blf, asc, log, csv, trc, ... : what ``can.LogReader`` reads),
    decoded; yields :class:`Frame` (time from the trace's first frame). A file python-can cannot read is a
    :class:`ConfigError` naming it."""
    import can

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"no such trace: {path}", location=str(path))
    try:
        reader = can.LogReader(str(path))
    except (ValueError, OSError, can.CanError) as exc:
        raise ConfigError(f"python-can cannot read {path}: {exc}", location=str(path)) from None
    decoder = Decoder(nodes)
    start = None
    try:
        for msg in reader:
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            start = msg.timestamp if start is None else start
            yield decoder.decode(msg, msg.timestamp - start)
    except (ValueError, struct.error, can.CanError, EOFError, OSError) as exc:
        raise ConfigError(f"{path} is not a valid trace: {type(exc).__name__}: {exc}", location=str(path)) from None
    finally:
        reader.stop()
    if start is None:
        raise ConfigError(f"python-can read no CAN frame from {path}: is it a trace?", location=str(path))
