"""R3: the instrument tip as a sphere moving through the workspace."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import BaseModel

from ..errors import PlanningInputError
from ..geometry import boxes
from ..models import StrictModel
from ..units import Length
from .base import Space


class R3Settings(StrictModel):
    """The instrument tip as a sphere of ``tip_radius`` (m); 0 plans for a point."""

    tip_radius: Length = 0.0


class R3Space(Space):
    """Tip positions (x, y, z) in metres within the scene bounds.

    Motions are straight lines; their clearance is exact (the swept volume of
    the tip sphere is a capsule), so :meth:`motion_is_clear` is exact too.
    """

    kind: ClassVar[str] = "r3"
    Settings: ClassVar[type[BaseModel]] = R3Settings
    euclidean_motions: ClassVar[bool] = True

    def __init__(self, scene, tip_radius: float = 0.0) -> None:
        super().__init__(scene)
        self.tip_radius = float(tip_radius)

    @classmethod
    def from_settings(cls, settings: R3Settings, scene) -> R3Space:
        return cls(scene, settings.tip_radius)

    @property
    def dimension(self) -> int:
        return 3

    @property
    def coordinate_names(self) -> tuple[str, ...]:
        return ("x", "y", "z")

    @property
    def low(self) -> np.ndarray:
        return self.scene.bounds_min

    @property
    def high(self) -> np.ndarray:
        return self.scene.bounds_max

    @property
    def coordinate_weights(self):
        return np.ones(3)

    def sample(self, rng, n):
        return boxes.uniform(rng, self.low, self.high, n)

    def distance(self, q1, q2):
        return np.linalg.norm(np.asarray(q2, float) - np.asarray(q1, float), axis=-1)

    def interpolate(self, q1, q2, t):
        q1 = np.asarray(q1, float)
        q2 = np.asarray(q2, float)
        t = np.asarray(t, float)[..., None]
        return q1 + t * (q2 - q1)

    def tip(self, q):
        return np.atleast_2d(np.asarray(q, dtype=float))

    def clearance(self, q, cutoff=np.inf):
        return self.scene.signed_distance(np.atleast_2d(q), cutoff + self.tip_radius)[0] - self.tip_radius

    def motion_is_clear(self, q1, q2, margin=0.0):
        return self.scene.is_motion_clear(np.atleast_2d(q1), np.atleast_2d(q2), self.tip_radius, margin)

    def corridor_halfwidths(self, q, slack):
        # the cube inscribed in the ball of radius slack
        return np.repeat(np.asarray(slack, float)[:, None] / np.sqrt(3.0), 3, axis=1)

    def motion_speed_bound(self, q1, q2):
        return self.distance(q1, q2)

    def segment_clearance(self, q1, q2):
        return self.scene.motion_clearance(np.atleast_2d(q1), np.atleast_2d(q2), self.tip_radius)

    def tip_path_length(self, path):
        path = np.atleast_2d(np.asarray(path, float))
        return float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))

    def configuration(self, value, *, what="point"):
        q = np.asarray(value, dtype=float).reshape(-1)
        if q.shape != (3,):
            raise PlanningInputError(f"{what}: expected a point (x, y, z), got {len(q)} numbers")
        return q

    def settings_spec(self):
        return {"tip_radius": self.tip_radius}
