"""The CANopen master: one ``canopen.RemoteNode`` per CiA 402 axis, its dictionary from the drive's EDS.

Start-up (:meth:`DriveMaster.start`), the standard sequence (CiA 301/302),
everything before any motion:

1. the master's own heartbeat producer starts (node ``master_node_id``, the
   drives consume it: a drive that loses its master performs 0x6007);
2. NMT *reset communication* to every node, then wait for each node's boot-up
   message; a node that sends none within ``boot_timeout`` is a
   :class:`~.bus.BusError` naming it and its joint;
3. per node, by SDO: device type 0x1000 (a CiA 402 drive?) and identity
   0x1018 against the EDS; supported drive modes 0x6502 (CSP? in torque
   mode: CST?); then the
   configuration, written as a DCF would (the EDS's variables with their
   values set, downloaded in order): heartbeat producer 0x1017 and consumer
   0x1016, communication cycle period 0x1006, abort connection option 0x6007
   (quick stop), mode of operation CSP 0x6060, interpolation period 0x60C2,
   following-error window and time-out 0x6065/0x6066, quick-stop deceleration
   and option code 0x6085/0x605A, maximum velocity 0x607F, software position
   limits 0x607D; a value the drive refuses is an error naming node, object
   and abort code;
4. PDO mapping with CiA 301's procedure (canopen's ``PdoMap.save``): RPDO1
   controlword + target position (torque mode: 0x6060 = CST, max torque
   0x6072 written, rated torque 0x6076 read, RPDO1 controlword + target
   torque), TPDO1 statusword + position actual value,
   both synchronous; the node's other PDOs invalidated;
5. NMT start (OPERATIONAL); enabling through the 402 state machine is the
   controller's (:meth:`.control.Controller.enable`).

Cyclic exchange (:meth:`DriveMaster.exchange`): SYNC, then one RPDO per axis.
The drives answer each SYNC with their TPDO; :meth:`DriveMaster.feedback`
returns the latest ones and which are fresh. Consumers: heartbeats (time of
the last one and the NMT state it reported, per node) and EMCY (a log),
both stamped with the control clock.
"""

from __future__ import annotations

import logging
import struct
import threading
from dataclasses import dataclass
from pathlib import Path

import can
import canopen
import numpy as np
from canopen.emcy import EmcyError
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from . import cia402
from .bus import BusError, MonitoredBus
from .clock import Clock, Scheduler, set_realtime_priority
from .network import PumpedNetwork, SimulationLink

#: RPDO1 (controlword, target position) and TPDO1 (statusword, position actual value)
_RPDO1 = struct.Struct("<Hl")
_TPDO1 = struct.Struct("<Hl")
#: RPDO1 in torque mode: controlword, target torque (thousandths of the rated torque)
_RPDO_TORQUE = struct.Struct("<Hh")
#: NMT command specifiers (CiA 301)
NMT_START, NMT_RESET_COMMUNICATION = 0x01, 0x82


@dataclass
class AxisConfig:
    """What the master configures on one axis (SI joint units: rad or m)."""

    name: str
    node_id: int
    counts_per_unit: float
    lower: float
    upper: float
    following_error_window: float
    max_velocity: float
    quick_stop_deceleration: float
    #: the drive's EDS (None: the generic dictionary of a simulated drive)
    eds: Path | None = None

    def counts(self, value) -> np.ndarray:
        return np.round(np.asarray(value, dtype=float) * self.counts_per_unit).astype(np.int64)


@dataclass
class Feedback:
    """The latest TPDO of every axis.

    ``fresh[i]``: a new one arrived since the previous call; ``current[i]``: it
    arrived after the last SYNC sent, so it answers that SYNC (a drive samples its
    position when the SYNC arrives).
    """

    statusword: np.ndarray
    position: np.ndarray  # counts
    fresh: np.ndarray
    current: np.ndarray

    @property
    def states(self) -> list[str]:
        return [cia402.state_of(int(s)) for s in self.statusword]


class DriveMaster:
    """CANopen master of the axes on one bus (see the module docstring)."""

    #: SDO transfers are tried this often before a node counts as not answering
    SDO_ATTEMPTS = 3

    def __init__(
        self,
        bus: MonitoredBus,
        axes: list[AxisConfig],
        clock: Clock,
        *,
        period: float,
        heartbeat_period: float,
        following_error_timeout: float,
        sdo_timeout: float,
        link: SimulationLink | None,
        description: str,
        master_node_id: int = 127,
        boot_timeout: float = 1.0,
        priority: int | None = None,
        max_torque: list[int] | None = None,
    ) -> None:
        self.bus = bus
        #: torque mode (cyclic synchronous torque, the haptic assist): each axis' max torque 0x6072 (thousandths
        #: of its rated torque), RPDO1 carries the target torque 0x6071; None: position mode (CSP)
        self.max_torque = None if max_torque is None else np.asarray(max_torque, dtype=np.int64)
        self._rpdo = _RPDO_TORQUE if max_torque is not None else _RPDO1
        #: each axis' rated torque 0x6076 (N·m, read at start-up in torque mode)
        self.rated_torque = np.full(len(axes), np.nan)
        self.axes = axes
        self.clock = clock
        self.period = period
        self.heartbeat_period = heartbeat_period
        self.following_error_timeout = following_error_timeout
        self.sdo_timeout = sdo_timeout
        self.description = description
        self.master_node_id = master_node_id
        self.boot_timeout = boot_timeout
        self.priority = priority
        if link is not None:
            # the simulated clock's scheduler sends the master's heartbeats, in time order with the drives'
            scheduler = getattr(clock, "scheduler", None) or Scheduler()
            self.network: canopen.Network = PumpedNetwork(bus, scheduler, clock.now, link)
        else:
            self.network = canopen.Network(bus)
            self.network.NOTIFIER_CYCLE = 0.02  # a prompt shutdown of the receive thread
        bus.own_ids = {0x000, 0x080, 0x700 + master_node_id} | {
            base + a.node_id for a in axes for base in (0x200, 0x600)
        }
        n = len(axes)
        self._lock = threading.Lock()
        self._statusword = np.zeros(n, dtype=np.int64)
        self._position = np.zeros(n, dtype=np.int64)
        self._fresh = np.zeros(n, dtype=bool)
        #: SYNCs sent so far, and per axis how many had been sent when its latest TPDO arrived
        self.syncs_sent = 0
        self._answered = np.full(n, -1, dtype=np.int64)
        self.last_heartbeat = np.full(n, -np.inf)
        self.heartbeat_state = np.zeros(n, dtype=np.int64)
        #: clock time of each node's boot-up message after the reset (nan: none yet)
        self.booted = np.full(n, np.nan)
        self._boot_event = threading.Event()
        #: set once every drive has answered the latest SYNC (cleared as each SYNC is counted)
        self._all_answered = threading.Event()
        #: (time s, node id, EMCY code, error register)
        self.emcy: list[tuple[float, int, int, int]] = []
        self.nodes: list[canopen.RemoteNode] = []
        #: per axis: RPDO1's COB-ID and the prepared frame (SYNC first)
        self._sync = can.Message(arbitration_id=0x080, data=b"", is_extended_id=False)
        self._rpdo_ids: list[int] = []
        self._cycle_messages: list[can.Message] = []
        self._heartbeat = None
        self.started = False
        #: what start() configured on each node: (node id, object, value) in the order written
        self.configuration: list[tuple[int, str, int]] = []

    # ------------------------------------------------------------------ start-up
    def _where(self, i: int) -> str:
        axis = self.axes[i]
        return f"CAN node {axis.node_id} (joint '{axis.name}') on {self.description}"

    def _sdo(self, i: int, what: str, action):
        client_log = logging.getLogger("canopen.sdo.client")
        level = client_log.level
        client_log.setLevel(logging.CRITICAL)  # our error says it all; canopen would also log the abort
        try:
            return action()
        except SdoCommunicationError:
            raise BusError(
                f"{self._where(i)} does not answer: no SDO response within {self.sdo_timeout:g} s, "
                f"{self.SDO_ATTEMPTS} attempts ({what}); "
                "is it powered, wired and set to this node id and bit rate?"
            ) from None
        except SdoAbortedError as exc:
            raise BusError(f"{self._where(i)} refused {what}: {exc}") from None
        except can.CanError as exc:
            raise BusError(
                f"CAN bus error on {self.description} while {what} on node {self.axes[i].node_id}: {exc}"
            ) from None
        finally:
            client_log.setLevel(level)

    def _send(self, what: str, action) -> None:
        try:
            action()
        except can.CanError as exc:
            raise BusError(f"CAN bus error on {self.description} while {what}: {exc}") from None

    def start(self) -> None:
        """The standard start-up (see the module docstring). Raises :class:`BusError`."""
        if not isinstance(self.network, PumpedNetwork):
            self.network.connect()  # the bus is open already: this starts the receive thread
            for reader in self.network.notifier._readers:  # the feedback's path: as urgent as the loop
                if isinstance(reader, threading.Thread):
                    set_realtime_priority(self.priority, reader.native_id)
        for i, axis in enumerate(self.axes):
            try:
                dictionary = cia402.cia402_object_dictionary(axis.node_id) if axis.eds is None else str(axis.eds)
                node = canopen.RemoteNode(axis.node_id, dictionary)
            except Exception as exc:  # a malformed EDS: name it
                raise BusError(f"cannot load the EDS '{axis.eds}' of {self._where(i)}: {exc}") from None
            node.sdo.RESPONSE_TIMEOUT = self.sdo_timeout
            node.sdo.MAX_RETRIES = self.SDO_ATTEMPTS  # a lost frame costs a retry, not the run
            self.network.add_node(node)
            self.nodes.append(node)
            node.nmt.add_heartbeat_callback(lambda state, i=i: self._on_heartbeat(i, state))
            node.emcy.add_callback(lambda entry, i=i: self._on_emcy(i, entry))
        # 1. our heartbeat, which the drives will consume
        beat = bytes([cia402.NMT_OPERATIONAL])
        self._send(
            "starting the master's heartbeat",
            lambda: setattr(
                self, "_heartbeat", self.network.send_periodic(0x700 + self.master_node_id, beat, self.heartbeat_period)
            ),
        )
        # python-can sends it from a thread of its own: at the loop's priority too, or, holding the GIL while
        # preempted by an ordinary process, it would make the real-time loop wait for it (priority inversion)
        thread = getattr(getattr(self._heartbeat, "_task", None), "thread", None)
        if thread is not None:
            set_realtime_priority(self.priority, thread.native_id)
        # 2. reset communication, every node, and wait for every boot-up
        self.booted[:] = np.nan
        self._boot_event.clear()
        for axis in self.axes:
            self._send(
                f"resetting the communication of node {axis.node_id}",
                lambda a=axis: self.network.send_message(0x000, bytes([NMT_RESET_COMMUNICATION, a.node_id])),
            )
        self._wait_for_boot_up()
        # 3. 4. identity, configuration, PDOs; 5. start
        for i in range(len(self.axes)):
            self._configure(i)
        positions, statuswords = self.read_state()
        with self._lock:
            self._position[:] = positions
            self._statusword[:] = statuswords
        for i, axis in enumerate(self.axes):
            self._send(
                f"starting node {axis.node_id}",
                lambda a=axis: self.network.send_message(0x000, bytes([NMT_START, a.node_id])),
            )
            self.nodes[i].nmt._state = cia402.NMT_OPERATIONAL
        self.last_heartbeat[:] = self.clock.now()  # a full timeout of grace from here
        self.heartbeat_state[:] = cia402.NMT_OPERATIONAL
        self.started = True

    def _wait_for_boot_up(self) -> None:
        deadline = self.clock.now() + self.boot_timeout
        step = 0.01
        for _ in range(int(np.ceil(self.boot_timeout / step)) + 2):  # bounded: boot_timeout at most
            if not np.any(np.isnan(self.booted)):
                return
            now = self.clock.now()
            if now >= deadline:
                break
            if self.clock.realtime:
                self._boot_event.wait(min(step, deadline - now))
                self._boot_event.clear()
            else:
                self.clock.sleep_until(min(deadline, now + step))
        missing = [i for i in range(len(self.axes)) if np.isnan(self.booted[i])]
        if missing:
            names = "; ".join(self._where(i) for i in missing)
            raise BusError(
                f"{names} does not answer: no boot-up message within {self.boot_timeout:g} s of the NMT reset "
                "communication; is it powered, wired and set to this node id and bit rate?"
            )

    def _configure(self, i: int) -> None:
        """Identity against the EDS, the configuration (a DCF's values, in order), the PDO mapping."""
        node, axis = self.nodes[i], self.axes[i]
        od = node.object_dictionary
        eds = f"the EDS {axis.eds}" if axis.eds is not None else "its dictionary"
        device_type = self._sdo(i, "reading the device type 0x1000", lambda: node.sdo[0x1000].raw)
        if device_type & 0xFFFF != 402:
            raise BusError(
                f"{self._where(i)} is not a CiA 402 drive: "
                f"device type 0x{device_type:08X} (profile {device_type & 0xFFFF})"
            )
        if 0x1018 in od:
            for sub, what in ((1, "vendor-ID"), (2, "product code")):
                if sub not in od[0x1018]:
                    continue
                expected = od[0x1018][sub].default
                found = self._sdo(i, f"reading its {what} 0x1018:{sub}", lambda s=sub: node.sdo[0x1018][s].raw)
                if expected is not None and found != expected:
                    raise BusError(
                        f"{self._where(i)} reports {what} 0x{found:08X}, {eds} describes 0x{expected:08X}: "
                        "give the drive's own EDS in the device's 'eds' setting"
                    )
        if 0x6502 in od:
            modes = self._sdo(i, "reading the supported drive modes 0x6502", lambda: node.sdo[0x6502].raw)
            mode = cia402.CST if self.max_torque is not None else cia402.CSP
            if not modes & (1 << (mode - 1)):
                what = "torque" if self.max_torque is not None else "position"
                raise BusError(f"{self._where(i)} does not support cyclic synchronous {what} (0x6502 = 0x{modes:08X})")
        cpu = axis.counts_per_unit
        value, index = cia402.interpolation_period(self.period)
        heartbeat = round(self.heartbeat_period * 1000)
        # (object, sub-index, value, required): what a DCF for this drive holds, in the order it is written
        writes = [
            (0x1017, None, heartbeat, True),
            (0x1016, 1, (self.master_node_id << 16) | min(0xFFFF, round(1.5 * heartbeat)), False),
            (0x1006, None, round(self.period * 1e6), False),
            (0x6007, None, 3, False),
            (0x6060, None, cia402.CST if self.max_torque is not None else cia402.CSP, True),
            (0x60C2, 1, value, True),
            (0x60C2, 2, index, True),
            (0x6065, None, max(1, round(axis.following_error_window * cpu)), True),
            (0x6066, None, round(self.following_error_timeout * 1000), True),
            (0x6085, None, round(axis.quick_stop_deceleration * cpu), True),
            (0x605A, None, 6, False),
            (0x607F, None, round(axis.max_velocity * cpu), True),
            (0x607D, 1, int(np.floor(axis.lower * cpu)), True),
            (0x607D, 2, int(np.ceil(axis.upper * cpu)), True),
        ]
        if self.max_torque is not None:
            writes.append((0x6072, None, int(self.max_torque[i]), True))
            rated = self._sdo(i, "reading the motor rated torque 0x6076", lambda: node.sdo[0x6076].raw)
            self.rated_torque[i] = rated / 1000.0  # mN·m
        for index_, sub, raw, required in writes:
            where = f"0x{index_:04X}" + (f":{sub}" if sub is not None else "")
            try:
                variable = od[index_] if sub is None else od[index_][sub]
            except KeyError:
                if required:
                    raise BusError(f"{self._where(i)}: {eds} has no object {where}, which the master needs") from None
                continue
            variable.value = raw  # the DCF value
            name = f"{variable.name} {where}"
            target = node.sdo[index_] if sub is None else node.sdo[index_][sub]
            self._sdo(i, f"writing {name} = {raw}", lambda t=target, r=raw: setattr(t, "raw", r))
            self.configuration.append((axis.node_id, name, raw))
        self._sdo(i, "configuring the PDOs", lambda: self._map_pdos(i, node))

    def _map_pdos(self, i: int, node: canopen.RemoteNode) -> None:
        """RPDO1 controlword + target position, TPDO1 statusword + position, synchronous; the others invalid."""
        target = 0x6071 if self.max_torque is not None else 0x607A
        for maps, number, entries in ((node.rpdo, 1, (0x6040, target)), (node.tpdo, 1, (0x6041, 0x6064))):
            pdo = maps[number]
            pdo.read()
            pdo.clear()
            for index in entries:
                pdo.add_variable(index)
            pdo.trans_type = 1
            pdo.enabled = True
            pdo.save()
            for other in maps.map.values():
                if other is pdo:
                    continue
                cob = other.com_record[1].raw
                if not cob & cia402.PDO_INVALID:
                    other.com_record[1].raw = cob | cia402.PDO_INVALID
        tpdo = node.tpdo[1]
        self._rpdo_ids.append(node.rpdo[1].cob_id)
        # the cyclic frames bypass canopen's PdoMap (its per-frame bookkeeping costs what a 1 kHz loop cannot
        # spare): TPDO1 straight to our callback, RPDO1 packed here
        self.network.unsubscribe(tpdo.cob_id, tpdo.on_message)
        self.network.subscribe(tpdo.cob_id, lambda can_id, data, timestamp, i=i: self._on_tpdo(i, data))

    def read_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions (counts) and statuswords of every axis, read by SDO (no SYNC needed)."""
        positions = np.zeros(len(self.axes), dtype=np.int64)
        statuswords = np.zeros(len(self.axes), dtype=np.int64)
        for i, node in enumerate(self.nodes):
            positions[i] = self._sdo(i, "reading the position 0x6064", lambda n=node: n.sdo[0x6064].raw)
            statuswords[i] = self._sdo(i, "reading the statusword 0x6041", lambda n=node: n.sdo[0x6041].raw)
        return positions, statuswords

    # ------------------------------------------------------------------ consumers
    def _on_tpdo(self, i: int, data) -> None:
        if len(data) < 6:
            return
        statusword, position = _TPDO1.unpack_from(data)
        with self._lock:
            self._statusword[i] = statusword
            self._position[i] = position
            self._fresh[i] = True
            self._answered[i] = self.syncs_sent
            if (self._answered == self.syncs_sent).all():
                self._all_answered.set()

    def _on_heartbeat(self, i: int, state: int) -> None:
        now = self.clock.now()
        if state == 0:  # the boot-up message
            if np.isnan(self.booted[i]):
                self.booted[i] = now
                self._boot_event.set()
            return
        self.last_heartbeat[i] = now
        self.heartbeat_state[i] = state

    def _on_emcy(self, i: int, entry: EmcyError) -> None:
        with self._lock:
            self.emcy.append((self.clock.now(), self.axes[i].node_id, entry.code, entry.register))

    # ------------------------------------------------------------------ cyclic exchange
    def feedback(self, into: Feedback | None = None) -> Feedback:
        """The latest TPDOs (see :class:`Feedback`); into ``into``'s arrays when given (the control loop's own,
        reused every cycle: nothing allocated), else new ones."""
        with self._lock:
            if into is None:
                into = Feedback(
                    self._statusword.copy(),
                    self._position.copy(),
                    self._fresh.copy(),
                    self._answered == self.syncs_sent,
                )
            else:
                np.copyto(into.statusword, self._statusword)
                np.copyto(into.position, self._position)
                np.copyto(into.fresh, self._fresh)
                np.equal(self._answered, self.syncs_sent, out=into.current)
            self._fresh[:] = False
        return into

    def empty_feedback(self) -> Feedback:
        """A :class:`Feedback` to fill with :meth:`feedback` ``(into=...)``."""
        n = len(self.axes)
        return Feedback(
            np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        )

    def exchange(self, controlwords, targets, sync: bool = True) -> None:
        """SYNC, then each axis' RPDO (controlword, target counts; torque mode: target torque, thousandths of the
        rated torque, clipped to each axis' max torque whatever the caller asks); ``sync`` False: the RPDOs alone
        (the cycle's SYNC went already, :meth:`sync`). Raises ``can.CanError`` on a bus error."""
        if self.max_torque is not None:
            targets = np.clip(np.rint(np.asarray(targets, dtype=float)), -self.max_torque, self.max_torque)
        if sync:
            self._count_sync()  # before sending: in real time the answers may arrive before transmit returns
        send_batch = getattr(self.bus, "send_batch", None)
        if send_batch is not None and not isinstance(self.network, PumpedNetwork):
            # one write for the cycle's frames where the interface can (loopback): SYNC first, in order; the
            # messages are made once and their data rewritten in place every cycle
            if len(self._cycle_messages) != 1 + len(self._rpdo_ids):
                self._cycle_messages = [self._sync] + [
                    can.Message(arbitration_id=cob, data=bytearray(self._rpdo.size), is_extended_id=False)
                    for cob in self._rpdo_ids
                ]
            pack_into = self._rpdo.pack_into
            for i in range(len(self._rpdo_ids)):
                pack_into(self._cycle_messages[i + 1].data, 0, int(controlwords[i]), int(targets[i]))
            send_batch(self._cycle_messages if sync else self._cycle_messages[1:])
            return
        pack = self._rpdo.pack
        if sync:
            self.network.send_message(0x080, b"")
        for cob, cw, tp in zip(self._rpdo_ids, controlwords, targets, strict=True):
            self.network.send_message(cob, pack(int(cw), int(tp)))

    def sync(self) -> None:
        """SYNC alone: every drive answers with its TPDOs (positions, statuswords); nothing is commanded (the
        observe mode of a guide stage: the drives stay disabled and a hand moves the instrument)."""
        self._count_sync()
        self.network.send_message(0x080, b"")

    def _count_sync(self) -> None:
        """A SYNC is about to go: counted, and no drive has answered it yet."""
        with self._lock:
            self.syncs_sent += 1
            self._all_answered.clear()

    def wait_for_answers(self, timeout: float) -> bool:
        """Real time: wait up to ``timeout`` s for every drive's TPDO answering the latest SYNC (at once when they
        are in); whether they are. A loop judges the answers a whole period after its SYNC went, not at the
        next SYNC's due time: a SYNC that went late would otherwise leave the drives less than a period."""
        return self._all_answered.wait(max(timeout, 0.0))

    def emcy_since(self, count: int) -> list[tuple[float, int, int, int]]:
        with self._lock:
            return list(self.emcy[count:])

    def close(self) -> None:
        """NMT pre-operational (PDOs stop) and the drives' heartbeat consumer off where possible, then our
        heartbeat stops and the bus is released."""
        if self.started:
            now = self.clock.now()
            for i, node in enumerate(self.nodes):
                if now - self.last_heartbeat[i] > 1.5 * self.heartbeat_period:
                    continue  # silent (dead, or its heartbeat lost): do not wait for its SDO time-outs
                try:
                    node.nmt.send_command(0x80)
                    if 0x1016 in node.object_dictionary:
                        node.sdo[0x1016][1].raw = 0
                except (can.CanError, RuntimeError, SdoCommunicationError, SdoAbortedError):
                    break
            self.started = False
        if self._heartbeat is not None:
            self._heartbeat.stop()
            self._heartbeat = None
        for node in self.nodes:
            for pdo in list(node.tpdo.map.values()) + list(node.rpdo.map.values()):
                pdo.stop()
        if self.network.notifier is not None:
            self.network.notifier.stop(1.0)
            self.network.notifier = None


def emcy_description(code: int) -> str:
    """A readable name for an EMCY error code."""
    names = {cia402.EMCY_FOLLOWING_ERROR: "following error", cia402.EMCY_SYNC_LOST: "SYNC lost (drive watchdog)"}
    if code in names:
        return names[code]
    return EmcyError(code, 0, b"", 0.0).get_desc().lower() or "device specific"
