"""SE(3): a rigid body (e.g. a gripper) free in position and orientation.

Coordinates ``q = (x, y, z, qx, qy, qz, qw)``: position in metres and a
scalar-last unit quaternion (Pinocchio's XYZQUAT layout). The distance is
``sqrt(|dp|^2 + (w * angle)^2)`` with ``w = rotation_weight`` in metres per
radian; motions interpolate the position linearly and the orientation by
slerp (constant angular speed), so a body point at distance rho from the
body origin moves at most ``|dp| + rho * angle`` along a motion, which is
the bound the certified motion check steps with.

The body is a list of parts in its own frame: spheres and capsules (exact,
vectorised distances) and boxes (coal).
"""

from __future__ import annotations

from typing import ClassVar

import coal
import numpy as np
from pydantic import BaseModel, Field, model_validator

from ..errors import PlanningInputError
from ..geometry import boxes
from ..geometry.transforms import canonical_quaternion, quaternion_angle, quaternion_to_matrix, slerp
from ..models import PoseModel, StrictModel
from ..units import Length, PositiveLength, Vec3
from .base import Space


class SphereShape(StrictModel):
    radius: Length


class CapsuleShape(StrictModel):
    a: Vec3
    b: Vec3
    radius: Length


class BoxShape(StrictModel):
    size: tuple[PositiveLength, PositiveLength, PositiveLength]


class BodyPart(StrictModel):
    """One part of the moving body: a sphere (at ``pose.xyz``), a capsule (a→b) or a box."""

    name: str | None = None
    sphere: SphereShape | None = None
    capsule: CapsuleShape | None = None
    box: BoxShape | None = None
    pose: PoseModel = Field(default_factory=PoseModel)

    @model_validator(mode="after")
    def _one_shape(self):
        given = [k for k in ("sphere", "capsule", "box") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of sphere, capsule, box (got {', '.join(given) or 'none'})")
        return self


def _default_body() -> list[BodyPart]:
    return [BodyPart(name="origin", sphere=SphereShape(radius=0.0))]


class SE3Settings(StrictModel):
    """The moving rigid body (its parts in its own frame), the rotation weight of the metric and the tool point."""

    body: list[BodyPart] = Field(default_factory=_default_body)
    #: metres per radian of rotation in the distance metric
    rotation_weight: PositiveLength = 0.05
    #: the tool point in the body frame, used for path lengths and figures
    tip: Vec3 = (0.0, 0.0, 0.0)


class SE3Space(Space):
    """A rigid body free in position and orientation: ``q = (x, y, z, qx, qy, qz, qw)`` (see the module); the
    position ranges over the scene's bounds, the orientation over all rotations."""

    kind: ClassVar[str] = "se3"
    Settings: ClassVar[type[BaseModel]] = SE3Settings

    def __init__(self, scene, settings: SE3Settings) -> None:
        super().__init__(scene)
        self.settings = settings
        self.rotation_weight = float(settings.rotation_weight)
        self._tip = np.asarray(settings.tip, dtype=float)
        self._spheres: list[tuple[np.ndarray, float]] = []
        self._capsules: list[tuple[np.ndarray, np.ndarray, float]] = []
        self._boxes: list[tuple[coal.Box, np.ndarray]] = []
        reach = float(np.linalg.norm(self._tip))
        for part in settings.body:
            pose = part.pose.to_pose()
            if part.sphere is not None:
                centre = pose.translation
                self._spheres.append((centre, part.sphere.radius))
                reach = max(reach, float(np.linalg.norm(centre)) + part.sphere.radius)
            elif part.capsule is not None:
                a = pose.apply(np.asarray(part.capsule.a))
                b = pose.apply(np.asarray(part.capsule.b))
                self._capsules.append((a, b, part.capsule.radius))
                reach = max(reach, float(max(np.linalg.norm(a), np.linalg.norm(b))) + part.capsule.radius)
            else:
                half = 0.5 * np.asarray(part.box.size)
                self._boxes.append((coal.Box(*map(float, part.box.size)), pose.as_matrix()))
                corners = pose.apply(np.array(np.meshgrid(*zip(-half, half, strict=True))).reshape(3, -1).T)
                reach = max(reach, float(np.max(np.linalg.norm(corners, axis=1))))
        #: largest distance (m) of any body point from the body origin
        self.reach = reach

    @classmethod
    def from_settings(cls, settings, scene):
        return cls(scene, settings)

    @property
    def dimension(self):
        return 7

    @property
    def coordinate_names(self) -> tuple[str, ...]:
        return ("x", "y", "z", "qx", "qy", "qz", "qw")

    @property
    def low(self):
        return np.concatenate([self.scene.bounds_min, -np.ones(4)])

    @property
    def high(self):
        return np.concatenate([self.scene.bounds_max, np.ones(4)])

    def sample(self, rng, n):
        from scipy.spatial.transform import Rotation  # scipy.spatial: at first use, not when spaces are listed

        position = boxes.uniform(rng, self.scene.bounds_min, self.scene.bounds_max, n)
        rotation = canonical_quaternion(Rotation.random(n, random_state=rng).as_quat())
        return np.concatenate([position, rotation], axis=1)

    def distance(self, q1, q2):
        q1 = np.asarray(q1, float)
        q2 = np.asarray(q2, float)
        translation = np.linalg.norm(q2[..., :3] - q1[..., :3], axis=-1)
        angle = quaternion_angle(q1[..., 3:], q2[..., 3:])
        return np.hypot(translation, self.rotation_weight * angle)

    def interpolate(self, q1, q2, t):
        q1 = np.asarray(q1, float)
        q2 = np.asarray(q2, float)
        t = np.asarray(t, float)
        position = q1[..., :3] + t[..., None] * (q2[..., :3] - q1[..., :3])
        return np.concatenate([position, slerp(q1[..., 3:], q2[..., 3:], t)], axis=-1)

    def within_limits(self, q):
        """Per configuration, whether its position is within the scene's bounds and its quaternion has unit norm
        (to 1e-6)."""
        q = np.atleast_2d(q)
        lo, hi = self.scene.bounds_min - 1e-12, self.scene.bounds_max + 1e-12
        inside = np.all((q[:, :3] >= lo) & (q[:, :3] <= hi), axis=1)
        return inside & (np.abs(np.linalg.norm(q[:, 3:], axis=1) - 1.0) < 1e-6)

    def in_workspace(self, q):
        # the position limits are the workspace; the tool point may reach past them
        return self.within_limits(q)

    def rotation(self, q) -> np.ndarray:
        """The body's rotation matrices (n, 3, 3) at configurations ``q`` (one, or (n, 7))."""
        return quaternion_to_matrix(np.atleast_2d(q)[:, 3:])

    def tip(self, q):
        q = np.atleast_2d(np.asarray(q, float))
        return q[:, :3] + self.rotation(q) @ self._tip

    def clearance(self, q, cutoff=np.inf):
        q = np.atleast_2d(np.asarray(q, float))
        position = q[:, :3]
        rotation = self.rotation(q)
        best = np.full(len(q), np.inf)
        for centre, radius in self._spheres:
            world = position + rotation @ centre
            best = np.minimum(best, self.scene.signed_distance(world, cutoff + radius)[0] - radius)
        for a, b, radius in self._capsules:
            wa = position + rotation @ a
            wb = position + rotation @ b
            best = np.minimum(best, self.scene.segment_distance(wa, wb, cutoff + radius)[0] - radius)
        if self._boxes:
            transforms = np.tile(np.eye(4), (len(q), 1, 1))
            transforms[:, :3, :3] = rotation
            transforms[:, :3, 3] = position
            best = np.minimum(best, self.scene.body_distance(self._boxes, transforms)[0])
        return best

    def motion_speed_bound(self, q1, q2):
        q1 = np.atleast_2d(q1)
        q2 = np.atleast_2d(q2)
        return np.linalg.norm(q2[:, :3] - q1[:, :3], axis=1) + self.reach * quaternion_angle(q1[:, 3:], q2[:, 3:])

    def configuration(self, value, *, what="point"):
        if isinstance(value, dict):
            xyz = np.asarray(value.get("xyz", (0, 0, 0)), float)
            if value.get("quaternion") is not None:
                quaternion = canonical_quaternion(np.asarray(value["quaternion"], float))
            else:
                from scipy.spatial.transform import Rotation

                quaternion = canonical_quaternion(Rotation.from_euler("xyz", value.get("rpy") or (0, 0, 0)).as_quat())
            return np.concatenate([xyz, quaternion])
        value = np.asarray(value, dtype=float).reshape(-1)
        if value.shape == (3,):
            return np.concatenate([value, [0.0, 0.0, 0.0, 1.0]])
        if value.shape == (7,):
            return np.concatenate([value[:3], canonical_quaternion(value[3:])])
        raise PlanningInputError(f"{what}: expected a pose {{xyz, rpy}}, a point, or 7 numbers (xyz + quaternion)")

    def settings_spec(self):
        return self.settings.model_dump(mode="json")
