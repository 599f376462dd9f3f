"""What was flown, measured against the plan and the scene: metrics, the flight log, the figure.

Everything is re-measured from the vehicle's own LOCAL_POSITION_NED reports
(mapped back into the scene), independently of what the vehicle was told:

* tracking error: the distance of each flown position to the *planned*
  path (the polyline the planner returned; paper 000's "deviation from the
  suggested path"), over the stretch between reaching the path's first and
  last waypoints; in offboard mode also the distance to the setpoint of the
  same instant;
* clearance: the flown path is the polyline through the reported positions;
  its exact minimum clearance (the vehicle a sphere of the plan's
  ``tip_radius``, each straight piece a capsule) against the scene's
  obstacles, overall and split into the stretches inside and outside the
  plan's critical regions (matched by arc length along the planned path);
* the length flown below the plan's clearance threshold.
"""

from __future__ import annotations

import io
import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np
from surgiplan.geometry.primitives import point_segment_distance
from surgiplan.storage import atomic_write, write_text_atomic


def project_onto_path(points: np.ndarray, path: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (m) of each point (N, 3) to the polyline ``path`` (M, 3), and the arc length of its foot."""
    points = np.atleast_2d(points)
    path = np.atleast_2d(path)
    if len(path) == 1:
        return np.linalg.norm(points - path[0], axis=1), np.zeros(len(points))
    a, b = path[:-1], path[1:]
    ab = b - a
    length = np.linalg.norm(ab, axis=1)
    start = np.concatenate([[0.0], np.cumsum(length)])
    distance = np.empty(len(points))
    arc = np.empty(len(points))
    chunk = max(1, 2_000_000 // len(a))
    for i in range(0, len(points), chunk):
        p = points[i : i + chunk, None, :]
        d = point_segment_distance(p, a[None], b[None])
        best = np.argmin(d, axis=1)
        distance[i : i + chunk] = d[np.arange(len(best)), best]
        seg = ab[best]
        t = np.einsum("ij,ij->i", p[:, 0] - a[best], seg) / np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-300)
        arc[i : i + chunk] = start[best] + np.clip(t, 0.0, 1.0) * length[best]
    return distance, arc


def split_at_regions(
    a: np.ndarray, b: np.ndarray, arc_a: np.ndarray, arc_b: np.ndarray, regions: list[tuple[float, float]]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segments a -> b cut where their arc length along the path (linear between the ends) crosses a region's
    ends, and for each piece whether it lies in a region (its middle's arc length inside one)."""
    ends = np.array(sorted({x for region in regions for x in region}))
    lo, hi = np.minimum(arc_a, arc_b), np.maximum(arc_a, arc_b)
    pieces_a, pieces_b, middles = [], [], []
    for i in range(len(a)):
        cuts = ends[(ends > lo[i]) & (ends < hi[i])]
        span = arc_b[i] - arc_a[i]
        fractions = np.concatenate([[0.0], np.sort((cuts - arc_a[i]) / span) if len(cuts) else [], [1.0]])
        for f0, f1 in itertools.pairwise(fractions):
            pieces_a.append(a[i] + f0 * (b[i] - a[i]))
            pieces_b.append(a[i] + f1 * (b[i] - a[i]))
            middles.append(arc_a[i] + 0.5 * (f0 + f1) * span)
    middle = np.array(middles)
    inside = np.zeros(len(middle), dtype=bool)
    for start, end in regions:
        inside |= (middle >= start) & (middle <= end)
    return np.array(pieces_a), np.array(pieces_b), inside


def flight_metrics(
    t: np.ndarray,
    flown: np.ndarray,
    velocity: np.ndarray,
    space,
    planned: np.ndarray,
    window: tuple[float, float],
    threshold: float | None,
    critical: list[tuple[float, float]],
    setpoints: np.ndarray | None = None,
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Metrics (SI) of a flight, and per-sample arrays (clearance, deviation, in_path) for the log and figure."""
    metrics: dict[str, Any] = {"samples": len(t)}
    arrays: dict[str, np.ndarray] = {}
    if len(t) == 0:
        return metrics, arrays
    steps = np.linalg.norm(np.diff(flown, axis=0), axis=1)
    metrics["flight_time_s"] = float(t[-1] - t[0])
    metrics["flown_length_m"] = float(steps.sum())
    metrics["max_speed_mps"] = float(np.max(np.linalg.norm(velocity, axis=1)))
    deviation, arc = project_onto_path(flown, planned)
    clearance = space.clearance(flown)
    arrays.update(clearance=clearance, deviation=deviation, arc=arc)
    in_path = (t >= window[0] - 1e-9) & (t <= window[1] + 1e-9)
    arrays["in_path"] = in_path
    metrics["planned_min_clearance_m"] = float(np.min(space.segment_clearance(planned[:-1], planned[1:])))
    if len(flown) >= 2:
        segment = space.segment_clearance(flown[:-1], flown[1:])
        metrics["flight_min_clearance_m"] = float(segment.min())
    if np.count_nonzero(in_path) >= 2:
        idx = np.flatnonzero(in_path)
        a, b = flown[idx[:-1]], flown[idx[1:]]
        segment = space.segment_clearance(a, b)
        worst = int(np.argmin(segment))
        nearest = int(space.scene.segment_distance(a[worst][None], b[worst][None])[1][0])
        metrics["path_time_s"] = float(t[idx[-1]] - t[idx[0]])
        metrics["flown_path_length_m"] = float(np.linalg.norm(b - a, axis=1).sum())
        metrics["flown_min_clearance_m"] = float(segment[worst])
        metrics["flown_min_clearance_obstacle"] = space.scene.obstacles[nearest].name if nearest >= 0 else None
        metrics["flown_min_clearance_point_m"] = [float(x) for x in 0.5 * (a[worst] + b[worst])]
        metrics["tracking_error_max_m"] = float(deviation[idx].max())
        metrics["tracking_error_rms_m"] = float(np.sqrt(np.mean(deviation[idx] ** 2)))
        metrics["tracking_error_p95_m"] = float(np.percentile(deviation[idx], 95))
        if critical:
            # split the flown segments where they cross a critical region's ends, so that what is measured inside
            # and outside does not depend on where the telemetry samples happen to fall (samples 5 cm apart at
            # 1 m/s moved the clearance 'outside the door' by 2.5 cm from one flight to the next)
            sa, sb, inside = split_at_regions(a, b, arc[idx[:-1]], arc[idx[1:]], critical)
            sub = space.segment_clearance(sa, sb)
            metrics["flown_min_clearance_in_critical_m"] = float(sub[inside].min()) if inside.any() else None
            metrics["flown_min_clearance_outside_critical_m"] = float(sub[~inside].min()) if (~inside).any() else None
        if threshold is not None:
            pieces = np.linalg.norm(b - a, axis=1)
            metrics["clearance_threshold_m"] = float(threshold)
            metrics["flown_length_below_threshold_m"] = float(pieces[segment < threshold].sum())
            if critical:
                lengths = np.linalg.norm(sb - sa, axis=1)
                below_outside = lengths[(sub < threshold) & ~inside].sum()
            else:
                below_outside = pieces[segment < threshold].sum()
            metrics["flown_length_below_threshold_outside_critical_m"] = float(below_outside)
    # the names the summary table (and the other devices) use, for the stretch along the path
    for common, ours in (
        ("length_m", "flown_path_length_m"),
        ("executed_min_clearance_m", "flown_min_clearance_m"),
        ("length_below_threshold_m", "flown_length_below_threshold_m"),
    ):
        if ours in metrics:
            metrics[common] = metrics[ours]
    if setpoints is not None and np.any(in_path):
        error = np.linalg.norm(flown - setpoints, axis=1)
        arrays["setpoint_error"] = error
        during = in_path & np.isfinite(error)
        if np.any(during):
            metrics["setpoint_error_max_m"] = float(error[during].max())
            metrics["setpoint_error_rms_m"] = float(np.sqrt(np.mean(error[during] ** 2)))
    return metrics, arrays


def fence_breaches(events, t: np.ndarray, flown: np.ndarray) -> list[dict[str, Any]]:
    """The vehicle's word on its geofence ((vehicle time s, text) pairs) with where it was (scene m, the sample
    nearest in time)."""
    out = []
    for when, text in events:
        entry: dict[str, Any] = {"vehicle_time_s": float(when), "message": text}
        if len(t):
            entry["position_m"] = [float(x) for x in flown[int(np.argmin(np.abs(t - when)))]]
        out.append(entry)
    return out


def fence_position_metrics(fence, space, point: np.ndarray) -> dict[str, float]:
    """Where the flight ended against the fence: its clearance from the obstacles (the vehicle a sphere) and its
    distance from the fence's nearest edge in plan view (positive inside the fence)."""
    from .zones import inside_fence

    xy = np.asarray(point, float)[None, :2]
    edge = min(float(zone.boundary_distance(xy)[0]) for zone in fence.zones)
    inside = bool(inside_fence(fence.zones, xy)[0])
    return {
        "final_clearance_m": float(space.clearance(np.asarray(point, float)[None])[0]),
        "final_fence_distance_m": edge if inside else -edge,
    }


def write_flight_csv(path: Path, t: np.ndarray, flown: np.ndarray, velocity: np.ndarray, arrays) -> None:
    """The flight log: vehicle time, scene position and velocity, clearance, deviation (SI), atomically."""
    columns = [t, *flown.T, *velocity.T, arrays["clearance"], arrays["deviation"], arrays["in_path"].astype(float)]
    header = "t_s,x_m,y_m,z_m,vx_mps,vy_mps,vz_mps,clearance_m,deviation_m,on_path"
    buffer = io.StringIO()
    np.savetxt(buffer, np.column_stack(columns), delimiter=",", header=header, comments="", fmt="%.9g")
    write_text_atomic(path, buffer.getvalue())


def flight_figure(
    path: Path,
    scene,
    planned: np.ndarray,
    route: np.ndarray,
    t: np.ndarray,
    flown: np.ndarray,
    arrays,
    metrics: dict[str, Any],
    threshold: float | None,
    critical: list[tuple[float, float]],
    title: str,
    link: np.ndarray | None = None,
    link_text: str = "",
    zones=None,
    breaches=(),
    setpoints: np.ndarray | None = None,
) -> None:
    """Planned versus flown: a top view coloured by clearance, and clearance, deviation and (given ``link``)
    the link's losses over time.

    ``link``: rows (vehicle time s, messages of the vehicle lost so far, received so far), from the gaps in
    its MAVLink sequence numbers; drawn as the share lost per second of vehicle time, with ``link_text``
    (totals) beside it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection, PolyCollection

    rows = 3 if link is not None and len(link) >= 2 else 2
    fig = plt.figure(figsize=(14, 6.2 if rows == 2 else 8.0))
    grid = fig.add_gridspec(rows, 2, width_ratios=[1.7, 1.0], hspace=0.45, wspace=0.3)
    top = fig.add_subplot(grid[:, 0])
    for obstacle in scene.obstacles:
        mesh = obstacle.to_trimesh()
        top.add_collection(
            PolyCollection(mesh.vertices[mesh.faces][:, :, :2], facecolor="#9a9a9a", edgecolor="none", alpha=0.8)
        )
        centre = mesh.vertices.mean(axis=0)[:2]
        top.annotate(obstacle.name, centre, ha="center", va="center", fontsize=7, color="#333333")
    lo, hi = scene.bounds_min, scene.bounds_max
    top.add_patch(plt.Rectangle(lo[:2], *(hi - lo)[:2], fill=False, edgecolor="black", linewidth=0.8))
    for i, zone in enumerate(z for z in zones or () if not z.inclusion):
        outline = zone.outline(72)
        top.fill(*outline.T, facecolor="#d62728", alpha=0.07, edgecolor="none")
        top.plot(
            *outline.T, "--", color="#d62728", linewidth=0.8, label="geofence (exclusion zones)" if i == 0 else None
        )
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(planned, axis=0), axis=1))])
    for i, (a, b) in enumerate(critical):
        dense = np.linspace(a, b, 50)
        pts = np.column_stack([np.interp(dense, arc, planned[:, k]) for k in range(2)])
        top.plot(
            *pts.T,
            color="orange",
            linewidth=12,
            alpha=0.35,
            solid_capstyle="round",
            label="critical region" if i == 0 else None,
        )
    top.plot(*route[:, :2].T, ":", color="#555555", linewidth=1.0, label="route (take-off, approach, landing)")
    top.plot(*planned[:, :2].T, "--", color="#1f6fb4", linewidth=1.6, label="planned path")
    if setpoints is not None and np.isfinite(setpoints).any():
        top.plot(*setpoints[:, :2].T, "-", color="#9467bd", linewidth=0.9, label="offboard setpoints")
    if len(flown) >= 2:
        segments = np.stack([flown[:-1, :2], flown[1:, :2]], axis=1)
        value = np.minimum(arrays["clearance"][:-1], arrays["clearance"][1:])
        # colours resolve the range that matters (up to twice the threshold); more is "plenty"
        upper = 2 * threshold if threshold else max(float(np.nanmax(value)), 1e-3)
        lines = LineCollection(segments, cmap="viridis", linewidths=2.4, label="flown")
        lines.set_array(np.clip(value, 0, upper))
        lines.set_clim(0, upper)
        top.add_collection(lines)
        bar = fig.colorbar(lines, ax=top, fraction=0.035, pad=0.02)
        bar.set_label("flown clearance (m)" + (f", capped at {upper:.2g}" if threshold else ""))
        if threshold is not None:
            low = value < threshold
            if np.any(low):
                top.add_collection(
                    LineCollection(segments[low], colors="#d62728", linewidths=1.0, label="flown below threshold")
                )
    point = metrics.get("flown_min_clearance_point_m")
    if point is not None:
        top.plot(
            point[0],
            point[1],
            "x",
            color="#d62728",
            markersize=10,
            mew=2,
            label=f"min clearance {metrics['flown_min_clearance_m']:.3f} m",
        )
    for i, breach in enumerate(b for b in breaches if "position_m" in b):
        label = "vehicle: geofence" if i == 0 else None
        top.plot(*breach["position_m"][:2], "D", color="#d62728", markersize=6, mfc="white", mew=1.5, label=label)
    top.plot(*planned[0, :2], "o", color="#2ca02c", label="start")
    top.plot(*planned[-1, :2], "*", color="black", markersize=12, label="goal")
    top.set_xlim(lo[0], hi[0])
    top.set_ylim(lo[1], hi[1])
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.legend(loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=4, fontsize=7, frameon=False)

    clearance_ax = fig.add_subplot(grid[0, 1])
    deviation_ax = fig.add_subplot(grid[1, 1], sharex=clearance_ax)
    if len(t):
        time = t - t[0]
        in_path = arrays["in_path"]
        for ax in (clearance_ax, deviation_ax):
            if np.any(in_path):
                ax.axvspan(time[in_path][0], time[in_path][-1], color="#1f6fb4", alpha=0.07, label="on the path")
        clearance_ax.plot(time, arrays["clearance"], color="#1f6fb4", linewidth=1.2, label="flown clearance")
        if threshold is not None:
            clearance_ax.axhline(threshold, color="#d62728", linestyle="--", linewidth=1, label="threshold")
        planned_min = metrics.get("planned_min_clearance_m")
        if planned_min is not None:
            clearance_ax.axhline(planned_min, color="orange", linestyle=":", linewidth=1.2, label="planned minimum")
        # the distance to the planned path means something only while on it (not climbing to it)
        on_path = np.where(in_path, arrays["deviation"], np.nan)
        deviation_ax.plot(time, on_path, color="#444444", linewidth=1.2, label="distance to planned path")
        if "setpoint_error" in arrays:
            deviation_ax.plot(
                time, arrays["setpoint_error"], color="#9467bd", linewidth=1.0, label="distance to setpoint"
            )
    clearance_ax.set_ylabel("clearance (m)")
    clearance_ax.set_ylim(0, max(3 * (threshold or 0), 3 * (metrics.get("planned_min_clearance_m") or 0), 0.5))
    clearance_ax.legend(fontsize=7, loc="upper right")
    deviation_ax.set_ylabel("tracking error (m)")
    deviation_ax.set_ylim(bottom=0)
    deviation_ax.legend(fontsize=7, loc="upper right")
    bottom = deviation_ax
    if rows == 3 and len(t):
        link_ax = fig.add_subplot(grid[2, 1], sharex=clearance_ax)
        times, lost, received = (np.asarray(c, float) for c in np.asarray(link).T)
        edges = np.arange(np.floor(times[0]), np.ceil(times[-1]) + 1.0, 1.0)
        at = np.searchsorted(times, edges, side="right") - 1
        at = np.clip(at, 0, len(times) - 1)
        d_lost, d_received = np.diff(lost[at]), np.diff(received[at])
        share = np.where(d_lost + d_received > 0, 100 * d_lost / np.maximum(d_lost + d_received, 1), 0.0)
        link_ax.bar(edges[:-1] - t[0], share, width=1.0, align="edge", color="#d62728", alpha=0.6,
                    label="vehicle's messages lost (per s)")  # fmt: skip
        total = 100 * (lost[-1] - lost[0]) / max((lost[-1] - lost[0]) + (received[-1] - received[0]), 1)
        link_ax.axhline(total, color="#333333", linestyle="--", linewidth=1, label=f"over the flight: {total:.1f} %")
        link_ax.set_ylabel("link loss (%)")
        link_ax.set_ylim(0, max(5.0, float(share.max()) * 1.5 if len(share) else 5.0))
        link_ax.legend(fontsize=7, loc="upper right", ncol=2)
        if link_text:
            link_ax.set_title(link_text, fontsize=7, loc="left")
        bottom = link_ax
    bottom.set_xlabel("vehicle time since arming (s)")
    fig.suptitle(title, fontsize=10)
    try:
        with atomic_write(path, "wb") as handle:
            fig.savefig(handle, format="png", dpi=110, bbox_inches="tight")
    finally:
        plt.close(fig)


def describe(metrics: dict[str, Any]) -> str:
    """One line for the figure's title."""
    parts = []
    for key, label in (
        ("tracking_error_max_m", "tracking error max"),
        ("tracking_error_rms_m", "rms"),
        ("flown_min_clearance_m", "flown min clearance"),
        ("planned_min_clearance_m", "planned"),
    ):
        value = metrics.get(key)
        if isinstance(value, float) and math.isfinite(value):
            parts.append(f"{label} {value:.3f} m")
    return ", ".join(parts)
