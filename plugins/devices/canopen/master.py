"""The CANopen master: one ``canopen.RemoteNode`` per CiA 402 axis.

Start-up (:meth:`DriveMaster.start`), per node, everything by SDO before any
motion: read the device type 0x1000 (a node that does not answer is a
:class:`~.bus.BusError` naming it; one that is no CiA 402 drive too), NMT
pre-operational, heartbeat producer time 0x1017, mode of operation CSP
(0x6060 = 8), interpolation period 0x60C2 (the control period),
following-error window and time-out (0x6065/0x6066), quick-stop deceleration
and option code (0x6085/0x605A), maximum velocity 0x607F, software position
limits 0x607D (the joint limits), and the PDO mappings (RPDO1: controlword +
target position, TPDO1: statusword + position actual value, both
synchronous) through canopen's ``PdoMap.save``; then NMT start.

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

import can
import canopen
import numpy as np
from canopen.emcy import EmcyError
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from . import cia402
from .bus import BusError, MonitoredBus
from .clock import Clock, Scheduler
from .network import PumpedNetwork, SimulationLink

NMT_OPERATIONAL = 5


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
    ) -> None:
        self.bus = bus
        self.axes = axes
        self.clock = clock
        self.period = period
        self.heartbeat_period = heartbeat_period
        self.following_error_timeout = following_error_timeout
        self.sdo_timeout = sdo_timeout
        self.description = description
        if link is not None:
            self.network: canopen.Network = PumpedNetwork(bus, Scheduler(), clock.now, link)
        else:
            self.network = canopen.Network(bus)
            self.network.NOTIFIER_CYCLE = 0.02  # a prompt shutdown of the receive thread
        bus.own_ids = {0x000, 0x080} | {base + a.node_id for a in axes for base in (0x200, 0x600)}
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
        #: (time s, node id, EMCY code, error register)
        self.emcy: list[tuple[float, int, int, int]] = []
        self.nodes: list[canopen.RemoteNode] = []
        self._rpdo: list = []
        self.started = False

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

    def start(self) -> None:
        """Configure every node by SDO and start them (NMT operational). Raises :class:`BusError`."""
        if isinstance(self.network, PumpedNetwork):
            pass  # frames are delivered by the simulation link
        else:
            self.network.connect()  # the bus is open already: this starts the receive thread
        value, index = cia402.interpolation_period(self.period)
        for i, axis in enumerate(self.axes):
            node = canopen.RemoteNode(axis.node_id, cia402.cia402_object_dictionary(axis.node_id))
            node.sdo.RESPONSE_TIMEOUT = self.sdo_timeout
            node.sdo.MAX_RETRIES = self.SDO_ATTEMPTS  # a lost frame costs a retry, not the run
            self.network.add_node(node)
            self.nodes.append(node)
            device_type = self._sdo(i, "reading the device type 0x1000", lambda n=node: n.sdo[0x1000].raw)
            if device_type & 0xFFFF != 402:
                raise BusError(
                    f"{self._where(i)} is not a CiA 402 drive: "
                    f"device type 0x{device_type:08X} (profile {device_type & 0xFFFF})"
                )
            node.nmt.state = "PRE-OPERATIONAL"
            cpu = axis.counts_per_unit
            writes = [
                ("the heartbeat time 0x1017", (0x1017,), round(self.heartbeat_period * 1000)),
                ("mode of operation CSP 0x6060", (0x6060,), cia402.CSP),
                ("the interpolation period 0x60C2", (0x60C2, 1), value),
                ("the interpolation period 0x60C2", (0x60C2, 2), index),
                ("the following error window 0x6065", (0x6065,), max(1, round(axis.following_error_window * cpu))),
                ("the following error time-out 0x6066", (0x6066,), round(self.following_error_timeout * 1000)),
                ("the quick stop deceleration 0x6085", (0x6085,), round(axis.quick_stop_deceleration * cpu)),
                ("the quick stop option code 0x605A", (0x605A,), 6),
                ("the maximum velocity 0x607F", (0x607F,), round(axis.max_velocity * cpu)),
                ("the software position limits 0x607D", (0x607D, 1), int(np.floor(axis.lower * cpu))),
                ("the software position limits 0x607D", (0x607D, 2), int(np.ceil(axis.upper * cpu))),
            ]
            for what, key, raw in writes:
                obj = node.sdo[key[0]] if len(key) == 1 else node.sdo[key[0]][key[1]]
                self._sdo(i, f"writing {what}", lambda obj=obj, raw=raw: setattr(obj, "raw", raw))
            self._sdo(i, "configuring the PDOs", lambda n=node: self._map_pdos(n))
            rpdo = node.rpdo[1]
            self._rpdo.append((rpdo, rpdo[0x6040], rpdo[0x607A]))
            node.tpdo[1].add_callback(lambda pdo, i=i: self._on_tpdo(i, pdo))
            node.nmt.add_heartbeat_callback(lambda state, i=i: self._on_heartbeat(i, state))
            node.emcy.add_callback(lambda entry, i=i: self._on_emcy(i, entry))
        positions, statuswords = self.read_state()
        with self._lock:
            self._position[:] = positions
            self._statusword[:] = statuswords
        for node in self.nodes:
            node.nmt.state = "OPERATIONAL"
        self.last_heartbeat[:] = self.clock.now()  # a full timeout of grace from here
        self.heartbeat_state[:] = NMT_OPERATIONAL
        self.started = True

    @staticmethod
    def _map_pdos(node: canopen.RemoteNode) -> None:
        node.rpdo.read()
        rpdo = node.rpdo[1]
        rpdo.clear()
        rpdo.add_variable(0x6040)
        rpdo.add_variable(0x607A)
        rpdo.trans_type = 1
        rpdo.enabled = True
        node.rpdo.save()
        node.tpdo.read()
        tpdo = node.tpdo[1]
        tpdo.clear()
        tpdo.add_variable(0x6041)
        tpdo.add_variable(0x6064)
        tpdo.trans_type = 1
        tpdo.enabled = True
        node.tpdo.save()

    def read_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions (counts) and statuswords of every axis, read by SDO (no SYNC needed)."""
        positions = np.zeros(len(self.axes), dtype=np.int64)
        statuswords = np.zeros(len(self.axes), dtype=np.int64)
        for i, node in enumerate(self.nodes):
            positions[i] = self._sdo(i, "reading the position 0x6064", lambda n=node: n.sdo[0x6064].raw)
            statuswords[i] = self._sdo(i, "reading the statusword 0x6041", lambda n=node: n.sdo[0x6041].raw)
        return positions, statuswords

    # ------------------------------------------------------------------ consumers
    def _on_tpdo(self, i: int, pdo) -> None:
        data = bytes(pdo.data)
        if len(data) < 6:
            return
        statusword, position = struct.unpack_from("<Hl", data)
        with self._lock:
            self._statusword[i] = statusword
            self._position[i] = position
            self._fresh[i] = True
            self._answered[i] = self.syncs_sent

    def _on_heartbeat(self, i: int, state: int) -> None:
        self.last_heartbeat[i] = self.clock.now()
        self.heartbeat_state[i] = state

    def _on_emcy(self, i: int, entry: EmcyError) -> None:
        with self._lock:
            self.emcy.append((self.clock.now(), self.axes[i].node_id, entry.code, entry.register))

    # ------------------------------------------------------------------ cyclic exchange
    def feedback(self) -> Feedback:
        with self._lock:
            out = Feedback(
                self._statusword.copy(),
                self._position.copy(),
                self._fresh.copy(),
                self._answered == self.syncs_sent,
            )
            self._fresh[:] = False
        return out

    def exchange(self, controlwords, targets) -> None:
        """SYNC, then each axis' RPDO (controlword, target counts). Raises ``can.CanError`` on a bus error."""
        with self._lock:
            # counted before sending: in real time the answers may arrive before transmit returns
            self.syncs_sent += 1
        self.network.sync.transmit()
        for (rpdo, controlword, target), cw, tp in zip(self._rpdo, controlwords, targets, strict=True):
            controlword.raw = int(cw)
            target.raw = int(tp)
            rpdo.transmit()

    def emcy_since(self, count: int) -> list[tuple[float, int, int, int]]:
        with self._lock:
            return list(self.emcy[count:])

    def close(self) -> None:
        """NMT pre-operational (PDOs stop) where possible, then release the bus."""
        if self.started:
            for node in self.nodes:
                try:
                    node.nmt.state = "PRE-OPERATIONAL"
                except (can.CanError, RuntimeError):
                    break
            self.started = False
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
