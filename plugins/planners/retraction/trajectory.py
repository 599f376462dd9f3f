"""The C¹ gripper trajectory through the plan's configurations (paper 002 §IV-E).

The paper interpolates the path's configurations with a cubic spline for
C¹ continuity. Positions and orientations need different splines: positions
get a natural cubic spline (scipy ``CubicSpline``), orientations scipy's
``RotationSpline`` (a cubic in the rotation vector with continuous angular
rate and acceleration, on SO(3) itself, so interpolated quaternions stay
unit and never take the long way round). Both share one parameter: the
cumulative roadmap distance along the path (the tissue's motion, DISP).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline
from surgiplan.geometry.transforms import canonical_quaternion


def parameters(lengths: np.ndarray) -> np.ndarray:
    """Knots (k,) from the path's edge lengths (k - 1,): cumulative, strictly increasing."""
    lengths = np.maximum(np.asarray(lengths, dtype=float), 1e-12)
    return np.concatenate([[0.0], np.cumsum(lengths)])


class SE3Spline:
    """A C¹ (indeed C²) curve through configurations (k, 7) at knots (k,)."""

    def __init__(self, knots: np.ndarray, q: np.ndarray) -> None:
        q = np.asarray(q, dtype=float)
        self.knots = np.asarray(knots, dtype=float)
        self.q = q
        if len(q) >= 2:
            self._position = CubicSpline(self.knots, q[:, :3], bc_type="natural")
            self._rotation = RotationSpline(self.knots, Rotation.from_quat(q[:, 3:]))

    def __call__(self, u) -> np.ndarray:
        u = np.atleast_1d(np.asarray(u, dtype=float))
        if len(self.q) < 2:
            return np.repeat(self.q, len(u), axis=0)
        u = np.clip(u, self.knots[0], self.knots[-1])
        return np.concatenate([self._position(u), canonical_quaternion(self._rotation(u).as_quat())], axis=1)

    def velocity(self, u) -> tuple[np.ndarray, np.ndarray]:
        """Linear (m per unit u, world frame) and angular (rad per unit u, body frame) rates at ``u``."""
        u = np.atleast_1d(np.asarray(u, dtype=float))
        return self._position(u, 1), self._rotation(u, 1)


def piece_parameters(knots: np.ndarray, counts: np.ndarray) -> list[np.ndarray]:
    """For each piece k (between knots k and k+1): ``counts[k]`` parameters after knot k, ending on knot k+1."""
    return [
        knots[k] + (knots[k + 1] - knots[k]) * np.arange(1, c + 1) / c for k, c in enumerate(np.asarray(counts, int))
    ]
