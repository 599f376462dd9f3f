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

from typing import Any

import numpy as np
from pydantic import Field, PrivateAttr, ValidationInfo, model_validator
from surgiplan.guidance import PoseSample, PoseSource
from surgiplan.guidance.files import read_attempt_csv
from surgiplan.models import StrictModel
from surgiplan.validation import file_length_scale, input_path

from .pacing import Pacer


class RecordedAttemptSettings(StrictModel):
    #: the CSV file, relative to the pipeline file
    file: str
    #: 1: replay in real time; 2: twice as fast; 0: as fast as possible
    speed: float = Field(default=1.0, ge=0.0)
    _times: np.ndarray = PrivateAttr(default=None)
    _values: np.ndarray = PrivateAttr(default=None)
    _kind: str = PrivateAttr(default="tip")

    @model_validator(mode="after")
    def _read(self, info: ValidationInfo):
        path = input_path(self.file, info)
        self._times, self._values, self._kind = read_attempt_csv(path, file_length_scale(info))
        self.file = str(path)
        return self

    @property
    def kind(self) -> str:
        return self._kind


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
