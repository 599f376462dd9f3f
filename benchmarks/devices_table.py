"""bench_devices.py's results: the drive modes as devices.json names them, and the README's table of them.

Light on purpose (no simulator, no kinematics): benchmarks/readme_tables.py renders the README's devices
block with :func:`readme_table`, and ``python benchmarks/bench_devices.py --table`` prints it.
"""

from __future__ import annotations

SEPARATE = "separate process (loopback bus)"
#: the SCHED_FIFO priority of the real-time runs (the master's loop, its receive and heartbeat threads), and
#: of the drives' process below it
PRIORITY = 30
DRIVES_PRIORITY = 20
SEPARATE_RT = f"separate process (loopback bus), SCHED_FIFO {PRIORITY} (drives {DRIVES_PRIORITY})"
THREAD = "in-process thread (virtual bus)"


def _causes(lapses: list) -> str:
    """The scheduler trace's account of a row's missed cycles ([late, wait, delivery, thread] ms each), in words."""
    from readme_blocks.formatting import HOST_DELIVERY_MS, QUEUED_MS, thread_label, wakeup_cause

    if not lapses:
        return "none missed"
    causes = [wakeup_cause(wait, delivery) for _, wait, delivery, _ in lapses]
    worst = max(lapses, key=lambda x: x[1])
    return (
        f"of {len(lapses)} missed cycles, {causes.count('host')} with a wake-up delivered "
        f"{HOST_DELIVERY_MS:g} ms or more late by the host, {causes.count('queue')} with one that waited "
        f"{QUEUED_MS:g} ms or more in a run queue, {causes.count('none')} with neither (the slowest: "
        f"{worst[1]:.2f} ms, {thread_label(worst[3])}, {worst[2]:.2f} ms of it delivery)"
    )


def readme_table(data: dict | None = None) -> str:
    """The README's table, from benchmarks/results/devices.json (so that its numbers are never typed by hand)."""
    import json

    from common import RESULTS
    from readme_blocks.formatting import floor_words, witness_words

    if data is None:
        data = json.loads((RESULTS / "devices.json").read_text())
    rows = data["rows"]
    machine = next(r for r in rows if r["section"] == "machine")
    seconds = machine.get("run_seconds", 10)
    lines = [
        f"{data['notes']} ({machine['date']}, {machine['runs_per_rate']} runs of at least {seconds:g} s per rate, "
        "the gimbal's gap path there and back)",
        "",
        "| drives | rate | runs completed / without a missed cycle | cycle jitter p50 / p99 / max | missed cycles "
        "| master CPU per cycle | drives CPU per SYNC | SYNC → all TPDOs p50 / p99 / max | bus load (worst case) "
        "| held |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    loops = [r for r in rows if r["section"] == "control_loop"]
    for r in loops:
        where = {SEPARATE: "other process"}.get(r["drives"], "thread")
        if "SCHED_FIFO" in r["drives"]:
            where = "other process, " + r["drives"].split(", ", 1)[1]
        drives_cpu = (
            f"{r['drives_cpu_per_sync_ms']} ms" if r["drives_cpu_per_sync_ms"] is not None else "(same process)"
        )
        answers = (
            f"{r['sync_to_tpdos_p50_ms']} / {r['sync_to_tpdos_p99_ms']} / {r['sync_to_tpdos_max_ms']} ms"
            if "sync_to_tpdos_p50_ms" in r
            else "—"
        )
        lines.append(
            f"| {where} | {r['rate_hz']:g} Hz | {r['runs_completed']} / {r.get('runs_without_missed', '—')} | "
            f"{r.get('jitter_p50_ms', '—')} / {r.get('jitter_p99_ms', '—')} / {r.get('jitter_max_ms', '—')} ms | "
            f"{r['missed_cycles']} of {r['cycles']:,} | {r['master_cpu_per_cycle_ms']} ms | "
            f"{drives_cpu} | {answers} | {r['bus_load_percent']} % ({r['bus_load_worst_case_percent']} %) | "
            f"{'yes' if r['held'] else 'no'} |"
        )

    for r in loops:
        if r.get("failures"):
            lines.append(
                f"- {r['drives']}, {r['rate_hz']:g} Hz: {len(r['failures'])} run(s) stopped; the first: "
                f"{r['failures'][0]}"
            )

    def clean(r: dict) -> bool:
        return r.get("runs_without_missed", "").split("/")[0] == str(machine["runs_per_rate"])

    floors = [r for r in rows if r["section"] == "scheduling_floor" and "runs_without_lapse" in r]
    fifo = [r for r in loops if "SCHED_FIFO" in r["drives"] and r["rate_hz"] == 1000]
    ordinary = [r for r in loops if r["drives"] == SEPARATE and r["rate_hz"] == 500]
    if fifo and ordinary:
        stolen = sum(r.get("steal_ticks", 0) for r in fifo + ordinary)
        lines += [
            "",
            f"Targets (issue 34): 1 kHz, 4 drives in another process, SCHED_FIFO, no missed cycle in every run: "
            f"{'met' if clean(fifo[0]) else 'not met'} ({fifo[0]['runs_without_missed']} runs, lapses "
            f"{', '.join(f'{x:g}' for x in fifo[0]['missed_lapses_late_ms']) or 'none'} ms late); 500 Hz at "
            f"ordinary priority, no missed cycle: {'met' if clean(ordinary[0]) else 'not met'} "
            f"({ordinary[0]['runs_without_missed']} runs). The hypervisor stole {stolen} clock ticks of this "
            "machine's time during those runs (/proc/stat)."
            + (
                " The machine's floor in the same session, rt-tests' cyclictest at 1 kHz under SCHED_FIFO, runs "
                "without a wake-up a period late: "
                + "; ".join(
                    f"{f['runs_without_lapse']} {'polling' if 'request 0' in f['loop'] else 'halting (as the loop)'}"
                    for f in floors
                )
                + " (below)."
                if floors
                else ""
            )
            + (
                " Beside every run "
                + witness_words(fifo[0].get("witness"))
                + ": "
                + "; ".join(
                    f"{r['rate_hz']:g} Hz {'under SCHED_FIFO' if r in fifo else 'at ordinary priority'}, late by up "
                    f"to {r['witness_late_max_ms']:.1f} ms, {r['missed_during_machine_stalls']} of the "
                    f"{r['missed_cycles']} missed cycles while it was late"
                    for r in fifo + ordinary
                )
                + "."
                if all("witness_late_max_ms" in r for r in fifo + ordinary)
                else ""
            )
            + (
                " The kernel's scheduler trace (`benchmarks/schedtrace.py`), for each missed cycle, the slowest "
                "wake-up of the master's or the drives' threads then: "
                + "; ".join(
                    f"{r['rate_hz']:g} Hz {'under SCHED_FIFO' if r in fifo else 'at ordinary priority'}: "
                    + _causes(r["missed_slowest_wakeup"])
                    for r in fifo + ordinary
                )
                + " (a wake-up's delivery: from the waker's CPU asking to the sleeper's CPU taking it, which on a "
                "virtual machine whose CPU had halted is the hypervisor running it again; a wait in a run queue is "
                "this machine's threads, or the host preempting a running CPU, which the witnesses see)."
                if all("missed_slowest_wakeup" in r for r in fifo + ordinary)
                else ""
            ),
        ]
    lines.append("")
    for r in rows:
        if r["section"] == "scheduling_floor" and "runs_without_lapse" in r:
            lines.append(f"- {floor_words(r)}")
        elif r["section"] == "scheduling_floor" and "error" not in r:
            lapses = ", ".join(f"{x:g}" for x in r["lapses_ms"])
            lines.append(
                f"- {r['loop']} (the machine's own floor), {r['seconds']:g} s: period p99 {r['period_p99_ms']} ms, "
                f"max {r['period_max_ms']} ms, {r['lapses_over_1_ms']} wake-ups more than a period late"
                + (f" ({lapses} ms)" if lapses else "")
                + (f", {r['steal_ticks']} ticks stolen by the hypervisor" if "steal_ticks" in r else "")
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
                + (f"; stopped: {r['error']}" if r.get("error") else "")
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
