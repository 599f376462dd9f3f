"""``cast_gimbal`` as a pose source: observe mode (and ``mode: assist``, :mod:`.assist`), for a ``guide`` stage.

The trainee moves the instrument by hand; the drives are **not commanded**:
the master runs the standard start-up (reset communication, boot-up, SDO
configuration, PDO mapping, NMT start) and then only sends SYNC. The drives
stay in SWITCH ON DISABLED (torque off), and answer each SYNC with TPDO1
(statusword and encoder position); no RPDO, no controlword, no target is ever
sent (the tests check the bus traffic). The encoder positions are the gimbal's
joints, so the guide stage measures the *whole shaft's* clearance through the
gimbal's kinematics (the ``cast_gimbal`` space), or, for a plan in ``r3``, the
tip from the device's Pinocchio model.

In simulation (``bus: {interface: virtual}``, the default) a trainee moves the
simulated drives' axes by hand (:meth:`DriveSimulator.move_by_hand`): the
synthetic trainee of :mod:`surgiplan.guidance.trainee` (``hand: {synthetic:
{level: beginner, seed: 3}}``, the default an intermediate one) or a recorded
attempt replayed (``hand: {replay: attempt.csv}``, tip positions or joints,
:mod:`surgiplan.guidance.files`). On real drives there is no ``hand``: the
trainee's.

The attempt ends when the simulated hand has finished (and ``rest_time`` has
passed), when the tip has rested within ``goal_tolerance`` of the path's end
for ``rest_time``, or after ``max_duration``; a drive whose TPDO does not come
for ``pdo_timeout_cycles`` stops it (:class:`SourceStopped`, naming the node), as does a bus error. Faults
injected in simulation (``bus: {faults: [...]}``) are timed from the attempt's start.
"""

from __future__ import annotations

import warnings
from typing import Any, Literal

import numpy as np
from pydantic import Field, NonNegativeFloat, PositiveFloat, PrivateAttr, ValidationInfo, model_validator
from surgiplan.errors import ConfigError, PlanningInputError
from surgiplan.guidance import PoseSample, PoseSource, SourceStopped, TraineeModel, synthetic_attempt
from surgiplan.guidance.files import read_attempt_csv
from surgiplan.units import PositiveLength
from surgiplan.validation import file_length_scale, input_path

from ..canopen.realtime import realtime_section
from ..canopen.sim.motor import HandMotion
from .assist import AssistLoop, AssistSettings, assistance_level, proficiency_of
from .device import CastGimbalDevice, CastGimbalDeviceSettings

#: the simulated hand as an impedance on the joints (yaw, pitch, insertion, roll) while the drives push (assist):
#: about 270 N/m at the tip at 15 cm insertion on yaw and pitch, 300 N/m along the shaft (a relaxed grip, of the
#: order measured for human arms), near critically damped with the axes' inertia
HAND_STIFFNESS = (6.0, 6.0, 300.0, 0.05)
HAND_DAMPING = (0.3, 0.3, 17.0, 0.006)


class HandModel(TraineeModel):
    """How the simulated trainee's hand moves the instrument: ``synthetic`` (the default, an intermediate
    trainee; the fields of :class:`surgiplan.guidance.TraineeModel`) or ``replay`` of a recorded file.

    In observe mode the hand carries the instrument where the trainee intends; in assist mode it is a
    spring-damper (``stiffness``, ``damping``: per joint, N·m/rad and N/m, N·m·s/rad and N·s/m) pulling toward
    there, its torques adding to the drives' in the motor model."""

    replay: str | None = None
    stiffness: list[NonNegativeFloat] = Field(default_factory=lambda: list(HAND_STIFFNESS), min_length=4, max_length=4)
    damping: list[NonNegativeFloat] = Field(default_factory=lambda: list(HAND_DAMPING), min_length=4, max_length=4)
    _recorded: tuple | None = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _read(self, info: ValidationInfo):
        if self.replay is not None:
            path = input_path(self.replay, info)
            times, values, kind = read_attempt_csv(path, file_length_scale(info))
            self.replay = str(path)
            self._recorded = (times - times[0], values, kind)
        return self


class CastGimbalObserveSettings(CastGimbalDeviceSettings):
    #: simulation only: the trainee's hand (default: a synthetic intermediate trainee)
    hand: HandModel | None = None
    #: the attempt ends at the latest after this many seconds
    max_duration: PositiveFloat = 300.0
    #: ... or once the tip has rested this long within goal_tolerance of the path's end
    rest_time: PositiveFloat = 0.5
    goal_tolerance: PositiveLength = 0.003
    #: ``observe`` (torque off) or ``assist`` (the drives pull toward the recommended path: :mod:`.assist`)
    mode: Literal["observe", "assist"] = "observe"
    #: the virtual fixture and its safety limits (mode assist)
    assist: AssistSettings = Field(default_factory=AssistSettings)

    @model_validator(mode="after")
    def _hand_only_in_simulation(self):
        if self.hand is not None and not self.bus.simulated:
            raise ValueError(
                "hand: moves simulated drives; on real drives (bus.interface other than virtual) a trainee does"
            )
        return self

    @model_validator(mode="after")
    def _assist_within_the_drives(self):
        peak = self.motors.peak_torque or CastGimbalDevice.default_motors["peak_torque"]
        if self.assist.torque_cap > min(peak):
            raise ValueError(
                f"assist.torque_cap {self.assist.torque_cap} (thousandths of the rated torque) is above the drives' "
                f"peak torque {min(peak)} (motors.peak_torque)"
            )
        if self.assist.max_sample_age < 1.0 / self.control_rate:
            raise ValueError(
                f"assist.max_sample_age {self.assist.max_sample_age:g} s is shorter than one SYNC period "
                f"({1.0 / self.control_rate:g} s at control_rate {self.control_rate:g} Hz): every sample would be "
                "too old"
            )
        return self


class CastGimbalObserver(PoseSource):
    """The CAST gimbal in observe mode (see the module)."""

    Settings = CastGimbalObserveSettings

    def __init__(self, settings: CastGimbalObserveSettings) -> None:
        super().__init__(settings)
        self.device: CastGimbalDevice | None = None
        self.hand_end = np.inf
        #: mode assist: the assistance of this attempt
        self.assist: AssistLoop | None = None
        #: SYNC cycles skipped because the loop ran late (real time), and the span of the loop (clock s)
        self.missed_syncs = 0
        self.loop_span = (np.nan, np.nan)
        self.loop_syncs = 0
        self.lateness = np.zeros(0)
        self.loop_cycles = 0

    @classmethod
    def check_plan(cls, settings: CastGimbalObserveSettings, plan) -> tuple[str, tuple[str, ...]] | None:
        """Mode assist pulls toward a recommended path of the gimbal's tip: refuse a plan stage without a goal (no
        path to a target) or planning in a space whose path is not the tip's (neither cast_gimbal nor r3)."""
        if settings.mode != "assist":
            return None
        space = getattr(getattr(plan, "space", None), "kind", None)
        if getattr(plan, "goal", 0) is None:
            why = "has no goal: no recommended path to a target to pull toward"
        elif space not in (None, "cast_gimbal", "r3"):
            why = f"plans in {space}: its path is not one of the gimbal's tip (plan in cast_gimbal or r3)"
        else:
            return None
        return f"mode assist needs a recommended path, and plan stage '{plan.name}' {why}; or use mode observe", (
            "mode",
        )

    # ------------------------------------------------------------------ opening
    def open(self, context) -> None:
        space = context.space
        s = self.settings
        if space.kind == "cast_gimbal":
            self.gimbal_space = space
        elif space.kind == "r3" and s.fulcrum is not None:
            from surgiplan.spaces import CastGimbalSpace

            self.gimbal_space = CastGimbalSpace.from_settings(
                CastGimbalSpace.Settings.model_validate({"fulcrum": s.fulcrum.model_dump()}), context.scene
            )
        else:
            raise ConfigError(
                f"observing the CAST gimbal needs the recommended path in the cast_gimbal space, or an r3 path and "
                f"the device's fulcrum setting; the plan is in {space.kind}"
            )
        self.yield_q = space.kind == "cast_gimbal"
        motion = None
        fields: dict[str, Any] = s.model_dump(exclude={"hand", "max_duration", "rest_time", "goal_tolerance"})
        if s.bus.simulated:
            times, joints = self._hand_motion(context)
            fields["simulation"] = {**fields.get("simulation", {}), "initial": joints[0].tolist()}
            motion = (times, joints)
        if fields.get("fulcrum") is None:
            from scipy.spatial.transform import Rotation

            with warnings.catch_warnings():  # at pitch +-90 deg any split of roll and yaw is the same frame
                warnings.simplefilter("ignore", UserWarning)
                rpy = Rotation.from_matrix(self.gimbal_space.frame).as_euler("xyz")  # URDF's fixed-axis rpy
            fields["fulcrum"] = {"xyz": self.gimbal_space.fulcrum.tolist(), "rpy": rpy.tolist()}
        fields.pop("mode", None)
        fields.pop("assist", None)
        self.device = CastGimbalDevice(CastGimbalDeviceSettings.model_validate(fields))
        assist = s.mode == "assist"
        if assist:
            self.device.max_torque = [s.assist.torque_cap] * 4  # torque mode: CST, 0x6072 = the cap
        self.device.configure(context.stage)  # the standard start-up; observe: the drives are never enabled
        if assist:
            level = assistance_level(proficiency_of(context, s.assist), s.assist)
            self.assist = AssistLoop(self.device, s.assist, context, level, self.gimbal_space)
        self.cpu = np.array([a.counts_per_unit for a in self.device.master.axes], dtype=float)
        self.goal_tip = np.asarray(context.tips[-1], dtype=float)
        if motion is not None:
            times, joints = motion
            start = self.device.clock.now()
            self.hand_end = float(times[-1])
            hand_model = s.hand or HandModel()
            self.device.simulator.move_by_hand(HandMotion(times, joints, start), hand_model.stiffness,
                                               hand_model.damping)  # fmt: skip
            self.origin = start
        else:
            self.origin = self.device.clock.now()
        # injected faults (bus.faults) are timed from the attempt's start, as from a trajectory's in execute
        self.device.faults.arm(self.origin)
        if self.device.simulator is not None:
            self.device.simulator.arm(self.origin)

    def _hand_motion(self, context) -> tuple[np.ndarray, np.ndarray]:
        """Times (s) and gimbal joints (n, 4) of the simulated hand."""
        hand = self.settings.hand or HandModel()
        recorded = hand._recorded
        if recorded is None:
            times, tips = synthetic_attempt(context.tips, hand, (context.scene.bounds_min, context.scene.bounds_max))
            kind, values = "tip", tips
        else:
            times, values, kind = recorded
        if kind == "joints":
            return np.asarray(times, float), np.asarray(values, float)
        joints = []
        for tip in values:
            try:
                joints.append(self.gimbal_space.configuration(tip, what="the trainee's tip"))
            except PlanningInputError as exc:
                raise ConfigError(f"the simulated hand's path leaves the gimbal's reach: {exc.message}") from None
        return np.asarray(times, float), np.asarray(joints, float)

    # ------------------------------------------------------------------ observing
    def samples(self):
        device, s = self.device, self.settings
        clock, master = device.clock, device.master
        period = 1.0 / s.control_rate
        next_due = clock.now()
        self.loop_span = (next_due, next_due)
        self.loop_syncs = 0
        missing = np.zeros(len(self.cpu), dtype=int)
        rest_since = None
        cycles = int(s.max_duration / period) + 2
        # how late each cycle woke after its due time (s; real time): the loop's jitter, into an array made now
        self.lateness = np.zeros(cycles)
        self.loop_cycles = 0
        # real time: the collector off (the heap frozen), a short GIL switch interval, SCHED_FIFO where the user
        # asks for it (realtime_priority); the guide's measuring of each sample runs inside too (it is in the cycle)
        with realtime_section(clock, s.realtime_priority):
            yield from self._cycles(clock, master, period, next_due, missing, rest_since, cycles)

    def _cycles(self, clock, master, period, next_due, missing, rest_since, cycles):
        s = self.settings
        previous_sync = None
        sent = next_due
        for k in range(cycles):  # bounded: max_duration
            clock.sleep_until(next_due)
            now = next_due
            next_due += period
            self.lateness[k] = clock.now() - now
            self.loop_cycles = k + 1
            if clock.realtime and clock.now() - now > period:  # descheduled: skip, never burst SYNCs
                self.missed_syncs += int((clock.now() - now) // period)
                # the drives get a whole period after the last SYNC went before their answers are judged (a SYNC
                # that went late must not make its TPDOs look missed)
                clock.sleep_until(max(clock.now(), sent + period))
                now = clock.now()
                next_due = now + period
            if clock.realtime and previous_sync is not None:
                # the drives get a whole period after the last SYNC went before their answers are judged, also when
                # it went less than a period late (the next SYNC then goes when they are in, or at that period's end)
                master.wait_for_answers(sent + period - clock.now())
            feedback = master.feedback()  # the answers to the previous SYNC
            sample = None
            done = False
            if previous_sync is not None:
                fresh = np.asarray(feedback.fresh, dtype=bool) & np.asarray(feedback.current, dtype=bool)
                missing = np.where(fresh, 0, missing + 1)
                late = np.flatnonzero(missing > s.pdo_timeout_cycles)
                if late.size:
                    axis = master.axes[int(late[0])]
                    raise SourceStopped(
                        f"no TPDO from CAN node {axis.node_id} (joint '{axis.name}') for {int(missing[late[0]])} "
                        f"SYNC cycles"
                    )
                if fresh.all():
                    q = np.asarray(feedback.position, dtype=float) / self.cpu
                    t = previous_sync - self.origin
                    tip = self.gimbal_space.tip(q[None])[0]
                    sample = PoseSample(t, q=q) if self.yield_q else PoseSample(t, tip=tip)
                    at_goal = float(np.linalg.norm(tip - self.goal_tip)) <= s.goal_tolerance
                    rest_since = (rest_since if rest_since is not None else t) if at_goal else None
                    rested = rest_since is not None and t - rest_since >= s.rest_time
                    done = rested or t >= self.hand_end + s.rest_time
            if done:  # the attempt's last sample: no SYNC after it
                yield sample
                return
            # the cycle's SYNC at once, before the sample is measured and the torques computed: what those cost does
            # not shorten the drives' time to answer (the same frames as SYNC with the RPDOs: RPDOs sent after a SYNC
            # act at the next one either way)
            try:
                master.sync()
            except Exception as exc:  # a bus error: the bus is gone
                raise SourceStopped(f"the CAN bus failed: {exc}") from None
            sent = clock.now()
            if sample is not None:
                yield sample
            # assist: the torques (a bus error is SourceStopped); observe, or once the assistance has ended: nothing
            if self.assist is not None:
                self.assist.cycle(now, feedback, previous_sync, period)
            previous_sync = now
            self.loop_span = (self.loop_span[0], now)
            self.loop_syncs += 1

    def close(self) -> None:
        if self.device is not None:
            try:
                if self.assist is not None:
                    self._end_assist()
                self.device.shutdown()
            finally:
                self.recordings = list(self.device.recordings)  # the device's trace (record.can) is the source's
                self.device = None

    def _end_assist(self) -> None:
        """Leave every drive in SWITCH ON DISABLED: zero torque and DISABLE VOLTAGE, applied at one more SYNC; the
        assistance's summary goes to the attempt record."""
        assist = self.assist
        try:
            if assist.ended is None or assist.active:
                assist.stop(self.device.clock.now(), None)
                self.device.master.sync()
                if self.device.clock.realtime:
                    self.device.clock.sleep_until(self.device.clock.now() + 2.0 / self.settings.control_rate)
        finally:
            summary = assist.summary()
            span = self.loop_span[1] - self.loop_span[0]
            if summary["ended_at_s"] is not None:  # from the attempt's start, as the samples' times
                summary["ended_at_s"] -= self.origin
            summary["missed_syncs"] = self.missed_syncs
            late = self.lateness[: self.loop_cycles]
            for q, name in ((50, "p50"), (99, "p99"), (100, "max")):  # the cycle jitter (real time; 0 simulated)
                summary[f"jitter_{name}_ms"] = 1000 * float(np.percentile(late, q)) if late.size else None
            summary["cycle_rate_hz"] = (self.loop_syncs - 1) / span if span > 0 else None
            self.assistance = summary
