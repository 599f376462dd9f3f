"""bench_devices.py's results: the drive modes as devices.json names them, and the README's table of them.

Light on purpose (no simulator, no kinematics): benchmarks/readme_tables.py renders the README's devices
block with :func:`readme_table`, and ``python benchmarks/bench_devices.py --table`` prints it.
"""

from __future__ import annotations

SEPARATE = "separate process (loopback bus)"
SEPARATE_RT = "separate process (loopback bus), SCHED_FIFO 20"
THREAD = "in-process thread (virtual bus)"
#: the SCHED_FIFO priority of the real-time runs (the loop's and the drives' threads)
PRIORITY = 20


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
