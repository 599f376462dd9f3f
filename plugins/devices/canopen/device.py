"""What the CiA 402 device plugins share: settings, lifecycle, and the execution pipeline.

Lifecycle (ros2_control's, :class:`surgiplan.Device`):

* ``configure``: the kinematic model is loaded, the bus opened (the simulated
  drives started on it), every node configured by SDO and started; states are
  readable. A bus that cannot be opened or a node that does not answer is a
  :class:`~.bus.BusError` here, before anything moves.
* ``activate``: every drive is brought to OPERATION ENABLED holding its
  position (a fault reset first where a drive is in FAULT). In real-time mode
  SYNC keeps running between trajectories.
* ``execute``: the path is mapped to joints (inverse kinematics), refused
  with the reason before any motion if a pose is out of reach, a waypoint
  leaves the joint limits or the plan's workspace bounds, the approach from
  where the device stands is not clear, or the drives are stopped from an
  earlier fault (:meth:`Cia402Device.reset_faults` first: a stopped device
  never restarts by itself); then time-parameterised at the control rate
  (:mod:`.timing`), refused if the timed motion's certified clearance
  (:mod:`.certify`, every body, between samples too) is below
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
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np
from surgiplan.devices import Device, ExecutionReport, LifecycleError, Trajectory
from surgiplan.errors import ConfigError
from surgiplan.plugins.devices.kinematics.model import KinematicModel
from surgiplan.status import ExecuteStatus

from . import cia402
from .bus import ArmedFaults, BusError, MonitoredBus, open_bus, worst_case_bits
from .certify import Certificate
from .clock import RealTimeClock, SimulatedClock, restore_priority, set_realtime_priority
from .control import Controller, ExecutionLog, Supervision
from .drives import AxisHardware, DriveSimulator, MotorModel
from .master import AxisConfig, DriveMaster
from .network import SimulationLink
from .report import bus_metrics, execution_figure, tracking_metrics, write_log_csv
from .settings import PRISMATIC_COUNTS, REVOLUTE_COUNTS, Cia402DeviceSettings
from .timing import time_parameterize


class Refusal(Exception):
    """A trajectory the device will not start; the message says why."""


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
    urdf_name: str = ""
    tip_frame: str = ""
    #: what the per-sample clearance of :meth:`clearance_along` is the clearance of (figure label)
    clearance_label: str = "executed clearance"

    def __init__(self, settings: Cia402DeviceSettings) -> None:
        super().__init__(settings)
        self.model: KinematicModel | None = None
        self.clock = None
        self.bus: MonitoredBus | None = None
        self.simulator: DriveSimulator | None = None
        self.master: DriveMaster | None = None
        self.controller: Controller | None = None
        self.faults: ArmedFaults | None = None
        self.placed = False
        #: the last execution's log (times, measured and commanded joints, faults): what the drives did
        self.last_log: ExecutionLog | None = None
        self._source: str | None = None
        self._frozen = False
        self.channel = ""

    # ------------------------------------------------------------------ for subclasses
    def build_model(self, base=None) -> KinematicModel:
        raise NotImplementedError

    def joint_path(self, trajectory: Trajectory, current: np.ndarray) -> JointPath:
        """Joint waypoints for the trajectory's path; raise :class:`Refusal` if impossible."""
        raise NotImplementedError

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
    def _per_joint(self, values, default, what: str) -> np.ndarray:
        nq = self.model.nq
        if values is None:
            return np.asarray(default, dtype=float)
        if len(values) != nq:
            raise ConfigError(f"{what}: give {nq} values, one per joint {self.model.joint_names}; got {len(values)}")
        return np.asarray(values, dtype=float)

    def limits(self) -> tuple[np.ndarray, np.ndarray]:
        """Velocity and acceleration limits the trajectories use (SI per joint)."""
        s = self.settings
        velocity = self.model.velocity_limit * s.velocity_scale
        acceleration = self._per_joint(s.acceleration_limits, self.default_acceleration, "acceleration_limits")
        return velocity, acceleration

    @classmethod
    def eds_folder(cls) -> Path:
        """Where the device package ships its simulated drives' EDS files (``<package>/eds``)."""
        package = cls.__module__.rpartition(".")[0]
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

    def _axes(self) -> tuple[list[AxisConfig], list[AxisHardware]]:
        s = self.settings
        model = self.model
        nq = model.nq
        ids = s.node_ids or list(range(1, nq + 1))
        if len(ids) != nq or len(set(ids)) != nq or not all(1 <= i <= 127 for i in ids):
            raise ConfigError(f"node_ids: give {nq} distinct CAN node ids (1-127), one per joint {model.joint_names}")
        if s.master_node_id in ids:
            raise ConfigError(f"master_node_id {s.master_node_id} is also a drive's node id (node_ids: {ids})")
        cpu = self._per_joint(
            s.counts_per_unit, np.where(model.prismatic, PRISMATIC_COUNTS, REVOLUTE_COUNTS), "counts_per_unit"
        )
        window = self._per_joint(
            s.following_error_window, np.where(model.prismatic, 0.001, 0.01), "following_error_window"
        )
        velocity, acceleration = self.limits()
        initial = s.simulation.initial
        if initial is not None:
            initial = self._per_joint(initial, None, "simulation.initial")
            if not model.within_limits(initial[None])[0]:
                raise ConfigError(f"simulation.initial {list(initial)} is outside the joint limits")
        start = initial if initial is not None else model.neutral()
        config, hardware = [], []
        for j in range(nq):
            config.append(
                AxisConfig(
                    model.joint_names[j],
                    ids[j],
                    float(cpu[j]),
                    float(model.lower[j]),
                    float(model.upper[j]),
                    float(window[j]),
                    float(velocity[j] * s.simulation.velocity_factor),
                    float(acceleration[j] * s.quick_stop_factor),
                )
            )
            hardware.append(
                AxisHardware(
                    ids[j],
                    float(cpu[j]),
                    float(acceleration[j] * s.simulation.peak_acceleration_factor),
                    float(model.velocity_limit[j] * s.simulation.velocity_factor),
                    float(start[j]),
                    name=model.joint_names[j],
                    unit="m" if model.prismatic[j] else "rad",
                    lower=float(model.lower[j]),
                    upper=float(model.upper[j]),
                    following_error_window=float(window[j]),
                    profile_velocity=float(velocity[j]),
                    profile_acceleration=float(acceleration[j]),
                )
            )
        return config, hardware

    def _check_bus_load(self, axes: list[AxisConfig]) -> None:
        """Refuse a control rate whose cyclic frames alone cannot fit on the bus."""
        s = self.settings
        per_cycle = worst_case_bits(0) + len(axes) * 2 * worst_case_bits(6)
        load = per_cycle * s.control_rate / s.bus.bitrate
        if load > 1.0:
            raise ConfigError(
                f"control_rate {s.control_rate:g} Hz with {len(axes)} drives needs {100 * load:.0f}% of the "
                f"{s.bus.bitrate / 1e6:g} Mbit/s bus (SYNC + RPDO + TPDO per drive, worst-case stuffing); "
                f"lower control_rate to at most {s.control_rate / load:.0f} Hz"
            )

    # ------------------------------------------------------------------ lifecycle
    def on_configure(self, context) -> None:
        s = self.settings
        if s.bus.faults and not s.bus.simulated:
            raise ConfigError("bus.faults are injected by the simulated bus: use them with interface: virtual")
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
        config, hardware = self._axes()
        for axis, eds in zip(config, self.eds_files(), strict=True):
            axis.eds = eds
        self._check_bus_load(config)
        self.clock = RealTimeClock() if realtime else SimulatedClock()
        self.faults = ArmedFaults(s.bus.faults, self.clock.now)
        inner, self.channel = open_bus(s.bus)
        self.bus = MonitoredBus(inner, self.clock.now, self.faults)
        description = f"{s.bus.interface} channel '{self.channel}'"
        try:
            link = None if realtime else SimulationLink()
            if s.bus.simulated:
                model = MotorModel(
                    s.simulation.position_gain, s.simulation.velocity_gain, sync_timeout=s.simulation.sync_timeout
                )
                drives_bus = can.Bus(interface="virtual", channel=self.channel)
                self.simulator = DriveSimulator(
                    drives_bus, hardware, model, self.clock, self.faults, link, device=self.urdf_name
                )
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
            self.bus.shutdown()
        self.master = self.simulator = self.bus = self.controller = None

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
    def _refused(self, reason: str, metrics: dict[str, Any] | None = None) -> ExecutionReport:
        # the execute stage's metric names stay the same whatever happened: nothing tracked, no fault
        out = {**(metrics or {}), "cycles": 0, "refused": True, "faults": []}
        out |= {"tracking_error_max_m": None, "tracking_error_rms_m": None}
        return ExecutionReport(ExecuteStatus.REFUSED, out, message=f"refused before any motion: {reason}")

    def _certified(self, planned, trajectory: Trajectory, metrics: dict[str, Any]) -> str | None:
        """Certify the timed motion's clearance (every body, between the samples too); the reason to refuse it
        if some body comes closer than the safety margin, else None. Adds the certified clearances to metrics."""
        margin = float(self.settings.safety_margin)
        certificates = self.certify_motion(planned.q, trajectory, margin)
        for certificate in certificates:
            metrics[f"certified_{certificate.body}_min_clearance_m"] = certificate.lowest
        worst = min(certificates, key=lambda c: c.lowest)
        metrics["certified_min_clearance_m"] = worst.lowest
        metrics["safety_margin_m"] = margin
        if worst.lowest >= margin:
            return None
        k, fraction = worst.segment, worst.fraction
        q = planned.q[k] + fraction * (planned.q[min(k + 1, len(planned.q) - 1)] - planned.q[k])
        tip = self.model.tip_positions(q[None])[0]
        what = "a collision" if worst.lowest < 0 else f"closer than the safety margin {margin * 1000:g} mm"
        return (
            f"the timed motion's certified {worst.body} clearance is {worst.lowest * 1000:.2f} mm "
            f"({worst.lowest:.6f} m), {what}, at t = {(k + fraction) * planned.period:.3f} s of "
            f"{planned.duration:.3f} s with the tip at {np.round(tip * 1000, 1).tolist()} mm (certified along the "
            "whole motion the drives would interpolate, between the samples too)"
        )

    def _check_path(self, q: np.ndarray, trajectory: Trajectory) -> None:
        """Refuse joint waypoints outside the joint limits, or a tip leaving the workspace bounds."""
        model = self.model
        outside = ~model.within_limits(q, 1e-9)
        if np.any(outside):
            i = int(np.argmax(outside))
            j = int(np.argmax((q[i] < model.lower - 1e-9) | (q[i] > model.upper + 1e-9)))
            raise Refusal(
                f"waypoint {i} needs joint '{model.joint_names[j]}' at {q[i, j]:.4g}, outside its limits "
                f"[{model.lower[j]:.4g}, {model.upper[j]:.4g}]"
            )
        scene = trajectory.space.scene  # the plan's scene: its bounds are the workspace planned in
        tips = model.tip_positions(q)
        inside = scene.in_bounds(tips)
        if not np.all(inside):
            i = int(np.argmin(inside))
            raise Refusal(
                f"waypoint {i} puts the tip at {np.round(tips[i], 5).tolist()} m, outside the workspace bounds "
                f"{scene.bounds_min.tolist()} to {scene.bounds_max.tolist()} m"
            )

    def run(self, trajectory: Trajectory) -> ExecutionReport:
        s = self.settings
        self._source = trajectory.source
        states = self.drive_states()
        stopped = {name: state for name, state in states.items() if state != cia402.OPERATION_ENABLED}
        if stopped or self.controller.pending_faults:
            # after a stop the drives stay stopped until the user resets them: never restart by itself
            what = ", ".join(f"'{name}' is {state}" for name, state in stopped.items())
            pending = "; ".join(
                f"{f['kind'].replace('_', ' ')} on node {f.get('node')}" for f in self.controller.pending_faults
            )
            return self._refused(
                f"the drives are not ready ({what or pending}): reset_faults() (a fault reset and re-enable) first"
            )
        current = self.joint_positions()
        try:
            joint_path = self.joint_path(trajectory, current)
            q = joint_path.q
            self._check_path(q, trajectory)
        except Refusal as exc:
            return self._refused(str(exc))
        # the simulated device starts where its first path starts, as if placed there by hand
        place = self.simulator is not None and not self.placed
        if place:
            current = q[0].copy()
        metrics: dict[str, Any] = dict(joint_path.metrics)
        gap = np.abs(q[0] - current)
        if np.any(gap > 1e-4 * np.maximum(1.0, np.abs(current))):
            if not s.approach:
                return self._refused(
                    f"the device is at {np.round(current, 5).tolist()}, the path starts at "
                    f"{np.round(q[0], 5).tolist()} (approach: false)"
                )
            if not self.approach_is_clear(current, q[0], trajectory):
                return self._refused(
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
        metrics["path_deviation_max_m"] = self._path_deviation(planned)
        refusal = self._certified(planned, trajectory, metrics)
        if refusal is not None:
            return self._refused(refusal, metrics)

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

    def _path_deviation(self, planned) -> float:
        """Largest distance (m) of a commanded tip sample from the straight tip segment between the
        waypoints it lies between (and their neighbours): how far the smooth timed path rounds the
        corners of the waypoint polyline (at most about ``path_resolution``)."""
        if planned.waypoints is None or len(planned.waypoints) < 2:
            return 0.0
        corners = self.model.tip_positions(planned.waypoints)
        tips = self.model.tip_positions(planned.q)
        segment = planned.segment_of_samples()
        best = np.full(len(tips), np.inf)
        for shift in (-1, 0, 1):  # a sample near a knot may be nearest to the neighbouring segment
            i = np.clip(segment + shift, 0, len(corners) - 2)
            a, d = corners[i], corners[i + 1] - corners[i]
            t = np.clip(np.sum((tips - a) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-300), 0.0, 1.0)
            best = np.minimum(best, np.linalg.norm(tips - (a + t[:, None] * d), axis=1))
        return float(best.max())

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
        self._explain_lost_heartbeats(log)
        metrics["faults"] = log.faults
        message = log.reason if log.status != "completed" else ""
        report = ExecutionReport(log.status, metrics, tips if len(tips) else None, log.faults, message)
        if s.outputs and self.context is not None and len(tips):
            report.files = self._write_outputs(log, tips, reference_tips, clearance, message)
        return report

    def _explain_lost_heartbeats(self, log: ExecutionLog) -> None:
        """Say so when a heartbeat time-out followed an injected frame loss of that node's heartbeat.

        A consumer cannot tell a lost heartbeat from a silent node within its time-out (1.5 periods,
        so that a silent node stops every axis within two): with frame_loss the device then stops
        safely although the node is alive. The simulation knows which frames it dropped.
        """
        dropper = self.bus.dropper
        if dropper is None:
            return
        for fault in log.faults:  # times relative to the trajectory start, as the dropper's
            if fault["kind"] != "heartbeat_timeout":
                continue
            since = fault.get("last_heartbeat_s", -np.inf)
            lost = [t for t, can_id in dropper.dropped if can_id == 0x700 + fault["node"] and t >= since]
            if lost:
                times = ", ".join(f"{t:.3f}" for t in lost)
                fault["cause"] = (
                    f"injected frame_loss dropped this node's heartbeat at {times} s; a lost heartbeat cannot be "
                    "told from a silent node within the time-out, so the device stopped safely"
                )

    def _plan_threshold(self) -> float | None:
        """The clearance threshold of the plan stage this execution's path came from, if it had one."""
        if self.context is None or self._source is None:
            return None
        plan = self.context.previous.get(self._source)
        threshold = getattr(plan, "clearance_threshold", None)
        return float(threshold) if threshold is not None else None

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
