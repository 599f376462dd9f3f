"""What an execution reports: metrics, a figure and a CSV log of the measured motion.

The metrics are measured from what the *drives reported* (TPDO positions at the
SYNC times), never from what was commanded:

* ``tracking_error_max_m``, ``tracking_error_rms_m``: the tip position (forward
  kinematics of the measured joints) against the tip of the trajectory sample
  the drives were commanded to be at, over the samples where every axis
  reported and before any fault; ``joint_tracking_error_max`` and
  ``joint_tracking_error_rms`` per joint (rad or m);
* ``executed_min_clearance_m``: the *executed* tip path's minimum clearance,
  re-measured on the scene (exact for the swept tip sphere between samples);
  devices add the clearance of their whole body (shaft, jaws, links);
* ``cycles``, ``bus_load_percent`` (every frame on the bus during the
  execution, stuff bits counted exactly, in % of the bit rate; the worst case
  beside it), ``faults``.

The figure (``<stage>.png``) shows the joints (measured against commanded,
normalised to their limits), the tip tracking error and the executed
clearance over time, with each fault marked; the CSV (``<stage>-execution.csv``)
holds every sample.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from surgiplan.storage import atomic_write, write_text_atomic
from surgiplan.units import ANGLE_UNITS, LENGTH_UNITS

from .bus import bus_load_percent
from .control import ExecutionLog


def tracking_metrics(tips: np.ndarray, reference_tips: np.ndarray, log: ExecutionLog, names: list[str]) -> dict:
    """Tip and joint tracking errors over the tracked samples (see the module docstring)."""
    tracked = log.tracking
    if not np.any(tracked):
        return {}
    error = np.linalg.norm(tips[tracked] - reference_tips[tracked], axis=1)
    joint_error = np.abs(log.measured[tracked] - log.reference[tracked])
    out: dict[str, Any] = {
        "tracking_error_max_m": float(error.max()),
        "tracking_error_rms_m": float(np.sqrt(np.mean(error**2))),
        "joint_tracking_error_max": dict(zip(names, joint_error.max(axis=0).tolist(), strict=True)),
        "joint_tracking_error_rms": dict(zip(names, np.sqrt(np.mean(joint_error**2, axis=0)).tolist(), strict=True)),
        "tracked_samples": int(np.count_nonzero(tracked)),
    }
    if log.status == "completed":
        out["final_error_m"] = float(np.linalg.norm(tips[-1] - reference_tips[-1]))
    return out


def bus_metrics(bus, log: ExecutionLog, bitrate: int, droppers) -> dict:
    """Bus load of every frame the master saw on the bus during the execution, and frames lost."""
    frames = bus.frames_between(log.start, log.end + 1e-12)
    exact, worst = bus_load_percent(frames, max(log.end - log.start, 1e-9), bitrate)
    return {
        "bus_load_percent": exact,
        "bus_load_worst_case_percent": worst,
        "frames": len(frames),
        "frames_dropped": sum(len(d.dropped) for d in droppers if d is not None),
    }


def write_log_csv(path: Path, log: ExecutionLog, names: list[str], tips: np.ndarray) -> None:
    """Every sample: time (s), measured and commanded joints (SI), tip (m), tracked flag."""
    header = ["t_s", *(f"measured_{n}" for n in names), *(f"commanded_{n}" for n in names)]
    header += ["tip_x_m", "tip_y_m", "tip_z_m", "tracked"]
    table = np.column_stack([log.t, log.measured, log.reference, tips, log.tracking.astype(float)])
    buffer = io.StringIO()
    np.savetxt(buffer, table, delimiter=",", header=",".join(header), comments="", fmt="%.9g")
    write_text_atomic(path, buffer.getvalue())


def execution_figure(
    path: Path,
    title: str,
    log: ExecutionLog,
    names: list[str],
    prismatic: np.ndarray,
    tip_error: np.ndarray,
    clearance: np.ndarray,
    clearance_label: str = "executed clearance",
    safety_margin: float = 0.0,
    plan_threshold: float | None = None,
) -> None:
    """One panel per joint (measured solid, commanded dashed on top, in degrees or mm), the tip tracking error,
    and the executed clearance against the device's safety margin and the plan's threshold; faults marked.
    Written atomically (PNG)."""
    nq = len(names)
    columns = 2 if nq > 1 else 1
    rows = int(np.ceil(nq / columns))
    fig = plt.figure(figsize=(10, 2.1 * rows + 5.4), constrained_layout=True)
    grid = fig.add_gridspec(rows + 2, columns, height_ratios=[1.0] * rows + [1.15, 1.35])
    t = log.t
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    axes = []
    for j, name in enumerate(names):
        ax = fig.add_subplot(grid[j // columns, j % columns], sharex=axes[0] if axes else None)
        unit = "mm" if prismatic[j] else "deg"
        scale = 1.0 / (LENGTH_UNITS[unit] if prismatic[j] else ANGLE_UNITS[unit])
        colour = colours[j % len(colours)]
        ax.plot(t, log.measured[:, j] * scale, "-", color=colour, lw=3.0, alpha=0.55, label="measured")
        ax.plot(t, log.reference[:, j] * scale, "--", color="black", lw=1.0, dashes=(4, 3), label="commanded")
        ax.set_ylabel(f"{name} ({unit})")
        span = np.nanmax(log.measured[:, j] * scale) - np.nanmin(log.measured[:, j] * scale) if len(t) else 0.0
        if span < 1e-3:  # a joint that does not move: show a small band around it, not float noise
            centre = float(np.nanmean(log.measured[:, j] * scale)) if len(t) else 0.0
            ax.set_ylim(centre - 1.0, centre + 1.0)
        if j == 0:
            ax.legend(loc="best", fontsize=8, framealpha=0.85)
        axes.append(ax)
    error_ax = fig.add_subplot(grid[rows, :], sharex=axes[0])
    tracked = log.tracking
    error_ax.plot(
        t[tracked], tip_error[tracked] * 1e6, ".", ms=2.5, color="tab:blue", label="tip: measured - commanded"
    )
    if np.any(tracked):
        rms = float(np.sqrt(np.mean(tip_error[tracked] ** 2)))
        error_ax.axhline(rms * 1e6, color="tab:blue", lw=1.0, ls=":", label=f"rms {rms * 1e6:.2f} µm")
        error_ax.legend(loc="upper right", fontsize=8, framealpha=0.85)
    error_ax.set_ylabel("tip tracking error (µm)")
    error_ax.set_ylim(bottom=0)
    clear_ax = fig.add_subplot(grid[rows + 1, :], sharex=axes[0])
    clear_ax.plot(t, clearance * 1e3, "-", color="tab:green", lw=1.6, label=clearance_label)
    contact = "contact (0 mm): the safety margin, refused below" if safety_margin <= 0 else "contact (0 mm)"
    clear_ax.axhline(0.0, color="black", lw=0.8, label=contact)
    if safety_margin > 0:
        label = f"safety margin {safety_margin * 1e3:g} mm (refused below)"
        clear_ax.axhline(safety_margin * 1e3, color="tab:red", lw=1.3, label=label)
    if plan_threshold is not None:
        clear_ax.axhline(
            plan_threshold * 1e3,
            color="tab:orange",
            lw=1.3,
            ls="--",
            label=f"plan's threshold {plan_threshold * 1e3:g} mm",
        )
        below = clearance < plan_threshold
        if np.any(below):
            clear_ax.fill_between(t, clearance * 1e3, plan_threshold * 1e3, where=below, color="tab:orange", alpha=0.15)
    clear_ax.set_ylabel(f"{clearance_label} (mm)")
    clear_ax.set_xlabel("time since the trajectory start (s)")
    clear_ax.legend(loc="best", fontsize=8, framealpha=0.85)
    all_axes = [*axes, error_ax, clear_ax]
    for fault in log.faults:
        if "t_s" not in fault:
            continue
        label = fault["kind"].replace("_", " ")
        if fault.get("node") is not None:
            label += f" (node {fault['node']})"
        for a in all_axes:
            a.axvline(fault["t_s"], color="tab:red", lw=1.0, alpha=0.7)
        clear_ax.annotate(
            label,
            (fault["t_s"], 0.03),
            xycoords=("data", "axes fraction"),
            rotation=90,
            va="bottom",
            ha="right",
            fontsize=8,
            color="tab:red",
        )
    for a in all_axes:
        a.grid(alpha=0.3)
    for a in axes[:-columns]:
        a.tick_params(labelbottom=False)
    fig.suptitle(title, fontsize=10)
    try:
        with atomic_write(path, "wb") as handle:
            fig.savefig(handle, format="png", dpi=110)
    finally:
        plt.close(fig)


def explain_lost_heartbeats(log: ExecutionLog, dropper) -> None:
    """Say so (``cause``) where a heartbeat time-out followed an injected frame loss of that node's heartbeat
    at the master (``dropper``: the master's :class:`.bus.FrameDropper`, None without frame loss).

    A consumer cannot tell a lost heartbeat from a silent node within its time-out (1.5 periods,
    so that a silent node stops every axis within two): with frame_loss the device then stops
    safely although the node is alive. The simulation knows which frames it dropped.
    """
    if dropper is None:
        return
    for fault in log.faults:  # times relative to the trajectory start, as the dropper's
        if fault["kind"] != "heartbeat_timeout":
            continue
        since = fault.get("last_heartbeat_s", -np.inf)
        lost = [t for t, can_id in dropper.dropped if can_id == 0x700 + fault["node"] and t >= since]
        if lost:
            times = ", ".join(f"{t:.3f}" for t in lost)
            fault["cause"] = (
                f"injected frame_loss dropped this node's heartbeat at {times} s; a lost heartbeat cannot be "
                "told from a silent node within the time-out, so the device stopped safely"
            )
