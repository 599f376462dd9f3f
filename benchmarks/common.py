"""Shared helpers for benchmarks: repeated timing with medians, and result files."""

from __future__ import annotations

import platform
import statistics
import time
from collections.abc import Callable
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def median_time(fn: Callable[[], object], repeat: int = 5, warmup: int = 1) -> tuple[float, list[float]]:
    """Median wall time (s) of ``fn()`` over ``repeat`` runs after ``warmup`` runs."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), times


def save(name: str, rows: list[dict], notes: str = "") -> Path:
    from surgiplan.storage import write_json_atomic

    path = RESULTS / f"{name}.json"
    write_json_atomic(
        path,
        {
            "benchmark": name,
            "machine": platform.platform(),
            "python": platform.python_version(),
            "notes": notes,
            "rows": rows,
        },
    )
    return path


def table(rows: list[dict], columns: list[str]) -> str:
    widths = [max(len(c), *(len(str(r.get(c, ""))) for r in rows)) for c in columns]
    line = "| " + " | ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True)) + " |"
    rule = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    body = [
        "| " + " | ".join(str(r.get(c, "")).ljust(w) for c, w in zip(columns, widths, strict=True)) + " |" for r in rows
    ]
    return "\n".join([line, rule, *body])
