"""Recorded attempts as files: time and the tip's position, or the CAST gimbal's joints (CSV).

The format (read by :func:`read_attempt_csv`): a header row and one row per
sample; lines starting with ``#`` are comments; other columns are ignored.

* ``t``: time (s; ``t_ms`` for milliseconds), increasing;
* either the tip position ``x, y, z`` (the pipeline's length unit, or the
  header's: ``x_mm``, ``x_m``, ...),
* or the CAST gimbal's joints ``yaw, pitch, insertion, roll`` (radians, or
  ``yaw_deg``; insertion in the length unit, or ``insertion_mm``).

A guide stage's own ``<stage>-samples.csv`` is such a file.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from ..units import ANGLE_UNITS, LENGTH_UNITS

TIME_UNITS = {"s": 1.0, "ms": 1e-3}
TIP = ("x", "y", "z")
JOINTS = ("yaw", "pitch", "insertion", "roll")


def read_attempt_csv(path: Path, length_scale: float) -> tuple[np.ndarray, np.ndarray, str]:
    """Times (s), values (tips in m, or joints in rad/m) and which ("tip" or "joints"); raises ValueError."""
    try:
        handle = path.open(newline="", encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    with handle:
        try:
            numbered = [(i, line) for i, line in enumerate(handle, start=1) if not line.lstrip().startswith("#")]
        except UnicodeDecodeError as exc:
            raise ValueError(f"{path} is not a CSV text file: {exc}") from None
        reader = csv.reader(line for _, line in numbered)
        line_numbers = iter(i for i, _ in numbered)
        try:
            header = [h.strip().lower() for h in next(reader)]
            next(line_numbers)
        except StopIteration:
            raise ValueError(f"{path} is empty") from None
        except csv.Error as exc:
            raise ValueError(f"{path} is not a CSV text file: {exc}") from None
        index: dict[str, tuple[int, float]] = {}
        for i, name in enumerate(header):
            base, _, unit = name.partition("_")
            if base not in ("t", *TIP, *JOINTS) or base in index:
                continue
            if base == "t":
                table = TIME_UNITS
            elif base in TIP or base == "insertion":
                table = LENGTH_UNITS
            else:
                table = ANGLE_UNITS
            if unit and unit not in table:
                raise ValueError(f"{path}: unknown unit '{unit}' in column '{name}'; choose one of: {', '.join(table)}")
            scale = table[unit] if unit else (length_scale if table is LENGTH_UNITS else 1.0)
            index[base] = (i, scale)
        if "t" not in index:
            raise ValueError(f"{path}: no time column 't' (seconds) in the header: {', '.join(header)}")
        if all(c in index for c in TIP):
            kind, columns = "tip", TIP
        elif all(c in index for c in JOINTS):
            kind, columns = "joints", JOINTS
        else:
            missing_tip = [c for c in TIP if c not in index]
            raise ValueError(
                f"{path}: the header needs t and either x, y, z or yaw, pitch, insertion, roll; missing "
                f"{', '.join(missing_tip)} (found {', '.join(header)})"
            )
        times, values = [], []
        previous = -math.inf
        try:
            for line, row in zip(line_numbers, reader, strict=False):
                if not row or all(not cell.strip() for cell in row):
                    continue
                try:
                    t = float(row[index["t"][0]]) * index["t"][1]
                    value = [float(row[index[c][0]]) * index[c][1] for c in columns]
                except (IndexError, ValueError):
                    raise ValueError(
                        f"{path}:{line}: expected numbers in columns t, {', '.join(columns)}, got {row}"
                    ) from None
                if not (math.isfinite(t) and all(math.isfinite(v) for v in value)):
                    raise ValueError(f"{path}:{line}: values must be finite, got {row}")
                if t <= previous:
                    raise ValueError(
                        f"{path}:{line}: time {t:.6g} s does not increase (the previous is {previous:.6g} s)"
                    )
                previous = t
                times.append(t)
                values.append(value)
        except csv.Error as exc:
            raise ValueError(f"{path}: not a valid CSV file: {exc}") from None
    if len(times) < 2:
        raise ValueError(f"{path}: an attempt needs at least 2 samples, found {len(times)}")
    return np.asarray(times), np.asarray(values), kind
