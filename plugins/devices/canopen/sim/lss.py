"""The simulated drives' LSS slave (CiA 305, layer setting services): node-ID and bit rate set over the bus.

A drive started without a node-ID (``surgiplan-sim-drives --unconfigured``, as a real drive whose rotary
switches say "LSS") is *non-configured* (node-ID FFh): it sends no boot-up, no heartbeat, answers no SDO,
and listens only to LSS (COB-ID 0x7E5; it answers on 0x7E4, every frame 8 bytes). Its 128-bit LSS
address is its identity 0x1018 (vendor-ID, product code, revision number, serial number).

* switch state global (04h) to the configuration (1) or waiting (0) state; switch state selective
  (40h-43h, answered 44h) by the whole LSS address;
* configure node-ID (11h; 1-127, or FFh to unconfigure; error 1 otherwise), configure bit timing (13h;
  table 0 of CiA 305: error 1 for another table or a bit rate the drive does not support), activate bit
  timing (15h: silent for the switch delay, then the new bit rate, silent for another delay; a bit rate
  other than the bus's takes the drive off this bus), store configuration (17h: the pending node-ID and
  bit rate go to the drive's memory, :mod:`.storage`, used at the next power-up);
* inquire vendor-ID, product code, revision, serial number and node-ID (5Ah-5Eh), in configuration state;
* identify remote slave (46h-4Bh: vendor-ID, product code, revision and serial number ranges, answered 4Fh),
  identify non-configured remote slave (4Ch, answered 50h), and the fast scan (51h, answered 4Fh): the
  non-configured slaves in the waiting state compare the bits the master names; the one whose whole
  address matched enters the configuration state.

The pending node-ID becomes active when a non-configured drive returns to the waiting state (it then boots:
boot-up message, PRE-OPERATIONAL) or at the next NMT reset (node or communication) of a configured one.
"""

from __future__ import annotations

import logging
import struct

from .. import cia402
from .node import DriveNode

log = logging.getLogger(__name__)

REQUEST, RESPONSE = 0x7E5, 0x7E4
WAITING, CONFIGURATION = 0, 1
UNCONFIGURED = 0xFF
#: CiA 305 table 0: bit timing index -> bit rate (bit/s); 5 is reserved, 9 is automatic bit rate detection
BIT_TIMING = {0: 1_000_000, 1: 800_000, 2: 500_000, 3: 250_000, 4: 125_000, 6: 50_000, 7: 20_000, 8: 10_000}


class LssSlave:
    """The LSS slave of one drive (axis ``i`` of the simulator ``drives``: its node, memory and clock)."""

    def __init__(
        self,
        drives,
        i: int,
        address: tuple[int, int, int, int],
        node_id: int,
        bit_rate: int,
        supported: tuple[int, ...],
    ) -> None:
        self.drives = drives
        self.i = i
        self.address = address
        self.active = node_id
        self.pending = node_id
        self.bit_rate = bit_rate
        self.pending_bit_rate = bit_rate
        self.supported = supported
        self.state = WAITING
        self._selective: list[int] = []  # the parts of the address matched so far (switch state selective)
        self._identify: list[int] = []  # the ranges received so far (identify remote slave)
        self._scan_position: int | None = None  # fast scan: the part of the address being compared
        self.silent_until = -1.0
        self.off_bus = False

    # ------------------------------------------------------------------ helpers
    def _now(self) -> float:
        return self.drives.clock.now()

    def _send(self, *payload: int) -> None:
        if self.off_bus or self._now() < self.silent_until or not self.drives.alive[self.i]:
            return
        data = bytearray(8)
        data[: len(payload)] = bytes(payload)
        self.drives.network.send_message(RESPONSE, bytes(data))

    def _send_u32(self, cs: int, value: int) -> None:
        self._send(cs, *struct.pack("<L", value & 0xFFFFFFFF))

    # ------------------------------------------------------------------ requests
    def on_request(self, data: bytes) -> None:
        if self.off_bus or len(data) != 8 or not self.drives.alive[self.i]:
            return
        cs = data[0]
        (value,) = struct.unpack_from("<L", data, 1)
        if cs == 0x04:
            self._switch_global(data[1])
        elif 0x40 <= cs <= 0x43:
            self._switch_selective(cs - 0x40, value)
        elif 0x46 <= cs <= 0x4B:
            self._identify_remote(cs - 0x46, value)
        elif cs == 0x4C:
            if self.active == UNCONFIGURED and self.pending == UNCONFIGURED:
                self._send(0x50)
        elif cs == 0x51:
            self._fast_scan(value, data[5], data[6], data[7])
        elif self.state == CONFIGURATION:
            self._configuration_request(cs, data)

    def _configuration_request(self, cs: int, data: bytes) -> None:
        if cs == 0x11:  # configure node-ID
            node_id = data[1]
            if 1 <= node_id <= 127 or node_id == UNCONFIGURED:
                self.pending = node_id
                self._send(0x11, 0, 0)
            else:
                self._send(0x11, 1, 0)  # node-ID out of range
        elif cs == 0x13:  # configure bit timing
            table, index = data[1], data[2]
            rate = BIT_TIMING.get(index) if table == 0 else None
            if rate is None or rate not in self.supported:
                self._send(0x13, 1, 0)  # bit rate not supported
            else:
                self.pending_bit_rate = rate
                self._send(0x13, 0, 0)
        elif cs == 0x15:  # activate bit timing (unconfirmed)
            (delay,) = struct.unpack_from("<H", data, 1)
            self._activate_bit_timing(delay / 1000.0)
        elif cs == 0x17:  # store configuration
            memory = self.drives.memories[self.i]
            try:
                memory.store_lss(self.pending, self.pending_bit_rate)
            except OSError as exc:
                log.warning("LSS store configuration: %s", exc)
                self._send(0x17, 2, 0)  # storage media access error
                return
            self._send(0x17, 0, 0)
        elif 0x5A <= cs <= 0x5D:
            self._send_u32(cs, self.address[cs - 0x5A])
        elif cs == 0x5E:
            self._send(0x5E, self.active)

    # ------------------------------------------------------------------ states
    def _switch_global(self, mode: int) -> None:
        if mode == CONFIGURATION:
            self.state = CONFIGURATION
        elif mode == WAITING and self.state == CONFIGURATION:
            self.state = WAITING
            self._selective = []
            if self.active == UNCONFIGURED and self.pending != UNCONFIGURED:
                self.drives.attach(self.i, self.pending, boot=True)  # a node now: it boots
                self.active = self.pending

    def _switch_selective(self, part: int, value: int) -> None:
        if self.state != WAITING:
            return
        if part != len(self._selective) or value != self.address[part]:
            self._selective = []
            return
        self._selective.append(value)
        if len(self._selective) == 4:
            self._selective = []
            self.state = CONFIGURATION
            self._send(0x44)

    def _identify_remote(self, part: int, value: int) -> None:
        if part != len(self._identify):
            self._identify = []
            if part != 0:
                return
        self._identify.append(value)
        if len(self._identify) < 6:
            return
        vendor, product, rev_lo, rev_hi, serial_lo, serial_hi = self._identify
        self._identify = []
        v, p, r, s = self.address
        if v == vendor and p == product and rev_lo <= r <= rev_hi and serial_lo <= s <= serial_hi:
            self._send(0x4F)

    def _fast_scan(self, number: int, bit_checked: int, sub: int, following: int) -> None:
        if self.state != WAITING or self.active != UNCONFIGURED:
            return
        if bit_checked == 0x80:  # the master asks who is there: every candidate starts with the vendor-ID
            self._scan_position = 0
            self._send(0x4F)
            return
        if self._scan_position != sub or bit_checked > 31 or sub > 3 or following > 3:
            return
        mask = (0xFFFFFFFF << bit_checked) & 0xFFFFFFFF
        if (number ^ self.address[sub]) & mask:
            return
        if bit_checked == 0:
            self._scan_position = following
            if following < sub:  # the last part matched too (the master wraps around): this slave is found
                self._scan_position = None
                self.state = CONFIGURATION
        self._send(0x4F)

    def _activate_bit_timing(self, delay: float) -> None:
        """Silent for ``delay``, switch, silent for another ``delay`` (CiA 305); the heartbeat pauses too."""
        now = self._now()
        self.silent_until = now + 2 * delay
        self.bit_rate = self.pending_bit_rate
        self.drives.mute(self.i, self.silent_until)
        bus_rate = self.drives.bus_bit_rate
        if self.bit_rate != bus_rate:
            log.info("node %s: now at %d bit/s, this bus runs at %d: off the bus", self.active, self.bit_rate, bus_rate)
            self.off_bus = True
            self.drives.leave_bus(self.i)

    def on_reset(self) -> int | None:
        """An NMT reset of the configured node: the node-ID it comes back with if LSS changed it (else None)."""
        if self.pending != self.active and self.pending != UNCONFIGURED:
            self.active = self.pending
            return self.active
        return None


class LayerSettings:
    """The simulator's side of LSS and node-IDs (a part of :class:`.drives.DriveSimulator`): a node for an
    axis once it has a node-ID, a new one when LSS renumbers it, the silence of a bit timing switch."""

    def attach(self, i: int, node_id: int, boot: bool) -> DriveNode:
        """Axis ``i``'s node with ``node_id``: its dictionary (the EDS at that node-ID) with the stored values,
        on the bus; ``boot``: it boots now (boot-up message, PRE-OPERATIONAL)."""
        axis = self.axes[i]
        dictionary = cia402.drive_object_dictionary(node_id, axis.defaults(self.device, self.model.sync_timeout))
        node = DriveNode(node_id, dictionary, self, i)
        self.network.add_node(node)
        node.add_read_callback(lambda index, subindex, od, i=i: self.read(i, index, subindex))
        node.add_write_callback(lambda index, subindex, od, data, i=i: self.write(i, index, subindex, od, data))
        self.ids[i] = node_id
        self.nodes[node_id] = node
        self.memories[i].apply(node, 0x1000, 0xFFFF)  # power-up: what was stored
        self._load_parameters(i)
        if boot:
            node.nmt.boot(application=True)
        return node

    def renumber(self, i: int, application: bool) -> bool:
        """An NMT reset (``application``: reset node) of axis ``i``'s node: if LSS configured another node-ID,
        the node of the old one leaves and one of the new boots (CiA 305); returns whether it did."""
        new = self.lss[i].on_reset()
        if new is None:
            return False
        old = self.ids[i]
        node = self.nodes.pop(old, None)
        kept = {}
        if node is not None:
            self.on_reset(i, node.nmt._state, application)
            node.nmt.stop_heartbeat()
            if not application:  # reset communication: the application's values stay
                kept = {index: subs for index, subs in node.data_store.items() if not 0x1000 <= index <= 0x1FFF}
            del self.network[old]
        new_node = self.attach(i, new, boot=False)
        for index, subs in kept.items():
            new_node.data_store.setdefault(index, {}).update(subs)
        self._load_parameters(i)
        new_node.nmt.boot(application=False)
        return True

    def mute(self, i: int, until: float) -> None:
        """LSS activate bit timing: axis ``i`` sends nothing (heartbeat, PDOs, SDO answers, EMCY) until
        ``until``."""
        node = self.nodes.get(self.ids[i])
        if node is None:
            return
        node.muted_until = until
        node.nmt.stop_heartbeat()

        def resume(node=node) -> None:
            if self.nodes.get(node.id) is node and node.on_bus:
                node.nmt.start_heartbeat(int(node.value(0x1017)))

        self.scheduler.call_at(until, resume)

    def leave_bus(self, i: int) -> None:
        """Axis ``i`` switched to another bit rate than the bus's: it neither hears nor sends on it."""
        node = self.nodes.get(self.ids[i])
        if node is not None:
            node.off_bus = True
            node.nmt.stop_heartbeat()

    def _on_lss(self, can_id, data, timestamp) -> None:
        with self._lock:
            for slave in self.lss:
                slave.on_request(bytes(data))
