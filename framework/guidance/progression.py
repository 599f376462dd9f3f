"""``surgiplan trainee NAME``: a trainee's history from the record, and a progression figure."""

from __future__ import annotations

import re
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ..storage import atomic_write
from .record import TraineeRecord


def history_rows(record: TraineeRecord, trainee: str, task: str | None = None) -> list[dict]:
    rows = []
    for i, a in enumerate(record.attempts(trainee, task), start=1):
        rows.append({"n": i, **{k: v for k, v in a.items() if k != "trainee_id"}})
    return rows


def progression_figure(path: Path, trainee: str, rows: list[dict], proficiency: dict[str, list[float]]) -> None:
    """Score and d_thresh (used and the trainee's own, from their deviations so far) over attempts, per task."""
    tasks = sorted({r["task"] for r in rows})
    fig, (ax_score, ax_thr) = plt.subplots(2, 1, figsize=(9, 6.4), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for c, task in zip(colours, tasks, strict=False):
        mine = [r for r in rows if r["task"] == task]
        n = [r["n"] for r in mine]
        ax_score.plot(n, [r["score"] for r in mine], "o-", color=c, label=task)
        ax_thr.plot(
            n,
            [1000 * r["d_thresh_m"] for r in mine],
            "s--",
            color=c,
            alpha=0.6,
            label=f"{task}: d_thresh of the recommended path",
        )
        ax_thr.plot(
            n,
            [1000 * v for v in proficiency[task]],
            "o-",
            color=c,
            label=f"{task}: the trainee's own (95th percentile of deviations so far)",
        )
    ax_score.set_ylabel("score (0-100)")
    ax_score.set_ylim(0, 100)
    ax_score.grid(alpha=0.3)
    ax_score.legend(fontsize=8, loc="lower right")
    ax_thr.set_ylabel("clearance threshold (mm)")
    ax_thr.set_xlabel("attempt")
    ax_thr.grid(alpha=0.3)
    ax_thr.legend(fontsize=8, loc="upper right")
    ax_thr.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
    fig.suptitle(f"trainee {trainee}: {len(rows)} attempt(s)")
    fig.tight_layout()
    try:
        with atomic_write(path, "wb") as handle:
            fig.savefig(handle, format="png", dpi=110)
    finally:
        plt.close(fig)


def cumulative_proficiency(record: TraineeRecord, rows: list[dict], percentile: float = 95.0) -> dict[str, list[float]]:
    """Per task, after each attempt: the percentile of every deviation recorded so far."""
    out: dict[str, list[float]] = {}
    seen: dict[str, list[np.ndarray]] = {}
    for r in rows:
        seen.setdefault(r["task"], []).append(record.samples(r["id"])["deviation"])
        out.setdefault(r["task"], []).append(float(np.percentile(np.concatenate(seen[r["task"]]), percentile)))
    return out


def safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name)
