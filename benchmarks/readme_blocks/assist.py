"""The haptic assist block (docs/howto/haptic-assist.md): the same beginners with the assistance off and on, the
fixture's time per cycle and the real-time loop (``bench_assist.py``)."""

from __future__ import annotations

from pathlib import Path

from .formatting import (
    HOST_DELIVERY_MS,
    QUEUED_MS,
    find,
    floor_words,
    load,
    section,
    table,
    thread_label,
    wakeup_cause,
    witness_words,
    wrap,
)


def _held(r: dict, target: float) -> bool:
    """Whether a real-time attempt held the target: the rate, no missed SYNC, the assistance lasting it."""
    rate = r["cycle_rate_hz"]
    return rate is not None and rate >= 0.99 * target and r["missed_syncs"] == 0 and not r["ended"]


def render_assist(results: Path) -> str:
    data = load(results, "assist")
    summary = {row["assist"]: row for row in data["summary"]}
    loop = data["loop"]
    seeds = data["seeds"]
    body = table(
        [
            "assist",
            "attempts",
            "deviation p95 (median)",
            "time below d_thresh outside critical regions (median / mean)",
            "contacts (total)",
            "score (median)",
            "completed",
        ],
        [
            [
                arm,
                str(row["attempts"]),
                f"{row['deviation_p95_mm_median']:.2f} mm",
                f"{row['below_threshold_s_median']:.3f} / {row['below_threshold_s_mean']:.3f} s",
                str(row["contacts_total"]),
                f"{row['score_median']:.1f}",
                f"{row['completed']}/{row['attempts']}",
            ]
            for arm, row in ((arm, summary[arm]) for arm in ("off", "on"))
        ],
    )
    load_avg = find(r"load average at the start ([\d./]+)", data["notes"], "assist.json notes").group(1)
    head = (
        f"`benchmarks/bench_assist.py` runs {seeds} synthetic beginners (seeds 0-{seeds - 1}) through the "
        f"`cast_gimbal` source in assist mode on the simulated drives, the fixture off (zero stiffness and damping: "
        f"the drives enabled at zero torque) and on (`configs/guide_assist.yaml`'s fixture at full assistance), "
        f"each seed the same intended motion in both arms (`benchmarks/results/assist.json`; load average "
        f"{load_avg} (1/5/15 min) at the start on 2 cores"
        + (", shared with other work, so the timings are provisional):" if float(load_avg.split("/")[0]) > 2 else "):")
    )
    target = loop["target_rate_hz"]
    seconds = loop["realtime_seconds"]
    full = round(target * seconds)
    rows, held = [], {}
    answered = ("sync_to_tpdos_p50_ms", "sync_to_tpdos_p99_ms", "sync_to_tpdos_max_ms")
    stalled = 0  # attempts whose slowest answer came while the stall witness was late too
    # the trace's account of a missed answer exists for the attempts that ended on one
    traced = all("span_wakeup_max_ms" in r for r in loop["realtime"] if r["ended"])
    for r in loop["realtime"]:
        rate = r["cycle_rate_hz"]
        ok = _held(r, target)
        held[r["drives"]] = held.get(r["drives"], True) and ok
        during = r.get("witness_late_when_missed_ms" if traced else "witness_late_during_slowest_answer_ms")
        stalled += bool(during) and not ok
        witness = "-"
        if "witness_late_max_ms" in r:
            late = f"{during:.1f}" if during is not None else "-"
            witness = f"{r['witness_late_max_ms']:.1f} ({late}) ms, {r['steal_ticks']}"
        wakeup = "-"
        if r.get("span_wakeup_max_ms") is not None:
            who = thread_label(r["span_wakeup_thread"])
            wakeup = f"{r['span_wakeup_max_ms']:.2f} ms, {who} ({r['span_delivery_ms']:.2f})"
        rows.append(
            [
                r["drives"],
                str(r.get("run", 0) + 1),
                f"{rate:.1f} Hz" if rate is not None else "-",
                str(r["missed_syncs"]),
                f"{r['cycles']:,} of {full:,}",
                " / ".join(f"{r[k]:.3f}" for k in ("jitter_p50_ms", "jitter_p99_ms", "jitter_max_ms"))
                if r.get("jitter_p50_ms") is not None
                else "-",
                " / ".join(f"{r[k]:.3f}" for k in answered) if r.get(answered[0]) is not None else "-",
                f"{r['drives_cpu_per_sync_ms']:.3f} ms" if r.get("drives_cpu_per_sync_ms") is not None else "-",
                witness,
                *([wakeup] if traced else []),
                r["ended"] or r.get("stopped") or "lasted the attempt",
            ]
        )
    during_words = "when the answer was missed" if traced else "during the slowest answer"
    realtime = table(
        ["drives (real-time mode)", "run", "cycle rate", "missed SYNCs", "cycles assisted",
         "jitter p50 / p99 / max (ms)", "SYNC → all TPDOs p50 / p99 / max (ms)", "drives CPU per SYNC",
         f"witness late max ({during_words}), ticks stolen",
         *(["slowest wake-up when the answer was missed, thread (its delivery, ms)"] if traced else []),
         "assistance ended"],
        rows,
    )  # fmt: skip
    best = [name for name, ok in held.items() if ok]
    runs = loop.get("realtime_runs", 1)
    witness_policy = next((r.get("witness") for r in loop["realtime"] if r.get("witness")), None)
    tail = (
        f"The deviation p95 is lower with the assistance in {data['paired_better']} of {seeds} paired seeds. "
        f"The fixture's computation (closest point, wall, Pinocchio Jacobian, τ = Jᵀ F) takes "
        f"{loop['fixture_median_ms']:.3f} ms per cycle at the median and {loop['fixture_p99_ms']:.2f} ms at the p99 "
        f"({loop['fixture_cycles']:,} cycles). In the simulated bus's real-time mode, "
        f"{runs if runs > 1 else 'one'} {seconds:g} s "
        f"attempt{'s' if runs > 1 else ''} at {target:.0f} Hz a configuration (an attempt ends its assistance, by "
        f"the safety rule, at the first SYNC a drive leaves unanswered a period after it went; SYNC → all TPDOs is the "
        f"time from the master's SYNC to its having every drive's answer, which that rule needs within a period "
        f"every cycle). Beside each attempt {witness_words(witness_policy)}: its lateness while the drives' "
        f"{'missed' if traced else 'slowest'} answer was awaited says the machine stalled then (the hypervisor's "
        f"stolen time, in 10 ms ticks, beside it)"
        + (
            ". The kernel's scheduler trace (ftrace, `benchmarks/schedtrace.py`) gives the slowest wake-up of a "
            "thread of the master or the drives while the missed answer was awaited, and its delivery: the time "
            "from the waker's CPU asking (`sched_waking`) to the sleeper's CPU taking it (`sched_wakeup`), which "
            "on a virtual machine whose CPU had halted, idle, is the hypervisor running it again; the witnesses, "
            "each woken by its own timer, cannot see it:"
            if traced
            else ":"
        )
    )
    verdict = f"Target ({target:.0f} Hz, 0 missed SYNCs, the assistance lasting the attempt, in every run): " + (
        f"met ({'; '.join(best)})." if best else "not met in any configuration."
    )
    ended = [r for r in loop["realtime"] if r["ended"]]  # below: the attempts whose assistance ended
    lasted_short = [r for r in loop["realtime"] if not _held(r, target) and not r["ended"]]
    short = len(ended)
    cpus = [r["drives_cpu_per_sync_ms"] for r in loop["realtime"] if r.get("drives_cpu_per_sync_ms") is not None]
    cpu_note = f"; {min(cpus):.2f}-{max(cpus):.2f} ms of its CPU a SYNC" if cpus else ""
    if short and traced:
        causes = [wakeup_cause(r.get("span_wakeup_max_ms"), r.get("span_delivery_ms")) for r in ended]
        host, queued = causes.count("host"), causes.count("queue")
        verdict += (
            f" Of the {short} attempts whose assistance ended, {host} had a wake-up whose delivery by the host took "
            f"{HOST_DELIVERY_MS:g} ms or more while the missed answer was awaited (a halted CPU run again late: the "
            f"machine's), {queued} a wake-up of {QUEUED_MS:g} ms or more that waited in a run queue, and the stall "
            f"witnesses were late in {stalled}; in the remaining {short - host - queued} neither the trace nor the "
            f"witnesses account for the late answer: what remains is the work on its way (the simulated drives, a "
            f"Python process handling the SYNC, its motors and the hand{cpu_note}, and the master's receive thread)."
        )
    elif short and any("witness_late_max_ms" in r for r in loop["realtime"]):
        verdict += (
            f" Of the {short} attempts whose assistance ended, the stall witness was late too while the slowest "
            f"answer was awaited in {stalled} (the machine stopped); in the other {short - stalled} it was on time: "
            "the simulated drives' answer itself came late (a Python process handling the SYNC, its motors and the "
            f"hand{cpu_note})."
        )
    if lasted_short:
        slowest = [
            f"{r['drives']}, run {r.get('run', 0) + 1}: {r['missed_syncs']} missed, the slowest wake-up of its threads "
            f"{r['wakeup_max_ms']:.2f} ms, {r['delivery_max_ms']:.2f} ms of it the delivery "
            f"({wakeup_cause(r['wakeup_max_ms'], r['delivery_max_ms'])})"
            if r.get("wakeup_max_ms") is not None
            else f"{r['drives']}, run {r.get('run', 0) + 1}: {r['missed_syncs']} missed"
            for r in lasted_short
        ]
        verdict += (
            f" {len(lasted_short)} attempt{'s' if len(lasted_short) > 1 else ''} lasted but missed SYNCs (a cycle "
            f"began more than a period late): {'; '.join(slowest)}."
        )
    if "floor" in loop:  # results since the floor was measured beside the attempts
        verdict += " " + floor_words(loop["floor"])
    return "\n\n".join((section(head, body, tail), realtime, wrap(verdict)))
