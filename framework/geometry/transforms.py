"""Rigid transforms, roll-pitch-yaw angles and unit quaternions.

Conventions (the URDF ones):

* ``rpy = (roll, pitch, yaw)`` in radians, applied about the fixed x, y, z axes
  in that order, i.e. ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
* Quaternions are stored scalar-last, ``(qx, qy, qz, qw)``, as in Pinocchio's
  ``XYZQUAT`` and :mod:`scipy.spatial.transform`.

Every function accepts batches: leading dimensions broadcast.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def _rotation():
    """scipy's ``Rotation``, imported at the first conversion: ``scipy.spatial`` costs about half a second, which a
    scene of boxes and ``surgiplan validate`` need not pay."""
    from scipy.spatial.transform import Rotation

    return Rotation


def rpy_to_matrix(rpy) -> np.ndarray:
    """Rotation matrix (…, 3, 3) from roll, pitch, yaw (…, 3) in radians."""
    rpy = np.asarray(rpy, dtype=float)
    if rpy.shape == (3,) and not rpy.any():
        return np.eye(3)
    if rpy.shape[-1:] == (3,) and not rpy.any():  # no rotation (most obstacles): exactly what scipy gives, sooner
        return np.broadcast_to(np.eye(3), (*rpy.shape[:-1], 3, 3)).copy()
    if rpy.shape[-1:] != (3,):
        return _rotation().from_euler("xyz", rpy).as_matrix()  # scipy's message for a wrong shape
    # Rz(yaw) @ Ry(pitch) @ Rx(roll) written out (scipy's from_euler("xyz") to 1e-15, the tests check): a scene
    # of 10,000 boxes, a tenth of them turned, costs no scipy import and no 1,000 Rotation objects
    cr, cp, cy = np.cos(rpy[..., 0]), np.cos(rpy[..., 1]), np.cos(rpy[..., 2])
    sr, sp, sy = np.sin(rpy[..., 0]), np.sin(rpy[..., 1]), np.sin(rpy[..., 2])
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=-1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=-1),
            np.stack([-sp, cp * sr, cp * cr], axis=-1),
        ],
        axis=-2,
    )


def matrix_to_rpy(rotation) -> np.ndarray:
    """Roll, pitch, yaw (…, 3) in radians from rotation matrices (…, 3, 3)."""
    return _rotation().from_matrix(np.asarray(rotation, dtype=float)).as_euler("xyz")


def quaternion_to_matrix(quaternion) -> np.ndarray:
    """Rotation matrices from scalar-last unit quaternions (…, 4)."""
    return _rotation().from_quat(np.asarray(quaternion, dtype=float)).as_matrix()


def matrix_to_quaternion(rotation) -> np.ndarray:
    """Scalar-last unit quaternions, sign chosen with ``qw >= 0``."""
    q = _rotation().from_matrix(np.asarray(rotation, dtype=float)).as_quat()
    return canonical_quaternion(q)


def canonical_quaternion(quaternion) -> np.ndarray:
    """Normalise and flip each quaternion so that ``qw >= 0`` (q and -q are one rotation)."""
    q = np.asarray(quaternion, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)


def quaternion_angle(q1, q2) -> np.ndarray:
    """Angle in radians of the rotation between unit quaternions, in [0, pi]."""
    dot = np.abs(np.sum(np.asarray(q1) * np.asarray(q2), axis=-1))
    return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


def slerp(q1, q2, t) -> np.ndarray:
    """Spherical linear interpolation along the shorter arc.

    ``q1``, ``q2``: (…, 4) unit quaternions; ``t``: broadcastable fractions in
    [0, 1]. Returns unit quaternions (…, 4).
    """
    q1 = np.asarray(q1, dtype=float)
    q2 = np.asarray(q2, dtype=float)
    t = np.asarray(t, dtype=float)[..., None]
    dot = np.sum(q1 * q2, axis=-1, keepdims=True)
    q2 = np.where(dot < 0, -q2, q2)  # shorter arc
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.sin(theta)
    small = sin_theta < 1e-9
    safe = np.where(small, 1.0, sin_theta)
    w1 = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    w2 = np.where(small, t, np.sin(t * theta) / safe)
    q = w1 * q1 + w2 * q2
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


@dataclass(frozen=True)
class Pose:
    """A rigid transform: ``x_world = rotation @ x_local + translation`` (metres)."""

    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def from_xyz_rpy(cls, xyz=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0)) -> Pose:
        return cls(rpy_to_matrix(rpy), np.asarray(xyz, dtype=float))

    @property
    def is_identity(self) -> bool:
        return bool(np.allclose(self.rotation, np.eye(3)) and not np.any(self.translation))

    def apply(self, points) -> np.ndarray:
        """Map local points (…, 3) to world coordinates."""
        return np.asarray(points, dtype=float) @ self.rotation.T + self.translation

    def apply_inverse(self, points) -> np.ndarray:
        """Map world points (…, 3) into this frame."""
        return (np.asarray(points, dtype=float) - self.translation) @ self.rotation

    def compose(self, other: Pose) -> Pose:
        """``self * other``: first ``other``, then ``self``."""
        return Pose(self.rotation @ other.rotation, self.apply(other.translation))

    def as_matrix(self) -> np.ndarray:
        matrix = np.eye(4)
        matrix[:3, :3] = self.rotation
        matrix[:3, 3] = self.translation
        return matrix
