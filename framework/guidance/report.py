"""What a guided attempt writes: the samples (CSV) and a figure, like a trainer would look at them.

``<stage>-samples.csv``: one row per sample, ``t_s, x_m, y_m, z_m, deviation_m,
progress_m, clearance_m, critical`` (SI; the file is itself a recorded
attempt the ``recorded_attempt`` source can replay).

``<stage>.png``: the followed tip path over the recommended one from above,
coloured by clearance, the critical regions circled, each event numbered
where it started; beside it the deviation and the clearance over time with
the tolerance and d_thresh, the events shaded.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import TwoSlopeNorm
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from ..storage import atomic_write, write_text_atomic
from .analysis import Guide

EVENT_COLOURS = {
    "contact": "#7f0000",
    "below_threshold": "#d62728",
    "deviation": "#ff7f0e",
    "wrong_way": "#9467bd",
    "stalled": "#8c564b",
}

CRITICAL_COLOUR = "#4a90c2"

CSV_HEADER = ["t_s", "x_m", "y_m", "z_m", "deviation_m", "progress_m", "clearance_m", "critical"]


def write_samples_csv(path: Path, guide: Guide) -> None:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_HEADER)
    for m in guide.measurements:
        writer.writerow(
            [
                f"{m.t:.6f}",
                *(f"{v:.9g}" for v in m.tip),
                f"{m.deviation:.9g}",
                f"{m.progress:.9g}",
                f"{m.clearance:.9g}",
                int(m.critical),
            ]
        )
    write_text_atomic(path, out.getvalue(), private=True)  # personal data: mode 0600


def attempt_figure(path: Path, guide: Guide, title: str) -> None:
    ms = guide.measurements
    k, unit = guide.k, guide.unit
    t = np.array([m.t for m in ms])
    tips = np.array([m.tip for m in ms]) * k
    deviation = np.array([m.deviation for m in ms]) * k
    clearance = np.array([m.clearance for m in ms]) * k
    threshold = guide.threshold * k
    fig = plt.figure(figsize=(14, 6.2))
    grid = fig.add_gridspec(2, 2, width_ratios=(1.25, 1.0), hspace=0.35, wspace=0.22)
    ax = fig.add_subplot(grid[:, 0])
    scene = guide.scene
    for obstacle in scene.obstacles:
        mesh = obstacle.to_trimesh()
        ax.add_collection(
            PolyCollection(mesh.vertices[mesh.faces][:, :, :2] * k, facecolor="#9a9a9a", edgecolor="none", alpha=0.8)
        )
        centre = mesh.vertices.mean(axis=0)[:2] * k
        ax.annotate(obstacle.name, centre, ha="center", va="center", fontsize=7, color="#333333")
    lo, hi = scene.bounds_min * k, scene.bounds_max * k
    ax.add_patch(plt.Rectangle(lo[:2], *(hi - lo)[:2], fill=False, edgecolor="black", linewidth=0.8))
    ax.plot(guide.tips[:, 0] * k, guide.tips[:, 1] * k, color="black", linestyle="--", linewidth=1.2)
    for a, b in guide.critical:
        inside = (guide.arc >= a) & (guide.arc <= b)
        if np.any(inside):
            pts = guide.tips[inside][:, :2] * k
            ax.plot(pts[:, 0], pts[:, 1], color=CRITICAL_COLOUR, linewidth=10, alpha=0.35, solid_capstyle="round")
    if len(tips) >= 2:
        segments = np.stack([tips[:-1, :2], tips[1:, :2]], axis=1)
        top = max(float(np.nanmax(clearance)), threshold + 1e-9, 1e-9)
        norm = TwoSlopeNorm(
            vmin=min(0.0, float(np.nanmin(clearance)) - 1e-9),
            vcenter=max(threshold, 1e-9),
            vmax=max(top, threshold * 2 + 1e-9),
        )
        lines = LineCollection(segments, cmap="RdYlGn", norm=norm, linewidths=2.4, capstyle="round")
        lines.set_array(0.5 * (clearance[:-1] + clearance[1:]))
        ax.add_collection(lines)
        bar = fig.colorbar(lines, ax=ax, fraction=0.04, pad=0.02)
        bar.set_label(f"clearance ({unit}); d_thresh {threshold:.3g} {unit} at the centre")
    for i, event in enumerate(guide.events, start=1):
        m = ms[int(np.searchsorted(t, event.start_t))]
        ax.plot(
            *(m.tip[:2] * k),
            "o",
            markersize=9,
            markerfacecolor="white",
            markeredgecolor=EVENT_COLOURS[event.kind],
            markeredgewidth=2,
        )
        ax.annotate(str(i), m.tip[:2] * k, ha="center", va="center", fontsize=6.5, color=EVENT_COLOURS[event.kind])
    ax.plot(*(guide.tips[0, :2] * k), "o", color="#2ca02c")
    ax.plot(*(guide.tips[-1, :2] * k), "*", color="black", markersize=11)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel(f"x ({unit})")
    ax.set_ylabel(f"y ({unit})")
    ax.set_title("followed (coloured by clearance) over recommended (dashed), from above", fontsize=9)

    ax_dev = fig.add_subplot(grid[0, 1])
    ax_clr = fig.add_subplot(grid[1, 1], sharex=ax_dev)
    ax_dev.plot(t, deviation, color="#1f6fb4", linewidth=1.2)
    ax_dev.axhline(guide.settings.deviation_tolerance * k, color="#ff7f0e", linestyle="--", linewidth=1)
    ax_dev.set_ylabel(f"deviation ({unit})")
    ax_clr.plot(t, clearance, color="#2ca02c", linewidth=1.2)
    if threshold > 0:
        ax_clr.axhline(threshold, color="#d62728", linestyle="--", linewidth=1)
    ax_clr.axhline(0.0, color="black", linewidth=0.8)
    ax_clr.set_ylabel(f"clearance ({unit})")
    ax_clr.set_xlabel("time (s)")
    for axis in (ax_dev, ax_clr):
        for a, b in _critical_spans(guide):
            axis.axvspan(a, b, facecolor="none", edgecolor=CRITICAL_COLOUR, hatch="///", alpha=0.6, linewidth=0)
        for event in guide.events:
            axis.axvspan(
                event.start_t,
                max(event.end_t, event.start_t + 1e-3),
                color=EVENT_COLOURS[event.kind],
                alpha=0.25,
                linewidth=0,
            )
        axis.grid(alpha=0.3)
    handles = [
        Line2D([], [], color="black", linestyle="--", label="recommended path"),
        Line2D([], [], color="#1f6fb4", label="deviation"),
        Line2D([], [], color="#ff7f0e", linestyle="--", label="deviation tolerance"),
        Line2D([], [], color="#2ca02c", label="clearance"),
        Line2D([], [], color="#d62728", linestyle="--", label="d_thresh"),
        Patch(facecolor="none", edgecolor=CRITICAL_COLOUR, hatch="///", label="in a critical region"),
    ]
    handles += [
        Patch(color=EVENT_COLOURS[kind], alpha=0.5, label=kind.replace("_", " ") + " (event)")
        for kind in EVENT_COLOURS
        if any(e.kind == kind for e in guide.events)
    ]
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 5), fontsize=8, frameon=False)
    fig.suptitle(title, fontsize=11)
    fig.subplots_adjust(left=0.05, right=0.98, top=0.9, bottom=0.16)
    try:
        with atomic_write(path, "wb") as handle:
            fig.savefig(handle, format="png", dpi=110)
    finally:
        plt.close(fig)


def _critical_spans(guide: Guide) -> list[tuple[float, float]]:
    """Time spans of consecutive samples in a critical region."""
    spans = []
    start = None
    last = None
    for m in guide.measurements:
        if m.critical and start is None:
            start = m.t
        if not m.critical and start is not None:
            spans.append((start, last))
            start = None
        last = m.t
    if start is not None:
        spans.append((start, last))
    return spans
