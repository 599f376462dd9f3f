"""The guide block: per-sample latency of the guidance (``bench_guide.py``)."""

from __future__ import annotations

from pathlib import Path

from .formatting import find, load, met, section, table


def render_guide(results: Path) -> str:
    data = load(results, "guide")
    rows = data["rows"]
    body = table(
        [
            "space",
            "samples",
            "analysis per sample: median / p99 / max",
            "paced at the source's rate: delay median / p99",
            "targets (median < 1 ms, p99 < 5 ms)",
        ],
        [
            [
                r["case"],
                f"{r['samples']:,}",
                f"{r['analysis_median_ms']:.3f} / {r['analysis_p99_ms']:.3f} / {r['analysis_max_ms']:.2f} ms",
                f"{r['paced_delay_median_ms']:.2f} / {r['paced_delay_p99_ms']:.2f} ms ({r['paced_samples']:,} samples)",
                met(
                    max(r["analysis_median_ms"], r["paced_delay_median_ms"]) < 1
                    and max(r["analysis_p99_ms"], r["paced_delay_p99_ms"]) < 5
                ),
            ]
            for r in rows
        ],
    )
    load_avg = find(r"load average at the start ([\d./]+)", data["notes"], "guide.json notes").group(1)
    head = (
        f"`benchmarks/bench_guide.py` measures the per-sample latency against a 5,000-milestone beginner's "
        f"recommended path (`benchmarks/results/guide.json`; load average {load_avg} (1/5/15 min) at the start on "
        f"2 shared cores): the analysis alone, over synthetic beginner attempts back to back, and the delay from "
        f"the source producing a sample to the end of its analysis with the synthetic trainee paced in real time "
        f"(100 samples/s), what a trainee watching feels:"
    )
    return section(head, body)
