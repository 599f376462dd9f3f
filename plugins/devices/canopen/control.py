"""The control loop: cyclic synchronous position at the control rate, supervised.

Every cycle k, at ``t_k = t_0 + k T``:

1. read the TPDOs that answered SYNC k-1 (positions sampled at ``t_{k-1}``;
   a TPDO that arrives after SYNC k was sent is late and not used for
   tracking);
2. supervise: EMCY received, heartbeats older than 1.5 heartbeat periods or
   reporting another NMT state than operational, an axis without TPDO for
   ``pdo_timeout_cycles`` cycles, a drive that left OPERATION ENABLED;
3. send SYNC k and one RPDO per axis.

Targets lead by two periods: the RPDO sent in cycle k is applied at SYNC
k+1 and reached, by the drive's linear interpolation, at SYNC k+2. So the
target sent in cycle k is the trajectory sample for ``t_{k+2}``, and the
drive's command at every SYNC equals the trajectory there: the tracking
error measured at the samples is the servo's, not the pipeline's latency.
Trajectory time 0 is SYNC 1.

On the first fault every axis is sent the quick-stop command (controlword
0x02) in every later cycle (a lost RPDO is repeated by the next); the loop
runs on until every axis stands still, then reports ``stopped`` with the
faults: what, when (s after the trajectory start), which node, what the
device did. A bus error (the master cannot send) leaves the drives to their
own SYNC watchdog, which quick-stops them.

In real time a loop that wakes more than a period late (the process was
descheduled) skips the missed cycles (``missed_cycles``) instead of sending a
burst of SYNCs; between trajectories a thread keeps SYNC and the hold
targets going, supervised, so that the drives' watchdogs stay quiet.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import can
import numpy as np

from . import cia402
from .bus import BusError
from .clock import Clock, set_realtime_priority
from .master import DriveMaster, emcy_description
from .realtime import realtime_section


@dataclass
class Supervision:
    heartbeat_timeout: float
    pdo_timeout_cycles: int = 5
    #: longest wait for the axes to stand still after a quick stop (s)
    stop_timeout: float = 1.0
    #: longest wait after the last trajectory sample for the final position (s)
    settle_time: float = 0.5
    #: per joint (units): "arrived" and "standing still"
    settle_tolerance: np.ndarray | None = None


@dataclass
class ExecutionLog:
    """What the loop saw: measurements at the SYNC times, references, faults, and how it ended."""

    #: time of each measurement, s after the trajectory start (SYNC 1)
    t: np.ndarray
    measured: np.ndarray
    reference: np.ndarray
    status: str
    reason: str
    cycles: int
    faults: list[dict[str, Any]]
    #: clock times (s) of the first and last cycle
    start: float
    end: float
    #: per measurement: every axis reported, while tracking (before any fault)
    tracking: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    #: cycles in which some axis' TPDO was missing
    samples_missing: int = 0
    #: wall time (s) each cycle's work took (real time only)
    work: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: actual cycle start times (s)
    wakeups: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: how late each cycle started after its scheduled time (s): the loop's jitter (real time only)
    lateness: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: process CPU time (s, every thread) the loop used
    cpu_s: float = 0.0


class Controller:
    """Runs cycles on a :class:`DriveMaster` (see the module docstring)."""

    def __init__(
        self, master: DriveMaster, clock: Clock, supervision: Supervision, priority: int | None = None
    ) -> None:
        self.master = master
        #: SCHED_FIFO priority of the loop's threads (real time), None: ordinary scheduling
        self.priority = priority
        self.clock = clock
        self.period = master.period
        self.supervision = supervision
        self.axes = master.axes
        self.cpu = np.array([a.counts_per_unit for a in master.axes])
        self.n = len(master.axes)
        self._next = None  # clock time of the next cycle
        #: real time: cycles skipped because the loop woke more than a period late
        self.missed_cycles = 0
        #: real time: (clock time the cycle was due, how late the loop woke (s), cycles skipped), per lapse
        self.missed_log: list[tuple[float, float, int]] = []
        self.controlword = np.zeros(self.n, dtype=np.int64)
        self.hold = np.zeros(self.n, dtype=np.int64)  # counts
        self._emcy_seen = 0
        self._missing = np.zeros(self.n, dtype=np.int64)
        # the supervision's scratch arrays, made once
        self._age = np.zeros(self.n)
        self._flags = np.zeros(self.n, dtype=bool)
        self._words = np.zeros(self.n, dtype=np.int64)
        self._hold_thread: threading.Thread | None = None
        self._hold_stop = threading.Event()
        #: faults seen while holding (real time), reported by the next execution
        self.pending_faults: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ one cycle
    def _wait(self) -> float:
        if self._next is None:
            self._next = self.clock.now()
        elif self.clock.realtime:
            late = self.clock.now() - self._next
            if late > self.period:
                # more than a period late (the process was descheduled, or computing between
                # trajectories): skip the missed cycles instead of sending a burst of SYNCs the
                # drives cannot answer in between
                missed = int(late // self.period)
                self.missed_log.append((self._next, late, missed))
                self._next += missed * self.period
                self.missed_cycles += missed
        self.clock.sleep_until(self._next)
        now = self._next
        self._next += self.period
        return now

    def _send(self, controlwords, targets) -> str | None:
        try:
            self.master.exchange(controlwords, targets)
        except (can.CanError, OSError) as exc:
            return str(exc)
        np.copyto(self.controlword, controlwords)
        return None

    # ------------------------------------------------------------------ supervision
    def _supervise(self, now: float, feedback, origin: float, check_states: bool) -> list[dict[str, Any]]:
        """The faults this cycle reveals (none, usually: then nothing but the checks is done, into arrays made
        once)."""
        found = []
        master = self.master
        if len(master.emcy) > self._emcy_seen:
            for t, node, code, _register in master.emcy_since(self._emcy_seen):
                self._emcy_seen += 1
                if code & 0xFF00 == 0:
                    continue  # error reset
                found.append(
                    {
                        "kind": "emcy",
                        "node": node,
                        "t_s": t - origin,
                        "code": f"0x{code:04X}",
                        "detail": emcy_description(code),
                    }
                )
        age = np.subtract(now, master.last_heartbeat, out=self._age)
        if age.max() > self.supervision.heartbeat_timeout:
            for i in np.flatnonzero(age > self.supervision.heartbeat_timeout):
                found.append(
                    {
                        "kind": "heartbeat_timeout",
                        "node": self.axes[i].node_id,
                        "t_s": now - origin,
                        "last_heartbeat_s": float(master.last_heartbeat[i] - origin),
                        "detail": f"no heartbeat for {age[i] * 1000:.0f} ms "
                        f"(timeout {self.supervision.heartbeat_timeout * 1000:.0f} ms)",
                    }
                )
        if np.not_equal(master.heartbeat_state, cia402.NMT_OPERATIONAL, out=self._flags).any():
            for i in np.flatnonzero(self._flags):
                found.append(
                    {
                        "kind": "nmt_state",
                        "node": self.axes[i].node_id,
                        "t_s": now - origin,
                        "detail": f"heartbeat reports NMT state {int(master.heartbeat_state[i])}, not operational",
                    }
                )
        self._missing += 1
        self._missing[feedback.fresh] = 0
        if self._missing.max() >= self.supervision.pdo_timeout_cycles:
            for i in np.flatnonzero(self._missing >= self.supervision.pdo_timeout_cycles):
                found.append(
                    {
                        "kind": "pdo_timeout",
                        "node": self.axes[i].node_id,
                        "t_s": now - origin,
                        "detail": f"no TPDO for {int(self._missing[i])} cycles",
                    }
                )
        if check_states:
            mask, value = cia402.OPERATION_ENABLED_MASK
            np.bitwise_and(feedback.statusword, mask, out=self._words)
            np.not_equal(self._words, value, out=self._flags)
            self._flags &= feedback.fresh
            if self._flags.any():
                for i in np.flatnonzero(self._flags):
                    state = cia402.state_of(int(feedback.statusword[i]))
                    node = self.axes[i].node_id
                    found.append({"kind": "drive_state", "node": node, "t_s": now - origin, "detail": state})
        return found

    # ------------------------------------------------------------------ enabling
    def enable(self, timeout: float = 1.0) -> None:
        """Bring every axis to OPERATION ENABLED (fault reset first where needed), holding position."""
        self.stop_holding()
        feedback = self.master.feedback()
        self.hold = feedback.position.copy()
        deadline = self.clock.now() + timeout
        enabled_cycles = 0
        answered = np.zeros(self.n, dtype=bool)
        silent = np.full(self.n, self.supervision.pdo_timeout_cycles)  # cycles since each axis' last TPDO
        while True:
            self._wait()
            feedback = self.master.feedback()
            states = feedback.states
            answered |= feedback.fresh
            silent = np.where(feedback.fresh, 0, silent + 1)
            # only a recent statusword counts (a silent drive's last one is stale); in real time an
            # answer may come a cycle late
            recent = silent < min(3, self.supervision.pdo_timeout_cycles)
            enabled = recent & np.array([s == cia402.OPERATION_ENABLED for s in states])
            if np.all(enabled):
                enabled_cycles += 1
                if enabled_cycles >= 2:
                    break
            else:
                enabled_cycles = 0
            not_enabled = ~enabled
            # while not enabled, hold targets follow the actual positions (no jump when enabling)
            self.hold = np.where(not_enabled, feedback.position, self.hold)
            words = [cia402.enabling_controlword(s, int(c)) for s, c in zip(states, self.controlword, strict=True)]
            error = self._send(words, self.hold)
            if error is not None:
                raise BusError(f"CAN bus error on {self.master.description} while enabling the drives: {error}")
            if self.clock.now() > deadline:
                stuck = [
                    f"node {a.node_id} ('{a.name}') " + (f"is {s}" if seen else "does not answer SYNC (no TPDO)")
                    for a, s, seen, ok in zip(self.axes, states, answered, enabled, strict=True)
                    if not ok
                ]
                raise BusError(f"drives did not reach OPERATION ENABLED within {timeout:g} s: {'; '.join(stuck)}")
        self._missing[:] = 0
        self._emcy_seen = len(self.master.emcy)
        self.pending_faults = []  # enabling (a fault reset) acknowledges what happened while holding

    def disable(self, timeout: float = 0.5) -> None:
        """Disable operation (controlword 0x06: READY TO SWITCH ON); the brakes hold the axes."""
        self.stop_holding()
        deadline = self.clock.now() + timeout
        while True:
            self._wait()
            feedback = self.master.feedback()
            if all(s not in (cia402.OPERATION_ENABLED, cia402.QUICK_STOP_ACTIVE) for s in feedback.states):
                return
            if self._send([cia402.CW_SHUTDOWN] * self.n, self.hold) is not None or self.clock.now() > deadline:
                return

    # ------------------------------------------------------------------ holding (real time)
    def start_holding(self) -> None:
        """Real time: keep SYNC and the hold targets going in a thread while no trajectory runs."""
        if not self.clock.realtime or self._hold_thread is not None:
            return
        self._hold_stop.clear()
        self._hold_thread = threading.Thread(target=self._holding, name="surgiplan-hold", daemon=True)
        self._hold_thread.start()
        set_realtime_priority(self.priority, self._hold_thread.native_id)

    def stop_holding(self) -> None:
        if self._hold_thread is not None:
            self._hold_stop.set()
            self._hold_thread.join(timeout=2.0)
            self._hold_thread = None

    def _holding(self) -> None:
        self.clock.precise()
        while not self._hold_stop.is_set():
            now = self._wait()
            feedback = self.master.feedback()
            seen = {(f["kind"], f.get("node")) for f in self.pending_faults}
            for fault in self._supervise(now, feedback, 0.0, check_states=False):
                if (fault["kind"], fault.get("node")) not in seen:
                    fault["action"] = "quick stop of every axis (while holding)"
                    self.pending_faults.append(fault)
                    seen.add((fault["kind"], fault.get("node")))
            if self.pending_faults:
                # a fault while holding: quick-stop every axis; the next trajectory will not start
                words = np.full(self.n, cia402.CW_QUICK_STOP)
            else:
                words = np.where(
                    self.controlword == cia402.CW_ENABLE_OPERATION, cia402.CW_ENABLE_OPERATION, self.controlword
                )
            if self._send(words, self.hold) is not None:
                return

    # ------------------------------------------------------------------ a trajectory
    def run(self, trajectory: np.ndarray, on_start=None, collect_garbage: bool = False) -> ExecutionLog:
        """Execute joint samples (m, nq) (units, one per period) from the current hold position.

        ``on_start(t0)`` is called with the clock time of the first cycle (arms injected faults).
        In real time Python's cyclic garbage collector is off during the loop (``collect_garbage``
        False): a full collection of a large heap stops every thread for tens of milliseconds, which
        is a run of missed cycles (see benchmarks/bench_devices.py); a cycle allocates no container
        (its feedback, position and log rows go into arrays made before the first cycle, its frames are
        rewritten in place), and what else it frees goes by reference counting. The GIL's switch
        interval is :data:`surgiplan.scheduling.SWITCH_INTERVAL` meanwhile. The process CPU time the loop used (all
        threads) is in ``ExecutionLog.cpu_s``.
        """
        self.stop_holding()
        cpu = time.process_time()
        # a thread that runs Python keeps the GIL up to the switch interval (5 ms) while the loop, awake, waits
        # for it: at most SWITCH_INTERVAL in the section
        with realtime_section(self.clock, self.priority, pause_collector=not collect_garbage):
            log = self._run(trajectory, on_start)
        log.cpu_s = time.process_time() - cpu
        return log

    def _run(self, trajectory: np.ndarray, on_start) -> ExecutionLog:
        if self.clock.realtime:
            # the first cycle is now: the hold loop's schedule may have lapsed while the trajectory was
            # timed and the axes placed, which skips no cycle of the trajectory (missed_cycles counts those)
            self._next = None
        trajectory = np.atleast_2d(np.asarray(trajectory, dtype=float))
        targets = np.round(trajectory * self.cpu).astype(np.int64)
        m = len(trajectory)
        sup = self.supervision
        tolerance = sup.settle_tolerance if sup.settle_tolerance is not None else 3.0 / self.cpu
        nq = trajectory.shape[1]
        # every row the loop records, in arrays made now (grown, rarely, if a stop or settling runs long)
        log = _Rows(m + int((sup.settle_time + sup.stop_timeout) / self.period) + 16, nq)
        feedback = self.master.empty_feedback()
        position = np.zeros(self.n)
        enable_words = np.full(self.n, cia402.CW_ENABLE_OPERATION, dtype=np.int64)
        stop_words = np.full(self.n, cia402.CW_QUICK_STOP, dtype=np.int64)
        faults = list(self.pending_faults)
        self.pending_faults = []
        phase = "stopping" if faults else "run"
        reason = ""
        if faults:  # seen while holding between trajectories: do not start
            first = faults[0]
            reason = f"{first['kind'].replace('_', ' ')} on node {first.get('node')} while holding: {first['detail']}"
        settle_start = stop_start = None
        all_stopped_at = None
        still = 0
        last_position = None
        missing_cycles = 0
        k = 0
        t0 = origin = None
        status = "completed"
        bus_error = None
        while True:
            now = self._wait()
            started = self.clock.now()
            if t0 is None:
                t0, origin = now, now + self.period
                if on_start is not None:
                    on_start(t0)
                self._missing[:] = 0
            log.cycle(k, started, started - now)
            self.master.feedback(into=feedback)
            np.divide(feedback.position, self.cpu, out=position)
            if k >= 1:
                # every cycle is recorded (a missing TPDO repeats the axis' last position); the
                # tracking error is taken over the cycles where every axis reported, before any fault
                complete = bool(feedback.current.all())
                # the sample the drives' command equals at that SYNC; none once quick-stopping
                stopping_then = phase == "stopping" and stop_start is not None and now - self.period > stop_start
                log.record(
                    now - self.period - origin,
                    position,
                    None if stopping_then else trajectory[min(max(k - 2, 0), m - 1)],
                    complete and phase in ("run", "settle"),
                )
                missing_cycles += not complete
            new = self._supervise(now, feedback, origin, check_states=phase in ("run", "settle") and k >= 2)
            if new:
                seen = {(f["kind"], f["node"]) for f in faults if "node" in f}
                new = [f for f in new if (f["kind"], f.get("node")) not in seen]
            if new and phase in ("run", "settle"):
                phase, stop_start = "stopping", now
                first = new[0]
                reason = (
                    f"{first['kind'].replace('_', ' ')} on node {first['node']}: {first['detail']}; "
                    "every axis quick-stopped"
                )
                new[0]["action"] = "quick stop of every axis"
                for f in new[1:]:
                    f["action"] = "already stopping"
            elif new:
                for f in new:
                    f["action"] = "already stopping"
            faults += new
            if phase == "stopping" and stop_start is None:
                stop_start = now

            if phase == "run":
                words = enable_words
                send = targets[min(k + 1, m - 1)]
                if k - 2 >= m - 1:
                    phase, settle_start = "settle", now
            if phase == "settle":
                words = enable_words
                send = targets[-1]
                if feedback.current.all() and np.all(np.abs(position - trajectory[-1]) <= tolerance):
                    break
                if now - settle_start > sup.settle_time:
                    status = "stopped"
                    error = np.abs(position - trajectory[-1])
                    worst = int(np.argmax(error / tolerance))
                    reason = (
                        f"did not reach the final position within {sup.settle_time:g} s: joint "
                        f"'{self.axes[worst].name}' is {error[worst]:.3g} off"
                    )
                    faults.append({"kind": "settle_timeout", "t_s": now - origin, "detail": reason})
                    break
            if phase == "stopping":
                status = "stopped"
                words = stop_words
                send = feedback.position
                # axes whose TPDOs stopped (a dead node) cannot report: judge the others
                known = self._missing < sup.pdo_timeout_cycles
                if all_stopped_at is None and np.all(feedback.fresh[known]):
                    states = feedback.states
                    if all(states[i] != cia402.OPERATION_ENABLED for i in np.flatnonzero(known)):
                        all_stopped_at = now - self.period - origin
                        if faults:
                            faults[0]["all_axes_quick_stopped_s"] = all_stopped_at
                if last_position is not None and np.all((np.abs(position - last_position) <= tolerance)[known]):
                    still += 1
                else:
                    still = 0
                last_position = position.copy()
                if (all_stopped_at is not None and still >= 3) or now - stop_start > sup.stop_timeout:
                    if faults:
                        faults[0]["standstill_s"] = now - origin
                    break
            error = self._send(words, send)
            log.work[k] = self.clock.now() - started
            if error is not None:
                bus_error = error
                faults.append(
                    {
                        "kind": "bus_error",
                        "t_s": now - origin,
                        "detail": error,
                        "action": "cannot send: the drives' SYNC watchdogs stop them",
                    }
                )
                status, reason = "stopped", f"CAN bus error: {error}"
                break
            np.copyto(self.hold, send)
            k += 1
        if bus_error is not None:
            # nothing can be sent or trusted; let the drives' own watchdogs act before reporting
            self.clock.sleep(0.2)
        end = self.clock.now()
        if status == "completed":
            self.start_holding()
        rows, cycles = log.rows, min(k + 1, len(log.wakeups))
        return ExecutionLog(
            log.t[:rows].copy(),
            log.measured[:rows].copy(),
            log.reference[:rows].copy(),
            status,
            reason,
            k + 1,
            faults,
            t0,
            end,
            log.tracking[:rows].copy(),
            missing_cycles,
            log.work[:cycles].copy(),
            log.wakeups[:cycles].copy(),
            log.lateness[:cycles].copy(),
        )


class _Rows:
    """The control loop's record in arrays made before its first cycle: per cycle its start and lateness (and
    the work, written by the loop), per measurement (cycle 1 on) its time, positions, reference and whether
    every axis answered while tracking. Grows (doubling) only if a run outlasts the room it was given."""

    def __init__(self, size: int, nq: int) -> None:
        self.rows = 0
        self.wakeups = np.zeros(size)
        self.lateness = np.zeros(size)
        self.work = np.zeros(size)
        self.t = np.zeros(size)
        self.measured = np.zeros((size, nq))
        self.reference = np.zeros((size, nq))
        self.tracking = np.zeros(size, dtype=bool)

    def _grow(self) -> None:
        for name in ("wakeups", "lateness", "work", "t", "measured", "reference", "tracking"):
            old = getattr(self, name)
            new = np.zeros((2 * len(old), *old.shape[1:]), dtype=old.dtype)
            new[: len(old)] = old
            setattr(self, name, new)

    def cycle(self, k: int, started: float, late: float) -> None:
        if k >= len(self.wakeups):
            self._grow()
        self.wakeups[k] = started
        self.lateness[k] = late

    def record(self, t: float, position: np.ndarray, reference: np.ndarray | None, tracking: bool) -> None:
        r = self.rows
        if r >= len(self.t):
            self._grow()
        self.t[r] = t
        self.measured[r] = position
        if reference is None:
            self.reference[r] = np.nan
        else:
            self.reference[r] = reference
        self.tracking[r] = tracking
        self.rows = r + 1
