"""Simulated CiA 402 servo drives: one CANopen node per joint, CiA 301 and CiA 402 as real drives do them.

canopen ships the master side of CiA 402 only; these are the slaves. Each
axis is a :class:`DriveNode` (a ``canopen.LocalNode`` with its object
dictionary from :func:`.cia402.drive_object_dictionary`, the same one its
EDS file states) on the simulator's bus, and a motor.

Communication (CiA 301):

* NMT: power-up and every reset send the boot-up message (0x700 + node, one
  byte 0x00) and enter PRE-OPERATIONAL; *reset communication* restores the
  communication area (0x1000-0x1FFF) to its power-on values, *reset node*
  every object and the drive itself (SWITCH ON DISABLED, errors cleared, the
  brake holding); STOPPED answers no SDO and sends no EMCY or PDO; PDOs only
  in OPERATIONAL. Leaving OPERATIONAL for STOPPED or a reset while the drive
  is enabled performs the abort connection option 0x6007 (CiA 402), as does
  a lost heartbeat of a consumed node (0x1016) or, in the cyclic synchronous
  modes, a SYNC that stops coming (0x2000, the SYNC watchdog).
* SDO: expedited and segmented (canopen's server); values checked on write
  with the standard abort codes (0x06090030 value range, 0x06040041/42 PDO
  mapping, 0x08000022 device state, ...); every parameter takes effect when
  written, also while enabled.
* PDO: four RPDOs and four TPDOs, mapped by SDO with CiA 301's procedure
  (invalidate the COB-ID, number of entries 0, entries, number, validate;
  only in PRE-OPERATIONAL); RPDO transmission types 0-240 apply at the next
  SYNC, 254/255 on reception; TPDO types 1-240 go every n-th SYNC, 0 on SYNC
  when changed, 254/255 on change and on the event timer.
* EMCY on entering every error, EMCY 0x0000 when the last is gone; error
  register 0x1001, error code 0x603F, pre-defined error field 0x1003
  (newest first; writing 0 to sub-index 0 clears it).

Drive (CiA 402): the state machine by controlword (written by SDO or RPDO:
the same object), statusword; modes profile position (1), profile velocity
(3), cyclic synchronous position (8) and velocity (9) (0x6502), anything
else refused with abort 0x06090030; 0x6061 always shows the mode in force.
The motor: a second-order model (inertia with viscous damping) under a
cascade of a proportional position loop (its correction capped at
``sqrt(a_peak |e|)``, so that it can always be braked) and a proportional
velocity loop, with speed and current (acceleration) limits, integrated with
semi-implicit Euler steps of at most ``substep`` seconds, vectorised over the
axes; an encoder quantising positions to whole counts. The reference each
mode gives the loops is piecewise quadratic (:class:`_Reference`): CSP
interpolates linearly to each SYNC's target over the interpolation period
(0x60C2) with the target rate as feed-forward; CSV ramps to each SYNC's
target velocity over one period; PP plans a trapezoid (0x6081, 0x6083,
0x6084, the set-point taken on the rising edge of controlword bit 4,
acknowledged in statusword bit 12, target reached in bit 10 within 0x6067
for 0x6068 ms); PV ramps to 0x60FF. Software position limits (0x607D) clamp
position targets and brake velocity modes before the limit (statusword bit
11). Following-error monitoring (0x6065/0x6066) in the position modes:
FAULT, EMCY 0x8611, the brake. Quick stop with option codes 0, 1, 2, 5, 6
(0x605A) at 0x6085 (or 0x6084 for the slow-down ramps).

Under the simulated clock every frame is handled synchronously
(:class:`~.network.SimulationLink`); in real time the simulator runs its own
receive-and-timer loop in a thread.
"""

from __future__ import annotations

import functools
import logging
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import can
import canopen
import numpy as np
from canopen import objectdictionary as od_types
from canopen.emcy import EmcyProducer
from canopen.nmt import NmtSlave
from canopen.sdo import SdoAbortedError, SdoServer

from . import cia402
from .bus import ArmedFaults
from .clock import Clock, Scheduler, set_realtime_priority
from .network import PumpedNetwork, SimulationLink

log = logging.getLogger(__name__)

_STATES = list(cia402.STATUSWORD)
_CODE = {name: i for i, name in enumerate(_STATES)}
NOT_READY = _CODE[cia402.NOT_READY]
SOD = _CODE[cia402.SWITCH_ON_DISABLED]
OE = _CODE[cia402.OPERATION_ENABLED]
QS = _CODE[cia402.QUICK_STOP_ACTIVE]
FAULT = _CODE[cia402.FAULT]
_STATUSWORD = [cia402.STATUSWORD[name] | cia402.SW_REMOTE for name in _STATES]
#: objects whose value is the motor's state: read after integrating the motor up to the moment of reading
_DYNAMIC = frozenset({0x6041, 0x6064, 0x606C, 0x6062, 0x60F4})

# NMT states (CiA 301) as the heartbeat reports them
NMT_INITIALISING, NMT_STOPPED, NMT_OPERATIONAL, NMT_PRE_OPERATIONAL = 0, 4, 5, 127
#: how often the drives' own monitoring runs (s): SYNC watchdog, heartbeat consumer, event-driven TPDOs
TICK = 0.005


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
    #: the joint's name, its kind ("rad" or "m") and travel: the EDS's product name and default limits
    name: str = "axis"
    unit: str = "rad"
    lower: float | None = None
    upper: float | None = None
    #: following error window at power-up (units; None: off)
    following_error_window: float | None = None
    #: profile velocity and acceleration at power-up (units/s, units/s^2; None: the motor's limits, a third
    #: of its current limit); the quick stop decelerates at twice the profile acceleration
    profile_velocity: float | None = None
    profile_acceleration: float | None = None

    def defaults(self, device: str = "", sync_watchdog: float = 0.05) -> cia402.DriveDefaults:
        """The power-on values of this axis' drive (its object dictionary's defaults, its EDS)."""
        what = f"{device} joint '{self.name}'" if device else f"joint '{self.name}'"
        return cia402.DriveDefaults(
            product_name=f"surgiplan simulated CiA 402 servo drive ({what})",
            counts_per_unit=self.counts_per_unit,
            unit=self.unit,
            lower=self.lower,
            upper=self.upper,
            max_velocity=self.max_velocity,
            profile_velocity=self.profile_velocity if self.profile_velocity is not None else self.max_velocity,
            acceleration=(
                self.profile_acceleration if self.profile_acceleration is not None else self.peak_acceleration / 3
            ),
            following_error_window=self.following_error_window,
            sync_watchdog=sync_watchdog,
        )


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
    #: an enabled drive in a cyclic synchronous mode without SYNC for this long performs 0x6007 (s);
    #: the power-on value of 0x2000
    sync_timeout: float = 0.05


def _locked(method):
    """Serialise the simulator's state changes (its thread, the master's or a test's thread) in real time."""

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)

    return wrapper


# ----------------------------------------------------------------------------- communication (CiA 301)
class _DriveNmt(NmtSlave):
    """CiA 301 NMT slave: commands, boot-up after every reset, the resets' restore semantics."""

    def __init__(self, node_id: int, node: DriveNode) -> None:
        super().__init__(node_id, node)
        self.node = node

    def on_command(self, can_id, data, timestamp):
        if len(data) != 2:
            return  # not an NMT command (CiA 301: two bytes)
        command, target = data[0], data[1]
        if target not in (0, self.id) or not self.node.alive:
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


class _GatedSdoServer(SdoServer):
    """An SDO server that is silent in STOPPED (and INITIALISING): CiA 301's NMT state rules."""

    def on_request(self, can_id, data, timestamp):
        if self._node.nmt._state in (NMT_STOPPED, NMT_INITIALISING) or not self._node.alive:
            return
        super().on_request(can_id, data, timestamp)


class _GatedEmcy(EmcyProducer):
    """EMCY only in PRE-OPERATIONAL and OPERATIONAL (CiA 301)."""

    def __init__(self, cob_id: int, node: DriveNode) -> None:
        super().__init__(cob_id)
        self.node = node

    def send(self, code: int, register: int = 0, data: bytes = b"") -> None:
        if self.node.alive and self.node.nmt._state in (NMT_PRE_OPERATIONAL, NMT_OPERATIONAL):
            super().send(code, register, data)


@dataclass
class _Pdo:
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
    #: the entries with the controlword last (RPDO)
    ordered: list = field(default_factory=list)
    #: TPDO of objects the simulator serves: packed in one go
    packer: struct.Struct | None = None
    getters: list = field(default_factory=list)


#: the objects a TPDO packs straight from the simulator's state, and the struct codes of their sizes
_TPDO_GETTERS = {
    0x6041: lambda sim, i: sim.statusword(i),
    0x6064: lambda sim, i: round(sim.pos[i] * sim.cpu[i]),
    0x606C: lambda sim, i: round(sim.vel[i] * sim.cpu[i]),
    0x6061: lambda sim, i: int(sim.mode[i]),
    0x603F: lambda sim, i: next(iter(reversed(sim.errors[i])), 0),
}
_FORMATS = {1: "B", 2: "H", 4: "L"}


class DriveNode(canopen.LocalNode):
    """One simulated drive's CANopen side: object dictionary, NMT, SDO, EMCY, PDO configuration."""

    def __init__(self, node_id: int, dictionary, simulator: DriveSimulator, axis: int) -> None:
        super().__init__(node_id, dictionary)
        self.simulator = simulator
        self.axis = axis
        self.alive = True
        # replace canopen's NMT slave (no boot-up after a reset, stuck in INITIALISING), its SDO server
        # (answers in STOPPED) and EMCY producer (sends in STOPPED) with CiA 301's behaviour
        self._write_callbacks.remove(self.nmt.on_write)
        self.nmt = _DriveNmt(node_id, self)
        self.add_write_callback(self.nmt.on_write)
        self.sdo = _GatedSdoServer(0x600 + node_id, 0x580 + node_id, self)
        self.emcy = _GatedEmcy(0x80 + node_id, self)
        self.rpdos: list[_Pdo] = []
        self.tpdos: list[_Pdo] = []

    # ------------------------------------------------------------------ values
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
        self.simulator._on_nmt(self.axis, old, new)

    def on_reset(self, old: int, application: bool) -> None:
        self.simulator._on_reset(self.axis, old, application)
        for index in list(self.data_store):
            if application or 0x1000 <= index <= 0x1FFF:
                del self.data_store[index]
        self.rpdos, self.tpdos = [], []
        self.simulator._reload(self.axis)  # the restored values take effect

    # ------------------------------------------------------------------ PDOs
    def compile_pdos(self) -> None:
        """Read the PDO configuration from the object dictionary (entering OPERATIONAL)."""
        self.rpdos = [self._compile(True, n) for n in (1, 2, 3, 4)]
        self.tpdos = [self._compile(False, n) for n in (1, 2, 3, 4)]

    def _compile(self, receive: bool, n: int) -> _Pdo:
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
        pdo = _Pdo(receive, n, cob & 0x7FF, not cob & cia402.PDO_INVALID, int(self.value(comm, 2)), inhibit,
                   event, entries, offset)  # fmt: skip
        pdo.ordered = sorted(entries, key=lambda entry: entry[0] == 0x6040)
        served = [index in _TPDO_GETTERS and size in _FORMATS for index, *_, size in entries]
        if not receive and entries and all(served):
            codes = ""
            for _, _, obj, _, size in entries:
                signed = obj.data_type in (od_types.INTEGER8, od_types.INTEGER16, od_types.INTEGER32)
                codes += _FORMATS[size].lower() if signed else _FORMATS[size]
            pdo.packer = struct.Struct("<" + codes)
            pdo.getters = [_TPDO_GETTERS[index] for index, *_ in entries]
        return pdo

    def tpdo_data(self, pdo: _Pdo) -> bytes:
        """A TPDO's data now: the mapped objects' values, packed in one go where the simulator serves them
        (the cyclic statusword and position), else each object's value as an SDO read would give it."""
        if pdo.packer is None:
            return b"".join(self.get_data(index, subindex) for index, subindex, *_ in pdo.entries)
        simulator, axis = self.simulator, self.axis
        return pdo.packer.pack(*[getter(simulator, axis) for getter in pdo.getters])

    def write_rpdo(self, pdo: _Pdo, data: bytes) -> None:
        """Write the mapped objects from an RPDO's data (as if by SDO), the controlword last: a drive acts on
        the whole PDO (a profile position set-point and its new target in one frame)."""
        if len(data) < pdo.length:
            return  # CiA 301: a PDO shorter than its mapping is not processed
        store = self.data_store
        for index, subindex, obj, offset, size in pdo.ordered:
            value = data[offset : offset + size]
            try:
                # as LocalNode.set_data, without its look-ups (the mapping was checked when it was written)
                self.simulator._write(self.axis, index, subindex, obj, value)
            except SdoAbortedError as exc:  # a value the drive refuses by PDO: ignored, as by SDO
                log.info("node %d: RPDO%d value for 0x%04X refused (0x%08X)", self.id, pdo.n, index, exc.code)
                continue
            store.setdefault(index, {})[subindex] = value


# ----------------------------------------------------------------------------- the motion reference
class _Reference:
    """Per axis, a piecewise-quadratic position reference: segments (start time, p, v, a), vectorised."""

    K = 4

    def __init__(self, n: int, t: float, pos: np.ndarray) -> None:
        self.t = np.full((n, self.K), np.inf)
        self.p = np.zeros((n, self.K))
        self.v = np.zeros((n, self.K))
        self.a = np.zeros((n, self.K))
        self.t[:, 0] = t
        self.p[:, 0] = pos

    def set(self, i: int, segments: list[tuple[float, float, float, float]]) -> None:
        self.t[i] = np.inf
        for k, (t, p, v, a) in enumerate(segments[: self.K]):
            self.t[i, k], self.p[i, k], self.v[i, k], self.a[i, k] = t, p, v, a

    def hold(self, i: int, t: float, p: float) -> None:
        self.set(i, [(t, p, 0.0, 0.0)])

    def at(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity of every axis at time ``t`` (scalar, or (S, 1) for S times)."""
        t = np.asarray(t, dtype=float)
        if t.ndim == 0:
            k = np.maximum(np.sum(self.t <= t, axis=1) - 1, 0)
            rows = np.arange(len(k))
            tau = np.maximum(t - self.t[rows, k], 0.0)
            a, v = self.a[rows, k], self.v[rows, k]
            return self.p[rows, k] + v * tau + 0.5 * a * tau * tau, v + a * tau
        k = np.maximum(np.sum(self.t[None] <= t[..., None], axis=2) - 1, 0)  # (S, n)
        cols = np.arange(self.t.shape[0])[None]
        tau = np.maximum(t - self.t[cols, k], 0.0)
        a, v = self.a[cols, k], self.v[cols, k]
        return self.p[cols, k] + v * tau + 0.5 * a * tau * tau, v + a * tau

    def at_axis(self, i: int, t: float) -> tuple[float, float]:
        """Position and velocity of axis ``i`` at time ``t`` (scalar arithmetic: one axis, cheaply)."""
        starts = self.t[i]
        k = 0
        for j in range(1, self.K):
            if starts[j] <= t:
                k = j
        tau = max(t - float(starts[k]), 0.0)
        a, v = float(self.a[i, k]), float(self.v[i, k])
        return float(self.p[i, k]) + v * tau + 0.5 * a * tau * tau, v + a * tau

    def end(self, i: int) -> float:
        """Start of the axis' last segment: from then on the reference is constant velocity (or still)."""
        finite = self.t[i][np.isfinite(self.t[i])]
        return float(finite[-1]) if len(finite) else -np.inf


def _stop_segments(t: float, p: float, v: float, decel: float) -> list:
    """Decelerate from (p, v) at ``decel`` to rest, then hold."""
    if v == 0.0 or decel <= 0:
        return [(t, p, 0.0, 0.0)]
    a = -np.sign(v) * decel
    duration = abs(v) / decel
    return [(t, p, v, a), (t + duration, p + v * duration / 2, 0.0, 0.0)]


def _velocity_segments(t: float, p: float, v: float, target: float, accel: float, decel: float) -> list:
    """Ramp from velocity v to ``target`` (accelerating at accel, slowing at decel), then constant."""
    if target == v:
        return [(t, p, v, 0.0)]
    slowing = abs(target) < abs(v) or np.sign(target) != np.sign(v)
    rate = decel if slowing else accel
    duration = abs(target - v) / rate
    a = np.sign(target - v) * rate
    return [(t, p, v, a), (t + duration, p + v * duration + 0.5 * a * duration**2, target, 0.0)]


def _trapezoid(t: float, p: float, v: float, goal: float, vmax: float, accel: float, decel: float) -> list:
    """Time-optimal move from (p, v) to rest at ``goal``: speed up at accel to at most vmax, slow at decel."""
    segments = []
    # moving away from the goal, or too fast to stop before it: brake to rest first
    stop = v * abs(v) / (2 * decel)
    if v != 0 and (np.sign(v) != np.sign(goal - p) or abs(stop) > abs(goal - p) + 1e-12):
        braking = _stop_segments(t, p, v, decel)
        segments += braking[:-1]
        t, p, v = braking[-1][0], braking[-1][1], 0.0
    distance = goal - p
    if abs(distance) < 1e-12:
        return [*segments, (t, goal, 0.0, 0.0)]
    s = np.sign(distance)
    d, u = abs(distance), abs(v)
    # peak speed w: (w^2 - u^2)/(2 accel) + w^2/(2 decel) = d
    w = np.sqrt((d + u * u / (2 * accel)) / (1 / (2 * accel) + 1 / (2 * decel)))
    w = max(min(w, vmax), u)
    t_up = (w - u) / accel
    d_up = (w * w - u * u) / (2 * accel)
    d_down = w * w / (2 * decel)
    t_cruise = max(0.0, (d - d_up - d_down) / w) if w > 0 else 0.0
    t_down = w / decel
    p1 = p + s * d_up
    p2 = p1 + s * w * t_cruise
    segments += [(t, p, s * u, s * accel), (t + t_up, p1, s * w, 0.0), (t + t_up + t_cruise, p2, s * w, -s * decel)]
    segments.append((t + t_up + t_cruise + t_down, goal, 0.0, 0.0))
    return [seg for k, seg in enumerate(segments) if k == len(segments) - 1 or seg[0] < segments[k + 1][0]]


# ----------------------------------------------------------------------------- the drives
class DriveSimulator:
    """Simulated drives on a python-can ``bus`` of their own, one :class:`DriveNode` per axis.

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
        device: str = "",
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
        self.hardware_vmax = np.array([a.max_velocity for a in axes], dtype=float)
        self.vmax = self.hardware_vmax.copy()
        self.pos = np.array([a.initial for a in axes], dtype=float)
        self.vel = np.zeros(n)
        self.t = clock.now()
        self.state = np.full(n, SOD)
        self.alive = np.array([not faults.never_answers(a.node_id) for a in axes])
        self.controlword = np.zeros(n, dtype=np.int64)
        self.reference = _Reference(n, self.t, self.pos)
        #: the mode in force (0x6061) per axis
        self.mode = np.full(n, cia402.CSP)
        # parameters in SI joint units (from the object dictionary; updated on every write)
        self.period = np.full(n, 1e-3)
        self.window = np.full(n, np.inf)
        self.window_time = np.full(n, 0.01)
        self.qs_decel = np.full(n, 1e9)
        self.profile_velocity = np.full(n, 1.0)
        self.profile_accel = np.full(n, 1.0)
        self.profile_decel = np.full(n, 1.0)
        self.limit_lo = np.full(n, -np.inf)
        self.limit_hi = np.full(n, np.inf)
        self.position_window = np.full(n, 0.0)
        self.position_window_time = np.zeros(n)
        self.velocity_window = np.full(n, 0.0)
        self.velocity_window_time = np.zeros(n)
        self.sync_watchdog = np.full(n, model.sync_timeout)
        self.abort_option = np.full(n, 3)
        self.qs_option = np.full(n, 6)
        # state of the modes and monitoring
        self.over_time = np.zeros(n)
        self.following_error = np.zeros(n, dtype=bool)
        self.load = np.zeros(n)
        self.last_sync = np.full(n, -np.inf)
        self.target = np.zeros(n)  # pp: the set-point being moved to (units)
        self.target_velocity = np.zeros(n)  # pv/csv (units/s)
        self.set_point_ack = np.zeros(n, dtype=bool)
        self.moving_to_target = np.zeros(n, dtype=bool)  # pp: a set-point was given and not yet reached
        self.inside_since = np.full(n, np.inf)
        self.limit_active = np.zeros(n, dtype=bool)
        self.qs_end = np.full(n, np.inf)  # quick stop ramps 1, 2: when to switch off
        self.errors: list[dict[int, int]] = [{} for _ in range(n)]
        self.error_history: list[list[int]] = [[] for _ in range(n)]
        #: heartbeat consumer per axis: {producer node id: [time s, last heartbeat time or None]}
        self.consumers: list[dict[int, list]] = [{} for _ in range(n)]
        self.pending: list[dict[int, bytes]] = [{} for _ in range(n)]  # synchronous RPDOs, by COB-ID
        #: ground truth for tests and diagnosis: (time s, node id, from state, to state)
        self.transitions: list[tuple[float, int, str, str]] = []
        self.nodes: dict[int, DriveNode] = {}
        self._subscribed: dict[int, object] = {}  # heartbeat consumers' COB-IDs
        self._rpdo_callbacks: dict[int, object] = {}
        #: real time: the time of the frame being handled (a SYNC's arrival), else None (the clock's now)
        self._event_time: float | None = None
        #: simulation only: where a hand holds the unpowered axes at time t (see move_by_hand)
        self.hand: Callable[[float], np.ndarray] | None = None
        self.dictionaries = []
        for i, axis in enumerate(axes):
            dictionary = cia402.drive_object_dictionary(axis.node_id, axis.defaults(device, model.sync_timeout))
            self.dictionaries.append(dictionary)
            if not self.alive[i]:
                continue
            node = DriveNode(axis.node_id, dictionary, self, i)
            self.network.add_node(node)
            node.add_read_callback(lambda index, subindex, od, i=i: self._read(i, index, subindex))
            node.add_write_callback(lambda index, subindex, od, data, i=i: self._write(i, index, subindex, od, data))
            self.nodes[axis.node_id] = node
            self._load_parameters(i)
        self.network.subscribe(0x80, self._on_sync)
        for node in self.nodes.values():  # power-up: boot-up message, then PRE-OPERATIONAL
            node.nmt.boot(application=True)
        self.scheduler.call_every(TICK, self._tick, self.t + TICK)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    def _now(self) -> float:
        return self._event_time if self._event_time is not None else self.clock.now()

    # ------------------------------------------------------------------ object dictionary: reads
    def _read(self, i: int, index: int, subindex: int):
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
        if index == 0x603F:
            return next(iter(reversed(self.errors[i])), 0)
        if index == 0x1001:
            register = 0
            for bits in self.errors[i].values():
                register |= bits
            return register
        if index == 0x1003:
            history = self.error_history[i]
            if subindex == 0:
                return len(history)
            if subindex > len(history):
                raise SdoAbortedError(0x08000024)  # no data available
            code = history[subindex - 1]
            return code | (cia402.ERROR_REGISTER.get(code, cia402.ERR_GENERIC) << 16)
        return None

    def statusword(self, i: int) -> int:
        state = int(self.state[i])
        word = _STATUSWORD[state]
        errors = self.errors[i]
        if errors and state != FAULT:
            word |= cia402.SW_WARNING
        if state == OE:
            mode = self.mode[i]
            if mode in cia402.CYCLIC_MODES:
                word |= cia402.SW_FOLLOWING_COMMAND
            elif mode == cia402.PP:
                if self.set_point_ack[i]:
                    word |= cia402.SW_SET_POINT_ACKNOWLEDGE
                if self._target_reached(i):
                    word |= cia402.SW_TARGET_REACHED
            elif mode == cia402.PV:
                if abs(self.vel[i]) * self.cpu[i] < 1.0:
                    word |= cia402.SW_SPEED_ZERO
                if self._target_reached(i):
                    word |= cia402.SW_TARGET_REACHED
            if self.limit_active[i]:
                word |= cia402.SW_INTERNAL_LIMIT
        if self.following_error[i]:
            word |= cia402.SW_FOLLOWING_ERROR
        return word

    def _target_reached(self, i: int) -> bool:
        if self.mode[i] == cia402.PP:
            if self.moving_to_target[i] or self.t < self.reference.end(i):
                return False
            return self.t - self.inside_since[i] >= self.position_window_time[i] - 1e-12
        if self.mode[i] == cia402.PV:
            return self.t - self.inside_since[i] >= self.velocity_window_time[i] - 1e-12
        return False

    # ------------------------------------------------------------------ object dictionary: writes
    def _write(self, i: int, index: int, subindex: int, od, data: bytes) -> None:
        """Check a write (SDO or RPDO) and make it take effect; raise SdoAbortedError to refuse it."""
        value = od.decode_raw(data)
        node = self.nodes[self.ids[i]]
        if 0x1400 <= index <= 0x1BFF:
            self._check_pdo_write(node, index, subindex, value)
            return
        with self._lock:
            now = self._now()
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
            elif index == 0x6007:
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
                if valid and not value & cia402.PDO_INVALID and value & 0x7FF != cob & 0x7FF:
                    raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)  # the COB-ID of a valid PDO is fixed
            elif subindex == 2 and not (value <= 240 or value in (254, 255)):
                raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)
            return
        if valid:
            raise SdoAbortedError(cia402.ABORT_DEVICE_STATE)  # invalidate the PDO first
        if subindex == 0:
            if value > 8:
                raise SdoAbortedError(cia402.ABORT_VALUE_RANGE)
            bits = 0
            for sub in range(1, value + 1):
                entry = int(node.value(index, sub))
                self._check_mapping_entry(node, entry, receive)
                bits += entry & 0xFF
            if bits > 64:
                raise SdoAbortedError(cia402.ABORT_PDO_TOO_LONG)
            return
        if int(node.value(index, 0)) != 0:
            raise SdoAbortedError(cia402.ABORT_DEVICE_STATE)  # set the number of entries to 0 first
        if value:
            self._check_mapping_entry(node, value, receive)

    @staticmethod
    def _check_mapping_entry(node: DriveNode, entry: int, receive: bool) -> None:
        index, subindex, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        try:
            obj = node._find_object(index, subindex)
        except SdoAbortedError:
            raise SdoAbortedError(cia402.ABORT_CANNOT_MAP) from None
        usable = obj.writable if receive else obj.readable
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
        elif index == 0x1016:
            self._consumers(i, subindex, int(value))

    def _load_parameters(self, i: int) -> None:
        """Every parameter from the object dictionary (power-up and after a reset)."""
        node = self.nodes[self.ids[i]]
        now = self.clock.now()
        for index, subindex in [(0x6065, 0), (0x6066, 0), (0x6085, 0), (0x6083, 0), (0x6084, 0), (0x6081, 0),
                                (0x607F, 0), (0x607D, 1), (0x60C2, 1), (0x6067, 0), (0x6068, 0), (0x606D, 0),
                                (0x606E, 0), (0x2000, 0)]:  # fmt: skip
            self._parameter(i, index, subindex, node.value(index, subindex), now)
        self.abort_option[i] = node.value(0x6007)
        self.qs_option[i] = node.value(0x605A)
        self.consumers[i] = {}
        for sub in (1, 2):
            self._consumers(i, sub, int(node.value(0x1016, sub)))
        mode = int(node.value(0x6060))
        self.mode[i] = mode if mode in cia402.SUPPORTED_MODES else cia402.CSP

    def _consumers(self, i: int, subindex: int, value: int) -> None:
        """Heartbeat consumer entry ``subindex`` of 0x1016: (producer node id, time ms); 0 disables."""
        node = self.nodes[self.ids[i]]
        entries = {}
        for sub in (1, 2):
            word = value if sub == subindex else int(node.value(0x1016, sub))
            producer, period = (word >> 16) & 0xFF, word & 0xFFFF
            if producer and period:
                previous = self.consumers[i].get(producer)
                entries[producer] = [period / 1000.0, previous[1] if previous else None]
        self.consumers[i] = entries
        for producer in entries:
            can_id = 0x700 + producer
            if can_id not in self._subscribed:
                callback = functools.partial(self._on_heartbeat, producer)
                self._subscribed[can_id] = callback
                self.network.subscribe(can_id, callback)

    # ------------------------------------------------------------------ NMT
    def _on_nmt(self, i: int, old: int, new: int) -> None:
        node = self.nodes[self.ids[i]]
        if new == NMT_OPERATIONAL:
            node.compile_pdos()
            self._subscribe_rpdos()
            for pdo in node.tpdos:
                pdo.sync_count, pdo.last, pdo.sent_at = 0, None, -np.inf
        elif old == NMT_OPERATIONAL:
            self.pending[i].clear()
        if new == NMT_STOPPED and self.state[i] == OE:
            self._abort_connection(i, f"NMT stopped (from {old})")

    def _on_reset(self, i: int, old: int, application: bool) -> None:
        now = self.clock.now()
        with self._lock:
            self._advance_locked(now)
            if self.state[i] == OE and not application:
                self._abort_connection(i, "NMT reset communication")
            if application:  # the drive restarts: power stage off, brake, errors gone
                self._set_state(i, NOT_READY, now)
                self.vel[i] = 0.0
                self.reference.hold(i, now, self.pos[i])
                self.errors[i].clear()
                self.following_error[i] = False
                self.limit_active[i] = False
                self.controlword[i] = 0
                self.pending[i].clear()
                self._set_state(i, SOD, now)  # transitions 0, 1: automatic after initialisation
            self.error_history[i].clear()  # 0x1003 is in the communication area

    def _reload(self, i: int) -> None:
        with self._lock:
            self._load_parameters(i)
            self._subscribe_rpdos()

    def _subscribe_rpdos(self) -> None:
        wanted = {}
        for i, node_id in enumerate(self.ids):
            node = self.nodes.get(node_id)
            if node is None or not self.alive[i] or node.nmt._state != NMT_OPERATIONAL:
                continue
            for pdo in node.rpdos:
                if pdo.valid:
                    wanted[pdo.cob_id] = (i, pdo)
        for cob_id, callback in list(self._rpdo_callbacks.items()):
            if cob_id not in wanted:
                self.network.unsubscribe(cob_id, callback)
                del self._rpdo_callbacks[cob_id]
        for cob_id, (i, pdo) in wanted.items():
            old = self._rpdo_callbacks.pop(cob_id, None)
            if old is not None:
                self.network.unsubscribe(cob_id, old)
            callback = functools.partial(self._on_rpdo, i, pdo)
            self._rpdo_callbacks[cob_id] = callback
            self.network.subscribe(cob_id, callback)

    def _on_heartbeat(self, producer: int, can_id, data, timestamp) -> None:
        now = self.clock.now()
        for consumers in self.consumers:
            entry = consumers.get(producer)
            if entry is not None:
                entry[1] = now

    # ------------------------------------------------------------------ PDOs
    def _on_rpdo(self, i: int, pdo: _Pdo, can_id, data, timestamp) -> None:
        node = self.nodes.get(self.ids[i])
        if node is None or not self.alive[i] or node.nmt._state != NMT_OPERATIONAL:
            return
        if pdo.trans <= 240:
            self.pending[i][pdo.cob_id] = bytes(data)  # applied at the next SYNC
        else:
            with self._lock:
                node.write_rpdo(pdo, bytes(data))
            self._event_tpdos(i)

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
        self._advance_locked(now)
        self._event_time = now
        try:
            self._sync_axes(now)
        finally:
            self._event_time = None

    def _sync_axes(self, now: float) -> None:
        batch = []
        for i, node_id in enumerate(self.ids):
            node = self.nodes.get(node_id)
            if node is None or not self.alive[i] or node.nmt._state not in (NMT_OPERATIONAL, NMT_PRE_OPERATIONAL):
                continue
            if self.sync_drop is not None and self.sync_drop.drop(0x80):
                continue  # this drive missed the SYNC: nothing latched, nothing sampled
            self.last_sync[i] = now
            if node.nmt._state != NMT_OPERATIONAL:
                continue
            pending = self.pending[i]
            if pending:
                for pdo in node.rpdos:
                    data = pending.pop(pdo.cob_id, None)
                    if data is not None:
                        node.write_rpdo(pdo, data)
            for pdo in node.tpdos:
                if not pdo.valid:
                    continue
                if 1 <= pdo.trans <= 240:
                    pdo.sync_count += 1
                    if pdo.sync_count >= pdo.trans:
                        pdo.sync_count = 0
                        batch.append((pdo, node.tpdo_data(pdo)))
                elif pdo.trans == 0:
                    payload = node.tpdo_data(pdo)
                    if payload != pdo.last:
                        batch.append((pdo, payload))
        self._send_tpdos(batch, now)

    def _send_tpdos(self, batch: list, now: float) -> None:
        if not batch:
            return
        bus = self.network.bus
        send_batch = getattr(bus, "send_batch", None)
        for pdo, payload in batch:
            pdo.last, pdo.sent_at = payload, now
        if send_batch is not None and self.network.link is None:
            send_batch([can.Message(arbitration_id=pdo.cob_id, data=payload, is_extended_id=False)
                        for pdo, payload in batch])  # fmt: skip
            return
        for pdo, payload in batch:
            self.network.send_message(pdo.cob_id, payload)

    def _event_tpdos(self, i: int | None = None, now: float | None = None) -> None:
        """Event-driven TPDOs (254/255): on change (after the inhibit time) and on the event timer."""
        now = self.clock.now() if now is None else now
        batch = []
        for j, node_id in enumerate(self.ids):
            if i is not None and j != i:
                continue
            node = self.nodes.get(node_id)
            if node is None or not self.alive[j] or node.nmt._state != NMT_OPERATIONAL:
                continue
            for pdo in node.tpdos:
                if not pdo.valid or pdo.trans < 254:
                    continue
                if now - pdo.sent_at < pdo.inhibit:
                    continue
                payload = node.tpdo_data(pdo)
                if payload != pdo.last or (pdo.event > 0 and now - pdo.sent_at >= pdo.event - 1e-9):
                    batch.append((pdo, payload))
        self._send_tpdos(batch, now)

    # ------------------------------------------------------------------ state machine
    def _set_state(self, i: int, code: int, t: float) -> None:
        if code != self.state[i]:
            self.transitions.append((t, self.ids[i], _STATES[self.state[i]], _STATES[code]))
        self.state[i] = code

    def _controlword(self, i: int, controlword: int, now: float) -> None:
        previous = int(self.controlword[i])
        self.controlword[i] = controlword
        state = _STATES[self.state[i]]
        new = cia402.next_state(state, controlword, previous)
        rising_reset = controlword & cia402.CW_FAULT_RESET and not previous & cia402.CW_FAULT_RESET
        if new != state:
            self._set_state(i, _CODE[new], now)
            if new == cia402.OPERATION_ENABLED:
                self._enable(i, now)
            elif new == cia402.QUICK_STOP_ACTIVE:
                self._quick_stop(i, now)
            elif new == cia402.SWITCH_ON_DISABLED and state == cia402.FAULT:
                self._clear_errors(i)  # transition 15: fault reset
            if state == cia402.QUICK_STOP_ACTIVE:
                self._clear_errors(i, communication_only=True)  # the stop was acknowledged
            if new in (cia402.SWITCH_ON_DISABLED, cia402.READY, cia402.SWITCHED_ON):
                self.vel[i] = 0.0  # power stage off: the brake holds
                self.reference.hold(i, now, self.pos[i])
        elif rising_reset and state != cia402.FAULT:
            self._clear_errors(i, communication_only=True)
        if self.state[i] == OE and self.mode[i] == cia402.PP:
            self._profile_position_bits(i, controlword, previous, now)
        if self.state[i] == OE and controlword & cia402.CW_HALT and not previous & cia402.CW_HALT:
            self._halt(i, now)
        elif self.state[i] == OE and previous & cia402.CW_HALT and not controlword & cia402.CW_HALT:
            if self.mode[i] == cia402.PV:
                self._plan_velocity(i, now)
            elif self.mode[i] == cia402.PP and self.moving_to_target[i]:
                self._plan_position(i, now)

    def _enable(self, i: int, now: float) -> None:
        self.reference.hold(i, now, self.pos[i])  # hold where it is: no jump
        self.over_time[i] = 0.0
        self.following_error[i] = False
        self.moving_to_target[i] = False
        self.set_point_ack[i] = False
        self.inside_since[i] = now
        self.last_sync[i] = now
        self.target[i] = self.pos[i]
        if self.mode[i] in cia402.VELOCITY_MODES:
            self.target_velocity[i] = 0.0

    def _switch_mode(self, i: int, mode: int, now: float) -> None:
        if mode == self.mode[i]:
            return
        self.mode[i] = mode
        self.moving_to_target[i] = False
        self.set_point_ack[i] = False
        if self.state[i] == OE:  # a new mode starts from rest where the reference is
            p, v = self.reference.at(now)
            self.reference.set(i, _stop_segments(now, p[i], v[i], self.profile_decel[i]))
            self.target[i] = p[i]
            self.target_velocity[i] = 0.0
            self.last_sync[i] = now

    def _halt(self, i: int, now: float) -> None:
        p, v = self.reference.at(now)
        self.reference.set(i, _stop_segments(now, p[i], v[i], self.profile_decel[i]))

    def _quick_stop(self, i: int, now: float) -> None:
        option = int(self.qs_option[i])
        if option == 0:  # disable drive function: no ramp
            self._set_state(i, SOD, now)
            self.vel[i] = 0.0
            self.reference.hold(i, now, self.pos[i])
            return
        decel = self.profile_decel[i] if option in (1, 5) else self.qs_decel[i]
        # the ramp starts from where the motor is and how fast it moves
        segments = _stop_segments(now, self.pos[i], self.vel[i], decel)
        self.reference.set(i, segments)
        self.qs_end[i] = segments[-1][0] if option in (1, 2) else np.inf

    def _abort_connection(self, i: int, why: str) -> None:
        """The abort connection option 0x6007 (CiA 402): 1 fault, 2 disable voltage, 3 quick stop."""
        now = self.t
        option = int(self.abort_option[i])
        log.info("node %d: abort connection (%s), option %d", self.ids[i], why, option)
        if option == 1:
            self._fault(i, None)
        elif option == 2:
            self._set_state(i, SOD, now)
            self.vel[i] = 0.0
            self.reference.hold(i, now, self.pos[i])
        elif option == 3 and self.state[i] == OE:
            self._set_state(i, QS, now)
            self._quick_stop(i, now)

    # ------------------------------------------------------------------ errors
    def _raise_error(self, i: int, code: int) -> None:
        errors = self.errors[i]
        if code in errors:
            return
        errors[code] = cia402.ERROR_REGISTER.get(code, cia402.ERR_GENERIC)
        history = self.error_history[i]
        history.insert(0, code)
        del history[8:]
        register = 0
        for bits in errors.values():
            register |= bits
        node = self.nodes.get(self.ids[i])
        if node is not None and self.alive[i]:
            node.emcy.send(code, register)

    def _clear_errors(self, i: int, communication_only: bool = False) -> None:
        errors = self.errors[i]
        if not errors:
            return
        for code in list(errors):
            if not communication_only or errors[code] & cia402.ERR_COMMUNICATION:
                del errors[code]
        if not errors:
            node = self.nodes.get(self.ids[i])
            if node is not None and self.alive[i]:
                node.emcy.reset()  # EMCY 0x0000: no error left

    def _fault(self, i: int, code: int | None, following_error: bool = False) -> None:
        self._set_state(i, FAULT, self.t)  # fault reaction: the brake holds the axis
        self.vel[i] = 0.0
        self.reference.hold(i, self.t, self.pos[i])
        self.following_error[i] = following_error
        if code is not None:
            self._raise_error(i, code)

    # ------------------------------------------------------------------ modes: references
    def _latch_position(self, i: int, target_counts: int, now: float) -> None:
        """CSP: from the command now to the target over one interpolation period, then hold."""
        command, _ = self.reference.at_axis(i, now)
        target = target_counts / self.cpu[i]
        clamped = min(max(target, self.limit_lo[i]), self.limit_hi[i])
        self.limit_active[i] = clamped != target
        period = self.period[i]
        rate = (clamped - command) / period
        self.reference.set(i, [(now, command, rate, 0.0), (now + period, clamped, 0.0, 0.0)])

    def _latch_velocity(self, i: int, now: float) -> None:
        """CSV: ramp to the target velocity over one interpolation period, then keep it."""
        p, v = self.reference.at(now)
        target = float(np.clip(self.target_velocity[i], -self.vmax[i], self.vmax[i]))
        period = self.period[i]
        a = (target - v[i]) / period
        segments = [(now, p[i], v[i], a), (now + period, p[i] + (v[i] + target) * period / 2, target, 0.0)]
        self.reference.set(i, segments)
        self._respect_limits(i, now)

    def _plan_velocity(self, i: int, now: float) -> None:
        """PV: ramp to 0x60FF (at 0x6083 up, 0x6084 down), limited by 0x607F; halt keeps it at rest."""
        p, v = self.reference.at(now)
        target = 0.0 if self.controlword[i] & cia402.CW_HALT else self.target_velocity[i]
        target = float(np.clip(target, -self.vmax[i], self.vmax[i]))
        self.inside_since[i] = np.inf
        segments = _velocity_segments(now, p[i], v[i], target, self.profile_accel[i], self.profile_decel[i])
        self.reference.set(i, segments)
        self._respect_limits(i, now)

    def _profile_position_bits(self, i: int, controlword: int, previous: int, now: float) -> None:
        """PP: a new set-point on the rising edge of bit 4 (acknowledged in statusword bit 12)."""
        if controlword & cia402.CW_NEW_SET_POINT and not previous & cia402.CW_NEW_SET_POINT:
            node = self.nodes[self.ids[i]]
            target = int(node.value(0x607A)) / self.cpu[i]
            if controlword & cia402.CW_RELATIVE:
                target += self.target[i]
            self.target[i] = target
            self.set_point_ack[i] = True
            self.moving_to_target[i] = True
            if not controlword & cia402.CW_HALT:
                self._plan_position(i, now)
        elif not controlword & cia402.CW_NEW_SET_POINT:
            self.set_point_ack[i] = False

    def _plan_position(self, i: int, now: float) -> None:
        p, v = self.reference.at(now)
        goal = min(max(self.target[i], self.limit_lo[i]), self.limit_hi[i])
        self.limit_active[i] = goal != self.target[i]
        vmax = min(self.profile_velocity[i], self.vmax[i])
        segments = _trapezoid(now, p[i], v[i], goal, vmax, self.profile_accel[i], self.profile_decel[i])
        self.reference.set(i, segments)
        self.inside_since[i] = np.inf

    def _respect_limits(self, i: int, now: float) -> None:
        """Keep the reference inside the software position limits: a target beyond them is clamped (position
        modes); a velocity mode brakes at 0x6085 so as to stop at the limit."""
        if not (np.isfinite(self.limit_lo[i]) or np.isfinite(self.limit_hi[i])):
            return
        if self.mode[i] == cia402.PP and self.moving_to_target[i]:
            self._plan_position(i, now)
            return
        if self.mode[i] == cia402.CSP:
            end = self.reference.p[i][np.isfinite(self.reference.t[i])][-1]
            if not self.limit_lo[i] <= end <= self.limit_hi[i]:
                self._latch_position(i, round(end * self.cpu[i]), now)
            return
        if self.mode[i] not in cia402.VELOCITY_MODES:
            return
        # velocity modes: find the first time the stopping point (p + v|v|/2d) reaches a limit
        decel = self.qs_decel[i]
        ref = self.reference
        times = ref.t[i][np.isfinite(ref.t[i])]
        horizon = max(times[-1], now) + 3600.0
        grid = np.concatenate([np.linspace(t0, t1, 65) for t0, t1 in zip(times, [*times[1:], horizon], strict=True)])
        grid = grid[grid >= now]
        p, v = ref.at(grid[:, None])
        p, v = p[:, i], v[:, i]
        stop_at = p + v * np.abs(v) / (2 * decel)
        beyond = (stop_at > self.limit_hi[i]) | (stop_at < self.limit_lo[i])
        if not np.any(beyond):
            self.limit_active[i] = False
            return
        k = int(np.argmax(beyond))
        if k == 0:
            t_brake = now
        else:
            lo, hi = grid[k - 1], grid[k]
            for _ in range(40):  # bisection on the crossing
                mid = 0.5 * (lo + hi)
                pm, vm = ref.at(np.array([[mid]]))
                s = pm[0, i] + vm[0, i] * abs(vm[0, i]) / (2 * decel)
                if self.limit_lo[i] <= s <= self.limit_hi[i]:
                    lo = mid
                else:
                    hi = mid
            t_brake = lo
        pb, vb = ref.at(np.array([[t_brake]]))
        kept = [(t, ref.p[i, j], ref.v[i, j], ref.a[i, j]) for j, t in enumerate(ref.t[i]) if t < t_brake]
        ref.set(i, kept[-2:] + _stop_segments(t_brake, pb[0, i], vb[0, i], decel))
        self.limit_active[i] = True

    # ------------------------------------------------------------------ physics
    def advance(self, t: float) -> None:
        """Integrate every motor from the last call to time ``t`` (s)."""
        with self._lock:
            self._advance_locked(t)

    def _advance_locked(self, t: float) -> None:
        span = t - self.t
        if span <= 0:
            return
        state = self.state
        powered_mask = ((state == OE) | (state == QS)) & self.alive
        if self.hand is not None:
            # unpowered axes moved by hand (a trainee holding the instrument): they go where the hand takes them
            by_hand = ~powered_mask & self.alive
            if by_hand.any():
                where = np.asarray(self.hand(t), dtype=float)
                self.vel[by_hand] = (where[by_hand] - self.pos[by_hand]) / span
                self.pos[by_hand] = where[by_hand]
                for i in np.flatnonzero(by_hand):
                    self.reference.hold(i, t, self.pos[i])
        if not powered_mask.any():
            if self.hand is not None:
                self.t = t
                return
            # every brake holds: nothing moves (unpowered velocities are zero)
            self.vel[:] = 0.0
            self.t = t
            return
        m = self.model
        steps = max(1, int(np.ceil(span / m.substep - 1e-9)))
        dt = span / steps
        powered = powered_mask.astype(float)
        mode = self.mode
        monitored = (state == OE) & self.alive & ((mode == cia402.PP) | (mode == cia402.CSP))
        # the commands of every substep at once; the integration itself is sequential
        # the loop compares the position at the start of each step with the command there
        if steps == 1:
            command, rate = self.reference.at(self.t)
            command, rate = command[None], rate[None]
        else:
            command, rate = self.reference.at(self.t + dt * np.arange(steps)[:, None])
        pos, vel, over_time = self.pos, self.vel, self.over_time
        cpu, resolution = self.cpu, 1.0 / self.cpu
        vmax, peak, load, window = self.vmax, self.peak, self.load, self.window
        tripped = np.zeros(len(pos), dtype=bool)
        kp, kv, damping = m.position_gain, m.velocity_gain, m.damping
        for k in range(steps):
            measured = np.rint(pos * cpu) * resolution  # the encoder
            # proportional position loop whose correction can always be braked within the current
            # limit (the square-root law of drives' position controllers), plus the feed-forward
            error = command[k] - measured
            magnitude = np.abs(error)
            correction = np.sign(error) * np.minimum(kp * magnitude, np.sqrt(peak * magnitude))
            velocity_command = np.minimum(np.maximum(rate[k] + correction, -vmax), vmax)
            torque = np.minimum(np.maximum(kv * (velocity_command - vel), -peak), peak)
            # the holding brake keeps unpowered axes still
            vel = (vel + (torque - damping * vel + load) * dt) * powered
            pos = pos + vel * dt
            over_time = (over_time + dt) * (monitored & (np.abs(command[k] - pos) > window))
            tripped |= over_time > self.window_time
        self.pos, self.vel, self.over_time = pos, vel, over_time
        self.t = t
        for i in np.flatnonzero(tripped & monitored):
            self._fault(i, cia402.EMCY_FOLLOWING_ERROR, following_error=True)
        self._windows(t)

    def _windows(self, t: float) -> None:
        """Target-reached windows (pp: position, pv: velocity), quick stop ramps that end in SWITCH ON DISABLED."""
        mode, state = self.mode, self.state
        if not (((mode == cia402.PP) | (mode == cia402.PV)) & (state == OE)).any() and not (state == QS).any():
            return
        for i in np.flatnonzero(self.state == OE):
            mode = self.mode[i]
            if mode == cia402.PP:
                inside = abs(self.pos[i] - min(max(self.target[i], self.limit_lo[i]), self.limit_hi[i]))
                inside = inside <= self.position_window[i] + 0.5 / self.cpu[i]
                if self.moving_to_target[i] and t >= self.reference.end(i):
                    self.moving_to_target[i] = False
            elif mode == cia402.PV:
                target = 0.0 if self.controlword[i] & cia402.CW_HALT else self.target_velocity[i]
                inside = abs(self.vel[i] - target) <= self.velocity_window[i]
            else:
                continue
            if not inside:
                self.inside_since[i] = np.inf
            elif not np.isfinite(self.inside_since[i]):
                self.inside_since[i] = t
        for i in np.flatnonzero((self.state == QS) & (t >= self.qs_end)):
            self._set_state(i, SOD, t)
            self.vel[i] = 0.0
            self.qs_end[i] = np.inf
            self.reference.hold(i, t, self.pos[i])

    @_locked
    def _tick(self) -> None:
        """The drives' own monitoring: SYNC watchdog, heartbeat consumer, event-driven TPDOs."""
        now = self.clock.now()
        self._advance_locked(now)
        cyclic = np.isin(self.mode, cia402.CYCLIC_MODES)
        lost = (self.state == OE) & self.alive & cyclic & (self.sync_watchdog > 0)
        lost &= now - self.last_sync > self.sync_watchdog
        for i in np.flatnonzero(lost):
            self._raise_error(i, cia402.EMCY_SYNC_LOST)
            self._abort_connection(i, "SYNC lost")
        for i, consumers in enumerate(self.consumers):
            for producer, entry in consumers.items():
                period, last = entry
                if last is not None and now - last > period and self.alive[i]:
                    entry[1] = None  # monitoring resumes with the producer's next heartbeat
                    self._raise_error(i, cia402.EMCY_HEARTBEAT_LOST)
                    if self.state[i] == OE:
                        self._abort_connection(i, f"heartbeat of node {producer} lost")
        self._event_tpdos(now=now)

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
        self._advance_locked(self.clock.now())
        direction = -np.sign(self.vel[i]) if self.vel[i] != 0 else -1.0
        self.load[i] = direction * load * self.peak[i]

    @_locked
    def _die(self, i: int) -> None:
        self._advance_locked(self.clock.now())
        node = self.nodes.get(self.ids[i])
        if node is not None:
            node.nmt.stop_heartbeat()
            node.alive = False
            del self.network[self.ids[i]]
        self.alive[i] = False
        self._set_state(i, NOT_READY, self.t)
        self.vel[i] = 0.0

    # ------------------------------------------------------------------ real time
    def start(self, priority: int | None = None) -> None:
        """Real-time mode: receive and run timers in a thread until :meth:`stop` (under SCHED_FIFO at
        ``priority``, with the loopback hub's thread if this bus hosts it)."""
        self._thread = threading.Thread(target=self._loop, name="surgiplan-simulated-drives", daemon=True)
        self._thread.start()
        set_realtime_priority(priority, self._thread.native_id)
        hub = getattr(self.network.bus, "_hub", None)
        if hub is not None:
            set_realtime_priority(priority, hub.thread.native_id)

    def _loop(self) -> None:
        self.clock.precise()
        while not self._stop.is_set():
            due = self.scheduler.next_due()
            wait = 0.005 if due is None else min(0.005, max(0.0, due - self.clock.now()))
            # a few frames at a time: the timers (heartbeats, the SYNC watchdog) must not wait behind
            # a backlog of frames when the process was descheduled
            try:
                self.network.pump(wait, limit=2 + 2 * len(self.axes))
            except can.CanError as exc:  # the bus went away (its hub closed): nothing more to serve
                log.warning("simulated drives: %s", exc)
                return
            now = self.clock.now()
            while (timer := self.scheduler.pop_due(now)) is not None:
                timer.action()

    @_locked
    def move_by_hand(self, motion: Callable[[float], np.ndarray] | None) -> None:
        """Simulation only: while an axis is unpowered (its drive not enabled, as when a trainee moves the
        instrument by hand, the observe mode of a guide stage), its position follows ``motion(t)`` (units per
        axis, ``t`` the clock's time); the encoders, TPDOs and SDO reads report it. None lets go."""
        self._advance_locked(self.clock.now())
        self.hand = motion

    def positions(self) -> np.ndarray:
        """True joint positions (units): the simulation's ground truth, for tests."""
        return self.pos.copy()

    @_locked
    def place(self, positions) -> None:
        """Simulation only: put the (still) axes at ``positions`` (units), as a hand would."""
        self.pos = np.asarray(positions, dtype=float).copy()
        self.vel[:] = 0.0
        for i in range(len(self.pos)):
            self.reference.hold(i, self.t, self.pos[i])
            self.pending[i].clear()  # targets sent for the old position no longer apply

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
