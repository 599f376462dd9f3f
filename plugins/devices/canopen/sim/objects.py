"""The simulated drives' object dictionary at work: what reading an object gives, what writing one does.

Reads of the objects that are the drive's state (statusword, position and
velocity actual values, the mode in force 0x6061, the error objects
0x1001, 0x1003, 0x603F) are computed from it, the motor integrated up to the
moment of reading. Writes (by SDO or RPDO: the same path) are checked with
the standard abort codes (0x06090031/32 above or below the limits the EDS
states, 0x06090030 value range, 0x06040041/42 PDO mapping, 0x06010000 a
mapping changed outside CiA 301's procedure, 0x08000022 device state, ...)
and take effect when written, also while enabled: the controlword drives the
state machine, the targets the operating mode, every parameter its SI value
(:meth:`ObjectDictionary._parameter`). PDO parameters change with
CiA 301's procedure only: in PRE-OPERATIONAL, the COB-ID invalidated, the
number of entries 0 while mapping; an object maps in the direction its access
type says (``ro``/``rwr`` to a TPDO, ``rww``/``wo`` to an RPDO, ``rw`` both);
TPDOs are not served by RTR (bit 30 of their COB-ID stays set). Writing 0 to
0x1003 sub-index 0 clears the error history; 0x1010/0x1011 store and restore
(:mod:`.storage`).
"""

from __future__ import annotations

import numpy as np
from canopen.sdo import SdoAbortedError

from .. import cia402
from ..cia402 import NMT_OPERATIONAL
from .node import DriveNode
from .statemachine import OE

#: objects whose value is the motor's state: read after integrating the motor up to the moment of reading
_DYNAMIC = frozenset({0x6041, 0x6064, 0x606C, 0x6062, 0x60F4, 0x6077})


class ObjectDictionary:
    """Reads and writes of the simulated drives' objects (a part of :class:`.drives.DriveSimulator`: what the
    values mean for its state machine, modes and motors)."""

    # ------------------------------------------------------------------ reads
    def read(self, i: int, index: int, subindex: int):
        """The value of object (``index``, ``subindex``) of axis ``i``'s drive where its state is the value;
        None: the stored value (canopen's read callback)."""
        if index in _DYNAMIC:
            self.advance(self._now())
        if index == 0x6041:
            return self.statusword(i)
        if index == 0x6064:
            return round(self.pos[i] * self.cpu[i])
        if index == 0x606C:
            return round(self.vel[i] * self.cpu[i])
        if index == 0x6061:
            return int(self.mode[i])
        if index == 0x6062:
            return round(self.reference.at(self.t)[0][i] * self.cpu[i])
        if index == 0x60F4:
            return round((self.reference.at(self.t)[0][i] - self.pos[i]) * self.cpu[i])
        if index == 0x6077:
            return self.torque(i)
        if index == 0x603F:
            return next(iter(reversed(self.errors[i])), 0)
        if index == 0x1001:
            return self._error_register(i)
        if index in (0x1010, 0x1011) and subindex:
            return 1  # CiA 301: the drive saves (restores) on command only
        if index == 0x1003:
            history = self.error_history[i]
            if subindex == 0:
                return len(history)
            if subindex > len(history):
                raise SdoAbortedError(0x08000024)  # no data available
            return history[subindex - 1]  # the error code; no additional information (as the EMCY's bytes 3-7)
        return None

    # ------------------------------------------------------------------ writes
    def write(self, i: int, index: int, subindex: int, od, data: bytes) -> None:
        """Check a write (SDO or RPDO) and make it take effect; raise SdoAbortedError to refuse it."""
        self.write_value(i, index, subindex, od, od.decode_raw(data))

    def write_value(self, i: int, index: int, subindex: int, od, value) -> None:
        """:meth:`write` of the value decoded (an RPDO decodes its objects in one go)."""
        node = self.nodes[self.ids[i]]
        if od.min is not None and value < od.min:
            raise SdoAbortedError(cia402.ABORT_VALUE_TOO_LOW)
        if od.max is not None and value > od.max:
            raise SdoAbortedError(cia402.ABORT_VALUE_TOO_HIGH)
        if index in (0x1010, 0x1011):
            self.memories[i].command(node, index, subindex, int(value))
            return
        if 0x1400 <= index <= 0x1BFF:
            self._check_pdo_write(node, index, subindex, value)
            return
        with self._lock:
            now = self._now()
            if self._command(i, index, value, now):
                return
            if index == 0x6007:
                if value not in cia402.ABORT_CONNECTION_OPTIONS:
                    raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)
                self.abort_option[i] = value
            elif index == 0x605A:
                if value not in cia402.QUICK_STOP_OPTIONS:
                    raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)
                self.qs_option[i] = value
            elif index in (0x6083, 0x6084, 0x6085) and value == 0:
                raise SdoAbortedError(cia402.ABORT_VALUE_TOO_LOW)
            elif index == 0x60C2:
                if subindex == 2 and not -6 <= value <= 0:
                    raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)
                if subindex == 1 and value == 0:
                    raise SdoAbortedError(cia402.ABORT_VALUE_TOO_LOW)
            elif index == 0x1003:
                if subindex != 0 or value != 0:
                    raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)  # CiA 301: only 0 may be written
                self.error_history[i].clear()
                return
            elif index == 0x1016:
                producer, period = (int(value) >> 16) & 0xFF, int(value) & 0xFFFF
                if producer and period:
                    for sub in (1, 2):
                        other = int(node.value(0x1016, sub))
                        if sub != subindex and (other >> 16) & 0xFF == producer and other & 0xFFFF:
                            raise SdoAbortedError(cia402.ABORT_INCOMPATIBLE)  # one entry per producer
            # the new value takes effect at once (stored by the node after this callback)
            self._parameter(i, index, subindex, value, now)

    def _command(self, i: int, index: int, value, now: float) -> bool:
        """The controlword, the mode and the targets act when written; False: ``index`` is none of them."""
        if index == 0x6040:
            self._advance_locked(now)
            self._controlword(i, int(value), now)
            if self._event_time is None:
                self._event_tpdos(i, now)  # a new statusword goes at once in an event-driven TPDO
        elif index == 0x6060:
            if value not in cia402.SUPPORTED_MODES:
                raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)
            self._advance_locked(now)
            self._switch_mode(i, int(value), now)
        elif index == 0x607A:  # pp: taken with the next new set-point; csp: now (at SYNC by RPDO)
            if self.mode[i] == cia402.CSP and self.state[i] == OE:
                self._advance_locked(now)
                self._latch_position(i, int(value), now)
        elif index == 0x60FF:
            self.target_velocity[i] = value / self.cpu[i]
            if self.state[i] == OE and self.mode[i] == cia402.PV:
                self._advance_locked(now)
                self._plan_velocity(i, now)
            elif self.state[i] == OE and self.mode[i] == cia402.CSV:
                self._advance_locked(now)
                self._latch_velocity(i, now)
        elif index == 0x6071:  # cst: the torque from now on (at SYNC by RPDO), within 0x6072
            self._advance_locked(now)
            self.target_torque[i] = value
        else:
            return False
        return True

    def _check_pdo_write(self, node: DriveNode, index: int, subindex: int, value: int) -> None:
        """CiA 301's rules for changing a PDO (only in PRE-OPERATIONAL; mapping only while invalid)."""
        if node.nmt._state == NMT_OPERATIONAL:
            raise SdoAbortedError(cia402.ABORT_DEVICE_STATE)
        comm_index = index if index < 0x1600 or 0x1800 <= index < 0x1A00 else index - 0x200
        receive = comm_index < 0x1800
        cob = int(node.value(comm_index, 1))
        valid = not cob & cia402.PDO_INVALID
        if index == comm_index:  # communication parameter
            if subindex == 1:
                if value & (1 << 29) or (not value & cia402.PDO_INVALID and not 1 <= value & 0x7FF <= 0x7FF):
                    raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)  # no extended ids; an id to be valid
                if not receive and not value & cia402.PDO_NO_RTR:
                    raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)  # no TPDO on request (RTR)
                if any(lo <= value & 0x7FF <= hi for lo, hi in cia402.RESTRICTED_IDS):
                    raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)  # a restricted CAN-ID (CiA 301 §7.3.5)
                if valid and not value & cia402.PDO_INVALID and value & 0x7FF != cob & 0x7FF:
                    raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)  # the COB-ID of a valid PDO is fixed
            elif subindex == 2 and not (value <= 240 or value in (254, 255)):
                raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)
            return
        if valid:
            raise SdoAbortedError(cia402.ABORT_UNSUPPORTED_ACCESS)  # invalidate the PDO first
        if subindex == 0:
            if value > 8:
                raise SdoAbortedError(cia402.ABORT_PDO_TOO_LONG)  # more objects than a PDO carries
            bits = 0
            for sub in range(1, value + 1):
                entry = int(node.value(index, sub))
                self._check_mapping_entry(node, entry, receive)
                bits += entry & 0xFF
            if bits > 64:
                raise SdoAbortedError(cia402.ABORT_PDO_TOO_LONG)
            return
        if int(node.value(index, 0)) != 0:
            raise SdoAbortedError(cia402.ABORT_UNSUPPORTED_ACCESS)  # set the number of entries to 0 first
        if value:
            self._check_mapping_entry(node, value, receive)

    @staticmethod
    def _check_mapping_entry(node: DriveNode, entry: int, receive: bool) -> None:
        index, subindex, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        try:
            obj = node._find_object(index, subindex)
        except SdoAbortedError:
            raise SdoAbortedError(cia402.ABORT_CANNOT_MAP) from None
        # the direction the access type says (CiA 306): process outputs to RPDOs, process inputs to TPDOs
        usable = obj.access_type in (("rw", "rww", "wo") if receive else ("rw", "rwr", "ro", "const"))
        if not obj.pdo_mappable or not usable or bits != len(obj) or bits % 8:
            raise SdoAbortedError(cia402.ABORT_CANNOT_MAP)

    def _parameter(self, i: int, index: int, subindex: int, value, now: float) -> None:
        """A parameter takes effect when written."""
        cpu = self.cpu[i]
        if index == 0x6065:
            self.window[i] = np.inf if value == 0xFFFFFFFF else value / cpu
        elif index == 0x6066:
            self.window_time[i] = value / 1000.0
        elif index == 0x6085:
            self.qs_decel[i] = value / cpu
        elif index == 0x6083:
            self.profile_accel[i] = value / cpu
        elif index == 0x6084:
            self.profile_decel[i] = value / cpu
        elif index == 0x6081:
            self.profile_velocity[i] = value / cpu
        elif index == 0x607F:
            self.vmax[i] = min(self.hardware_vmax[i], value / cpu)
        elif index == 0x607D:
            node = self.nodes[self.ids[i]]
            lo = value if subindex == 1 else int(node.value(0x607D, 1))
            hi = value if subindex == 2 else int(node.value(0x607D, 2))
            self.limit_lo[i], self.limit_hi[i] = (lo / cpu, hi / cpu) if lo < hi else (-np.inf, np.inf)
            if self.state[i] == OE:
                self._advance_locked(now)
                self._respect_limits(i, now)
        elif index == 0x60C2:
            node = self.nodes[self.ids[i]]
            number = value if subindex == 1 else int(node.value(0x60C2, 1))
            exponent = value if subindex == 2 else int(node.value(0x60C2, 2))
            self.period[i] = number * 10.0**exponent
        elif index == 0x6067:
            self.position_window[i] = value / cpu
        elif index == 0x6068:
            self.position_window_time[i] = value / 1000.0
        elif index == 0x606D:
            self.velocity_window[i] = value / cpu
        elif index == 0x606E:
            self.velocity_window_time[i] = value / 1000.0
        elif index == 0x2000:
            self.sync_watchdog[i] = value / 1000.0
        elif index == 0x6072:
            self._advance_locked(now)
            self.max_torque[i] = value
        elif index == 0x1016:
            self._consumers(i, subindex, int(value))

    def _load_parameters(self, i: int) -> None:
        """Every parameter from the object dictionary (power-up and after a reset)."""
        node = self.nodes[self.ids[i]]
        now = self.clock.now()
        for index, subindex in [(0x6065, 0), (0x6066, 0), (0x6085, 0), (0x6083, 0), (0x6084, 0), (0x6081, 0),
                                (0x607F, 0), (0x607D, 1), (0x60C2, 1), (0x6067, 0), (0x6068, 0), (0x606D, 0),
                                (0x606E, 0), (0x2000, 0), (0x6072, 0)]:  # fmt: skip
            self._parameter(i, index, subindex, node.value(index, subindex), now)
        self.target_torque[i] = node.value(0x6071)
        self.abort_option[i] = node.value(0x6007)
        self.qs_option[i] = node.value(0x605A)
        self.consumers[i] = {}
        for sub in (1, 2):
            self._consumers(i, sub, int(node.value(0x1016, sub)))
        mode = int(node.value(0x6060))
        self.mode[i] = mode if mode in cia402.SUPPORTED_MODES else cia402.CSP
