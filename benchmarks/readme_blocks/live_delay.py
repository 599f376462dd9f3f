"""The live view's cost to the stage it watches: a page and a stalled client against no viewer
(``bench_live_delay.py``)."""

from __future__ import annotations

from pathlib import Path

from .formatting import (
    HOST_DELIVERY_MS,
    QUEUED_MS,
    find,
    floor_words,
    load,
    met,
    section,
    table,
    witness_per_cpu,
    witness_words,
)


def _causes(runs: list[dict]) -> dict[str, int]:
    """How many of the samples the viewer delayed in ``runs`` had each cause, as the benchmark counted them
    (``formatting.wakeup_cause`` of the slowest wake-up of the stage's threads meanwhile: "host", "queue", "none")."""
    return {c: sum(r["delayed_wakeup_causes"][c] for r in runs) for c in ("host", "queue", "none")}


def _page_words(runs: list[dict]) -> str:
    """What the page was: its renderer and frame budget, and that nothing automated it (results since 0a7da3e)."""
    if not all("page_frames" in r for r in runs):
        return ""
    budgets = sorted({r["page_fps_budget"] for r in runs})
    renderers = sorted({r["page_renderer"] for r in runs})
    return (
        f" The page drew {', '.join(str(r['page_frames']) for r in runs)} frames in those runs, within its "
        f"budget of {' and '.join(f'{b:g}' for b in budgets)} a second (report.js chooses it from the WebGL "
        f"renderer: {'; '.join(renderers)}); nothing automated it while the attempt ran "
        "(`benchmarks/unattended_page.py`)."
    )


def render_live_delay(results: Path) -> str:
    data = load(results, "live_delay")
    late = data["late_ms"]
    rows = data["rows"]
    body = table(
        ["stage's threads", "attempt", "runs", "samples", f"later than {late:g} ms", "median", "p99", "max"],
        [
            [
                r["scheduling"],
                r["case"],
                str(r["runs"]),
                f"{r['samples']:,}",
                f"{r['late_over_2ms']:,}",
                f"{r['median_ms']:.2f} ms",
                f"{r['p99_ms']:.2f} ms",
                f"{r['max_ms']:.1f} ms",
            ]
            for r in rows
        ],
    )
    loads = find(r"load average before ([\d./]+) and after ([\d./]+)", data["notes"], "live_delay.json notes")
    head = (
        f"`benchmarks/bench_live_delay.py` (`benchmarks/results/live_delay.json`) runs a guide stage following a "
        f"synthetic beginner paced at 100 samples/s ({data['seconds']:g} s attempts), alternately with no viewer "
        f"and fed to `surgiplan view --live` watched by a headless chromium page (software WebGL) and a stalled "
        f"client (a socket that upgrades to `/watch` and never reads), with the stage's threads at ordinary "
        f"priority and under SCHED_FIFO (`guidance.realtime_priority: 10`). A sample's lateness: how far behind "
        f"its own time the stage was done with it (analysis and publication), less the attempt's best (load "
        f"average {loads.group(1)} before and {loads.group(2)} after, 1/5/15 min, 2 shared cores):"
    )
    runs = data["viewer_runs"]
    witnessed = all("delayed_during_machine_stalls" in r for r in runs)
    traced = all("delayed_wakeup_causes" in r for r in runs)
    verdicts = []
    for watched in rows[1::2]:
        delayed = watched["delayed_by_viewer_over_2ms"]
        mine = [r for r in runs if r["scheduling"] == watched["scheduling"]]
        stalled = sum(r.get("delayed_during_machine_stalls", 0) for r in mine)
        verdicts.append(
            f"{watched['scheduling']}: {met(delayed == 0)} ({delayed:,} of {watched['samples']:,} samples were, "
            f"paired with the same sample of the attempt with no viewer"
            + (f", {stalled:,} of them while the stall witness was late too" if witnessed and delayed else "")
            + (
                "; in the scheduler trace, {host} had a wake-up of the stage's threads whose delivery by the host "
                "took {host_ms:g} ms or more, {queue} a wake-up of {queued_ms:g} ms or more that waited in a run "
                "queue, and {none} neither".format(**_causes(mine), host_ms=HOST_DELIVERY_MS, queued_ms=QUEUED_MS)
                if traced and delayed
                else ""
            )
            + (
                f"; {sum(r['delayed_during_collections'] for r in mine):,} came during a pass of Python's garbage "
                "collector of 0.5 ms or more (which holds the GIL)"
                if delayed and all("delayed_during_collections" in r for r in mine)
                else ""
            )
            + f"; p99 of the difference {watched['paired_p99_ms']:.2f} ms, max {watched['paired_max_ms']:.1f} ms)"
        )
    cut = [r["stalled_cut_after_s"] for r in runs if r["stalled_cut_after_s"] is not None]
    tail = (
        f"Target: no sample delayed by more than {late:g} ms by the viewer. "
        + "; ".join(verdicts)
        + ". "
        + (
            "The kernel's scheduler trace (ftrace, `benchmarks/schedtrace.py`) gives, for each delayed sample, the "
            "slowest wake-up of the stage's threads (the one that follows the samples and the source's reader) from "
            "the sample's due time to when the stage was done with it, and its delivery: the time from the waker's "
            "CPU asking (`sched_waking`) to the sleeper's CPU taking it (`sched_wakeup`), which on a virtual machine "
            "whose CPU had halted, idle, is the hypervisor running it again (the machine's); the rest, to "
            "`sched_switch`, it waited in a run queue, as does a thread pushed off its CPU while it could run "
            "(`prev_state=R`), until it runs again. A sample with neither was delayed with no slow wake-up or "
            "preemption: while those threads ran, waited for Python's GIL in short waits, or by a timer that fired "
            "late. "
            if traced and any(w["delayed_by_viewer_over_2ms"] for w in rows[1::2])
            else ""
        )
        + (
            "The kernel's scheduler trace was not available (it needs root and tracefs). "
            if any("sched_trace" in r for r in runs) and not traced
            else ""
        )
        + "On 2 cores "
        "the page's software rendering keeps both busy: a C probe beside it at ordinary priority wakes more than "
        "2 ms late now and then, with or without the shortest slice; one under SCHED_FIFO never did. "
        + (
            f"Beside every attempt, {witness_words(runs[0].get('witness'))}; a sample late while it was late too "
            "was late because the machine stopped"
            + (
                " (the witnesses also preempt the browser every millisecond on both CPUs, which gives an ordinary "
                "thread the CPU sooner than it would get it without them: the ordinary rows are better with them than "
                "without; a thread under SCHED_FIFO preempts the browser anyway)"
                if witness_per_cpu(runs[0].get("witness"))
                else ""
            )
            + ". Per run (no viewer / "
            "viewer), samples later than 2 ms, of them during such stalls, the witness's worst lateness and the "
            "ticks stolen: "
            + "; ".join(
                f"{r['scheduling']} {r['run']}: {r['late_alone_over_2ms']} ({r['late_alone_during_machine_stalls']}) "
                f"/ {r['late_over_2ms']} ({r['delayed_during_machine_stalls']} of {r['delayed_by_viewer_over_2ms']} "
                f"delayed by the viewer), witness {r['witness_late_max_ms_alone']:.1f} / "
                f"{r['witness_late_max_ms_watched']:.1f} ms, {r['steal_ticks_alone']} / {r['steal_ticks_watched']} "
                "ticks"
                for r in runs
            )
            + ". "
            if witnessed
            else ""
        )
        + f"The stalled client was disconnected in {len(cut)} of {len(runs)} runs"
        + (f" ({', '.join(f'{c:.1f}' for c in cut)} s after it connected)" if cut else "")
        + f"; the page got {', '.join(str(r['page_samples']) for r in runs)} samples and was told of "
        f"{sum(r['page_drops'] + r['feed_drops'] for r in runs)} dropped."
        + _page_words(runs)
        + (" " + floor_words(data["floor"]) if "floor" in data else "")
        + (
            " Time the host stole from this virtual machine per run (10 ms ticks, no viewer / viewer): "
            + ", ".join(
                f"{r['scheduling']} {r['run']}: {r['steal_ticks_alone']}/{r['steal_ticks_watched']}" for r in runs
            )
            + "."
            if all("steal_ticks_alone" in r for r in runs) and not witnessed
            else ""
        )
    )
    return section(head, body, tail)
