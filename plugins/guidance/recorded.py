"""``recorded_attempt``: replay a recorded attempt from a CSV file.

The file has a header row and one row per sample; lines starting with ``#``
are comments. Columns (any order; other columns are ignored, so a guide
stage's own ``<stage>-samples.csv`` replays):

* ``t``: time (s; ``t_ms`` for milliseconds), increasing;
* either the tip position ``x, y, z`` (the pipeline's length unit, or the
  header's: ``x_mm``, ``x_m``, ...),
* or the CAST gimbal's joints ``yaw, pitch, insertion, roll`` (radians, or
  ``yaw_deg``; insertion in the length unit, or ``insertion_mm``); the
  recommended path must then be in the ``cast_gimbal`` space, and the whole
  shaft's clearance is measured.

The file is read and checked when the pipeline is validated: a missing
column, a unit it does not know, a number that is not one, or a time that
does not increase is an error naming the file and the line.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationInfo, model_validator
from surgiplan.guidance import PoseSample, PoseSource
from surgiplan.units import ANGLE_UNITS, LENGTH_SCALE_KEY, LENGTH_UNITS

from .pacing import Pacer

TIME_UNITS = {"s": 1.0, "ms": 1e-3}
TIP = ("x", "y", "z")
JOINTS = ("yaw", "pitch", "insertion", "roll")


class RecordedAttemptSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")
    #: the CSV file, relative to the pipeline file
    file: str
    #: 1: replay in real time; 2: twice as fast; 0: as fast as possible
    speed: float = Field(default=1.0, ge=0.0)
    _times: np.ndarray = PrivateAttr(default=None)
    _values: np.ndarray = PrivateAttr(default=None)
    _kind: str = PrivateAttr(default="tip")

    @model_validator(mode="after")
    def _read(self, info: ValidationInfo):
        context = info.context or {}
        path = (Path(context.get("base_dir", ".")) / self.file).resolve()
        self._times, self._values, self._kind = read_attempt_csv(path, context.get(LENGTH_SCALE_KEY, 1.0))
        self.file = str(path)
        return self

    @property
    def kind(self) -> str:
        return self._kind


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


class RecordedAttempt(PoseSource):
    """Replays the file's samples, paced by ``speed``."""

    Settings = RecordedAttemptSettings

    def open(self, context: Any) -> None:
        self.context = context
        if self.settings.kind == "joints" and context.space.kind != "cast_gimbal":
            from surgiplan.errors import ConfigError

            raise ConfigError(
                f"{self.settings.file} has gimbal joints, but the recommended path is in the {context.space.kind} "
                "space; record tip positions (x, y, z) or plan in the cast_gimbal space"
            )

    def samples(self):
        pacer = Pacer(self.settings.speed)
        times, values = self.settings._times, self.settings._values
        t0 = float(times[0])
        joints = self.settings.kind == "joints"
        for t, value in zip(times, values, strict=True):
            pacer.wait(t - t0)
            yield PoseSample(float(t - t0), q=value) if joints else PoseSample(float(t - t0), tip=value)
