"""bench_devices.py, parts 1-3 and 5: the real-time CiA 402 loop with the gimbal's 4 drives, measured.

The control loop at each rate with the drives in another process or in a thread (:func:`control_loop`), the
machine's own floor for a 1 kHz loop (:func:`scheduling_floor`; measured by rt-tests' cyclictest too, in
``cyclictest.py``), the cost of a full garbage collection in the
loop (:func:`garbage_collection`), the bus's capacity for the cyclic frames (:func:`bus_ceiling`) and the
simulated clock's speed (:func:`simulation_speed`). Imported by bench_devices.py, which puts benchmarks/ and
tests/ on the import path (``common``, ``devices_support``).
"""

from __future__ import annotations

import contextlib
import gc
import os
import socket
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
from common import steal_ticks, table
from devices_support import FULCRUM, GAP_TIPS, active, gimbal_path, gimbal_space
from devices_table import DRIVES_PRIORITY, PRIORITY, SEPARATE, SEPARATE_RT, THREAD
from schedtrace import SchedTrace, benchmark_threads, slowest_during
from surgiplan import load_scene
from surgiplan.devices import Trajectory
from surgiplan.errors import SurgiplanError
from surgiplan.plugins.devices.canopen.bus import frame_bits, worst_case_bits
from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice
from witness import Witness

ROOT = Path(__file__).resolve().parent.parent


def percentile(values, q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if len(values) else float("nan")


@contextlib.contextmanager
def drives_process(initial, priority: int | None = None, extra=()):
    """Four simulated drives in another process on the loopback bus (127.0.0.1), ``extra`` arguments to
    ``surgiplan-sim-drives`` (e.g. ``--hand``); yields the bus settings and the process id."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    command = [sys.executable, "-m", "surgiplan.plugins.devices.canopen.sim.process", "--device", "cast_gimbal"]
    command += ["--interface", "loopback", "--channel", str(port), "--option", "hub=host"]
    command += ["--sync-timeout", "0.2", "--initial", *map(str, initial)]
    if priority is not None:
        command += ["--realtime-priority", str(priority)]
    command += list(extra)
    process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    try:
        if process.stdout.readline().strip() != "ready":
            raise RuntimeError("the drive simulator did not start")
        yield {"interface": "loopback", "channel": str(port), "options": {"hub": "join"}}, process.pid
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:  # a starved or stuck simulator: the benchmark goes on without it
            process.kill()
            process.wait(timeout=10)


def answer_latencies(frames, node_ids) -> np.ndarray:
    """Per SYNC in a master's frame log (time s, COB-ID, data), how long until the master had every drive's
    TPDO1 answering it (s): the drives' answer as the loop sees it (their work, both hosts' scheduling, the hub).
    Each drive answers every SYNC with one TPDO1 (synchronous, OPERATIONAL), so the k-th of a node's answers
    after the log's first SYNC answers the k-th SYNC."""
    syncs = np.array([t for t, cob, _ in frames if cob == 0x080])
    if not len(syncs):
        return np.zeros(0)
    answers = [np.array([t for t, cob, _ in frames if cob == 0x180 + node and t >= syncs[0]]) for node in node_ids]
    count = min(len(syncs), *(len(a) for a in answers))
    if count == 0:
        return np.zeros(0)
    return np.max([a[:count] for a in answers], axis=0) - syncs[:count]


def latency_summary(latencies: np.ndarray, period: float) -> dict:
    """p50 / p99 / max of :func:`answer_latencies` (ms), and how many answers took longer than a period."""
    if not len(latencies):
        return {}
    return {
        "sync_to_tpdos_p50_ms": round(percentile(latencies, 50) * 1e3, 3),
        "sync_to_tpdos_p99_ms": round(percentile(latencies, 99) * 1e3, 3),
        "sync_to_tpdos_max_ms": round(float(latencies.max()) * 1e3, 3),
        "answers_later_than_a_period": int(np.sum(latencies > period)),
    }


def fifo_allowed() -> bool:
    """Whether this process may run threads under SCHED_FIFO (Linux, CAP_SYS_NICE)."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        return False
    return True


def process_cpu(pid) -> float:
    """CPU seconds (user + system) a process has used so far; 0 without a process."""
    if pid is None:
        return 0.0
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def loop_settings(rate: float) -> dict:
    # supervision generous enough for a shared machine: what is measured is the loop, not a stop
    return {
        "fulcrum": FULCRUM,
        "control_rate": rate,
        "heartbeat_period": 0.5,
        # configuration and fault resets by SDO happen outside the loop; a loaded machine may delay the drives'
        # process past the default 0.2 s
        "sdo_timeout": 1.0,
        "pdo_timeout_cycles": max(10, int(rate) // 20),
        "outputs": False,
    }


@contextlib.contextmanager
def gimbal(mode: str, rate: float, start):
    """An active gimbal at ``rate`` with its drives as ``mode`` says; yields (device, drives' pid or None)."""
    settings = loop_settings(rate)
    if mode in (SEPARATE, SEPARATE_RT):
        priority = PRIORITY if mode == SEPARATE_RT else None
        # the drives stand for other hardware (in a real cell they have processors of their own): under SCHED_FIFO
        # wherever the system allows it, also when the master runs at ordinary priority, so that what is measured
        # is the master's loop, not a simulator starved by other jobs (SDO answers later than 1 s, TPDOs missing
        # for 25 cycles under load 11); below the master's priority, so that they cannot hold a core its loop needs
        context = drives_process(start, DRIVES_PRIORITY if fifo_allowed() else None)
        settings["realtime_priority"] = priority
    else:
        context = contextlib.nullcontext((None, None))
        settings |= {"clock": "realtime", "simulation": {"initial": list(map(float, start)), "sync_timeout": 0.2}}
    with context as (bus, pid):
        if bus is not None:
            settings["bus"] = bus
        scene = load_scene(ROOT / "configs" / "scenes" / "block_world.yaml")
        with active(CastGimbalDevice, settings, scene, ROOT / "out") as device:
            yield device, pid


def long_path(path: np.ndarray, seconds: float, one_way: float) -> np.ndarray:
    """The gap path there and back (and there...) until it takes at least ``seconds`` (one way: ``one_way``)."""
    legs = max(1, int(np.ceil(seconds / one_way)))
    pieces = [path]
    for leg in range(1, legs):
        pieces.append((path[::-1] if leg % 2 else path)[1:])
    return np.concatenate(pieces)


def one_way_duration(scene) -> float:
    """How long the gimbal takes for the gap path once (the simulated clock: no waiting)."""
    space = gimbal_space(scene)
    path = gimbal_path(space, GAP_TIPS)
    with active(CastGimbalDevice, {"fulcrum": FULCRUM, "outputs": False}, scene, ROOT / "out") as device:
        return float(device.execute(Trajectory(path, space, "bench")).metrics["duration_s"])


def release(stack: contextlib.ExitStack) -> None:
    """Close a device and its drives; one that fails to stop cleanly (a starved drives process) is left behind."""
    try:
        stack.close()
    except (SurgiplanError, RuntimeError) as exc:
        print(f"  (closing the device: {exc})", flush=True)


def control_loop(scene, rates, runs: int, mode: str, seconds: float = 10.0) -> list[dict]:
    """``runs`` runs of at least ``seconds`` each (the gap path there and back) per rate."""
    space = gimbal_space(scene)
    path = long_path(gimbal_path(space, GAP_TIPS), seconds, one_way_duration(scene))
    rows = []
    for rate in rates:
        periods, work, missed, missing, completed, cycles, load, worst = [], [], 0, 0, 0, 0, [], []
        answers: list[np.ndarray] = []  # per run: SYNC -> every TPDO at the master (s)
        lateness, missed_per_run, durations = [], [], []
        stolen = steal_ticks()
        loop_cpu = drives_cpu = execute_cpu = 0.0
        syncs = 0
        lapses = []
        lapses_stalled = 0  # missed cycles while the stall witness was late too
        lapse_wakeups: list[list] = []  # per missed cycle: its lateness, the slowest wake-up then, its delivery (ms)
        traced = False  # whether the scheduler trace ran (root and tracefs)
        witness_worst, witness_late = 0.0, 0
        witness_policy = None
        error = ""
        failures: list[str] = []
        clean = 0
        stack = contextlib.ExitStack()
        device = pid = None
        for k in range(runs):
            try:
                if device is None:  # the first run, or the last one left the drives where a reset could not help
                    device, pid = stack.enter_context(gimbal(mode, rate, path[0]))
                before_cpu, before_frames = process_cpu(pid), len(device.bus.frames)
                before_execute = time.process_time()
                before_lapses = len(device.controller.missed_log)
                threads = benchmark_threads(pid)
                with Witness() as witness, SchedTrace(tids=threads) as trace:
                    report = device.execute(Trajectory(path[::-1] if k % 2 else path, space, "bench"))
                traced |= trace.available
                witness_worst = max(witness_worst, witness.worst)
                witness_policy = witness.policy
                witness_late += witness.summary()["witness_late_over_2ms"]
                execute_cpu += time.process_time() - before_execute
                drives_cpu += process_cpu(pid) - before_cpu
                run_frames = device.bus.frames[before_frames:]
                syncs += sum(1 for f in run_frames if f[1] == 0x080)
                answers.append(answer_latencies(run_frames, [a.node_id for a in device.master.axes]))
                if report.metrics.get("refused"):  # e.g. a fault while holding before it: a run that did not run
                    error = report.message
                    print(f"  {mode} {rate} Hz run {k}: refused: {report.message}", flush=True)
                    failures.append(f"run {k + 1}: refused: {report.message}")
                    device.reset_faults()
                    continue
                log = device.last_log
                loop_cpu += log.cpu_s
                periods += np.diff(log.wakeups).tolist()
                work += log.work.tolist()
                lateness += log.lateness.tolist()
                durations.append(log.end - log.start)
                missed_per_run.append(report.metrics.get("missed_cycles", 0))
                missed += report.metrics.get("missed_cycles", 0)
                missing += report.metrics.get("samples_missing", 0)
                cycles += report.metrics["cycles"]
                completed += report.status == "completed"
                clean += report.status == "completed" and not report.metrics.get("missed_cycles", 0)
                load.append(report.metrics["bus_load_percent"])
                worst.append(report.metrics["bus_load_worst_case_percent"])
                new = [m for m in device.controller.missed_log[before_lapses:] if log.start <= m[0] <= log.end]
                lapses += [round(late * 1e3, 1) for due, late, _ in new]
                origin = device.controller.clock.origin  # the clock's time 0 on perf_counter
                # a witness late within the cycle's lateness either side of its due time
                lapses_stalled += sum(
                    1 for due, late, _ in new if witness.late_during(origin + due - late, origin + due + late) > 0
                )
                # the kernel's account of each missed cycle: the slowest wake-up of the two processes' threads then
                # (and its delivery part, the host's: see schedtrace)
                if trace.available and new:
                    rows_ = trace.wakeups(threads)
                    for due, late, _ in new:
                        wait, tid, delivery = slowest_during(rows_, origin + due - late, origin + due + late)
                        lapse_wakeups.append([round(late * 1e3, 2), round(wait * 1e3, 3), round(delivery * 1e3, 3),
                                              threads.get(tid)])  # fmt: skip
                if report.status != "completed":
                    print(f"  {mode} {rate} Hz run {k}: {report.message}", flush=True)
                    failures.append(f"run {k + 1}: {report.message}")
                    device.reset_faults()
            except (SurgiplanError, RuntimeError) as exc:
                # on a loaded machine the drives may not start, or not answer a fault reset, in time: the run
                # counts as not completed, and the next one starts with a new device and drives
                print(f"  {mode} {rate} Hz run {k}: {exc}", flush=True)
                failures.append(f"run {k + 1}: {exc}")
                error = str(exc)
                release(stack)
                stack = contextlib.ExitStack()
                device = pid = None
        release(stack)
        period = 1.0 / rate
        row = {
            "drives": mode,
            "rate_hz": rate,
            "runs_completed": f"{completed}/{runs}",
            "cycles": cycles,
            "period_p50_ms": round(percentile(periods, 50) * 1e3, 3),
            "period_p99_ms": round(percentile(periods, 99) * 1e3, 3),
            "period_max_ms": round(max(periods) * 1e3, 2) if periods else None,
            "work_p50_ms": round(percentile(work, 50) * 1e3, 3),
            "work_p99_ms": round(percentile(work, 99) * 1e3, 3),
            "missed_cycles": missed,
            "missed_per_run": missed_per_run,
            # completed with no missed cycle (a run that stopped on a fault is not one)
            "runs_without_missed": f"{clean}/{runs}",
            "run_seconds_median": round(statistics.median(durations), 2) if durations else None,
            # the loop's jitter: how late each cycle started after its scheduled time
            "jitter_p50_ms": round(percentile(lateness, 50) * 1e3, 4),
            "jitter_p99_ms": round(percentile(lateness, 99) * 1e3, 4),
            "jitter_max_ms": round(max(lateness) * 1e3, 3) if lateness else None,
            "missed_lapses_late_ms": lapses[:20],
            "steal_ticks": steal_ticks() - stolen,
            "missed_during_machine_stalls": lapses_stalled,
            "missed_slowest_wakeup": lapse_wakeups[:20],
            "sched_trace": "ftrace sched_waking/wakeup/switch" if traced else "not available",
            "witness_late_over_2ms": witness_late,
            "witness_late_max_ms": round(witness_worst * 1e3, 3),
            "witness": witness_policy,
            "cycles_missing_a_tpdo": missing,
            "bus_load_percent": round(statistics.median(load), 2) if load else None,
            "bus_load_worst_case_percent": round(statistics.median(worst), 2) if worst else None,
            # CPU per cycle of every thread of the master's process during the loop: what a core must give it
            "master_cpu_per_cycle_ms": round(loop_cpu / cycles * 1e3, 3) if cycles else None,
            # as the earlier results measured it: the whole execute (inverse kinematics, timing, certification,
            # the report) over the cycles
            "master_cpu_per_cycle_with_preparation_ms": round(execute_cpu / cycles * 1e3, 3) if cycles else None,
            "drives_cpu_per_sync_ms": round(drives_cpu / syncs * 1e3, 3) if syncs and mode != THREAD else None,
            **latency_summary(np.concatenate(answers) if answers else np.zeros(0), 1.0 / rate),
            "drives_priority": (f"SCHED_FIFO {DRIVES_PRIORITY}" if fifo_allowed() else "ordinary")
            if mode != THREAD
            else None,
            "error": error,
            "failures": failures[:10],
        }
        row["held"] = bool(completed == runs and missed == 0 and periods and row["period_p99_ms"] <= 1.1 * period * 1e3)
        rows.append(row)
        columns = ["rate_hz", "runs_completed", "runs_without_missed", "jitter_p99_ms", "jitter_max_ms", "held"]
        columns += ["master_cpu_per_cycle_ms", "drives_cpu_per_sync_ms", "bus_load_percent"]
        print(table([row], columns), flush=True)
    return rows


def scheduling_floor(seconds: float) -> list[dict]:
    """What the machine gives any 1 kHz loop: a bare single-thread Python loop sleeping to each 1 ms deadline
    (1 us timer slack), no CAN, no GIL contention; with ordinary scheduling (the kernel's default slice, then the
    short slice the control loop's threads ask for at ordinary priority) and under SCHED_FIFO; the CPU wake-up
    latency asked for as the control loop asks for it (:func:`surgiplan.scheduling.cpu_latency_request`)."""
    from surgiplan.plugins.devices.canopen.clock import (
        LOOP_SLICE,
        RealTimeClock,
        restore_priority,
        set_realtime_priority,
    )
    from surgiplan.scheduling import cpu_latency_request

    rows = []
    short = f"ordinary, {LOOP_SLICE * 1e3:g} ms slice"
    with cpu_latency_request() as held:  # as the control loop asks for it
        for policy in ("ordinary", short, f"SCHED_FIFO {PRIORITY}"):
            try:
                previous = (
                    None if policy == "ordinary" else set_realtime_priority(None if policy == short else PRIORITY)
                )
            except OSError as exc:
                rows.append({"loop": f"bare 1 kHz sleep loop, {policy}", "error": str(exc)})
                continue
            RealTimeClock.precise()
            wakes, lapses = [], []
            stolen = steal_ticks()
            try:
                start = time.perf_counter()
                deadline = start
                for _ in range(int(seconds * 1000)):
                    deadline += 0.001
                    remaining = deadline - time.perf_counter()
                    if remaining > 0:
                        time.sleep(remaining)
                    woke = time.perf_counter()
                    if woke - deadline > 0.001:  # more than a period late: a missed cycle, skipped as the loop does
                        lapses.append(round((woke - deadline) * 1e3, 1))
                        deadline = woke
                    wakes.append(woke)
            finally:
                restore_priority(previous)
            periods = np.diff(wakes) * 1e3
            rows.append(
                {
                    "loop": f"bare 1 kHz sleep loop, {policy}",
                    "seconds": seconds,
                    "period_p50_ms": round(percentile(periods, 50), 3),
                    "period_p99_ms": round(percentile(periods, 99), 3),
                    "period_max_ms": round(float(periods.max()), 2),
                    "lapses_over_1_ms": len(lapses),
                    "lapses_ms": sorted(lapses, reverse=True)[:12],
                    "steal_ticks": steal_ticks() - stolen,
                }
            )
            print(rows[-1], flush=True)
    for row in rows:
        row["cpu_latency_request"] = held
    return rows


def garbage_collection(scene, runs: int) -> list[dict]:
    """The 250 Hz missed cycles: a full collection of the master's heap, forced in mid-trajectory."""
    rows = []
    started = time.perf_counter()
    gc.collect()
    full = time.perf_counter() - started
    objects = len(gc.get_objects())
    rows.append(
        {
            "what": "full collection of this process's heap",
            "objects": objects,
            "pause_ms": round(full * 1e3, 1),
            "cycles_at_250_hz": round(full / 0.004, 1),
        }
    )
    print(rows[-1], flush=True)
    space = gimbal_space(scene)
    path = gimbal_path(space, GAP_TIPS)
    for config in ("as before: collector on, heap not frozen", "now: collector off in the loop, heap frozen"):
        pauses: list[float] = []
        marks = {}

        def timing(phase, info, pauses=pauses, marks=marks):
            if phase == "start":
                marks["t"] = time.perf_counter()
            elif info["generation"] == 2:
                pauses.append(time.perf_counter() - marks["t"])

        gc.callbacks.append(timing)
        missed = cycles = 0
        error = ""
        try:
            with gimbal(SEPARATE, 250, path[0]) as (device, _):
                controller = device.controller
                if config.startswith("as before"):
                    gc.unfreeze()  # undo what activation does
                    device._frozen = False
                original = controller.run

                def run(trajectory, on_start=None, original=original, config=config):
                    # a full collection half-way through the trajectory, as one that happens to fall there
                    timer = threading.Timer(0.5 * len(trajectory) / 250, gc.collect)
                    timer.start()
                    try:
                        return original(trajectory, on_start, collect_garbage=config.startswith("as before"))
                    finally:
                        timer.cancel()

                controller.run = run
                for k in range(runs):
                    report = device.execute(Trajectory(path[::-1] if k % 2 else path, space, "bench"))
                    missed += report.metrics.get("missed_cycles", 0)
                    cycles += report.metrics.get("cycles", 0)
                    if report.status != "completed":
                        device.reset_faults()
        except (SurgiplanError, RuntimeError) as exc:  # a loaded machine: the drives stopped or did not start
            error = str(exc)
            print(f"  {config}: {error}", flush=True)
        finally:
            gc.callbacks.remove(timing)
        rows.append(
            {
                "what": f"250 Hz, a full collection forced mid-trajectory; {config}",
                "runs": runs,
                "cycles": cycles,
                "missed_cycles": missed,
                "full_collection_pause_ms_median": round(statistics.median(pauses) * 1e3, 1) if pauses else None,
                "error": error,
            }
        )
        print(rows[-1], flush=True)
    return rows


def bus_ceiling() -> list[dict]:
    """Control rates at which the cyclic frames alone fill 1 Mbit/s, exact and worst case."""
    rng = np.random.default_rng(0)
    rows = []
    for drives in (4, 6):
        # SYNC (no data) + per drive an RPDO and a TPDO of 6 bytes; typical payloads for the exact length
        ids = [0x80] + [0x200 + n for n in range(1, drives + 1)] + [0x180 + n for n in range(1, drives + 1)]
        payloads = [b""] + [bytes(rng.integers(0, 256, 6, dtype=np.uint8)) for _ in range(2 * drives)]
        exact = float(np.sum(frame_bits(ids, payloads)))
        worst = worst_case_bits(0) + 2 * drives * worst_case_bits(6)
        rows.append(
            {
                "drives": drives,
                "bits_per_cycle_typical": int(exact),
                "bits_per_cycle_worst": worst,
                "max_rate_hz_typical": round(1e6 / exact),
                "max_rate_hz_worst_case": round(1e6 / worst),
                "frames_per_s_at_worst_case_max": round((1 + 2 * drives) * 1e6 / worst),
            }
        )
    rows.append({"8-byte frames per second at 1 Mbit/s": f"{1e6 / 135:.0f} (worst case) - {1e6 / 111:.0f} (unstuffed)"})
    return rows


def simulation_speed(scene) -> dict:
    space = gimbal_space(scene)
    path = gimbal_path(space, GAP_TIPS)
    settings = {"fulcrum": FULCRUM, "outputs": False}
    with active(CastGimbalDevice, settings, scene, ROOT / "out") as device:
        started = time.perf_counter()
        report = device.execute(Trajectory(path, space, "bench"))
        wall = time.perf_counter() - started
    return {
        "simulated_s": round(report.metrics["duration_s"], 3),
        "wall_s": round(wall, 3),
        "simulated_s_per_wall_s": round(report.metrics["duration_s"] / wall, 2),
        "cycles": report.metrics["cycles"],
    }
