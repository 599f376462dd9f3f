"""One simulated drive's CANopen side (CiA 301): a ``canopen.LocalNode`` with its NMT slave, SDO server, EMCY
producer and PDOs.

canopen ships the master side of CiA 402 only; this is the slave. The node's
object dictionary is :func:`..cia402.drive_object_dictionary` (the one its
EDS file states); what the objects *do* is the drive's (:class:`Drive`: the
simulator behind the node, :mod:`.drives`).

* NMT: power-up and every reset send the boot-up message (0x700 + node, one
  byte 0x00) and enter PRE-OPERATIONAL; *reset communication* restores the
  communication area (0x1000-0x1FFF) to its power-on values, *reset node*
  every object and the drive itself; STOPPED answers no SDO and sends no EMCY
  or PDO; PDOs only in OPERATIONAL.
* SDO: expedited, segmented and block transfer (:mod:`.sdo`), silent in STOPPED.
* EMCY only in PRE-OPERATIONAL and OPERATIONAL.
* PDO: four RPDOs and four TPDOs, compiled from their communication and
  mapping parameters on entering OPERATIONAL (:class:`Pdo`); a TPDO of the
  cyclic objects is packed straight from the drive's state in one go, an
  RPDO of integer objects is decoded in one go and writes its objects as an
  SDO would, the controlword last.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass, field
from typing import Protocol

import can
import canopen
import numpy as np
from canopen import objectdictionary as od_types
from canopen.emcy import EmcyProducer
from canopen.nmt import NmtSlave
from canopen.sdo import SdoAbortedError

from .. import cia402
from ..cia402 import NMT_INITIALISING, NMT_OPERATIONAL, NMT_PRE_OPERATIONAL, NMT_STOPPED
from .sdo import DriveSdoServer

log = logging.getLogger(__name__)


class Drive(Protocol):
    """What a :class:`DriveNode` needs of the drive behind it (:class:`.drives.DriveSimulator`, axis ``i``): the
    state its TPDOs pack, the values written to its objects, and its NMT events."""

    pos: np.ndarray
    vel: np.ndarray
    cpu: np.ndarray
    mode: np.ndarray
    errors: list[dict[int, int]]
    #: each axis' non-volatile memory (:class:`.storage.Memory`)
    memories: list
    clock: object

    def statusword(self, i: int) -> int: ...

    def torque(self, i: int) -> int: ...

    def write(self, i: int, index: int, subindex: int, od, data: bytes) -> None: ...

    def write_value(self, i: int, index: int, subindex: int, od, value) -> None: ...

    def on_nmt(self, i: int, old: int, new: int) -> None: ...

    def on_reset(self, i: int, old: int, application: bool) -> None: ...

    def reload(self, i: int) -> None: ...

    def renumber(self, i: int, application: bool) -> bool: ...


class _DriveNmt(NmtSlave):
    """CiA 301 NMT slave: commands, boot-up after every reset, the resets' restore semantics."""

    def __init__(self, node_id: int, node: DriveNode) -> None:
        super().__init__(node_id, node)
        self.node = node

    def on_command(self, can_id, data, timestamp):
        if len(data) != 2:
            return  # not an NMT command (CiA 301: two bytes)
        command, target = data[0], data[1]
        if target not in (0, self.id) or not self.node.on_bus:
            return
        if command == 0x01:
            self.enter(NMT_OPERATIONAL)
        elif command == 0x02:
            self.enter(NMT_STOPPED)
        elif command == 0x80:
            self.enter(NMT_PRE_OPERATIONAL)
        elif command in (0x81, 0x82):
            self.boot(application=command == 0x81)

    def enter(self, state: int) -> None:
        old = self._state
        if state == old:
            return
        self._state = state
        self.update_heartbeat()
        self.node.on_nmt(old, state)

    def boot(self, application: bool) -> None:
        """Reset (application: the whole node; else communication), boot-up message, PRE-OPERATIONAL."""
        if self.node.simulator.renumber(self.node.axis, application):
            return  # LSS gave the drive another node-ID: a node of that ID replaced this one, and booted
        old = self._state
        self.node.on_reset(old, application)
        self.stop_heartbeat()
        self._state = NMT_INITIALISING
        self.network.send_message(0x700 + self.id, b"\x00")  # the boot-up message
        self._state = NMT_PRE_OPERATIONAL
        self.start_heartbeat(int(self.node.value(0x1017)))
        self.node.on_nmt(NMT_INITIALISING, NMT_PRE_OPERATIONAL)

    def send_command(self, code: int) -> None:  # canopen's API for the local side: as a received command
        self.on_command(0, bytes([code, self.id]), 0.0)


class _GatedEmcy(EmcyProducer):
    """EMCY only in PRE-OPERATIONAL and OPERATIONAL (CiA 301)."""

    def __init__(self, cob_id: int, node: DriveNode) -> None:
        super().__init__(cob_id)
        self.node = node

    def send(self, code: int, register: int = 0, data: bytes = b"") -> None:
        if self.node.talking and self.node.nmt._state in (NMT_PRE_OPERATIONAL, NMT_OPERATIONAL):
            super().send(code, register, data)


@dataclass
class Pdo:
    """One PDO's configuration as the object dictionary holds it, compiled for the exchange."""

    receive: bool
    n: int
    cob_id: int
    valid: bool
    trans: int
    inhibit: float  # s
    event: float  # s
    entries: list  # (index, subindex, ODVariable, offset, size)
    length: int
    sync_count: int = 0
    last: bytes | None = None
    sent_at: float = -np.inf
    pending: bytes | None = None
    #: the entries with the controlword last (RPDO), each with its position in the PDO: (position, *entry)
    ordered: list = field(default_factory=list)
    #: RPDO of integer objects: every value decoded in one go, as each object's own decoding would
    unpacker: struct.Struct | None = None
    #: TPDO of objects the simulator serves: packed in one go
    packer: struct.Struct | None = None
    getters: list = field(default_factory=list)
    #: TPDO: the frame it goes in where the bus sends a batch (made once, its data rewritten for each send)
    frame: can.Message | None = None


#: the objects a TPDO packs straight from the simulator's state, and the struct codes of their sizes
_TPDO_GETTERS = {
    0x6041: lambda sim, i: sim.statusword(i),
    0x6064: lambda sim, i: round(sim.pos.item(i) * sim.cpu.item(i)),  # Python floats: numpy's round is slow
    0x606C: lambda sim, i: round(sim.vel.item(i) * sim.cpu.item(i)),
    0x6061: lambda sim, i: sim.mode.item(i),
    0x603F: lambda sim, i: next(iter(reversed(sim.errors[i])), 0),
    0x6077: lambda sim, i: sim.torque(i),
}
_FORMATS = {1: "B", 2: "H", 4: "L"}


class DriveNode(canopen.LocalNode):
    """One simulated drive's CANopen side: object dictionary, NMT, SDO, EMCY, PDO configuration."""

    def __init__(self, node_id: int, dictionary, simulator: Drive, axis: int) -> None:
        super().__init__(node_id, dictionary)
        self.simulator = simulator
        self.axis = axis
        self.alive = True
        #: bit timing switched to another bit rate than the bus's (LSS): hears and says nothing
        self.off_bus = False
        #: LSS activate bit timing: says nothing until this time (the simulator's clock)
        self.muted_until = -np.inf
        # replace canopen's NMT slave (no boot-up after a reset, stuck in INITIALISING), its SDO server
        # (answers in STOPPED) and EMCY producer (sends in STOPPED) with CiA 301's behaviour
        self._write_callbacks.remove(self.nmt.on_write)
        self.nmt = _DriveNmt(node_id, self)
        self.add_write_callback(self.nmt.on_write)
        self.sdo = DriveSdoServer(0x600 + node_id, 0x580 + node_id, self)
        self.emcy = _GatedEmcy(0x80 + node_id, self)
        self.rpdos: list[Pdo] = []
        self.tpdos: list[Pdo] = []
        #: the valid TPDOs by what sends them: SYNC (types 0-240), events (254, 255)
        self.sync_tpdos: list[Pdo] = []
        self.event_tpdos: list[Pdo] = []

    @property
    def on_bus(self) -> bool:
        """The node hears the bus (alive, at the bus's bit rate)."""
        return self.alive and not self.off_bus

    @property
    def talking(self) -> bool:
        """The node may send (on the bus, not inside an LSS switch delay)."""
        return self.alive and not self.off_bus and self.simulator.clock.now() >= self.muted_until

    # ------------------------------------------------------------------ values
    def _find_object(self, index, subindex):
        """canopen's look-up, strict about sub-indices: a variable has sub-index 0 only, an ARRAY those its EDS
        lists (canopen's would take any sub-index of a variable, and imply an array's)."""
        obj = super()._find_object(index, subindex)
        parent = self.object_dictionary[index]
        known = (0,) if isinstance(parent, od_types.ODVariable) else parent.subindices
        if subindex not in known:
            raise SdoAbortedError(0x06090011)
        return obj

    def value(self, index: int, subindex: int = 0):
        """The object's current value (stored, else its default), decoded."""
        obj = self._find_object(index, subindex)
        store = self.data_store.get(index)
        if store is not None and subindex in store:
            return obj.decode_raw(store[subindex])
        return obj.default

    def store(self, index: int, subindex: int, value) -> None:
        obj = self._find_object(index, subindex)
        self.data_store.setdefault(index, {})[subindex] = obj.encode_raw(value)

    # ------------------------------------------------------------------ NMT
    def on_nmt(self, old: int, new: int) -> None:
        self.simulator.on_nmt(self.axis, old, new)

    def on_reset(self, old: int, application: bool) -> None:
        self.simulator.on_reset(self.axis, old, application)
        for index in list(self.data_store):
            if application or 0x1000 <= index <= 0x1FFF:
                del self.data_store[index]
        # what was stored (0x1010) is what the reset brings back
        self.simulator.memories[self.axis].apply(self, 0x1000, 0xFFFF if application else 0x1FFF)
        self.rpdos, self.tpdos, self.sync_tpdos, self.event_tpdos = [], [], [], []
        self.simulator.reload(self.axis)  # the restored values take effect

    # ------------------------------------------------------------------ PDOs
    def compile_pdos(self) -> None:
        """Read the PDO configuration from the object dictionary (entering OPERATIONAL)."""
        self.rpdos = [self._compile(True, n) for n in (1, 2, 3, 4)]
        self.tpdos = [self._compile(False, n) for n in (1, 2, 3, 4)]
        self.sync_tpdos = [pdo for pdo in self.tpdos if pdo.valid and pdo.trans <= 240]
        self.event_tpdos = [pdo for pdo in self.tpdos if pdo.valid and pdo.trans >= 254]

    def _compile(self, receive: bool, n: int) -> Pdo:
        comm = (0x1400 if receive else 0x1800) + n - 1
        mapping = (0x1600 if receive else 0x1A00) + n - 1
        cob = int(self.value(comm, 1))
        entries, offset = [], 0
        for sub in range(1, int(self.value(mapping, 0)) + 1):
            word = int(self.value(mapping, sub))
            index, subindex, bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
            obj = self._find_object(index, subindex)
            entries.append((index, subindex, obj, offset, bits // 8))
            offset += bits // 8
        inhibit = 0.0 if receive else int(self.value(comm, 3)) * 1e-4
        event = 0.0 if receive else int(self.value(comm, 5)) * 1e-3
        pdo = Pdo(receive, n, cob & 0x7FF, not cob & cia402.PDO_INVALID, int(self.value(comm, 2)), inhibit,
                   event, entries, offset)  # fmt: skip
        ordered = sorted(enumerate(entries), key=lambda item: item[1][0] == 0x6040)
        pdo.ordered = [(k, *entry) for k, entry in ordered]
        # canopen's own decoding of each object (a plain struct of the entry's size), all in one
        codecs = [(obj.STRUCT_TYPES.get(obj.data_type), size) for _, _, obj, _, size in entries]
        if receive and entries and all(type(codec) is struct.Struct and codec.size == size for codec, size in codecs):
            pdo.unpacker = struct.Struct("<" + "".join(codec.format.lstrip("<") for codec, _ in codecs))
        served = [index in _TPDO_GETTERS and size in _FORMATS for index, *_, size in entries]
        if not receive and entries and all(served):
            codes = ""
            for _, _, obj, _, size in entries:
                signed = obj.data_type in (od_types.INTEGER8, od_types.INTEGER16, od_types.INTEGER32)
                codes += _FORMATS[size].lower() if signed else _FORMATS[size]
            pdo.packer = struct.Struct("<" + codes)
            pdo.getters = [_TPDO_GETTERS[index] for index, *_ in entries]
        return pdo

    def tpdo_data(self, pdo: Pdo) -> bytes:
        """A TPDO's data now: the mapped objects' values, packed in one go where the simulator serves them
        (the cyclic statusword and position), else each object's value as an SDO read would give it."""
        if pdo.packer is None:
            return b"".join(self.get_data(index, subindex) for index, subindex, *_ in pdo.entries)
        simulator, axis = self.simulator, self.axis
        return pdo.packer.pack(*[getter(simulator, axis) for getter in pdo.getters])

    def write_rpdo(self, pdo: Pdo, data: bytes) -> None:
        """Write the mapped objects from an RPDO's data (as if by SDO), the controlword last: a drive acts on
        the whole PDO (a profile position set-point and its new target in one frame)."""
        if len(data) < pdo.length:
            return  # CiA 301: a PDO shorter than its mapping is not processed
        store = self.data_store
        values = pdo.unpacker.unpack_from(data) if pdo.unpacker is not None else None
        write, axis = self.simulator.write_value, self.axis
        for k, index, subindex, obj, offset, size in pdo.ordered:
            raw = data[offset : offset + size]
            try:
                # as LocalNode.set_data, without its look-ups (the mapping was checked when it was written)
                write(axis, index, subindex, obj, values[k] if values is not None else obj.decode_raw(raw))
            except SdoAbortedError as exc:  # a value the drive refuses by PDO: ignored, as by SDO
                log.info("node %d: RPDO%d value for 0x%04X refused (0x%08X)", self.id, pdo.n, index, exc.code)
                continue
            store.setdefault(index, {})[subindex] = raw
