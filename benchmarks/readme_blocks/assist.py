"""The haptic assist block (docs/howto/haptic-assist.md): the same beginners with the assistance off and on, the
fixture's time per cycle and the real-time loop (``bench_assist.py``)."""

from __future__ import annotations

from pathlib import Path

from .formatting import find, load, met, section, table


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
        f"{load_avg} (1/5/15 min) at the start on 2 shared cores, so the timings are provisional):"
    )
    rate = loop["realtime_rate_hz"]
    rate_text = f"{rate:.0f} Hz" if rate is not None else "no rate (the loop did not run)"
    ended = loop["realtime_ended"]
    tail = (
        f"The deviation p95 is lower with the assistance in {data['paired_better']} of {seeds} paired seeds. "
        f"The fixture's computation (closest point, wall, Pinocchio Jacobian, τ = Jᵀ F) takes "
        f"{loop['fixture_median_ms']:.3f} ms per cycle at the median and {loop['fixture_p99_ms']:.2f} ms at the p99 "
        f"({loop['fixture_cycles']:,} cycles; wall-clock times, so the p99 includes the process being descheduled "
        f"on the shared machine). In the simulated bus's real-time mode the loop held {rate_text} for "
        f"a target of {loop['target_rate_hz']:.0f} Hz with {loop['realtime_missed_syncs']} missed SYNCs: the "
        f"target ({loop['target_rate_hz']:.0f} Hz, 0 missed) is "
        f"{met(loop['realtime_missed_syncs'] == 0 and rate is not None and rate >= 0.99 * loop['target_rate_hz'])}"
        + (f"; the assistance ended there: {ended}." if ended else ".")
    )
    return section(head, body, tail)
