"""Simulated CiA 402 servo drives: one CANopen node per joint, CiA 301 and CiA 402 as real drives do them.

Each axis is a :class:`.node.DriveNode` (a ``canopen.LocalNode`` with its
object dictionary from :func:`..cia402.drive_object_dictionary`, the same one
its EDS file states, :mod:`.eds`) on the simulator's bus, and a motor.
:class:`DriveSimulator` is the drives of one device, one concern per module:

* :mod:`.node`, :mod:`.objects`, :mod:`.communication` — CiA 301: the node
  (NMT, SDO, EMCY, PDO objects), what reading and writing each object means,
  NMT events, heartbeat consumers, SYNC and the PDO exchange, EMCY;
* :mod:`.statemachine`, :mod:`.modes`, :mod:`.reference` — CiA 402: the
  state machine and statusword, the operating modes (profile position and
  velocity, cyclic synchronous position, velocity and torque) and the piecewise
  quadratic reference they give the servo loops;
* :mod:`.motor` — how that reference becomes the axes' actual positions and
  velocities (the drive's servo cascade and the motor);
* :mod:`.faults` — the injected faults (jams, lost heartbeats, dead nodes);
* this module — the drives' state, time (the motors integrated up to each
  event), and the real-time loop; :mod:`.process` runs them in a process of
  their own.

Under the simulated clock every frame is handled synchronously
(:class:`..network.SimulationLink`); in real time the simulator runs its own
receive-and-timer loop in a thread (:meth:`DriveSimulator.start`).
"""

from __future__ import annotations

import contextlib
import logging
import threading
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np
from surgiplan.registry import default_registry
from surgiplan.scheduling import cpu_latency_request

from .. import cia402
from ..bus import ArmedFaults
from ..clock import Clock, Scheduler, set_realtime_priority
from ..device import Cia402Device
from ..network import PumpedNetwork, SimulationLink
from .communication import TICK, Communication
from .faults import FaultInjection
from .lss import UNCONFIGURED, LayerSettings, LssSlave
from .modes import OperatingModes
from .motor import HandMotion, MotorModel
from .node import DriveNode
from .objects import ObjectDictionary
from .reference import Reference
from .statemachine import OE, QS, SOD, Cia402StateMachine
from .storage import Memory

log = logging.getLogger(__name__)


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
    #: the drive's serial number (0x1018:4, part of its LSS address); None: its node-ID
    serial: int | None = None
    unit: str = "rad"
    lower: float | None = None
    upper: float | None = None
    #: following error window at power-up (units; None: off)
    following_error_window: float | None = None
    #: profile velocity and acceleration at power-up (units/s, units/s^2; None: the motor's limits, a third
    #: of its current limit); the quick stop decelerates at twice the profile acceleration
    profile_velocity: float | None = None
    profile_acceleration: float | None = None
    #: the motor (cyclic synchronous torque): rated torque at the motor (N·m; 0x6076), peak torque (thousandths
    #: of the rated: 0x6072's ceiling), gear ratio (joint torque per motor torque: 1/m on a linear axis), and the
    #: axis' inertia (kg·m² or kg, at the joint), viscous (N·m·s/rad or N·s/m) and Coulomb friction (N·m or N)
    rated_torque: float = 0.1
    peak_torque: int = 3000
    gear_ratio: float = 10.0
    inertia: float = 0.005
    viscous_friction: float = 0.01
    coulomb_friction: float = 0.005

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
            serial_number=self.serial,
            rated_torque=self.rated_torque,
            peak_torque=self.peak_torque,
        )


class DriveSimulator(
    ObjectDictionary, Communication, Cia402StateMachine, OperatingModes, FaultInjection, LayerSettings
):
    """Simulated drives on a python-can ``bus`` of their own, one :class:`.node.DriveNode` per axis.

    The bus is usually a second handle on the master's virtual channel; for the
    stand-alone simulator (:mod:`.process`) any python-can interface.
    ``link`` (simulated clock) delivers frames synchronously; without it (real
    time) call :meth:`start`. ``memory``: the folder of the drives' non-volatile
    memory (stored parameters, LSS configuration; :mod:`.storage`), None: kept
    in memory only. ``unconfigured``: the drives start without a node-ID
    (unless one was stored by LSS) and wait for LSS (:mod:`.lss`).
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
        memory: Path | None = None,
        unconfigured: bool = False,
    ) -> None:
        self.axes = axes
        self.device = device
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
        self.reference = Reference(n, self.t, self.pos)
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
        # cyclic synchronous torque: the motors and the torques (thousandths of the rated torque)
        self.torque_unit = np.array([a.rated_torque * a.gear_ratio / cia402.PER_MILLE for a in axes])  # joint/‰
        self.inertia = np.array([a.inertia for a in axes], dtype=float)
        self.viscous = np.array([a.viscous_friction for a in axes], dtype=float)
        self.coulomb = np.array([a.coulomb_friction for a in axes], dtype=float)
        self.max_torque = np.array([a.peak_torque for a in axes], dtype=float)
        self.target_torque = np.zeros(n)
        self.torque_actual = np.zeros(n)
        #: the hand as an impedance on axes the drives power in torque mode (joint units: N·m/rad, N·m·s/rad)
        self.hand_stiffness = np.zeros(n)
        self.hand_damping = np.zeros(n)
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
        self.hand: HandMotion | None = None
        self.memories = [Memory(memory / f"{device or 'drive'}_{a.name}.json" if memory else None) for a in axes]
        self.lss: list[LssSlave] = []
        #: the bus's bit rate (a drive switched to another by LSS is off the bus)
        self.bus_bit_rate = bit_rate = getattr(bus, "bitrate", None) or 1_000_000
        for i, axis in enumerate(axes):
            stored = self.memories[i].lss.get("node_id", UNCONFIGURED)
            node_id = (stored if 1 <= stored <= 127 else UNCONFIGURED) if unconfigured else axis.node_id
            self.ids[i] = node_id
            identity = cia402.drive_object_dictionary(axis.node_id, axis.defaults(device, model.sync_timeout))[0x1018]
            address = tuple(int(identity[sub].default) for sub in (1, 2, 3, 4))
            rate = self.memories[i].lss.get("bit_rate", bit_rate)
            self.lss.append(LssSlave(self, i, address, node_id, rate, cia402.BIT_RATES))
            if rate != bit_rate:  # stored by LSS at another bit rate than this bus's: it cannot take part
                self.lss[i].off_bus = True
            elif self.alive[i] and node_id != UNCONFIGURED:
                self.attach(i, node_id, boot=False)
        self.network.subscribe(0x80, self._on_sync)
        self.network.subscribe(0x7E5, self._on_lss)
        for node in self.nodes.values():  # power-up: boot-up message, then PRE-OPERATIONAL
            node.nmt.boot(application=True)
        self.scheduler.call_every(TICK, self._tick, self.t + TICK)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._latency = contextlib.ExitStack()  # the CPU latency request held in real time

    def _now(self) -> float:
        return self._event_time if self._event_time is not None else self.clock.now()

    @classmethod
    def for_device(
        cls, device: Cia402Device, bus: can.BusABC, clock: Clock, faults: ArmedFaults, link: SimulationLink | None
    ) -> DriveSimulator:
        """The simulated drives of a CiA 402 device (its model built): its joints' hardware
        (:func:`axis_hardware`) and its ``simulation`` settings, on ``bus``."""
        model = MotorModel.of(device.settings.simulation)
        return cls(bus, axis_hardware(device), model, clock, faults, link, device=device.urdf_name)

    # ------------------------------------------------------------------ time
    def advance(self, t: float) -> None:
        """Integrate every motor from the last call to time ``t`` (s)."""
        with self._lock:
            self._advance_locked(t)

    def _advance_locked(self, t: float) -> None:
        span = t - self.t
        if span <= 0:
            return
        # Python lists: numpy's per-call cost is most of it on a few axes, at every SYNC
        alive = self.alive.tolist()
        powered = [(s == OE or s == QS) and a for s, a in zip(self.state.tolist(), alive, strict=True)]
        if self.hand is not None and any(a and not p for p, a in zip(powered, alive, strict=True)):
            # unpowered axes moved by hand (a trainee holding the instrument): they go where the hand takes them
            by_hand = ~np.array(powered, dtype=bool) & self.alive
            where = np.asarray(self.hand(t), dtype=float)
            self.vel[by_hand] = (where[by_hand] - self.pos[by_hand]) / span
            self.pos[by_hand] = where[by_hand]
            for i in np.flatnonzero(by_hand):
                self.reference.hold(i, t, self.pos[i])
        if not any(powered):
            if self.hand is not None:
                self.t = t
                return
            # every brake holds: nothing moves (unpowered velocities are zero)
            self.vel[:] = 0.0
            self.t = t
            return
        tripped = self.model.integrate(self, self.t, span)
        self.t = t
        for i, trip in enumerate(tripped.tolist()):
            if trip:
                self._fault(i, cia402.EMCY_FOLLOWING_ERROR, following_error=True)
        self._windows(t)

    # ------------------------------------------------------------------ real time
    def start(self, priority: int | None = None) -> None:
        """Real-time mode: receive and run timers in a thread until :meth:`stop` (under SCHED_FIFO at
        ``priority``, with the loopback hub's thread if this bus hosts it), holding the CPU wake-up latency request
        that paced sections make, if any (:func:`surgiplan.scheduling.cpu_latency_request`: none unless
        ``SURGIPLAN_CPU_LATENCY_US`` asks), as the master's loop does."""
        self._latency.enter_context(cpu_latency_request())
        self._thread = threading.Thread(target=self._loop, name="surgiplan-simulated-drives", daemon=True)
        self._thread.start()
        set_realtime_priority(priority, self._thread.native_id)
        hub = getattr(self.network.bus, "_hub", None)
        if hub is not None and hub.thread is not None:
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

    def move_by_hand(self, motion: HandMotion | None, stiffness=None, damping=None) -> None:
        """Simulation only: while an axis is unpowered (its drive not enabled, as when a trainee moves the
        instrument by hand, the observe mode of a guide stage), its position follows ``motion(t)`` (units per
        axis, ``t`` the clock's time); the encoders, TPDOs and SDO reads report it. None lets go.

        While a drive powers its axis in cyclic synchronous torque, the hand is an impedance instead: a spring
        (``stiffness`` per axis, N·m/rad or N/m) and damper (``damping``, N·m·s/rad or N·s/m) pulling toward
        ``motion(t)``, where the trainee intends to be; its torque adds to the drive's in the motor model."""
        with self._lock:
            self._advance_locked(self.clock.now())
            self.hand = motion
            n = len(self.pos)
            self.hand_stiffness = np.zeros(n) if stiffness is None else np.broadcast_to(stiffness, (n,)).astype(float)
            self.hand_damping = np.zeros(n) if damping is None else np.broadcast_to(damping, (n,)).astype(float)

    def torque(self, i: int) -> int:
        """Torque actual value 0x6077 of axis ``i`` (thousandths of the rated torque): the torque its drive applies
        in cyclic synchronous torque (within 0x6072), 0 with the power stage off or in another mode."""
        return round(self.torque_actual.item(i)) if self.state[i] == OE and self.mode[i] == cia402.CST else 0

    def positions(self) -> np.ndarray:
        """True joint positions (units): the simulation's ground truth, for tests."""
        return self.pos.copy()

    def place(self, positions) -> None:
        """Simulation only: put the (still) axes at ``positions`` (units), as a hand would."""
        with self._lock:
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
        self._latency.close()
        for node in self.nodes.values():
            node.nmt.stop_heartbeat()
        if self.network.bus is not None:
            self.network.bus.shutdown()
            self.network.bus = None


def axis_hardware(device: Cia402Device) -> list[AxisHardware]:
    """The simulated hardware of a CiA 402 device's joints, from its settings (:meth:`..device.Cia402Device.joints`;
    raises ConfigError) and its model (built). Joint j's drive has serial number j + 1 whatever its node-ID (the
    identity its EDS states; unique on the device's bus, so that LSS tells the drives apart)."""
    s, model = device.settings, device.model
    joints = device.joints()
    return [
        AxisHardware(
            joints.node_ids[j],
            float(joints.counts_per_unit[j]),
            float(joints.acceleration[j] * s.simulation.peak_acceleration_factor),
            float(model.velocity_limit[j] * s.simulation.velocity_factor),
            float(joints.start[j]),
            name=model.joint_names[j],
            unit="m" if model.prismatic[j] else "rad",
            lower=float(model.lower[j]),
            upper=float(model.upper[j]),
            following_error_window=float(joints.following_error_window[j]),
            profile_velocity=float(joints.velocity[j]),
            profile_acceleration=float(joints.acceleration[j]),
            serial=j + 1,
            rated_torque=float(joints.motors["rated_torque"][j]),
            peak_torque=int(joints.motors["peak_torque"][j]),
            gear_ratio=float(joints.motors["gear_ratio"][j]),
            inertia=float(joints.motors["inertia"][j]),
            viscous_friction=float(joints.motors["viscous_friction"][j]),
            coulomb_friction=float(joints.motors["coulomb_friction"][j]),
        )
        for j in range(model.nq)
    ]


def simulated_devices() -> dict[str, type[Cia402Device]]:
    """The registered device plugins whose joints are CiA 402 drives, by name (found by registered name, so
    the CANopen layer never imports a device package; a third party's CiA 402 device is simulated the same
    way)."""
    registry = default_registry()
    found = {}
    for name in registry.names("device"):
        cls = registry.get("device", name).cls
        if isinstance(cls, type) and issubclass(cls, Cia402Device):
            found[name] = cls
    return found
