"""``cast_gimbal`` source ``mode: assist``: the gimbal's drives pull the trainee toward the recommended path.

Beside observe mode (:mod:`.observe`: torque off, the encoders read), the
master configures the drives for cyclic synchronous torque (CiA 402 mode 10:
0x6060 = 10, max torque 0x6072 = ``assist.torque_cap``, RPDO1 controlword +
target torque 0x6071, synchronous), enables them through the state machine
with zero torque, and at every SYNC sends the joint torques

    τ = J_tipᵀ F_g + J_pᵀ F_w

of the virtual fixture (:mod:`surgiplan.guidance.fixture`: the guidance
spring-damper at the tip, the forbidden-region wall at the shaft's point
``p`` nearest the obstacles), ``J`` the gimbal's Pinocchio Jacobian
(``J_p = J_v − [p − o]× J_ω``, ``o`` the tip), in thousandths of each motor's
rated torque 0x6076 times its gear ratio, clipped to the cap. The joint
velocity is the encoders' difference over one SYNC period.

**Safety.** Every torque on the bus is within ``torque_cap`` and 0x6072 (the
master clips what it packs; the drive clips to 0x6072 again). Any of these
ends the assistance: zero torque with controlword DISABLE VOLTAGE in the very
next RPDO (the drive applies it at the next SYNC: within one SYNC period), the
drives in SWITCH ON DISABLED, the attempt going on in observe mode:

* a sample older than ``max_sample_age`` (the loop fell behind);
* a missed TPDO (a drive did not answer the last SYNC within a period of its going out);
* a heartbeat loss (a drive silent for 1.5 heartbeat periods);
* any EMCY.

Stopping the stage (its end, an error, a stop) disables every drive the same
way before the bus is released: they are left in SWITCH ON DISABLED.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from pydantic import Field, PositiveFloat, PositiveInt
from surgiplan.guidance import SourceStopped
from surgiplan.guidance.fixture import FixtureSettings, VirtualFixture, assistance_level

from ..canopen import cia402


class AssistSettings(FixtureSettings):
    """``assist:`` of the ``cast_gimbal`` source (the fixture's keys: :class:`surgiplan.guidance.FixtureSettings`)."""

    #: every torque sent, in thousandths of each motor's rated torque (also written to max torque 0x6072); at
    #: most the drive's peak torque (``motors.peak_torque``)
    torque_cap: PositiveInt = 1000
    #: a sample older than this (s) ends the assistance
    max_sample_age: PositiveFloat = 0.01
    #: cycles with zero torque after enabling before the fixture acts
    settle_cycles: int = Field(default=2, ge=0)


def skew(r: np.ndarray) -> np.ndarray:
    """The cross-product matrix [r]×: [r]× w = r × w."""
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


class TorqueLaw:
    """τ = Jᵀ F of the fixture on the gimbal's kinematic model, in thousandths of the rated torques."""

    def __init__(self, model, fixture: VirtualFixture, scene, fulcrum, radius: float, unit, cap: float) -> None:
        self.model = model
        self.fixture = fixture
        self.scene = scene
        self.fulcrum = np.asarray(fulcrum, dtype=float)
        self.radius = float(radius)
        #: joint torque (N·m or N) per thousandth of the rated torque, per axis
        self.unit = np.asarray(unit, dtype=float)
        self.cap = float(cap)

    def joint_torque(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, dict]:
        """Joint torques (N·m, N on the insertion) at ``q`` moving at ``qd``, and what they came from."""
        placement, jac = self.model.jacobian(q)
        tip = np.asarray(placement.translation, dtype=float)
        linear, angular = jac[:3], jac[3:]
        guide, progress = self.fixture.guidance(tip, linear @ qd)
        limit = self.fixture.wall_limit(progress)
        wall, point, clearance = self.fixture.wall(self.scene, self.fulcrum, tip, self.radius, limit)
        tau = linear.T @ guide
        if wall.any():
            tau = tau + (linear - skew(point - tip) @ angular).T @ wall
        return tau, {"guide": guide, "wall": wall, "clearance": clearance, "progress": progress, "tip": tip}

    def per_mille(self, tau: np.ndarray) -> np.ndarray:
        """Joint torques as the drives' target torques (thousandths of the rated), within the cap."""
        return np.clip(np.rint(tau / self.unit), -self.cap, self.cap).astype(np.int64)


class AssistLoop:
    """One attempt's assistance on a configured gimbal device (see the module); ``level``: the assistance level."""

    def __init__(self, device, settings: AssistSettings, context, level: float, space) -> None:
        self.device = device
        self.settings = settings
        self.master = master = device.master
        self.level = level
        fixture = VirtualFixture(context.tips, context.critical, context.threshold, settings, level)
        gear = device.joints().motors["gear_ratio"]
        unit = master.rated_torque * gear / cia402.PER_MILLE
        self.law = TorqueLaw(device.model, fixture, context.scene, space.fulcrum, space.shaft_radius, unit,
                             settings.torque_cap)  # fmt: skip
        n = len(master.axes)
        self.n = n
        self.active = False  # the drives enabled and the fixture acting
        self.ended: str | None = None  # why the assistance ended (None: it did not)
        self.enabling = True
        self.enabled_cycles = 0
        self.previous_q: np.ndarray | None = None
        self.emcy_seen = len(master.emcy)
        self.controlword = np.zeros(n, dtype=np.int64)
        self.heartbeat_timeout = 1.5 * device.settings.heartbeat_period
        #: (clock time s, reason) when the assistance ended on a fault
        self.events: list[dict] = []
        self.started: float | None = None
        #: the fixture's computing time of each cycle (s)
        self.compute_s: list[float] = []

    def _send(self, controlwords, torques) -> None:
        """The cycle's RPDOs (its SYNC went at the start of the cycle, the source's loop sent it)."""
        try:
            self.master.exchange(controlwords, torques, sync=False)
        except Exception as exc:  # a bus error: the bus is gone (the drives' SYNC watchdogs stop them)
            raise SourceStopped(f"the CAN bus failed: {exc}") from None
        self.controlword = np.asarray(controlwords, dtype=np.int64)

    def fault(self, now: float, feedback, sample_time: float | None) -> str | None:
        """Why the assistance must end now (None: it may go on)."""
        master = self.master
        fresh = np.asarray(feedback.fresh, dtype=bool) & np.asarray(feedback.current, dtype=bool)
        # while enabling, every torque sent is zero: a TPDO not yet in (the first SYNC has no answer before it;
        # a real-time bus's first answers may come late) only delays enabling, which counts fresh cycles alone
        if not fresh.all() and not self.enabling:
            axis = master.axes[int(np.flatnonzero(~fresh)[0])]
            return f"missed TPDO from CAN node {axis.node_id} (joint '{axis.name}')"
        if self.started is None:
            self.started = now
        silent = now - np.maximum(master.last_heartbeat, self.started) > self.heartbeat_timeout
        if silent.any():
            axis = master.axes[int(np.flatnonzero(silent)[0])]
            return f"heartbeat lost from CAN node {axis.node_id} (joint '{axis.name}')"
        if len(master.emcy) > self.emcy_seen:
            _, node, code, _ = master.emcy[self.emcy_seen]
            return f"EMCY 0x{code:04X} from CAN node {node}"
        age = self.device.clock.now() - sample_time if sample_time is not None else 0.0
        if age > self.settings.max_sample_age:
            return f"the sample is {1000 * age:.1f} ms old (max_sample_age)"
        return None

    def cycle(self, now: float, feedback, sample_time: float | None, period: float) -> bool:
        """One SYNC cycle of the assistance (after the feedback of the previous SYNC and this cycle's SYNC): send the
        RPDOs; returns False once the assistance has ended (the caller then goes on observing: SYNC alone)."""
        if self.ended is not None:
            return False
        why = self.fault(now, feedback, sample_time) if sample_time is not None else None
        if why is not None:
            self.stop(now, why)
            return False
        states = feedback.states
        zero = np.zeros(self.n)
        if self.enabling:
            fresh = np.asarray(feedback.fresh, dtype=bool) & np.asarray(feedback.current, dtype=bool)
            enabled = fresh.all() and all(s == cia402.OPERATION_ENABLED for s in states)
            self.enabled_cycles = self.enabled_cycles + 1 if enabled else 0
            if self.enabled_cycles > self.settings.settle_cycles:
                self.enabling = False
                self.active = True
            else:
                words = [cia402.enabling_controlword(s, int(c)) for s, c in zip(states, self.controlword, strict=True)]
                self._send(words, zero)
                self.previous_q = None
                return True
        if any(s != cia402.OPERATION_ENABLED for s in states):
            self.stop(now, "a drive left OPERATION ENABLED: " + ", ".join(states))
            return False
        q = np.asarray(feedback.position, dtype=float) / self.device_cpu
        qd = zero if self.previous_q is None else (q - self.previous_q) / period
        self.previous_q = q
        started = time.perf_counter()
        tau, _ = self.law.joint_torque(q, qd)
        torques = self.law.per_mille(tau)
        self.compute_s.append(time.perf_counter() - started)
        self._send([cia402.CW_ENABLE_OPERATION] * self.n, torques)
        return True

    @property
    def device_cpu(self) -> np.ndarray:
        """Encoder counts per joint unit, per axis."""
        return np.array([a.counts_per_unit for a in self.master.axes], dtype=float)

    def stop(self, now: float, why: str | None) -> None:
        """Zero torque and DISABLE VOLTAGE in the next RPDO: the drives go to SWITCH ON DISABLED at the next SYNC;
        ``why``: the fault that ends the assistance (None: the attempt's end)."""
        if self.ended is None and why is not None:
            self.ended = why
            self.events.append({"t": now, "event": "assist ended", "reason": why})
        self.active = False
        self._send([cia402.CW_DISABLE_VOLTAGE] * self.n, np.zeros(self.n))

    def summary(self) -> dict:
        """What the attempt record keeps of the assistance."""
        s = self.settings
        return {
            "mode": "assist",
            "level": self.level,
            "fade": s.fade,
            "stiffness_n_per_m": self.law.fixture.k,
            "damping_n_s_per_m": self.law.fixture.c,
            "wall_stiffness_n_per_m": s.wall_stiffness,
            "torque_cap_per_mille": s.torque_cap,
            "ended": self.ended,
            "ended_at_s": self.events[0]["t"] if self.events else None,
            "cycles": len(self.compute_s),
            "fixture_median_ms": 1000 * float(np.median(self.compute_s)) if self.compute_s else None,
            "fixture_p99_ms": 1000 * float(np.percentile(self.compute_s, 99)) if self.compute_s else None,
        }


def proficiency_of(context, settings: AssistSettings) -> float | None:
    """The trainee's proficiency (m) from the trainee record (None: no trainee, record or attempt)."""
    record = getattr(context, "record", None)
    trainee = getattr(context, "trainee", None)
    task = getattr(context, "task", None)
    if record is None or trainee is None or task is None or settings.fade == "none":
        return None
    from surgiplan.guidance.record import RecordError, TraineeRecord

    if not Path(record).is_file():
        return None
    try:
        with TraineeRecord(record) as r:
            return float(r.proficiency(trainee, task, last=settings.last).d_thresh)
    except RecordError:
        return None


__all__ = ["AssistLoop", "AssistSettings", "TorqueLaw", "assistance_level", "proficiency_of", "skew"]
