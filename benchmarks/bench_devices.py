"""Devices: the real-time CiA 402 control loop with 4 drives, bus load, inverse kinematics per waypoint.

1. Control-loop rate in real-time mode with 4 drives (the CAST gimbal): the
   gimbal's gap path executed ``--runs`` times (default 10) at 100, 250, 500
   and 1000 Hz, the drives in a process of their own reached over surgiplan's
   loopback python-can interface (a hub on 127.0.0.1 that the drives' process
   hosts: ``surgiplan-sim-drives``; the master's process does only what it
   would do with hardware), and side by side the drives simulated in a thread
   of the master's process (``clock: realtime`` on the virtual bus). Per rate:
   the cycle period (p50, p99, max), the loop's work per cycle, missed cycles
   (the loop woke more than a period late and skipped them), cycles without
   every TPDO, runs completed, the master's CPU per cycle (process CPU of every
   thread during the loop, over its cycles) and the drives' CPU per SYNC, and
   the bus load (every frame, stuff bits counted exactly; worst case beside
   it). A rate is **held** when every run completes with no missed cycle and
   the period's p99 is within 10 % of the period.
2. Why 250 Hz missed 19 cycles in 6 runs earlier: Python's cyclic garbage
   collector. A full collection of the master's heap stops every thread of
   the process; measured here on the benchmark's own heap, then shown on the
   loop: a full collection forced in the middle of a 250 Hz trajectory, with
   the collector as it was (on, heap not frozen) and as it is now (off during
   a trajectory, the heap frozen at activation).
3. Bus load against the 1 Mbit/s physical limit: the control rate at which
   SYNC + one RPDO and one TPDO per drive fill the bus, for 4 and 6 drives.
4. Inverse kinematics time per waypoint: the gimbal's tip positions (QP,
   OSQP with joint and velocity limits) against its closed form, and
   gripper6's SE(3) poses warm-started along a path (QP) against Pinocchio's
   documented CLIK loop (damped pseudo-inverse on log6, no limits:
   https://gepettoweb.laas.fr/doc/stack-of-tasks/pinocchio/master/
   doxygen-html/md_doc_b-examples_i-inverse-kinematics.html).
5. The simulated clock's speed: simulated seconds per wall second.

The load average is recorded at the start and the end: real-time figures
from a loaded machine (load above about 1 on these 2 cores) say so in the notes.

    python benchmarks/bench_devices.py [--quick] [--runs N] [--rates 250 1000]
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import pinocchio as pin
from common import median_time, save, table
from devices_support import ARM_BASE, FULCRUM, GAP_TIPS, active, gimbal_path, gimbal_space
from scipy.spatial.transform import Rotation
from surgiplan import load_scene
from surgiplan.devices import Trajectory
from surgiplan.errors import SurgiplanError
from surgiplan.geometry.transforms import Pose
from surgiplan.plugins.devices.canopen.bus import frame_bits, worst_case_bits
from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice
from surgiplan.plugins.devices.kinematics.model import DifferentialIK, KinematicModel, urdf_path

ROOT = Path(__file__).resolve().parent.parent
SEPARATE = "separate process (loopback bus)"
SEPARATE_RT = "separate process (loopback bus), SCHED_FIFO 20"
THREAD = "in-process thread (virtual bus)"
#: the SCHED_FIFO priority of the real-time runs (the loop's and the drives' threads)
PRIORITY = 20


def percentile(values, q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if len(values) else float("nan")


@contextlib.contextmanager
def drives_process(initial, priority: int | None = None):
    """Four simulated drives in another process on the loopback bus (127.0.0.1); yields the bus settings."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    command = [sys.executable, "-m", "surgiplan.plugins.devices.canopen.sim.process", "--device", "cast_gimbal"]
    command += ["--interface", "loopback", "--channel", str(port), "--option", "hub=host"]
    command += ["--sync-timeout", "0.2", "--initial", *map(str, initial)]
    if priority is not None:
        command += ["--realtime-priority", str(priority)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    try:
        if process.stdout.readline().strip() != "ready":
            raise RuntimeError("the drive simulator did not start")
        yield {"interface": "loopback", "channel": str(port), "options": {"hub": "join"}}, process.pid
    finally:
        process.terminate()
        process.wait(timeout=10)


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
        "pdo_timeout_cycles": max(10, int(rate) // 20),
        "outputs": False,
    }


@contextlib.contextmanager
def gimbal(mode: str, rate: float, start):
    """An active gimbal at ``rate`` with its drives as ``mode`` says; yields (device, drives' pid or None)."""
    settings = loop_settings(rate)
    if mode in (SEPARATE, SEPARATE_RT):
        priority = PRIORITY if mode == SEPARATE_RT else None
        context = drives_process(start, priority)
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


def control_loop(scene, rates, runs: int, mode: str) -> list[dict]:
    space = gimbal_space(scene)
    path = gimbal_path(space, GAP_TIPS)
    rows = []
    for rate in rates:
        periods, work, missed, missing, completed, cycles, load, worst = [], [], 0, 0, 0, 0, [], []
        loop_cpu = drives_cpu = execute_cpu = 0.0
        syncs = 0
        lapses = []
        error = ""
        try:
            with gimbal(mode, rate, path[0]) as (device, pid):
                for k in range(runs):
                    before_cpu, before_frames = process_cpu(pid), len(device.bus.frames)
                    before_execute = time.process_time()
                    before_lapses = len(device.controller.missed_log)
                    report = device.execute(Trajectory(path[::-1] if k % 2 else path, space, "bench"))
                    execute_cpu += time.process_time() - before_execute
                    drives_cpu += process_cpu(pid) - before_cpu
                    syncs += sum(1 for f in device.bus.frames[before_frames:] if f[1] == 0x080)
                    if report.metrics.get("refused"):
                        error = report.message
                        break
                    log = device.last_log
                    loop_cpu += log.cpu_s
                    periods += np.diff(log.wakeups).tolist()
                    work += log.work.tolist()
                    missed += report.metrics.get("missed_cycles", 0)
                    missing += report.metrics.get("samples_missing", 0)
                    cycles += report.metrics["cycles"]
                    completed += report.status == "completed"
                    load.append(report.metrics["bus_load_percent"])
                    worst.append(report.metrics["bus_load_worst_case_percent"])
                    new = device.controller.missed_log[before_lapses:]
                    lapses += [round(late * 1e3, 1) for due, late, _ in new if log.start <= due <= log.end]
                    if report.status != "completed":
                        print(f"  {mode} {rate} Hz run {k}: {report.message}", flush=True)
                        device.reset_faults()
        except SurgiplanError as exc:  # on a loaded machine the drives may not even start in time
            error = str(exc)
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
            "missed_lapses_late_ms": lapses[:20],
            "cycles_missing_a_tpdo": missing,
            "bus_load_percent": round(statistics.median(load), 2) if load else None,
            "bus_load_worst_case_percent": round(statistics.median(worst), 2) if worst else None,
            # CPU per cycle of every thread of the master's process during the loop: what a core must give it
            "master_cpu_per_cycle_ms": round(loop_cpu / cycles * 1e3, 3) if cycles else None,
            # as the earlier results measured it: the whole execute (inverse kinematics, timing, certification,
            # the report) over the cycles
            "master_cpu_per_cycle_with_preparation_ms": round(execute_cpu / cycles * 1e3, 3) if cycles else None,
            "drives_cpu_per_sync_ms": round(drives_cpu / syncs * 1e3, 3) if syncs and mode != THREAD else None,
            "error": error,
        }
        row["held"] = bool(completed == runs and missed == 0 and periods and row["period_p99_ms"] <= 1.1 * period * 1e3)
        rows.append(row)
        columns = ["rate_hz", "runs_completed", "period_p50_ms", "period_p99_ms", "missed_cycles", "held"]
        columns += ["master_cpu_per_cycle_ms", "drives_cpu_per_sync_ms", "bus_load_percent"]
        print(table([row], columns), flush=True)
    return rows


def scheduling_floor(seconds: float) -> list[dict]:
    """What the machine gives any 1 kHz loop: a bare single-thread Python loop sleeping to each 1 ms deadline
    (1 us timer slack), no CAN, no GIL contention; with ordinary scheduling and under SCHED_FIFO."""
    from surgiplan.plugins.devices.canopen.clock import RealTimeClock, restore_priority, set_realtime_priority

    rows = []
    for policy in ("ordinary", f"SCHED_FIFO {PRIORITY}"):
        try:
            previous = set_realtime_priority(PRIORITY if policy != "ordinary" else None)
        except OSError as exc:
            rows.append({"loop": f"bare 1 kHz sleep loop, {policy}", "error": str(exc)})
            continue
        RealTimeClock.precise()
        wakes, lapses = [], []
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
            }
        )
        print(rows[-1], flush=True)
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
        finally:
            gc.callbacks.remove(timing)
        rows.append(
            {
                "what": f"250 Hz, a full collection forced mid-trajectory; {config}",
                "runs": runs,
                "cycles": cycles,
                "missed_cycles": missed,
                "full_collection_pause_ms_median": round(statistics.median(pauses) * 1e3, 1) if pauses else None,
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


def clik(model: pin.Model, data: pin.Data, frame: int, target: pin.SE3, q: np.ndarray) -> np.ndarray:
    """Pinocchio's documented CLIK (damped pseudo-inverse on log6), for a frame target."""
    eps, it_max, dt, damp = 1e-7, 1000, 1e-1, 1e-12
    for _ in range(it_max):
        pin.forwardKinematics(model, data, q)
        placement = pin.updateFramePlacement(model, data, frame)
        error = pin.log6(placement.actInv(target)).vector
        if np.linalg.norm(error) < eps:
            break
        jac = pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL)
        jac = -pin.Jlog6(placement.actInv(target)) @ jac
        v = -jac.T @ np.linalg.solve(jac @ jac.T + damp * np.eye(6), error)
        q = pin.integrate(model, q, v * dt)
    return q


def inverse_kinematics(scene, waypoints: int) -> list[dict]:
    rows = []
    space = gimbal_space(scene)
    gimbal = KinematicModel(
        urdf_path("surgiplan.plugins.devices.cast_gimbal", "cast_gimbal"),
        "tip",
        Pose.from_xyz_rpy(FULCRUM["xyz"], FULCRUM["rpy"]),
    )
    tips = np.linspace(GAP_TIPS[0], GAP_TIPS[-1], waypoints)
    ik = DifferentialIK(gimbal)
    qp, _ = median_time(lambda: ik.solve_positions(tips, gimbal.neutral()), repeat=5)
    closed, _ = median_time(lambda: space.inverse(tips), repeat=5)
    result = ik.solve_positions(tips, gimbal.neutral())
    deviation = float(np.max(np.abs(result.q[:, :3] - space.inverse(tips)[:, :3])))
    rows.append(
        {
            "ik": "cast_gimbal tip positions: QP (OSQP, limits)",
            "waypoints": waypoints,
            "per_waypoint_us": round(qp / waypoints * 1e6, 1),
            "iterations_mean": round(float(result.iterations.mean()), 2),
            "max_residual_m": float(result.position_error.max()),
            "vs_closed_form_max_joint_difference": deviation,
        }
    )
    rows.append(
        {
            "ik": "cast_gimbal closed form (reference)",
            "waypoints": waypoints,
            "per_waypoint_us": round(closed / waypoints * 1e6, 2),
        }
    )

    arm = KinematicModel(
        urdf_path("surgiplan.plugins.devices.gripper6", "gripper6"),
        "jaws",
        Pose.from_xyz_rpy(ARM_BASE["xyz"], ARM_BASE["rpy"]),
    )
    q_path = np.linspace([0.2, 0.3, 0.8, 0.1, 0.9, -0.2], [-0.4, 0.5, 0.4, -0.3, 1.2, 0.6], waypoints)
    poses = arm.tip_poses(q_path)
    arm_ik = DifferentialIK(arm)
    warm, _ = median_time(lambda: arm_ik.solve_poses(poses, q_path[0]), repeat=3)
    result = arm_ik.solve_poses(poses, q_path[0])
    rows.append(
        {
            "ik": "gripper6 SE(3) poses, warm-started along a path: QP (OSQP, limits)",
            "waypoints": waypoints,
            "per_waypoint_us": round(warm / waypoints * 1e6, 1),
            "iterations_mean": round(float(result.iterations.mean()), 2),
            "max_residual_m": float(result.position_error.max()),
            "max_rotation_residual_rad": float(result.rotation_error.max()),
        }
    )
    model, data, frame = arm.model, arm.model.createData(), arm.tip_id
    targets = [pin.SE3(Rotation.from_quat(p[3:]).as_matrix(), p[:3]) for p in poses]

    def reference():
        q = q_path[0].copy()
        out = []
        for target in targets:
            q = clik(model, data, frame, target, q)
            out.append(q)
        return np.array(out)

    ref_time, _ = median_time(reference, repeat=3)
    ref = reference()
    reached = arm.tip_poses(ref)
    rows.append(
        {
            "ik": "gripper6: Pinocchio's documented CLIK, same warm start (reference, no limits)",
            "waypoints": waypoints,
            "per_waypoint_us": round(ref_time / waypoints * 1e6, 1),
            "max_residual_m": float(np.max(np.linalg.norm(reached[:, :3] - poses[:, :3], axis=1))),
        }
    )
    # a cold solve (first pose of a path, from the neutral configuration, with restarts when needed)
    rng = np.random.default_rng(1)
    cold_targets = arm.tip_poses(rng.uniform(arm.lower * 0.9, arm.upper * 0.9, size=(20, 6)))
    cold, _ = median_time(lambda: [arm_ik.solve_poses(t[None], arm.neutral()) for t in cold_targets], repeat=3)
    rows.append(
        {
            "ik": "gripper6 cold pose from the neutral configuration: QP",
            "waypoints": 20,
            "per_waypoint_us": round(cold / 20 * 1e6, 1),
        }
    )
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


def readme_table(data: dict | None = None) -> str:
    """The README's table, from benchmarks/results/devices.json (so that its numbers are never typed by hand)."""
    import json

    from common import RESULTS

    if data is None:
        data = json.loads((RESULTS / "devices.json").read_text())
    rows = data["rows"]
    machine = next(r for r in rows if r["section"] == "machine")
    lines = [
        f"{data['notes']} ({machine['date']}, {machine['runs_per_rate']} runs of the gimbal path per rate)",
        "",
        "| drives | rate | runs completed | period p50 / p99 / max | missed cycles | master CPU per cycle "
        "| drives CPU per SYNC | bus load (worst case) | held |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r["section"] != "control_loop":
            continue
        where = {SEPARATE: "other process", SEPARATE_RT: f"other process, SCHED_FIFO {PRIORITY}"}.get(
            r["drives"], "thread"
        )
        drives_cpu = (
            f"{r['drives_cpu_per_sync_ms']} ms" if r["drives_cpu_per_sync_ms"] is not None else "(same process)"
        )
        lines.append(
            f"| {where} | {r['rate_hz']:g} Hz | {r['runs_completed']} | {r['period_p50_ms']} / {r['period_p99_ms']} / "
            f"{r['period_max_ms']} ms | {r['missed_cycles']} of {r['cycles']:,} | {r['master_cpu_per_cycle_ms']} ms | "
            f"{drives_cpu} | {r['bus_load_percent']} % ({r['bus_load_worst_case_percent']} %) | "
            f"{'yes' if r['held'] else 'no'} |"
        )
    lines.append("")
    for r in rows:
        if r["section"] == "scheduling_floor" and "error" not in r:
            lapses = ", ".join(f"{x:g}" for x in r["lapses_ms"])
            lines.append(
                f"- {r['loop']} (the machine's own floor), {r['seconds']:g} s: period p99 {r['period_p99_ms']} ms, "
                f"max {r['period_max_ms']} ms, {r['lapses_over_1_ms']} wake-ups more than a period late"
                + (f" ({lapses} ms)" if lapses else "")
            )
        elif r["section"] == "garbage_collection" and "pause_ms" in r:
            lines.append(
                f"- a full garbage collection of the benchmark's heap ({r['objects']:,} objects): {r['pause_ms']} ms, "
                f"{r['cycles_at_250_hz']} cycles at 250 Hz"
            )
        elif r["section"] == "garbage_collection":
            lines.append(
                f"- {r['what']}: {r['missed_cycles']} missed cycles of {r['cycles']:,} in {r['runs']} runs "
                f"(the collection's pause, median: {r['full_collection_pause_ms_median']} ms)"
            )
    ceiling = [r for r in rows if r["section"] == "bus_ceiling" and "drives" in r]
    if ceiling:
        rates = ", ".join(f"{r['max_rate_hz_worst_case']:,} Hz for {r['drives']} drives" for r in ceiling)
        lines.append(
            f"- the bus at 1 Mbit/s (SYNC + an RPDO and a TPDO per drive, worst-case stuffing) fills at {rates}"
        )
    if any(r["section"] == "inverse_kinematics" for r in rows):
        parts = [f"{r['ik']} {r['per_waypoint_us']} µs" for r in rows if r["section"] == "inverse_kinematics"]
        lines.append("- inverse kinematics per waypoint: " + "; ".join(parts))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="reduced sizes, to check the script (not saved)")
    parser.add_argument("--runs", type=int, help="runs of the gimbal path per rate (default 10)")
    parser.add_argument("--rates", type=float, nargs="+", help="control rates (default 100 250 500 1000)")
    parser.add_argument(
        "--modes",
        nargs="+",
        choices=["separate", "fifo", "thread"],
        default=["separate", "fifo", "thread"],
        help="drives in another process, the same under SCHED_FIFO, drives in a thread of this process",
    )
    parser.add_argument("--table", action="store_true", help="print the README's table from the saved results")
    args = parser.parse_args()
    if args.table:
        print(readme_table())
        return
    load_start = os.getloadavg()
    print(f"load average at start (1, 5, 15 min): {load_start} on {os.cpu_count()} CPUs", flush=True)
    scene = load_scene(ROOT / "configs" / "scenes" / "block_world.yaml")
    rates = args.rates or ([250, 1000] if args.quick else [100, 250, 500, 1000])
    runs = args.runs or (2 if args.quick else 10)

    print("## control loop in real time, 4 drives in another process", flush=True)
    loop = control_loop(scene, rates, runs, SEPARATE) if "separate" in args.modes else []
    if "fifo" in args.modes:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
            print(f"## the same, the loop's and the drives' threads under SCHED_FIFO {PRIORITY}", flush=True)
            loop += control_loop(scene, rates, runs, SEPARATE_RT)
        except OSError as exc:
            print(f"## no SCHED_FIFO here ({exc}): skipped", flush=True)
    if "thread" in args.modes:
        print("## control loop in real time, 4 drives in a thread of this process", flush=True)
        loop += control_loop(scene, rates, max(2, runs // 2), THREAD)
    print("\n## the machine's own floor: a bare 1 kHz loop", flush=True)
    floor = scheduling_floor(5.0 if args.quick else 20.0)
    print("\n## garbage collection and missed cycles", flush=True)
    collection = garbage_collection(scene, 2 if args.quick else 4)
    print("\n## the bus at 1 Mbit/s", flush=True)
    ceiling = bus_ceiling()
    print(table(ceiling[:2], list(ceiling[0])))
    print(ceiling[2])
    print("\n## inverse kinematics per waypoint", flush=True)
    ik = inverse_kinematics(scene, 50 if args.quick else 300)
    print(table(ik, ["ik", "waypoints", "per_waypoint_us", "iterations_mean", "max_residual_m"]))
    print("\n## the simulated clock", flush=True)
    speed = simulation_speed(scene)
    print(speed)
    load_end = os.getloadavg()
    separate = [r for r in loop if r["drives"] == SEPARATE]
    held = [r["rate_hz"] for r in separate if r["held"]]
    cpu = [r["master_cpu_per_cycle_ms"] for r in separate if r["master_cpu_per_cycle_ms"]]
    held_rt = [r["rate_hz"] for r in loop if r["drives"] == SEPARATE_RT and r["held"]]
    summary = {
        "highest_rate_held_hz_separate_process": max(held) if held else None,
        "highest_rate_held_hz_separate_process_sched_fifo": max(held_rt) if held_rt else None,
        "master_cpu_per_cycle_ms_median": statistics.median(cpu) if cpu else None,
        # the rate at which the master's loop would need a whole core
        "cpu_bound_rate_hz_master": round(1e3 / statistics.median(cpu)) if cpu else None,
        "bus_limited_rate_hz_4_drives_worst_case": ceiling[0]["max_rate_hz_worst_case"],
    }
    print("\n", summary)
    loaded = max(load_start[0], load_end[0]) > 1.0
    notes = (
        f"Load average (1 min) {load_start[0]:.2f} at the start, {load_end[0]:.2f} at the end, on {os.cpu_count()} "
        "CPUs: "
        + (
            "a LOADED machine (other jobs running): real-time figures are what a shared machine gave, not "
            "what the loop can do. "
            if loaded
            else "a quiet machine. "
        )
        + "'held': every run completed, no missed "
        "cycle, period p99 within 10 % of the period. "
        + ("QUICK run (reduced sizes), not saved." if args.quick else "")
    )
    rows = (
        [
            {
                "section": "machine",
                "date": datetime.date.today().isoformat(),
                "cpus": os.cpu_count(),
                "load_average_start": [round(x, 2) for x in load_start],
                "load_average_end": [round(x, 2) for x in load_end],
                "runs_per_rate": runs,
            }
        ]
        + [{"section": "control_loop", **r} for r in loop]
        + [{"section": "scheduling_floor", **r} for r in floor]
        + [{"section": "garbage_collection", **r} for r in collection]
        + [{"section": "bus_ceiling", **r} for r in ceiling]
        + [{"section": "inverse_kinematics", **r} for r in ik]
        + [{"section": "simulated_clock", **speed}, {"section": "summary", **summary}]
    )
    if args.quick:
        print(notes)
        return
    print(save("devices", rows, notes))


if __name__ == "__main__":
    main()
