"""The command line's speed block: ``--help``, ``validate``, ``plugins`` and a small run's memory (``bench_cli.py``)."""

from __future__ import annotations

from pathlib import Path

from .formatting import load, met, section, span, table


def render_cli(results: Path) -> str:
    data = load(results, "cli")
    rows = data["rows"]
    memory = data["small_run"]
    loads = data["provenance"]
    repeats = len(rows[0]["runs_s"])

    def libraries(row: dict) -> str:
        found = row["imports"]["libraries"]
        return ", ".join(found) if found else "none"

    body = table(
        ["command", "median", "runs", "CPU (median)", "target", "", "peak memory", "imports", "libraries loaded"],
        [
            [
                f"`{r['command']}`",
                f"{r['median_s']:.2f} s",
                span(r["runs_s"], lambda v: f"{v:.2f}") + " s",
                f"{r['cpu_median_s']:.2f} s",
                f"≤ {r['target_s']:g} s",
                met(r["met"]),
                f"{r['peak_rss_MB']:.0f} MB",
                f"{r['imports']['total_s']:.2f} s",
                libraries(r),
            ]
            for r in rows
        ],
    )
    head = (
        f"Measured by `benchmarks/bench_cli.py`: each command a fresh process, as typed, {repeats} runs after a "
        f"warm-up, with Python's bytecode cache; 2 cores shared with other work, load average "
        f"{loads['load_before'][0]:.1f} before and {loads['load_after'][0]:.1f} after (1 min), so the times are "
        f"upper bounds; the CPU time (user + system) does not count the waiting for a core. A bare "
        f"`python -c pass` takes {data['python_startup_s']:.2f} s here. *imports* is what "
        f"`python -X importtime` counts for the command (one run):"
    )
    breakdown = []
    for r in rows:
        top = [t for t in r["imports"]["top"] if t["depth"] == 0][:4]
        if top:
            parts = ", ".join(f"`{t['module']}` {t['cum_s']:.2f} s" for t in top)
            breakdown.append(f"- `{r['command']}`: {parts}")
    tail = (
        f"A small run (`{memory['config']}`) holds {memory['rss'] / 2**20:.0f} MB when its first planner is "
        f"constructed (stage `{memory['stage']}`, {memory['modules']:,} modules loaded: "
        f"{', '.join(memory['loaded'])})."
    )
    parts = [section(head, body, tail)]
    if breakdown:
        parts.append("The largest imports by cumulative time (top level):\n\n" + "\n".join(breakdown))
    return "\n\n".join(parts)
