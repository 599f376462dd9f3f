"""The ``planar`` space (an example space plugin): the tip, a sphere, in a horizontal plane.

A configuration is ``(x, y)``; the tip is at ``(x, y, height)``. Motions are
straight, so the swept volume of the tip is a capsule and clearance along a
motion is exact (:meth:`surgiplan.Scene.motion_clearance`). A space supplies
coordinates (limits, sampling, distance, interpolation), the body's
placement (``tip``) and clearance, and a certified motion check; the rest of
:class:`surgiplan.Space` has defaults built on those.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import BaseModel
from surgiplan import Coordinate, Length, PlanningInputError, Space
from surgiplan.models import StrictModel


class PlanarSettings(StrictModel):
    #: the plane's height (z), in the pipeline's length unit
    height: Coordinate
    #: the tip sphere's radius
    tip_radius: Length = 0.0


class PlanarSpace(Space):
    kind: ClassVar[str] = "planar"
    Settings: ClassVar[type[BaseModel]] = PlanarSettings

    def __init__(self, scene, height: float, tip_radius: float = 0.0) -> None:
        super().__init__(scene)
        if not scene.bounds_min[2] <= height <= scene.bounds_max[2]:
            raise PlanningInputError(f"the plane's height {height} m is outside the scene's z bounds")
        self.height = float(height)
        self.tip_radius = float(tip_radius)

    @classmethod
    def from_settings(cls, settings: PlanarSettings, scene) -> PlanarSpace:
        return cls(scene, settings.height, settings.tip_radius)

    # ------------------------------------------------------------------ coordinates
    @property
    def dimension(self) -> int:
        return 2

    @property
    def low(self) -> np.ndarray:
        return self.scene.bounds_min[:2]

    @property
    def high(self) -> np.ndarray:
        return self.scene.bounds_max[:2]

    def sample(self, rng, n):
        return rng.uniform(self.low, self.high, size=(n, 2))

    def distance(self, q1, q2):
        return np.linalg.norm(np.asarray(q2, float) - np.asarray(q1, float), axis=-1)

    def interpolate(self, q1, q2, t):
        q1, q2, t = np.asarray(q1, float), np.asarray(q2, float), np.asarray(t, float)[..., None]
        return q1 + t * (q2 - q1)

    # ------------------------------------------------------------------ the body
    def tip(self, q):
        q = np.atleast_2d(np.asarray(q, float))
        return np.column_stack([q, np.full(len(q), self.height)])

    def clearance(self, q, cutoff=np.inf):
        return self.scene.signed_distance(self.tip(q), cutoff + self.tip_radius)[0] - self.tip_radius

    def motion_is_clear(self, q1, q2, margin=0.0):
        return self.scene.is_motion_clear(self.tip(q1), self.tip(q2), self.tip_radius, margin)

    def motion_speed_bound(self, q1, q2):
        return self.distance(q1, q2)

    def segment_clearance(self, q1, q2):
        return self.scene.motion_clearance(self.tip(q1), self.tip(q2), self.tip_radius)

    def corridor_halfwidths(self, q, slack):
        return np.repeat(np.asarray(slack, float)[:, None] / np.sqrt(2.0), 2, axis=1)

    # ------------------------------------------------------------------ user input
    def configuration(self, value, *, what="point"):
        q = np.asarray(value, dtype=float).reshape(-1)
        if q.shape == (2,):
            return q
        if q.shape == (3,):
            if abs(q[2] - self.height) > 1e-9:
                raise PlanningInputError(
                    f"{what}: ({q[0]:.4g}, {q[1]:.4g}, {q[2]:.4g}) m is not in the plane z = {self.height:.4g} m"
                )
            return q[:2]
        raise PlanningInputError(f"{what}: expected (x, y) or a point (x, y, z) in the plane")

    def settings_spec(self):
        return {"height": self.height, "tip_radius": self.tip_radius}
