"""Small pydantic models shared by the scene, spaces and plugins (SI after validation).

:class:`StrictModel` is the one settings base of the core and of every plugin: it forbids unknown keys, so a
misspelt key in a file is an error naming it (with the valid keys) instead of being silently ignored.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, model_validator

from .geometry.transforms import Pose
from .units import Angle, Finite, Vec3


class StrictModel(BaseModel):
    """Base of every settings model: unknown keys are errors (``extra="forbid"``).

    Plugin authors subclass it for their ``Settings``; the registry refuses a plugin whose settings (at any
    level) accept unknown keys::

        class Settings(StrictModel):
            margin: Length = 0.0
    """

    model_config = ConfigDict(extra="forbid")


class RegionModel(StrictModel):
    """An axis-aligned box: its ``min`` and ``max`` corners (length unit of the file), ``max`` not below ``min``
    along any axis. A deformable model's regions of its rest mesh (materials, anchors, loads) and a retraction's
    anchors and sampling workspace are such boxes."""

    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _ordered(self):
        bad = [axis for axis, lo, hi in zip("xyz", self.min, self.max, strict=True) if hi < lo]
        if bad:
            raise ValueError(f"max must not be below min along {', '.join(bad)}")
        return self


class PoseModel(StrictModel):
    """A rigid pose: position ``xyz`` (length unit of the file) and ``rpy`` (radians, or '30 deg')."""

    xyz: Vec3 = (0.0, 0.0, 0.0)
    rpy: tuple[Angle, Angle, Angle] = (0.0, 0.0, 0.0)

    def to_pose(self) -> Pose:
        """The pose as a ``Pose`` (rotation matrix and translation, m): ``rpy`` as extrinsic rotations about x, y
        then z."""
        return Pose.from_xyz_rpy(self.xyz, self.rpy)


class QuaternionPoseModel(StrictModel):
    """A pose by position and either ``rpy`` or a scalar-last ``quaternion`` (qx, qy, qz, qw)."""

    xyz: Vec3 = (0.0, 0.0, 0.0)
    rpy: tuple[Angle, Angle, Angle] | None = None
    quaternion: tuple[Finite, Finite, Finite, Finite] | None = None

    @model_validator(mode="after")
    def _one_orientation(self):
        if self.rpy is not None and self.quaternion is not None:
            raise ValueError("give either rpy or quaternion, not both")
        if self.quaternion is not None and not np.linalg.norm(self.quaternion) > 0:
            raise ValueError("quaternion must not be zero")
        return self


class AngleRange(StrictModel):
    """Joint limits in radians (``[min, max]``; '60 deg' accepted)."""

    min: Angle
    max: Angle

    @model_validator(mode="after")
    def _ordered(self):
        if self.max < self.min:
            raise ValueError(f"max ({self.max}) is below min ({self.min})")
        return self
