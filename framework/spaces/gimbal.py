"""The CAST laparoscopic gimbal: an instrument pivoting about a fixed fulcrum.

Coordinates ``q = (yaw, pitch, insertion, roll)`` in (rad, rad, m, rad). The
fulcrum frame (``fulcrum: {xyz, rpy}``) puts the neutral shaft direction
(yaw = pitch = 0) along its x axis with z up; yaw turns about z, pitch tips
the shaft down (positive pitch points below the horizontal):

    u(yaw, pitch) = (cos p cos y, cos p sin y, -sin p)      (fulcrum frame)
    tip = fulcrum + insertion * R_fulcrum @ u

The shaft is the capsule of ``shaft_radius`` from the fulcrum to the tip: a
configuration is free only if the *whole shaft* is, not only its tip (paper
000 §4.1 plans for the CAST instrument in this space). Roll turns the
instrument about its own axis; it does not move the (axisymmetric) shaft.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, Field, model_validator

from ..errors import PlanningInputError
from ..geometry import boxes
from ..models import AngleRange, PoseModel, StrictModel
from ..units import Length, PositiveLength
from .base import Space


class InsertionRange(StrictModel):
    min: Length
    max: PositiveLength

    @model_validator(mode="after")
    def _ordered(self):
        if self.max <= self.min:
            raise ValueError(f"max ({self.max} m) must exceed min ({self.min} m)")
        return self


def _deg(lo: float, hi: float) -> AngleRange:
    return AngleRange(min=math.radians(lo), max=math.radians(hi))


class CastGimbalSettings(StrictModel):
    """The gimbal's fulcrum pose, joint limits and shaft.

    Defaults are those of a laparoscopic box trainer: ±60° yaw, -10° to 80°
    pitch, 20-300 mm insertion, full roll, a 5 mm instrument shaft.
    """

    fulcrum: PoseModel
    yaw: AngleRange = Field(default_factory=lambda: _deg(-60, 60))
    pitch: AngleRange = Field(default_factory=lambda: _deg(-10, 80))
    insertion: InsertionRange = Field(default_factory=lambda: InsertionRange(min=0.02, max=0.30))
    roll: AngleRange = Field(default_factory=lambda: _deg(-180, 180))
    shaft_radius: Length = 0.0025
    #: metres per radian in the distance metric; default: the mid insertion
    angle_weight: PositiveLength | None = None


class CastGimbalSpace(Space):
    """The CAST gimbal's space: ``q = (yaw, pitch, insertion, roll)`` (rad, rad, m, rad) about a fixed fulcrum,
    the whole shaft checked for clearance (see the module)."""

    kind: ClassVar[str] = "cast_gimbal"
    Settings: ClassVar[type[BaseModel]] = CastGimbalSettings

    def __init__(self, scene, settings: CastGimbalSettings) -> None:
        super().__init__(scene)
        self.settings = settings
        pose = settings.fulcrum.to_pose()
        self.fulcrum = pose.translation
        self.frame = pose.rotation
        self.shaft_radius = float(settings.shaft_radius)
        self._low = np.array([settings.yaw.min, settings.pitch.min, settings.insertion.min, settings.roll.min])
        self._high = np.array([settings.yaw.max, settings.pitch.max, settings.insertion.max, settings.roll.max])
        weight = settings.angle_weight or 0.5 * (settings.insertion.min + settings.insertion.max)
        # roll does not move the shaft: weigh it lightly so it does not dominate neighbours
        self._weights = np.array([weight, weight, 1.0, 0.1 * weight])

    @classmethod
    def from_settings(cls, settings, scene):
        return cls(scene, settings)

    @property
    def dimension(self):
        return 4

    @property
    def coordinate_names(self) -> tuple[str, ...]:
        return ("yaw", "pitch", "insertion", "roll")

    @property
    def low(self):
        return self._low

    @property
    def high(self):
        return self._high

    @property
    def coordinate_weights(self):
        return self._weights

    def sample(self, rng, n):
        return boxes.uniform(rng, self._low, self._high, n)

    def distance(self, q1, q2):
        diff = (np.asarray(q2, float) - np.asarray(q1, float)) * self._weights
        return np.linalg.norm(diff, axis=-1)

    def interpolate(self, q1, q2, t):
        q1 = np.asarray(q1, float)
        q2 = np.asarray(q2, float)
        t = np.asarray(t, float)[..., None]
        return q1 + t * (q2 - q1)

    # ------------------------------------------------------------------ kinematics
    def direction(self, q) -> np.ndarray:
        """Unit shaft directions (n, 3) in the world frame."""
        q = np.atleast_2d(np.asarray(q, float))
        yaw, pitch = q[:, 0], q[:, 1]
        local = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), -np.sin(pitch)], axis=1)
        return local @ self.frame.T

    def tip(self, q):
        q = np.atleast_2d(np.asarray(q, float))
        return self.fulcrum + q[:, 2:3] * self.direction(q)

    def inverse(self, tip) -> np.ndarray:
        """Closed-form (yaw, pitch, insertion) for tip positions (n, 3); roll set to 0 (or its limit)."""
        tip = np.atleast_2d(np.asarray(tip, float))
        v = (tip - self.fulcrum) @ self.frame
        insertion = np.linalg.norm(v, axis=1)
        safe = np.where(insertion > 0, insertion, 1.0)
        pitch = np.arcsin(np.clip(-v[:, 2] / safe, -1.0, 1.0))
        yaw = np.arctan2(v[:, 1], v[:, 0])
        roll = np.full(len(tip), np.clip(0.0, self._low[3], self._high[3]))
        return np.stack([yaw, pitch, insertion, roll], axis=1)

    # ------------------------------------------------------------------ clearance
    def clearance(self, q, cutoff=np.inf):
        q = np.atleast_2d(np.asarray(q, float))
        fulcrum = np.broadcast_to(self.fulcrum, (len(q), 3))
        return self.scene.segment_distance(fulcrum, self.tip(q), cutoff + self.shaft_radius)[0] - self.shaft_radius

    def corridor_halfwidths(self, q, slack):
        # |d insertion| <= slack/2 and (insertion + slack/2) * |d(yaw, pitch)| <= slack/2 keep every shaft
        # point within slack (see motion_speed_bound); roll does not move the shaft
        q = np.atleast_2d(np.asarray(q, float))
        slack = np.asarray(slack, float)
        insertion = slack / 2.0
        angle = slack / (2.0 * np.sqrt(2.0) * (q[:, 2] + insertion))
        roll = np.full(len(q), np.inf)
        return np.stack([angle, angle, insertion, roll], axis=1)

    def nearest_obstacle(self, q):
        q = np.atleast_2d(np.asarray(q, float))
        return self.scene.segment_distance(np.broadcast_to(self.fulcrum, (len(q), 3)), self.tip(q))[1]

    def motion_speed_bound(self, q1, q2):
        """Bound (m per unit t) on how fast any shaft point moves along q1 → q2.

        A point a fraction s of the way down the shaft is at
        ``fulcrum + s * insertion * u``; its speed is at most
        ``|d insertion| + insertion * |du|`` and ``|du| <= |(d yaw, d pitch)|``.
        """
        d = np.atleast_2d(q2) - np.atleast_2d(q1)
        reach = np.maximum(np.atleast_2d(q1)[:, 2], np.atleast_2d(q2)[:, 2])
        return np.abs(d[:, 2]) + reach * np.hypot(d[:, 0], d[:, 1])

    def workspace_slack(self, q):
        # the tip moves no faster than the shaft's end: its distance to the bounds is a slack too
        tip = self.tip(q)
        inside = np.min(np.concatenate([tip - self.scene.bounds_min, self.scene.bounds_max - tip], axis=1), axis=1)
        return inside + 1e-12

    def configuration(self, value, *, what="point"):
        value = np.asarray(value, dtype=float).reshape(-1)
        if value.shape == (4,):
            q = value
        elif value.shape == (3,):
            q = self.inverse(value)[0]
        else:
            raise PlanningInputError(
                f"{what}: expected a tip point (x, y, z) or a configuration (yaw, pitch, insertion, roll)"
            )
        names = ("yaw", "pitch", "insertion", "roll")
        for i, name in enumerate(names):
            if not self._low[i] - 1e-12 <= q[i] <= self._high[i] + 1e-12:
                unit, scale = ("mm", 1000.0) if name == "insertion" else ("deg", 180.0 / math.pi)
                raise PlanningInputError(
                    f"{what}: out of the gimbal's reach: {name} {q[i] * scale:.4g} {unit} is outside "
                    f"[{self._low[i] * scale:.4g}, {self._high[i] * scale:.4g}] {unit}"
                )
        return q

    def settings_spec(self):
        return self.settings.model_dump(mode="json")
