"""Simulated CiA 402 servo drives: one CANopen node per joint on ``canopen.LocalNode``.

canopen ships the master side of CiA 402 only; these are the slaves. Each
axis is a :class:`canopen.LocalNode` (SDO server, NMT slave with heartbeat
producer, EMCY producer, TPDO/RPDO per the object dictionary of
:mod:`.cia402`) on a bus of its own (the simulator's), and a motor:

* the CiA 402 state machine, driven by the controlword of RPDO1 (applied at
  SYNC, as transmission type 1 says), reported in the statusword;
* cyclic synchronous position: at each SYNC the drive latches its target and
  interpolates linearly to it over one interpolation period (0x60C2), with
  the target rate as velocity feed-forward;
* a second-order motor (inertia with viscous damping) under a cascade of a
  proportional position loop (its correction capped at ``sqrt(a_peak |e|)``,
  so that it can always be braked: the square-root law) and a proportional
  velocity loop, with a velocity limit and a current (acceleration) limit,
  integrated with
  semi-implicit Euler steps of at most ``substep`` seconds, vectorised over
  the axes;
* an incremental encoder: positions are quantised to whole counts, in the
  position loop and in the TPDO;
* following-error monitoring (0x6065 window, 0x6066 time-out): FAULT, an EMCY
  0x8611, and the holding brake; quick stop (ramp at 0x6085, option code 6:
  stay in QUICK STOP ACTIVE); software position limits (0x607D) clamp targets;
* a SYNC watchdog (abort connection, 0x6007 = 3): an enabled drive that sees
  no SYNC for ``sync_timeout`` quick-stops by itself and sends EMCY 0x8730.

Under the simulated clock every frame is handled synchronously
(:class:`~.network.SimulationLink`); in real time the simulator runs its own
receive-and-timer loop in a thread.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from dataclasses import dataclass

import can
import canopen
import numpy as np

from . import cia402
from .bus import ArmedFaults
from .clock import Clock, Scheduler
from .network import PumpedNetwork, SimulationLink

log = logging.getLogger(__name__)

_STATES = list(cia402.STATUSWORD)
_CODE = {name: i for i, name in enumerate(_STATES)}
OE = _CODE[cia402.OPERATION_ENABLED]
QS = _CODE[cia402.QUICK_STOP_ACTIVE]
FAULT = _CODE[cia402.FAULT]


@dataclass
class AxisHardware:
    """The simulated hardware of one joint (SI joint units: rad or m)."""

    node_id: int
    counts_per_unit: float
    #: current limit, as the joint acceleration it allows (units/s^2)
    peak_acceleration: float
    #: motor speed limit (units/s)
    max_velocity: float
    #: position at power-up (units)
    initial: float = 0.0


@dataclass
class MotorModel:
    """Servo loop and motor constants shared by the simulated axes."""

    #: position loop gain (1/s)
    position_gain: float = 150.0
    #: velocity loop gain (1/s)
    velocity_gain: float = 1000.0
    #: viscous damping over inertia (1/s)
    damping: float = 2.0
    #: largest integration step (s)
    substep: float = 5e-4
    #: an enabled drive without SYNC for this long quick-stops (s)
    sync_timeout: float = 0.05


def _locked(method):
    """Serialise the simulator's state changes (its thread, the master's thread) in real time."""

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)

    return wrapper


class DriveSimulator:
    """Simulated drives on a python-can ``bus`` of their own, one LocalNode per axis.

    The bus is usually a second handle on the master's virtual channel; for the
    stand-alone simulator (:mod:`.sim_drives`) any python-can interface.
    ``link`` (simulated clock) delivers frames synchronously; without it (real
    time) call :meth:`start`.
    """

    def __init__(
        self,
        bus: can.BusABC,
        axes: list[AxisHardware],
        model: MotorModel,
        clock: Clock,
        faults: ArmedFaults,
        link: SimulationLink | None,
    ) -> None:
        self.axes = axes
        self.model = model
        self.clock = clock
        self.faults = faults
        self.realtime = link is None
        self._lock = threading.RLock()
        self.scheduler = Scheduler() if self.realtime else clock.scheduler
        self.frame_drop = frame_drop = faults.frame_loss(stream=1)
        self.sync_drop = faults.frame_loss(stream=2)
        self.network = PumpedNetwork(
            bus,
            self.scheduler,
            clock.now,
            link,
            drop=(lambda can_id: can_id != 0x80 and frame_drop.drop(can_id)) if frame_drop else None,
        )
        n = len(axes)
        self.ids = [a.node_id for a in axes]
        self.cpu = np.array([a.counts_per_unit for a in axes], dtype=float)
        self.peak = np.array([a.peak_acceleration for a in axes], dtype=float)
        self.vmax = np.array([a.max_velocity for a in axes], dtype=float)
        self.pos = np.array([a.initial for a in axes], dtype=float)
        self.vel = np.zeros(n)
        self.t = clock.now()
        self.state = np.full(n, _CODE[cia402.SWITCH_ON_DISABLED])
        self.alive = np.array([not faults.never_answers(a.node_id) for a in axes])
        self.controlword = np.zeros(n, dtype=np.int64)
        self.pending: list[tuple[int, int] | None] = [None] * n
        # interpolation: from cmd_from at t_latch to cmd_to one period later
        self.cmd_from = self.pos.copy()
        self.cmd_to = self.pos.copy()
        self.t_latch = np.full(n, self.t)
        self.period = np.full(n, 1e-3)
        # quick stop ramp
        self.qs_t = np.zeros(n)
        self.qs_pos = np.zeros(n)
        self.qs_vel = np.zeros(n)
        self.qs_decel = np.full(n, 1e9)
        # monitoring and parameters (read from the object dictionary when enabling)
        self.window = np.full(n, np.inf)
        self.window_time = np.full(n, 0.01)
        self.over_time = np.zeros(n)
        self.following_error = np.zeros(n, dtype=bool)
        self.limit_lo = np.full(n, -np.inf)
        self.limit_hi = np.full(n, np.inf)
        self.load = np.zeros(n)
        self.error_code = np.zeros(n, dtype=np.int64)
        self.last_sync = np.full(n, -np.inf)
        self.pdo_ready = np.zeros(n, dtype=bool)
        #: ground truth for tests and diagnosis: (time s, node id, from state, to state)
        self.transitions: list[tuple[float, int, str, str]] = []
        self.nodes: dict[int, canopen.LocalNode] = {}
        for i, axis in enumerate(axes):
            if not self.alive[i]:
                continue
            node = canopen.LocalNode(axis.node_id, cia402.cia402_object_dictionary(axis.node_id))
            self.network.add_node(node)
            node.add_read_callback(lambda index, subindex, od, i=i: self._read(i, index, subindex))
            node.rpdo[1].add_callback(lambda pdo, i=i: self._on_rpdo(i, pdo))
            self.nodes[axis.node_id] = node
        self.network.subscribe(0x80, self._on_sync)
        self.network.subscribe(0x000, self._on_nmt)
        for node in self.nodes.values():  # power-up: boot-up message, then PRE-OPERATIONAL
            node.nmt.send_command(0x81)
            node.nmt.send_command(0x80)
        self.scheduler.call_every(0.01, self._watchdog, self.t + 0.01)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    # ------------------------------------------------------------------ object dictionary
    def _read(self, i: int, index: int, subindex: int):
        if index == 0x6041:
            return self.statusword(i)
        if index == 0x6064:
            return round(self.pos[i] * self.cpu[i])
        if index == 0x6061:
            return cia402.CSP if self.state[i] == OE else 0
        if index == 0x603F:
            return int(self.error_code[i])
        if index == 0x1001:
            return 0x21 if self.error_code[i] else 0
        return None

    def statusword(self, i: int) -> int:
        word = cia402.STATUSWORD[_STATES[self.state[i]]] | cia402.SW_REMOTE
        if self.state[i] == OE:
            word |= cia402.SW_FOLLOWING_COMMAND
        if self.following_error[i]:
            word |= cia402.SW_FOLLOWING_ERROR
        return word

    def _parameter(self, node, index, subindex=None) -> int:
        obj = node.sdo[index] if subindex is None else node.sdo[index][subindex]
        return int(obj.raw)

    def _load_parameters(self, i: int) -> None:
        node = self.nodes[self.ids[i]]
        cpu = self.cpu[i]
        value, exponent = self._parameter(node, 0x60C2, 1), self._parameter(node, 0x60C2, 2)
        self.period[i] = value * 10.0**exponent
        self.window[i] = self._parameter(node, 0x6065) / cpu
        self.window_time[i] = self._parameter(node, 0x6066) / 1000.0
        self.qs_decel[i] = self._parameter(node, 0x6085) / cpu
        self.vmax[i] = min(self.axes[i].max_velocity, self._parameter(node, 0x607F) / cpu)
        lo, hi = self._parameter(node, 0x607D, 1), self._parameter(node, 0x607D, 2)
        self.limit_lo[i], self.limit_hi[i] = (lo / cpu, hi / cpu) if lo < hi else (-np.inf, np.inf)

    # ------------------------------------------------------------------ NMT and PDO
    def _on_nmt(self, can_id, data, timestamp) -> None:
        for i, node_id in enumerate(self.ids):
            node = self.nodes.get(node_id)
            if node is None or not self.alive[i]:
                continue
            operational = node.nmt.state == "OPERATIONAL"
            if operational and not self.pdo_ready[i]:
                node.rpdo.read()  # the mapping the master configured by SDO
                node.tpdo.read()
            self.pdo_ready[i] = operational

    @_locked
    def _on_rpdo(self, i: int, pdo) -> None:
        if not self.pdo_ready[i] or not self.alive[i]:
            return
        controlword = target = None
        for var in pdo:
            if var.index == 0x6040:
                controlword = int(var.raw)
            elif var.index == 0x607A:
                target = int(var.raw)
        self.pending[i] = (controlword, target)

    @_locked
    def _on_sync(self, can_id, data, timestamp) -> None:
        now = self.clock.now()
        if self.realtime:
            # a drive latches and samples at the SYNC's arrival (in hardware); this thread may run
            # later, so go back by the frame's age (python-can stamps frames with time.time()); an
            # implausible age (an interface without receive timestamps) is ignored
            age = time.time() - timestamp
            if 0.0 < age < self.model.sync_timeout:
                now = max(self.t, now - age)
        self.advance(now)
        for i, node_id in enumerate(self.ids):
            if not self.alive[i] or not self.pdo_ready[i]:
                continue
            if self.sync_drop is not None and self.sync_drop.drop(0x80):
                continue  # this drive missed the SYNC: nothing latched, nothing sampled
            self.last_sync[i] = now
            if self.pending[i] is not None:
                controlword, target = self.pending[i]
                self.pending[i] = None
                if controlword is not None:
                    self._apply_controlword(i, controlword, now)
                if target is not None and self.state[i] == OE:
                    self._latch(i, target, now)
            tpdo = self.nodes[node_id].tpdo[1]
            for var in tpdo:
                if var.index == 0x6041:
                    var.raw = self.statusword(i)
                elif var.index == 0x6064:
                    var.raw = round(self.pos[i] * self.cpu[i])
            tpdo.transmit()

    # ------------------------------------------------------------------ state machine
    def _set_state(self, i: int, code: int, t: float) -> None:
        if code != self.state[i]:
            self.transitions.append((t, self.ids[i], _STATES[self.state[i]], _STATES[code]))
        self.state[i] = code

    def _apply_controlword(self, i: int, controlword: int, now: float) -> None:
        state = _STATES[self.state[i]]
        new = cia402.next_state(state, controlword, int(self.controlword[i]))
        self.controlword[i] = controlword
        if new == state:
            return
        if new == cia402.OPERATION_ENABLED:
            self._load_parameters(i)
            mode = self._parameter(self.nodes[self.ids[i]], 0x6060)
            if mode != cia402.CSP:
                log.warning("node %d: mode of operation %d is not CSP (8); staying disabled", self.ids[i], mode)
                return
            self.cmd_from[i] = self.cmd_to[i] = self.pos[i]  # hold where it is: no jump
            self.t_latch[i] = now
            self.over_time[i] = 0.0
            self.following_error[i] = False
        elif new == cia402.QUICK_STOP_ACTIVE:
            self._enter_quick_stop(i, now)
        elif new == cia402.SWITCH_ON_DISABLED and state == cia402.FAULT:
            self.error_code[i] = 0
            self.following_error[i] = False
            self.nodes[self.ids[i]].emcy.reset()
        self._set_state(i, _CODE[new], now)

    def _command(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Position command and its rate for every axis at times ``t`` (scalar, or (S, 1) for S times)."""
        frac = np.minimum(np.maximum((t - self.t_latch) / self.period, 0.0), 1.0)
        step = self.cmd_to - self.cmd_from
        interp = self.cmd_from + frac * step
        interp_rate = np.where(frac < 1.0, step / self.period, 0.0)
        quick = self.state == QS
        if not np.any(quick):
            return interp, interp_rate
        # quick stop: decelerate from (qs_pos, qs_vel) at qs_decel to rest
        tau = np.minimum(np.maximum(t - self.qs_t, 0.0), np.abs(self.qs_vel) / self.qs_decel)
        sign = np.sign(self.qs_vel)
        stop = self.qs_pos + self.qs_vel * tau - 0.5 * sign * self.qs_decel * tau**2
        stop_rate = self.qs_vel - sign * self.qs_decel * tau
        return np.where(quick, stop, interp), np.where(quick, stop_rate, interp_rate)

    def _enter_quick_stop(self, i: int, now: float) -> None:
        # the ramp starts from where the motor is and how fast it moves
        self.qs_t[i] = now
        self.qs_pos[i] = self.pos[i]
        self.qs_vel[i] = self.vel[i]

    def _latch(self, i: int, target_counts: int, now: float) -> None:
        command, _ = self._command(now)
        target = np.clip(target_counts / self.cpu[i], self.limit_lo[i], self.limit_hi[i])
        self.cmd_from[i] = command[i]
        self.cmd_to[i] = target
        self.t_latch[i] = now

    # ------------------------------------------------------------------ physics
    def advance(self, t: float) -> None:
        """Integrate every motor from the last call to time ``t`` (s)."""
        span = t - self.t
        if span <= 0:
            return
        if not np.any(((self.state == OE) | (self.state == QS)) & self.alive):
            # every brake holds: nothing moves (unpowered velocities are zero)
            self.vel[:] = 0.0
            self.t = t
            return
        steps = max(1, int(np.ceil(span / self.model.substep - 1e-9)))
        dt = span / steps
        m = self.model
        powered = (((self.state == OE) | (self.state == QS)) & self.alive).astype(float)
        monitored = (self.state == OE) & self.alive
        # the commands of every substep at once; the integration itself is sequential
        # the loop compares the position at the start of each step with the command there
        command, rate = self._command(self.t + dt * np.arange(steps)[:, None])
        command = np.broadcast_to(command, (steps, len(self.pos)))
        rate = np.broadcast_to(rate, (steps, len(self.pos)))
        pos, vel, over_time = self.pos, self.vel, self.over_time
        cpu, resolution = self.cpu, 1.0 / self.cpu
        vmax, peak, load, window = self.vmax, self.peak, self.load, self.window
        tripped = np.zeros(len(pos), dtype=bool)
        for k in range(steps):
            measured = np.rint(pos * cpu) * resolution  # the encoder
            # proportional position loop whose correction can always be braked within the current
            # limit (the square-root law of drives' position controllers), plus the feed-forward
            error = command[k] - measured
            correction = np.sign(error) * np.minimum(m.position_gain * np.abs(error), np.sqrt(peak * np.abs(error)))
            velocity_command = np.minimum(np.maximum(rate[k] + correction, -vmax), vmax)
            torque = np.minimum(np.maximum(m.velocity_gain * (velocity_command - vel), -peak), peak)
            # the holding brake keeps unpowered axes still
            vel = (vel + (torque - m.damping * vel + load) * dt) * powered
            pos = pos + vel * dt
            over_time = (over_time + dt) * (monitored & (np.abs(command[k] - pos) > window))
            tripped |= over_time > self.window_time
        self.pos, self.vel, self.over_time = pos, vel, over_time
        self.t = t
        for i in np.flatnonzero(tripped & monitored):
            self._fault(i, cia402.EMCY_FOLLOWING_ERROR, following_error=True)

    def _fault(self, i: int, code: int, following_error: bool = False) -> None:
        self._set_state(i, FAULT, self.t)  # fault reaction: the brake holds the axis
        self.vel[i] = 0.0
        self.error_code[i] = code
        self.following_error[i] = following_error
        node = self.nodes.get(self.ids[i])
        if node is not None and self.alive[i]:
            node.emcy.send(code, 0x21)

    @_locked
    def _watchdog(self) -> None:
        now = self.clock.now()
        self.advance(now)
        lost = (self.state == OE) & self.alive & (now - self.last_sync > self.model.sync_timeout)
        for i in np.flatnonzero(lost):
            self._set_state(i, QS, now)
            self._enter_quick_stop(i, now)
            self.nodes[self.ids[i]].emcy.send(cia402.EMCY_SYNC_LOST, 0x11)

    # ------------------------------------------------------------------ injected faults
    def arm(self, origin: float) -> None:
        """Schedule the injected faults relative to ``origin`` (the trajectory start, s)."""
        index = {node_id: i for i, node_id in enumerate(self.ids)}
        for fault in self.faults.faults:
            i = index.get(getattr(fault, "node", None))
            if fault.kind == "heartbeat_loss" and i is not None and fault.node in self.nodes:
                self.scheduler.call_at(origin + fault.at_s, self.nodes[fault.node].nmt.stop_heartbeat)
            elif fault.kind == "following_error" and i is not None:
                self.scheduler.call_at(origin + fault.at_s, lambda i=i, f=fault: self._push(i, f.load))
                self.scheduler.call_at(origin + fault.at_s + fault.duration_s, lambda i=i: self._push(i, 0.0))
            elif fault.kind == "dead_node" and i is not None and fault.at_s is not None:
                self.scheduler.call_at(origin + fault.at_s, lambda i=i: self._die(i))

    @_locked
    def _push(self, i: int, load: float) -> None:
        self.advance(self.clock.now())
        direction = -np.sign(self.vel[i]) if self.vel[i] != 0 else -1.0
        self.load[i] = direction * load * self.peak[i]

    @_locked
    def _die(self, i: int) -> None:
        self.advance(self.clock.now())
        node = self.nodes.get(self.ids[i])
        if node is not None:
            node.nmt.stop_heartbeat()
            del self.network[self.ids[i]]
        self.alive[i] = False
        self._set_state(i, _CODE[cia402.NOT_READY], self.t)
        self.vel[i] = 0.0

    # ------------------------------------------------------------------ real time
    def start(self) -> None:
        """Real-time mode: receive and run timers in a thread until :meth:`stop`."""
        self._thread = threading.Thread(target=self._loop, name="surgiplan-simulated-drives", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.is_set():
            due = self.scheduler.next_due()
            wait = 0.005 if due is None else min(0.005, max(0.0, due - self.clock.now()))
            # a few frames at a time: the timers (heartbeats, the SYNC watchdog) must not wait behind
            # a backlog of frames when the process was descheduled
            self.network.pump(wait, limit=2 + 2 * len(self.axes))
            now = self.clock.now()
            while (timer := self.scheduler.pop_due(now)) is not None:
                timer.action()

    def positions(self) -> np.ndarray:
        """True joint positions (units): the simulation's ground truth, for tests."""
        return self.pos.copy()

    @_locked
    def place(self, positions) -> None:
        """Simulation only: put the (still) axes at ``positions`` (units), as a hand would."""
        self.pos = np.asarray(positions, dtype=float).copy()
        self.vel[:] = 0.0
        self.cmd_from = self.pos.copy()
        self.cmd_to = self.pos.copy()
        self.pending = [None] * len(self.pos)  # targets sent for the old position no longer apply

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for node in self.nodes.values():
            node.nmt.stop_heartbeat()
        if self.network.bus is not None:
            self.network.bus.shutdown()
            self.network.bus = None
