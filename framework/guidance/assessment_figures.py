"""Figures of the skill assessment: a trainee's metrics against their thresholds over attempts (the history bar
charts of simulators' score cards), a cohort's learning curves with the benchmark band, and CUSUM charts."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from ..outputs.figures import save_figure
from .benchmark import GATE_METRICS, Benchmark
from .cohort import Cohort
from .metrics import METRIC_BY_NAME

WITHIN, OUTSIDE, UNJUDGED = "#2ca02c", "#d62728", "#8c8c8c"


def _scale(name: str) -> tuple[float, str]:
    """Display factor and unit of a metric (lengths in mm)."""
    unit = METRIC_BY_NAME[name].unit
    if unit == "m":
        return 1000.0, "mm"
    return 1.0, {"s": "s", "count": "", "": ""}[unit]


def metric_history_figure(
    path: Path, trainee: str, task: str, history: Sequence[dict[str, Any]], benchmark: Benchmark | None, status: str
) -> None:
    """One bar chart per metric: every attempt's value, green within its threshold (dashed), red outside."""
    names = list(benchmark.thresholds) if benchmark else [m for m in GATE_METRICS]
    names = [n for n in names if any(h["metrics"].get(n) is not None for h in history)]
    cols = 4
    rows = max(1, math.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.4 * cols, 2.5 * rows + 0.9), squeeze=False)
    n = np.arange(1, len(history) + 1)
    for ax, name in zip(axes.flat, names, strict=False):
        k, unit = _scale(name)
        values = np.array([h["metrics"].get(name, np.nan) for h in history], float) * k
        threshold = benchmark.thresholds.get(name) if benchmark else None
        colours = [
            UNJUDGED
            if threshold is None
            else (WITHIN if threshold.within(v / k if np.isfinite(v) else None) else OUTSIDE)
            for v in values
        ]
        ax.bar(n, np.nan_to_num(values), color=colours, width=0.75)
        if threshold is not None:
            ax.axhline(threshold.value * k, color="black", linestyle="--", linewidth=1)
        label = METRIC_BY_NAME[name].label
        last = values[-1]
        title = f"{label}" + (f" ({unit})" if unit else "")
        if threshold is not None:
            sign = "≤" if threshold.better == "lower" else "≥"
            title += f"\nlast {last:.3g}, threshold {sign} {threshold.value * k:.3g}"
        else:
            title += f"\nlast {last:.3g}"
        ax.set_title(title, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
        ax.grid(axis="y", alpha=0.3)
    for ax in list(axes.flat)[len(names) :]:
        ax.axis("off")
    handles = [
        Patch(color=WITHIN, label="within the threshold"),
        Patch(color=OUTSIDE, label="outside"),
        Line2D([], [], color="black", linestyle="--", label="threshold (benchmark)"),
    ]
    if benchmark is None:
        handles = [Patch(color=UNJUDGED, label="no benchmark for this task (surgiplan benchmark-task)")]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)
    fig.suptitle(f"trainee {trainee} at {task}: {len(history)} attempt(s); gate {status}", fontsize=10)
    fig.tight_layout(rect=(0, 0.05, 1, 0.95))
    save_figure(fig, path)


def learning_curves_figure(path: Path, result: Cohort) -> None:
    """Score over attempts, one line per trainee, over the benchmark's band (expert mean ± k SD of the score) and
    threshold; a star where a trainee passed the gate."""
    fig, ax = plt.subplots(figsize=(9, 5))
    benchmark = result.benchmark
    score = benchmark.thresholds.get("score") if benchmark else None
    longest = max(len(c.attempts) for c in result.trainees)
    if score is not None:
        k = benchmark.k if benchmark.method == "mean_sd" and benchmark.k else 1.0
        ax.axhspan(score.mean - k * score.sd, score.mean + k * score.sd, color="#2ca02c", alpha=0.15)
        ax.axhline(score.value, color="#2ca02c", linestyle="--", linewidth=1)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, curve in enumerate(result.trainees):
        c = colours[i % len(colours)]
        n = [a["n"] for a in curve.attempts]
        ax.plot(n, [a["score"] for a in curve.attempts], "o-", color=c, markersize=3, linewidth=1.2, label=curve.name)
        if curve.passed_at is not None:
            ax.plot(curve.passed_at, curve.attempts[curve.passed_at - 1]["score"], "*", color=c, markersize=14)
    ax.set_xlim(0.5, longest + 0.5)
    ax.set_ylim(0, 100)
    ax.set_xlabel("attempt")
    ax.set_ylabel("score (0-100)")
    ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
    ax.grid(alpha=0.3)
    handles, _ = ax.get_legend_handles_labels()
    if score is not None:
        handles += [
            Patch(color="#2ca02c", alpha=0.3, label=f"benchmark: expert score {score.mean:.0f} ± {k:g} SD"),
            Line2D([], [], color="#2ca02c", linestyle="--", label=f"score threshold {score.value:.0f}"),
        ]
    handles.append(Line2D([], [], marker="*", color="black", linestyle="none", markersize=10, label="gate passed"))
    ax.legend(handles=handles, fontsize=8, loc="lower right", ncol=2)
    ax.set_title(f"learning curves at {result.task}: {len(result.trainees)} trainee(s)", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)


def verdict_of(chart) -> str:
    """What a CUSUM chart said: acceptable at #n, unacceptable at #m, or no decision yet (both, in order)."""
    said = sorted(
        (n, what)
        for n, what in ((chart.unacceptable_at, "unacceptable"), (chart.acceptable_at, "acceptable"))
        if n is not None
    )
    return ", then ".join(f"{what} at #{n}" for n, what in said) or "no decision yet"


def cusum_figure(path: Path, result: Cohort) -> None:
    """One CUSUM chart per trainee, with the decision lines h1 (unacceptable) and -h0 (acceptable)."""
    curves = [c for c in result.trainees if c.cusum is not None]
    cols = min(3, max(1, len(curves)))
    rows = max(1, math.ceil(len(curves) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.8 * rows + 0.8), squeeze=False)
    for ax, curve in zip(axes.flat, curves, strict=False):
        chart = curve.cusum
        n = np.arange(0, len(chart.values) + 1)
        values = np.concatenate([[0.0], chart.values])
        ax.plot(n, values, "-", color="#1f6fb4", linewidth=1.3)
        failed = np.array(curve.failed, bool)
        ax.plot(n[1:][failed], values[1:][failed], "x", color=OUTSIDE, markersize=5)
        ax.plot(n[1:][~failed], values[1:][~failed], "o", color=WITHIN, markersize=3)
        ax.step(
            n, np.concatenate([[-chart.h0], chart.acceptable_line]), where="post", color=WITHIN, linestyle="--", lw=1
        )
        ax.step(
            n, np.concatenate([[chart.h1], chart.unacceptable_line]), where="post", color=OUTSIDE, linestyle="--", lw=1
        )
        ax.axhline(0, color="black", linewidth=0.6)
        verdict = verdict_of(chart)
        ax.set_title(f"{curve.name}: {verdict}", fontsize=9)
        ax.set_xlabel("attempt", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(curves) :]:
        ax.axis("off")
    s = result.settings
    rule = "outside the benchmark" if result.benchmark else f"score below {result.pass_score:g}"
    fig.suptitle(
        f"CUSUM at {result.task}: failure = {rule}; acceptable rate p0 {s.p0:g}, unacceptable p1 {s.p1:g}, "
        f"alpha {s.alpha:g}, beta {s.beta:g}",
        fontsize=9,
    )
    handles = [
        Line2D([], [], color=OUTSIDE, linestyle="--", label="lowest so far + h1: unacceptable"),
        Line2D([], [], color=WITHIN, linestyle="--", label="highest so far - h0: acceptable"),
        Line2D([], [], color=OUTSIDE, marker="x", linestyle="none", label="failed attempt"),
        Line2D([], [], color=WITHIN, marker="o", linestyle="none", label="successful attempt"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 0.94))
    save_figure(fig, path)
