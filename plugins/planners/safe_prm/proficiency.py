"""Proficiency: the clearance threshold d_thresh a trainee's path must keep.

Paper 000 §3.1 models proficiency as a virtual boundary of thickness
d_thresh around every obstacle: a beginner deviates more from a suggested
path, so needs more room (block world: expert 0, intermediate 4 mm,
beginner 8 mm, §4.2). The levels are a table in the settings.

Beyond the paper, d_thresh can come from data: the tip paths a trainee
actually executed while following a suggested path. The deviation of an
executed point is its distance to the suggested path (a polyline); d_thresh
is a high percentile (default 95th) of all deviations, so a path with that
clearance keeps the trainee's instrument off the obstacles in that share of
their motion.

The CSV file has a header and columns ``attempt, x, y, z``. Rows whose
attempt is ``suggested`` give the suggested path, in order; the others are
executed tip positions of attempts named or numbered in the first column.
Coordinates are in the pipeline's ``length_unit``; a header like ``x_mm``
names the unit explicitly.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from surgiplan.geometry.primitives import point_segment_distance
from surgiplan.units import LENGTH_UNITS

#: paper 000 §4.2: thresholds for the block world (m)
DEFAULT_LEVELS = {"expert": 0.0, "intermediate": 0.004, "beginner": 0.008}


@dataclass(frozen=True)
class AttemptStatistics:
    """What a set of recorded attempts says about a trainee (metres)."""

    d_thresh: float
    percentile: float
    attempts: int
    points: int
    deviation_median: float
    deviation_max: float


def path_deviation(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Distance (m) of each point (N, 3) to the polyline ``path`` (M, 3)."""
    points = np.atleast_2d(points)
    path = np.atleast_2d(path)
    if len(path) == 1:
        return np.linalg.norm(points - path[0], axis=1)
    a, b = path[:-1], path[1:]
    # (N, M-1) distances to every segment, in chunks to bound memory
    out = np.empty(len(points))
    chunk = max(1, 2_000_000 // max(len(a), 1))
    for start in range(0, len(points), chunk):
        p = points[start : start + chunk, None, :]
        out[start : start + chunk] = point_segment_distance(p, a[None], b[None]).min(axis=1)
    return out


def read_attempts(path: Path, length_scale: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The suggested path and the executed tip paths from a CSV file (metres).

    Raises ``ValueError`` naming the file, the line and the problem.
    """
    try:
        handle = path.open(newline="", encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    with handle:
        reader = csv.reader(handle)
        try:
            header = [h.strip().lower() for h in next(reader)]
        except StopIteration:
            raise ValueError(f"{path} is empty") from None
        columns = {}
        scale = length_scale
        for name in ("attempt", "x", "y", "z"):
            matches = [i for i, h in enumerate(header) if h == name or h.startswith(f"{name}_")]
            if not matches:
                raise ValueError(f"{path}: the header needs columns attempt, x, y, z; found {', '.join(header)}")
            columns[name] = matches[0]
            unit = header[matches[0]].partition("_")[2]
            if name != "attempt" and unit:
                if unit not in LENGTH_UNITS:
                    raise ValueError(f"{path}: unknown unit '{unit}' in column '{header[matches[0]]}'")
                scale = LENGTH_UNITS[unit]
        rows: dict[str, list[list[float]]] = {}
        for line, row in enumerate(reader, start=2):
            if not row or all(not cell.strip() for cell in row):
                continue
            try:
                attempt = row[columns["attempt"]].strip()
                xyz = [float(row[columns[c]]) for c in "xyz"]
            except (IndexError, ValueError):
                raise ValueError(f"{path}:{line}: expected an attempt name and three numbers, got {row}") from None
            if not np.all(np.isfinite(xyz)):
                raise ValueError(f"{path}:{line}: coordinates must be finite, got {xyz}")
            rows.setdefault(attempt, []).append(xyz)
    if "suggested" not in rows:
        raise ValueError(f"{path}: no rows with attempt 'suggested' (the suggested path the trainee followed)")
    suggested = np.asarray(rows.pop("suggested")) * scale
    if not rows:
        raise ValueError(f"{path}: no executed attempts, only the suggested path")
    return suggested, {name: np.asarray(points) * scale for name, points in rows.items()}


def threshold_from_attempts(path: Path, length_scale: float, percentile: float) -> AttemptStatistics:
    suggested, attempts = read_attempts(path, length_scale)
    deviation = np.concatenate([path_deviation(points, suggested) for points in attempts.values()])
    return AttemptStatistics(
        d_thresh=float(np.percentile(deviation, percentile)),
        percentile=float(percentile),
        attempts=len(attempts),
        points=len(deviation),
        deviation_median=float(np.median(deviation)),
        deviation_max=float(deviation.max()),
    )
