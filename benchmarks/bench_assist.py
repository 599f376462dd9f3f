"""Haptic guidance: the same synthetic beginners on the CAST gimbal with the assistance off and on.

Each attempt runs the ``cast_gimbal`` source in ``mode: assist`` on the simulated drives (cyclic synchronous
torque) and the simulated bus, the beginner's hand an impedance pulling toward where they intend to be
(``surgiplan.guidance.trainee``, seeded), measured as the guide stage measures it
(:class:`surgiplan.guidance.Guide`): deviation p95, time below d_thresh outside critical regions, contacts and the
score. **off**: the same loop with the fixture's stiffnesses and damping 0 (the drives enabled, sending zero
torque), so that only the guidance differs; **on**: the fixture of ``configs/guide_assist.yaml`` at full
assistance (``fade: none``). Seeds 0 .. N-1, each seed the same intended motion in both arms (paired).

Then the loop's timing: the fixture's computation per cycle (median, p99, over every cycle of the "on" arm) and,
in the simulated bus's real-time mode (``clock: realtime``: the drives in a thread of their own on the virtual
bus), one attempt at 500 Hz (the paired comparison runs the simulated clock at 250 Hz): the cycle rate the loop
held and the SYNCs it missed (target: 500 Hz, 0 missed). Beside it, the same attempt with the drives and the
trainee's hand in a process of their own (``surgiplan-sim-drives --hand``, the loopback bus on 127.0.0.1, as
bench_devices' "other process" configuration; the drives under SCHED_FIFO 20 where the system allows it), the
loop at ordinary priority and under SCHED_FIFO 30: rate, missed SYNCs, cycle jitter p50/p99/max, and whether the
assistance lasted the attempt.

    python benchmarks/bench_assist.py [--seeds 20] [--quick] [--realtime-only]
    (--quick: 3 seeds, writes nothing; --realtime-only: only the real-time attempts, writes nothing)
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from common import save, table
from cyclictest import cyclictest_floor
from devices_table import DRIVES_PRIORITY, PRIORITY
from schedtrace import SchedTrace, benchmark_threads
from schedtrace import summary as schedtrace_summary
from surgiplan import load_pipeline, run_pipeline
from surgiplan.clearance import intervals, threshold_value
from surgiplan.guidance import Guide, GuideContext, SourceStopped
from surgiplan.results import StageContext
from witness import Witness

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "configs" / "guide_assist.yaml"
OFF = {"stiffness": 0.0, "damping": 0.0, "wall_stiffness": 0.0, "fade": "none"}
ON = {"fade": "none"}  # the config's fixture, at full assistance
#: the paired comparison's SYNC rate (the simulated clock: the physics is the same at any rate; 250 Hz halves the
#: benchmark's time on a shared machine), and the real-time loop's target
RATE = 250.0
REALTIME_RATE = 500.0
#: runs of the machine's floor (cyclictest) after the real-time attempts
FLOOR_RUNS = 10


def pipeline_file(tmp: Path, settings: dict) -> Path:
    data = yaml.safe_load(CONFIG.read_text())
    data["scene"] = str(CONFIG.parent / data["scene"])
    data["output"] = {"dir": str(tmp / "out"), "figures": False, "gltf": False}
    guide = data["pipeline"][1]
    guide.pop("trainee", None)
    guide["settings"].pop("record", None)
    guide["settings"].update(settings)
    path = tmp / "assist.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def attempt(tmp: Path, plan, space, settings: dict, drives_pid: int | None = None) -> dict:
    """One attempt of the source as the guide stage runs it: its metrics and the assistance summary; in real time
    also how long the drives took to answer each SYNC (:func:`devices_loop.answer_latencies`) and, with the drives'
    process id, their CPU time during the loop."""
    from devices_loop import answer_latencies, process_cpu

    spec = load_pipeline(pipeline_file(tmp, settings)).stages[1]
    critical = intervals(list(plan.critical_regions))
    guide = Guide(space, plan.path, space.scene, threshold_value(plan.clearance_threshold), critical, spec.guidance)
    context = StageContext("attempt", space.scene, tmp / "out", tmp)
    (tmp / "out").mkdir(exist_ok=True)
    source = spec.plugin.cls(spec.settings)
    source.open(GuideContext(context, plan.path, guide.tips, space, space.scene, guide.threshold, critical))
    compute = []
    stopped = None
    drives_cpu = process_cpu(drives_pid)
    try:
        for sample in source.samples():
            guide.measure(sample)
    except SourceStopped as exc:
        stopped = str(exc)
    finally:
        drives_cpu = process_cpu(drives_pid) - drives_cpu
        compute = list(source.assist.compute_s) if source.assist is not None else []
        clock = source.device.clock
        nodes = [a.node_id for a in source.device.master.axes]
        frames = list(source.device.bus.frames) if clock.realtime else []
        answers = answer_latencies(frames, nodes) if clock.realtime else np.zeros(0)
        threads = benchmark_threads(drives_pid)
        ended = source.assist.events[0]["t"] if source.assist is not None and source.assist.events else None
        last_cycle = source.loop_span[1]
        source.close()
    syncs = np.array([t for t, cob, _ in frames if cob == 0x080])
    slowest = None  # the loop's SYNC the drives answered last (perf_counter time s) and how long they took (s)
    looped = int(np.sum(syncs[: len(answers)] <= last_cycle + 1e-9))  # not the SYNC that disables them after it
    if looped:
        k = int(np.argmax(answers[:looped]))
        slowest = (clock.origin + syncs[k], float(answers[k]))
    ending = None  # from the SYNC whose answers were missed to when they were judged missing (perf_counter s): the
    # cycle's due time, or a period after that SYNC went when the loop waited for them that long
    if ended is not None and np.any(syncs < ended):
        missed = float(syncs[syncs < ended][-1])
        ending = (clock.origin + missed, clock.origin + max(ended, missed + 1.0 / REALTIME_RATE))
    guide.finish()
    metrics = guide.metrics()
    return {"metrics": metrics, "assistance": source.assistance, "compute": compute, "stopped": stopped,
            "completed": guide.reached_goal, "answers": answers, "drives_cpu_s": drives_cpu,
            "slowest": slowest, "ending": ending, "threads": threads}  # fmt: skip


def realtime_elsewhere(tmp: Path, plan, space, seed: int, priority: int | None) -> dict:
    """One real-time attempt at REALTIME_RATE with the drives and the beginner's hand in another process (SCHED_FIFO
    ``priority`` for the loop, None: ordinary; the drives at DRIVES_PRIORITY where allowed): the assistance
    summary."""
    from devices_loop import drives_process, fifo_allowed

    spec = load_pipeline(pipeline_file(tmp, {"hand": {"level": "beginner", "seed": seed}})).stages[1]
    critical = intervals(list(plan.critical_regions))
    guide = Guide(space, plan.path, space.scene, threshold_value(plan.clearance_threshold), critical, spec.guidance)
    source = spec.plugin.cls(spec.settings)
    source.gimbal_space = space  # the hand's joints as the source computes them in-process
    context = GuideContext(StageContext("hand", space.scene, tmp / "out", tmp), plan.path, guide.tips, space,
                           space.scene, guide.threshold, critical)  # fmt: skip
    times, joints = source._hand_motion(context)
    hand = tmp / "hand.npz"
    np.savez(hand, times=times, joints=joints)
    model = spec.settings.hand
    extra = ["--hand", str(hand), "--hand-stiffness", *map(str, model.stiffness), "--hand-damping"]
    extra += list(map(str, model.damping))
    # the drives stand for hardware: under SCHED_FIFO below the loop wherever allowed, as in bench_devices
    drives = DRIVES_PRIORITY if fifo_allowed() else None
    with drives_process(joints[0], drives, extra) as (bus, pid):
        live = {"control_rate": REALTIME_RATE, "clock": "realtime", "max_duration": 8.0, "bus": bus, "hand": None}
        if priority is not None:
            live["realtime_priority"] = priority
        out = attempt(tmp, plan, space, {"assist": ON, **live}, drives_pid=pid)
    cpu = {"drives_cpu_per_sync_ms": 1e3 * out["drives_cpu_s"] / max(1, len(out["answers"]))}
    return {**assistance_of(out), **cpu}


def assistance_of(out: dict) -> dict:
    """A real-time attempt's assistance summary, its drives' answers (:func:`answered`), how it stopped and its
    slowest answer: what :func:`realtime_row` takes."""
    return {**out["assistance"], **answered(out), "stopped": out["stopped"], "slowest": out["slowest"],
            "ending": out["ending"], "threads": out["threads"]}  # fmt: skip


def answered(out: dict) -> dict:
    """How long the drives took to answer each SYNC of an attempt (at the master, all four TPDOs; ms)."""
    from devices_loop import latency_summary

    return latency_summary(out["answers"], 1.0 / REALTIME_RATE)


def realtime_row(configuration: str, run: int, assistance: dict, witness: Witness, trace: SchedTrace) -> dict:
    """One real-time attempt's row, with what the stall witness saw meanwhile and while the drives' slowest answer
    was awaited (a late wake-up of a SCHED_FIFO-99 process then: the machine stalled, not the drives), and what the
    kernel's scheduler trace says of the two processes' wake-ups: the slowest, and the slowest between the SYNC
    whose answer was missed and the cycle that found it missing (its delivery part: the host's, see
    :mod:`schedtrace`)."""
    keys = ("cycle_rate_hz", "missed_syncs", "cycles", "ended", "jitter_p50_ms", "jitter_p99_ms", "jitter_max_ms",
            "sync_to_tpdos_p50_ms", "sync_to_tpdos_p99_ms", "sync_to_tpdos_max_ms", "answers_later_than_a_period",
            "drives_cpu_per_sync_ms")  # fmt: skip
    row = {"drives": configuration, "run": run, **{k: assistance.get(k) for k in keys}}
    row["stopped"] = assistance.get("stopped")
    row.update(witness.summary())
    slowest = assistance.get("slowest")
    if slowest is not None:
        t, took = slowest
        row["witness_late_during_slowest_answer_ms"] = round(1e3 * witness.late_during(t, t + took), 3)
    ending = assistance.get("ending")
    row.update(schedtrace_summary(trace, assistance.get("threads") or {}, ending))
    if ending is not None:
        row["witness_late_when_missed_ms"] = round(1e3 * witness.late_during(*ending), 3)
    return row


def realtime_loops(tmp: Path, plan, space, runs: int) -> list[dict]:
    """The real-time attempts, ``runs`` of each configuration, each beside the stall witness: the drives in a
    thread of this process, and in a process of their own (ordinary priority, then SCHED_FIFO where allowed)."""
    from devices_loop import fifo_allowed

    live = {"control_rate": REALTIME_RATE, "clock": "realtime", "max_duration": 8.0}
    configurations = [
        ("in-process thread (virtual bus)", None),
        ("other process (loopback bus), loop at ordinary priority",
         lambda: realtime_elsewhere(tmp, plan, space, 0, None)),
    ]  # fmt: skip
    if fifo_allowed():
        configurations.append(
            (f"other process (loopback bus), SCHED_FIFO {PRIORITY} (drives {DRIVES_PRIORITY})",
             lambda: realtime_elsewhere(tmp, plan, space, 0, PRIORITY))
        )  # fmt: skip
    else:
        print("no SCHED_FIFO here: its configuration is skipped", flush=True)
    rows = []
    for run in range(runs):
        for name, elsewhere in configurations:
            with Witness() as witness, SchedTrace() as trace:
                if elsewhere is None:
                    out = attempt(tmp, plan, space, {"hand": {"level": "beginner", "seed": 0}, "assist": ON, **live})
                    assistance = assistance_of(out)
                else:
                    assistance = elsewhere()
            rows.append(realtime_row(name, run, assistance, witness, trace))
            r = rows[-1]
            print(
                f"run {run}, {name}: {r['cycles']} cycles, {r['missed_syncs']} missed SYNCs, ended: {r['ended']}; "
                f"witness max late {r['witness_late_max_ms']} ms "
                f"({r.get('witness_late_during_slowest_answer_ms', '-')} ms during the slowest answer, "
                f"{r['sync_to_tpdos_max_ms']} ms), {r['steal_ticks']} ticks stolen; slowest wake-up when the answer "
                f"was missed: {r.get('span_wakeup_max_ms', '-')} ms ({r.get('span_wakeup_thread')}, delivery "
                f"{r.get('span_delivery_ms', '-')} ms)",
                flush=True,
            )
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--quick", action="store_true", help="3 seeds, no results file")
    parser.add_argument("--realtime-only", action="store_true", help="only the real-time attempts, no results file")
    parser.add_argument("--realtime-runs", type=int, default=3, help="real-time attempts per configuration")
    args = parser.parse_args(argv)
    if args.realtime_only:
        with tempfile.TemporaryDirectory() as folder:
            tmp = Path(folder)
            planning = load_pipeline(pipeline_file(tmp, {}))
            planning.stages = planning.stages[:1]
            plan = run_pipeline(planning).results[0]
            rows = realtime_loops(tmp, plan, planning.stages[0].space, args.realtime_runs)
        print(table(rows, list(rows[0])))
        print(f"load average {os.getloadavg()}")
        return 0
    seeds = 3 if args.quick else args.seeds
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        planning = load_pipeline(pipeline_file(tmp, {}))
        planning.stages = planning.stages[:1]
        plan = run_pipeline(planning).results[0]
        space = planning.stages[0].space
        rows, compute = [], []
        for seed in range(seeds):
            for arm, fixture in (("off", OFF), ("on", ON)):
                started = time.perf_counter()
                hand = {"level": "beginner", "seed": seed}
                out = attempt(tmp, plan, space, {"hand": hand, "assist": fixture, "control_rate": RATE})
                m = out["metrics"]
                if arm == "on":
                    compute += out["compute"]
                rows.append({
                    "seed": seed,
                    "assist": arm,
                    "deviation_p95_mm": 1000 * m["deviation_p95_m"],
                    "below_threshold_s": m["below_threshold_s"],
                    "contacts": int(m["contacts"]),
                    "score": m["score"],
                    "duration_s": m["duration_s"],
                    "completed": bool(out["completed"]),
                    "assist_ended": out["assistance"]["ended"],
                    "wall_s": time.perf_counter() - started,
                })  # fmt: skip
                r = rows[-1]
                print(
                    f"seed {seed:2d} {arm:3s}: p95 {r['deviation_p95_mm']:.2f} mm, below "
                    f"{r['below_threshold_s']:.2f} s, contacts {r['contacts']}, score {r['score']:.1f} "
                    f"({r['wall_s']:.1f} s)",
                    flush=True,
                )
        # the real-time loop at 500 Hz: the drives in a thread of this process, then in a process of their own
        # (the loop at ordinary priority, then under SCHED_FIFO where allowed)
        realtime = realtime_loops(tmp, plan, space, 1 if args.quick else args.realtime_runs)
    # the machine's floor for the same loop, measured by rt-tests' cyclictest in the same session: its rate, its
    # priority under SCHED_FIFO, a cycle late by more than a period lost, as long as an attempt
    floor = cyclictest_floor(
        2 if args.quick else FLOOR_RUNS, 2.0 if args.quick else 8.0, False, priority=PRIORITY,
        interval_us=round(1e6 / REALTIME_RATE),
    )  # fmt: skip
    print(floor, flush=True)
    summary = []
    for arm in ("off", "on"):
        mine = [r for r in rows if r["assist"] == arm]
        summary.append({
            "assist": arm,
            "attempts": len(mine),
            "deviation_p95_mm_median": float(np.median([r["deviation_p95_mm"] for r in mine])),
            "below_threshold_s_median": float(np.median([r["below_threshold_s"] for r in mine])),
            "below_threshold_s_mean": float(np.mean([r["below_threshold_s"] for r in mine])),
            "contacts_total": int(sum(r["contacts"] for r in mine)),
            "score_median": float(np.median([r["score"] for r in mine])),
            "completed": int(sum(r["completed"] for r in mine)),
        })  # fmt: skip
    paired = np.array([
        [r["deviation_p95_mm"] for r in rows if r["assist"] == arm] for arm in ("off", "on")
    ])  # fmt: skip
    better = int(np.sum(paired[1] < paired[0]))
    loop = {
        "fixture_median_ms": 1000 * float(np.median(compute)),
        "fixture_p99_ms": 1000 * float(np.percentile(compute, 99)),
        "fixture_cycles": len(compute),
        "realtime": realtime,
        "realtime_seconds": 8.0,
        "realtime_runs": 1 if args.quick else args.realtime_runs,
        "target_rate_hz": REALTIME_RATE,
        "floor": floor,
    }
    print(table(summary, list(summary[0])))
    print(f"deviation p95 lower with assist in {better}/{seeds} paired seeds")
    print(loop)
    if args.quick:
        return 0
    notes = (
        f"load average at the start {load[0]:.2f}/{load[1]:.2f}/{load[2]:.2f} (1/5/15 min) on 2 shared cores; "
        f"{seeds} synthetic beginners (seeds 0-{seeds - 1}) on configs/guide_assist.yaml's plan, simulated clock at "
        f"{RATE:g} Hz; off: fixture stiffness, damping and wall 0 (drives enabled at zero torque); on: the config's "
        f"fixture, fade none; real time: {args.realtime_runs} attempts at {REALTIME_RATE:g} Hz a configuration, clock "
        "realtime, max 8 s, each beside the stall witnesses (benchmarks/witness.py: SCHED_FIFO 99, one per CPU)"
    )
    save("assist", rows, notes, extra={"summary": summary, "loop": loop, "paired_better": better, "seeds": seeds})
    return 0


if __name__ == "__main__":
    sys.exit(main())
