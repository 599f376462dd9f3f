"""What the CiA 402 device plugins share: settings, lifecycle, and the execution pipeline.

Lifecycle (ros2_control's, :class:`surgiplan.Device`):

* ``configure``: the kinematic model is loaded, the settings resolved per
  joint (:mod:`.joints`), the bus opened (on the virtual bus the simulated
  drives the device class names, :attr:`Cia402Device.simulated_drives`,
  started on it), every node configured by SDO and started; states are
  readable. A bus that cannot be opened or a node that does not answer is a
  :class:`~.bus.BusError` here, before anything moves.
* ``activate``: every drive is brought to OPERATION ENABLED holding its
  position (a fault reset first where a drive is in FAULT). In real-time mode
  SYNC keeps running between trajectories.
* ``execute``: the path is mapped to joints (inverse kinematics), refused
  with the reason (:mod:`.refusal`) before any motion if a pose is out of
  reach, a waypoint leaves the joint limits or the plan's workspace bounds,
  the approach from where the device stands is not clear, or the drives are
  stopped from an earlier fault (:meth:`Cia402Device.reset_faults` first: a
  stopped device never restarts by itself); then time-parameterised at the
  control rate (:mod:`.timing`), refused if the timed motion's certified
  clearance (:mod:`.certify`, every body, between samples too) is below
  ``safety_margin``, and run (:mod:`.control`); the report (:mod:`.report`)
  says what the hardware actually did.
* ``deactivate``: drives disabled, brakes hold; ``cleanup``/``shutdown``:
  NMT pre-operational, bus released. A failed transition is the error
  state, with everything released; ``shutdown`` leaves it.

Subclasses say how a path becomes joint waypoints (:meth:`Cia402Device.joint_path`),
how clearance is measured (:meth:`Cia402Device.clearance_along`) and certified
(:meth:`Cia402Device.certify_motion`).
"""

from __future__ import annotations

import gc
import importlib.resources
import logging
import sys
import textwrap
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol

import can
import numpy as np
from surgiplan.devices import Device, ExecutionReport, LifecycleError, Trajectory
from surgiplan.errors import ConfigError
from surgiplan.plugins.devices.kinematics.model import KinematicModel
from surgiplan.scheduling import paced_section

from . import cia402
from .bus import ArmedFaults, BusError, FrameDropper, MonitoredBus, open_bus
from .certify import Certificate
from .clock import Clock, RealTimeClock, SimulatedClock, restore_priority, set_realtime_priority
from .control import Controller, ExecutionLog, Supervision
from .joints import Joints, axis_configs, check_bus_load, joint_limits, resolve_joints
from .master import DriveMaster
from .network import SimulationLink
from .refusal import Refusal, certification_refusal, check_path, refused
from .report import bus_metrics, execution_figure, explain_lost_heartbeats, tracking_metrics, write_log_csv
from .settings import Cia402DeviceSettings
from .timing import time_parameterize
from .trace import trace_name, write_trace

log = logging.getLogger(__name__)


class SimulatedDrives(Protocol):
    """What a device uses of the simulated drives it runs on the virtual bus (``bus: {interface: virtual}``).

    The CANopen master never imports the simulator (:mod:`.sim`): a device class names its simulated drives in
    :attr:`Cia402Device.simulated_drives` (the built-in devices: :class:`.sim.drives.DriveSimulator`).
    """

    #: frame loss injected at the drives' receivers, for the report (None: none)
    frame_drop: FrameDropper | None
    sync_drop: FrameDropper | None

    @classmethod
    def for_device(
        cls, device: Cia402Device, bus: can.BusABC, clock: Clock, faults: ArmedFaults, link: SimulationLink | None
    ) -> SimulatedDrives:
        """The drives of ``device``'s joints on ``bus`` (``link``: the simulated clock's; None: real time)."""
        ...

    def start(self, priority: int | None = None) -> None:
        """Real time: serve the bus in a thread of their own."""
        ...

    def arm(self, origin: float) -> None:
        """Schedule the injected faults from ``origin`` (s)."""
        ...

    def place(self, positions) -> None:
        """Put the still axes at ``positions`` (SI), as a hand would."""
        ...

    def close(self) -> None: ...


@dataclass
class JointPath:
    """Joint waypoints (n, nq) from a path, and what the mapping measured."""

    q: np.ndarray
    metrics: dict[str, Any] = field(default_factory=dict)


class Cia402Device(Device):
    """Base of the CiA 402 devices (``cast_gimbal``, ``gripper6``)."""

    Settings = Cia402DeviceSettings
    #: defaults per device, overridden by subclasses
    default_acceleration: tuple[float, ...] = ()
    #: each joint's motor by default (:class:`.settings.MotorSettings` names -> one value per joint)
    default_motors: ClassVar[dict[str, tuple]] = {}
    urdf_name: str = ""
    tip_frame: str = ""
    #: what the per-sample clearance of :meth:`clearance_along` is the clearance of (figure label)
    clearance_label: str = "executed clearance"
    #: the simulated drives run on the virtual bus; None: this device has none (it needs a real bus)
    simulated_drives: ClassVar[type[SimulatedDrives] | None] = None

    def __init__(self, settings: Cia402DeviceSettings) -> None:
        super().__init__(settings)
        self.model: KinematicModel | None = None
        self.clock = None
        self.bus: MonitoredBus | None = None
        self.simulator: SimulatedDrives | None = None
        self.master: DriveMaster | None = None
        self.controller: Controller | None = None
        self.faults: ArmedFaults | None = None
        self.placed = False
        #: the last execution's log (times, measured and commanded joints, faults): what the drives did
        self.last_log: ExecutionLog | None = None
        self._source: str | None = None
        #: the clearance threshold of the plan the trajectory came from (its Trajectory carries it)
        self._threshold = None
        self._frozen = False
        self.channel = ""
        #: wall-clock time (s since the epoch) of the clock's zero: a trace's time stamps are ``epoch + clock``
        self.epoch = 0.0
        #: torque mode (the haptic assist of :mod:`surgiplan.plugins.devices.cast_gimbal.assist`): each drive's
        #: max torque 0x6072 (thousandths of its rated torque), set before configuring; None: position mode
        self.max_torque: list[int] | None = None

    # ------------------------------------------------------------------ for subclasses
    def build_model(self, base=None) -> KinematicModel:
        raise NotImplementedError

    def joint_path(self, trajectory: Trajectory, current: np.ndarray) -> JointPath:
        """Joint waypoints for the trajectory's path; raise :class:`Refusal` if impossible."""
        raise NotImplementedError

    def executed_geometry(self, q: np.ndarray, trajectory: Trajectory) -> tuple[Any, np.ndarray | None]:
        """The space (with the device's body) and configurations in which the framework re-measures the executed
        joints ``q`` (:mod:`surgiplan.verify_motion`); (None, None): the executed tip path is measured."""
        return None, None

    def clearance_along(self, q: np.ndarray, trajectory: Trajectory) -> tuple[dict[str, float], np.ndarray]:
        """Clearance metrics (m) of the executed joint path ``q`` (n, nq), re-measured on the scene,
        and the body's clearance at each sample (for the figure)."""
        raise NotImplementedError

    def approach_is_clear(self, q_from: np.ndarray, q_to: np.ndarray, trajectory: Trajectory) -> bool:
        raise NotImplementedError

    def certify_motion(self, q: np.ndarray, trajectory: Trajectory, margin: float) -> list[Certificate]:
        """Certified clearance of each of the device's bodies along the timed joint samples ``q`` as the drives
        interpolate them (linearly, one sample per control period): :func:`.certify.certify`."""
        raise NotImplementedError

    # ------------------------------------------------------------------ settings
    def limits(self) -> tuple[np.ndarray, np.ndarray]:
        """Velocity and acceleration limits the trajectories use (SI per joint)."""
        return joint_limits(self.settings, self.model, self.default_acceleration)

    def joints(self) -> Joints:
        """The settings per joint, checked against the model (raises ConfigError): :mod:`.joints`."""
        return resolve_joints(self.settings, self.model, self.default_acceleration, self.default_motors)

    def can_nodes(self) -> list[tuple[int, str, Path]]:
        """(node-id, joint name, EDS file) of each drive as the settings give them (the model is loaded if it is
        not yet): what ``surgiplan can-decode --device`` decodes a trace with."""
        if self.model is None:
            self.model = self.build_model()
        return list(zip(self.joints().node_ids, self.model.joint_names, self.eds_files(), strict=True))

    @classmethod
    def eds_folder(cls) -> Path:
        """Where the device package ships its simulated drives' EDS files (``<package>/eds``): the package the
        class is defined in (its ``__init__`` or a module of it)."""
        module = sys.modules[cls.__module__]
        package = module.__name__ if hasattr(module, "__path__") else module.__name__.rpartition(".")[0]
        return Path(str(importlib.resources.files(package))) / "eds"

    def eds_files(self) -> list[Path]:
        """Each joint's drive's EDS: the ``eds`` setting, else the shipped simulated drive's."""
        s = self.settings
        names = self.model.joint_names
        if s.eds is None:
            files = [self.eds_folder() / f"{self.urdf_name}_{name}.eds" for name in names]
        else:
            given = s.eds if isinstance(s.eds, list) else [s.eds] * len(names)
            if len(given) != len(names):
                raise ConfigError(f"eds: give one file for all joints or {len(names)}, one per joint {names}")
            base = Path(self.context.base_dir) if self.context is not None else Path.cwd()
            files = [path if path.is_absolute() else base / path for path in given]
        for name, path in zip(names, files, strict=True):
            if not path.is_file():
                raise ConfigError(f"eds: the EDS file of joint '{name}' does not exist: {path}")
        return files

    # ------------------------------------------------------------------ conformance
    @classmethod
    def conformance(cls, name: str, settings: dict[str, Any], progress=None):
        """Run the CiA conformance test families on this device's drives (``surgiplan canopen-conformance``):
        its simulated drives in a process of their own, or real ones on the bus ``settings`` names
        (:class:`.conformance.ConformanceSettings`; raises ConfigError). Returns the
        :class:`.conformance.Report`: ``as_dict()``, ``failed``."""
        from pydantic import ValidationError

        from .conformance import ConformanceSettings, run_conformance

        try:
            parsed = ConformanceSettings.model_validate(settings)
        except ValidationError as exc:
            problems = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
            raise ConfigError(f"canopen-conformance settings: {problems}") from None
        return run_conformance(cls, name, parsed, progress)

    # ------------------------------------------------------------------ lifecycle
    def on_configure(self, context) -> None:
        s = self.settings
        scene = getattr(context, "scene", None)
        if scene is not None and scene.obstacles:
            # the scene's distance queries (compiled kernels, numba: seconds to import on a loaded machine) load
            # now, before the bus is opened: certifying a trajectory needs them, and an import that holds the GIL
            # while drives wait for SDO answers or SYNC trips their time-outs and watchdogs
            scene.signed_distance(np.asarray(scene.bounds_min, dtype=float)[None, :])
        if s.bus.faults and not s.bus.simulated:
            raise ConfigError("bus.faults are injected by the simulated bus: use them with interface: virtual")
        if s.bus.simulated and self.simulated_drives is None:
            raise ConfigError(
                f"{type(self).__name__} has no simulated drives for the virtual bus: give a real bus (bus.interface)"
            )
        realtime = s.clock == "realtime" or (s.clock == "auto" and not s.bus.simulated)
        if not realtime and not s.bus.simulated:
            raise ConfigError(
                f"clock: simulated needs the simulated bus; interface '{s.bus.interface}' is real hardware"
            )
        period = 1.0 / s.control_rate
        if s.realtime_priority is not None and realtime:
            try:  # refuse before anything is opened if the system does not allow it
                restore_priority(set_realtime_priority(s.realtime_priority))
            except (OSError, AttributeError) as exc:
                raise ConfigError(
                    f"realtime_priority {s.realtime_priority}: this system does not let the process run under "
                    f"SCHED_FIFO ({exc}); it needs Linux and CAP_SYS_NICE (or root), or leave the setting out"
                ) from None
        try:
            cia402.interpolation_period(period)
        except ValueError as exc:
            raise ConfigError(f"control_rate {s.control_rate:g} Hz: {exc}") from None
        if s.heartbeat_period < 10 * period:
            raise ConfigError(
                f"heartbeat_period {s.heartbeat_period:g} s must be at least 10 control periods ({10 * period:g} s) "
                "so that a lost node is detected within two heartbeat periods"
            )
        self.model = self.build_model()
        config = axis_configs(s, self.model, self.joints())
        for axis, eds in zip(config, self.eds_files(), strict=True):
            axis.eds = eds
        check_bus_load(s, config)
        self.clock = RealTimeClock() if realtime else SimulatedClock()
        self.faults = ArmedFaults(s.bus.faults, self.clock.now)
        inner, self.channel = open_bus(s.bus)
        self.bus = MonitoredBus(inner, self.clock.now, self.faults)
        self.epoch = time.time() - self.clock.now()
        description = f"{s.bus.interface} channel '{self.channel}'"
        try:
            link = None if realtime else SimulationLink()
            if s.bus.simulated:
                drives_bus = can.Bus(interface="virtual", channel=self.channel)
                self.simulator = self.simulated_drives.for_device(self, drives_bus, self.clock, self.faults, link)
                if realtime:
                    self.simulator.start(s.realtime_priority)
            self.master = DriveMaster(
                self.bus,
                config,
                self.clock,
                period=period,
                heartbeat_period=s.heartbeat_period,
                following_error_timeout=s.following_error_timeout,
                sdo_timeout=s.sdo_timeout,
                link=link,
                description=description,
                master_node_id=s.master_node_id,
                boot_timeout=s.boot_timeout,
                priority=s.realtime_priority if realtime else None,
                max_torque=self.max_torque,
            )
            self.master.start()
            self.controller = Controller(
                self.master,
                self.clock,
                Supervision(1.5 * s.heartbeat_period, s.pdo_timeout_cycles, s.stop_timeout, s.settle_time),
                s.realtime_priority if realtime else None,
            )
            self.placed = s.simulation.initial is not None or not s.bus.simulated
        except BaseException:
            self._release()
            raise

    def on_activate(self) -> None:
        if self.clock.realtime and not self._frozen:
            # what exists now (models, dictionaries, imported modules) is never garbage: out of the cyclic
            # collector's sight, so that a full collection while holding or between trajectories scans only
            # what is new (a full collection of the whole heap was measured at 150 ms: a SYNC gap that trips
            # the drives' watchdogs); trajectories run with the collector off (Controller.run)
            gc.collect()
            gc.freeze()
            self._frozen = True
        self.controller.enable(self.settings.enable_timeout)
        self.controller.start_holding()

    def on_deactivate(self) -> None:
        self.controller.disable()

    def on_cleanup(self) -> None:
        self._release()

    def on_shutdown(self) -> None:
        if self.controller is not None and self.state.value == "active":
            try:
                self.controller.disable()
            except Exception:  # shutting down must release the bus whatever the drives do
                pass
        self._release()

    def _release(self) -> None:
        if self._frozen:
            gc.unfreeze()
            self._frozen = False
        if self.controller is not None:
            self.controller.stop_holding()
        if self.master is not None:
            try:
                self.master.close()
            except Exception:  # releasing must not hide the error that brought us here
                pass
        if self.simulator is not None:
            self.simulator.close()
        if self.bus is not None:
            self._write_trace()
            self.bus.shutdown()
        self.master = self.simulator = self.bus = self.controller = None

    def _write_trace(self) -> None:
        """``record.can``: the bus traffic so far as ``<stage>.can.<format>`` (:mod:`.trace`), listed in
        :attr:`recordings`. Written when the bus is released, however the stage ended: a trace of a failed
        start-up is what one needs to see why it failed."""
        fmt = self.settings.record.can
        if fmt is None or self.context is None:
            return
        name = trace_name(self.context.name, fmt)
        try:
            write_trace(self.context.output_dir / name, fmt, self.bus.frames, self.bus.own_ids, self.epoch)
        except OSError as exc:  # a full disk must not hide what the stage did
            log.warning("could not write the CAN trace %s: %s", name, exc)
            return
        if name not in self.recordings:
            self.recordings.append(name)

    # ------------------------------------------------------------------ state (inactive or active)
    def _require_configured(self) -> None:
        if self.master is None:
            raise LifecycleError(f"the device's states are readable once configured; it is {self.state.value}")

    def joint_positions(self) -> np.ndarray:
        """The drives' actual positions (SI), read from them by SDO (readable once configured)."""
        self._require_configured()
        counts, _ = self.master.read_state()
        return counts / np.array([a.counts_per_unit for a in self.master.axes])

    def drive_states(self) -> dict[str, str]:
        """Each joint's CiA 402 state, read from its drive by SDO (readable once configured)."""
        self._require_configured()
        _, statuswords = self.master.read_state()
        return {a.name: cia402.state_of(int(w)) for a, w in zip(self.master.axes, statuswords, strict=True)}

    def reset_faults(self) -> None:
        """Fault reset and re-enable every drive (CiA 402 transition 15, then 2-4); needs ``active``."""
        if self.state.value != "active":
            raise LifecycleError(f"a fault reset needs an active device; it is {self.state.value}")
        self.controller.enable(self.settings.enable_timeout)
        self.controller.start_holding()

    # ------------------------------------------------------------------ execution
    def run(self, trajectory: Trajectory) -> ExecutionReport:
        """The trajectory executed (see :meth:`_run`). In real time with a ``realtime_priority``, the calling
        thread computes the joint path, its timing and its certification under SCHED_FIFO too, with a short GIL
        switch interval: the hold thread keeps SYNC going meanwhile and needs the GIL every cycle, and an
        ordinary thread that holds it when the machine preempts it would stall the drives' SYNC (their
        watchdog then stops them)."""
        controller = self.controller
        if controller is None or not controller.clock.realtime or controller.priority is None:
            return self._run(trajectory)
        with paced_section(controller.priority):
            return self._run(trajectory)

    def _run(self, trajectory: Trajectory) -> ExecutionReport:
        s = self.settings
        self._source = trajectory.source
        self._threshold = trajectory.clearance_threshold
        states = self.drive_states()
        stopped = {name: state for name, state in states.items() if state != cia402.OPERATION_ENABLED}
        if stopped or self.controller.pending_faults:
            # after a stop the drives stay stopped until the user resets them: never restart by itself
            # both what the drives are in and why, where the holding loop saw it (a fault while holding
            # quick-stops every axis: the states alone would not say which node, or what, stopped them)
            what = ", ".join(f"'{name}' is {state}" for name, state in stopped.items())
            pending = "; ".join(
                f"{f['kind'].replace('_', ' ')} on node {f.get('node')}"
                + (f" ({f['detail']})" if f.get("detail") else "")
                for f in self.controller.pending_faults
            )
            why = "; ".join(part for part in (what, f"while holding: {pending}" if pending else "") if part)
            return refused(f"the drives are not ready ({why}): reset_faults() (a fault reset and re-enable) first")
        current = self.joint_positions()
        try:
            joint_path = self.joint_path(trajectory, current)
            q = joint_path.q
            check_path(self.model, q, trajectory.space.scene)
        except Refusal as exc:
            return refused(str(exc))
        # the simulated device starts where its first path starts, as if placed there by hand
        place = self.simulator is not None and not self.placed
        if place:
            current = q[0].copy()
        metrics: dict[str, Any] = dict(joint_path.metrics)
        gap = np.abs(q[0] - current)
        if np.any(gap > 1e-4 * np.maximum(1.0, np.abs(current))):
            if not s.approach:
                return refused(
                    f"the device is at {np.round(current, 5).tolist()}, the path starts at "
                    f"{np.round(q[0], 5).tolist()} (approach: false)"
                )
            if not self.approach_is_clear(current, q[0], trajectory):
                return refused(
                    "the straight joint motion from the current configuration "
                    f"{np.round(current, 5).tolist()} to the path start is not clear of the obstacles"
                )
            q = np.concatenate([current[None], q])
            metrics["approach"] = True
        velocity, acceleration = self.limits()
        planned = time_parameterize(q, velocity, acceleration, 1.0 / s.control_rate)
        metrics["planned_duration_s"] = planned.duration
        metrics["optimal_duration_s"] = planned.optimal_duration
        metrics["max_joint_velocity_ratio"] = float(np.max(np.abs(planned.velocity()) / velocity, initial=0.0))
        metrics["max_joint_acceleration_ratio"] = float(
            np.max(np.abs(planned.acceleration()) / acceleration, initial=0.0)
        )
        metrics["path_deviation_max_m"] = planned.tip_deviation(self.model.tip_positions)
        margin = float(s.safety_margin)
        certificates = self.certify_motion(planned.q, trajectory, margin)
        refusal = certification_refusal(certificates, planned, self.model, margin, metrics)
        if refusal is not None:
            return refused(refusal, metrics)

        def arm(t0: float) -> None:
            # injected faults happen once, timed from the first trajectory's start: a rehearsal of
            # "fault, reset, carry on" must not meet the same jam again
            if self.faults.origin is None:
                self.faults.arm(t0)
                if self.simulator is not None:
                    self.simulator.arm(t0)

        # everything is computed: only now stop holding (in real time the drives' SYNC watchdog would trip
        # during a long computation), so that missed_cycles counts the trajectory's cycles alone
        self.controller.stop_holding()
        if place:
            self.simulator.place(q[0])
            self.controller.hold = np.round(q[0] * self.controller.cpu).astype(np.int64)
            self.placed = True
        missed = self.controller.missed_cycles
        log = self.controller.run(planned.q, on_start=arm)
        self.last_log = log
        metrics["missed_cycles"] = self.controller.missed_cycles - missed
        report = self._report(log, trajectory, metrics)
        if log.status != "completed" and s.fault_reset:
            report.metrics["fault_reset"] = self._try_fault_reset()
        return report

    def _try_fault_reset(self) -> dict[str, Any]:
        """After a stop: fault reset and re-enable; what came back (the rehearsal of a recovery)."""
        try:
            self.controller.enable(self.settings.enable_timeout)
        except BusError as exc:
            return {"ok": False, "detail": str(exc)}
        self.controller.start_holding()
        return {"ok": True, "states": self.drive_states()}

    def _report(self, log: ExecutionLog, trajectory: Trajectory, metrics: dict[str, Any]) -> ExecutionReport:
        s = self.settings
        model = self.model
        metrics["cycles"] = log.cycles
        metrics["control_rate_hz"] = s.control_rate
        metrics["duration_s"] = log.end - log.start
        metrics["samples_missing"] = log.samples_missing
        tips = model.tip_positions(log.measured) if len(log.measured) else np.zeros((0, 3))
        clearance = np.zeros(0)
        if len(tips):
            metrics["length_m"] = float(np.sum(np.linalg.norm(np.diff(tips, axis=0), axis=1)))
            clearance_metrics, clearance = self.clearance_along(log.measured, trajectory)
            metrics.update(clearance_metrics)
            # no commanded sample once quick-stopping (NaN rows)
            commanded = np.all(np.isfinite(log.reference), axis=1)
            reference_tips = np.full((len(log.reference), 3), np.nan)
            if np.any(commanded):
                reference_tips[commanded] = model.tip_positions(log.reference[commanded])
            metrics.update(tracking_metrics(tips, reference_tips, log, model.joint_names))
        # stable names: a run that tracked nothing (stopped at once) says so with None
        metrics.setdefault("tracking_error_max_m", None)
        metrics.setdefault("tracking_error_rms_m", None)
        simulator = self.simulator
        droppers = (self.bus.dropper, getattr(simulator, "frame_drop", None), getattr(simulator, "sync_drop", None))
        metrics.update(bus_metrics(self.bus, log, s.bus.bitrate, droppers))
        explain_lost_heartbeats(log, self.bus.dropper)
        metrics["faults"] = log.faults
        message = log.reason if log.status != "completed" else ""
        report = ExecutionReport(log.status, metrics, tips if len(tips) else None, log.faults, message)
        report.executed_t = log.t if len(log.t) == len(tips) else None
        if len(tips):  # what the framework re-measures: the device's own geometry where it has one
            report.executed_space, report.executed_path = self.executed_geometry(log.measured, trajectory)
            report.tip_radius = metrics.get("tip_radius_m")
        if s.outputs and self.context is not None and len(tips):
            report.files = self._write_outputs(log, tips, reference_tips, clearance, message)
        return report

    def _plan_threshold(self) -> float | None:
        """The clearance threshold of the plan stage this execution's path came from, if it had one."""
        return float(self._threshold) if self._threshold is not None else None

    def _write_outputs(self, log, tips, reference_tips, clearance, message: str) -> list[str]:
        name = self.context.name
        out = Path(self.context.output_dir)
        model = self.model
        write_log_csv(out / f"{name}-execution.csv", log, model.joint_names, tips)
        title = f"{name}: {type(self).__name__} {log.status}"
        if message:
            title += "\n" + textwrap.shorten(message, 150)
        error = np.linalg.norm(tips - reference_tips, axis=1)
        execution_figure(
            out / f"{name}.png",
            title,
            log,
            model.joint_names,
            model.prismatic,
            error,
            clearance,
            self.clearance_label,
            float(self.settings.safety_margin),
            self._plan_threshold(),
        )
        return [f"{name}.png", f"{name}-execution.csv"]
