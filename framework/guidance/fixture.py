"""Virtual fixtures for haptic guidance: the force that pulls a trainee's instrument toward the recommended path.

A device that can push (the CAST gimbal's drives in cyclic synchronous torque,
``cast_gimbal`` source ``mode: assist``) asks :class:`VirtualFixture` at every
control cycle for the Cartesian forces to render, and maps them to joint
torques itself (τ = Jᵀ F). Two forces, from the current sample alone:

* **guidance**, a spring-damper toward the closest point ``c`` of the
  recommended path (its dense tip polyline) from the tip ``p``::

      F_g = α k (c − p) − α b (v − (v·t) t)

  ``k`` (``stiffness``, N/m), ``b`` (``damping``, N·s/m), ``v`` the tip's
  velocity and ``t`` the path's unit tangent at ``c``: the damper brakes
  motion *across* the path, never progress along it. ``α`` is the
  assistance level (:func:`assistance_level`), ``|F_g|`` at most
  ``max_force``;
* **the forbidden-region wall**, on the *shaft* (the segment from the
  fulcrum to the tip, of radius ``r``): where its clearance ``d`` falls below
  the limit ``d_wall`` — the plan's clearance threshold d_thresh outside a
  critical region, ``critical_clearance`` inside one (the closest point's
  progress along the path decides) — a spring pushes the shaft's point
  nearest the obstacles away from them::

      F_w = k_w (d_wall − d) n        (0 when d ≥ d_wall)

  at that point, ``n`` the distance field's gradient there (the direction
  that increases the clearance); the wall is never faded.

**Assist-as-needed** (:func:`assistance_level`): the guidance fades with the
trainee's proficiency, their recorded tip deviation (95th percentile over
the ``last`` attempts of the task, :meth:`~surgiplan.guidance.record.TraineeRecord.proficiency`,
the same number paper 000 takes d_thresh from)::

    α = max(α_min, clip((P − P_none) / (P_full − P_none), 0, 1))

full help (α = 1) at a deviation of ``full_at`` or more, the floor
``minimum`` at ``none_at`` or less, linear between; a trainee without a
recorded attempt gets full help; ``fade: none`` keeps α = 1.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, NonNegativeFloat, PositiveFloat, PositiveInt, model_validator

from ..models import StrictModel
from ..units import Length, PositiveLength


class FixtureSettings(StrictModel):
    """The virtual fixture of a haptic guide (see :mod:`surgiplan.guidance.fixture`)."""

    #: guidance spring toward the closest point of the recommended path (N/m)
    stiffness: NonNegativeFloat = 150.0
    #: guidance damper across the path (N·s/m)
    damping: NonNegativeFloat = 4.0
    #: the guidance force's magnitude at most (N)
    max_force: PositiveFloat = 4.0
    #: the forbidden-region wall's stiffness (N/m); never faded
    wall_stiffness: NonNegativeFloat = 1500.0
    #: the wall's limit inside a critical region (m); outside one it is the plan's clearance threshold
    critical_clearance: Length = Field(default=0.0, ge=0.0)
    #: how the guidance fades with proficiency: ``proficiency`` (the schedule above) or ``none`` (always full)
    fade: Literal["proficiency", "none"] = "proficiency"
    #: proficiency (recorded 95th-percentile tip deviation, m) at or above which the assistance is full
    full_at: PositiveLength = 0.008
    #: ... and at or below which it is at its floor
    none_at: Length = Field(default=0.002, ge=0.0)
    #: the assistance level's floor (0-1)
    minimum: float = Field(default=0.2, ge=0.0, le=1.0)
    #: the proficiency is measured over this many of the trainee's latest attempts at the task
    last: PositiveInt = 5

    @model_validator(mode="after")
    def _ordered(self):
        if self.none_at >= self.full_at:
            raise ValueError(f"none_at ({self.none_at} m) must be below full_at ({self.full_at} m)")
        return self


def assistance_level(proficiency: float | None, settings: FixtureSettings) -> float:
    """The assistance level α (0-1) for a trainee of ``proficiency`` (m, None: no recorded attempt)."""
    if settings.fade == "none" or proficiency is None:
        return 1.0
    span = settings.full_at - settings.none_at
    return float(max(settings.minimum, min(1.0, max(0.0, (proficiency - settings.none_at) / span))))


class VirtualFixture:
    """The fixture of one attempt: the path's dense tips (n, 3), its critical regions (arc-length intervals, m),
    the clearance threshold (m; None: no wall outside critical regions), the settings and the assistance level."""

    def __init__(
        self,
        tips: np.ndarray,
        critical: list[tuple[float, float]],
        threshold: float | None,
        settings: FixtureSettings,
        level: float = 1.0,
    ) -> None:
        tips = np.asarray(tips, dtype=float)
        if len(tips) < 2:
            raise ValueError("a virtual fixture needs a path of at least two points")
        self.a, self.b = tips[:-1], tips[1:]
        self.d = self.b - self.a
        self.length2 = np.maximum(np.einsum("ij,ij->i", self.d, self.d), 1e-300)
        seg = np.sqrt(self.length2)
        self.s0 = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
        self.tangent = self.d / seg[:, None]
        self.critical = list(critical)
        self.threshold = threshold
        self.settings = settings
        self.level = float(level)
        self.k = self.level * settings.stiffness
        self.c = self.level * settings.damping

    def closest(self, tip: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """The closest point of the path to ``tip``, the path's unit tangent there, and its progress (m)."""
        u = np.clip(np.einsum("ij,ij->i", tip - self.a, self.d) / self.length2, 0.0, 1.0)
        points = self.a + u[:, None] * self.d
        k = int(np.argmin(np.einsum("ij,ij->i", points - tip, points - tip)))
        return points[k], self.tangent[k], float(self.s0[k] + u[k] * np.sqrt(self.length2[k]))

    def guidance(self, tip: np.ndarray, velocity: np.ndarray) -> tuple[np.ndarray, float]:
        """The guidance force (N) at ``tip`` moving at ``velocity`` (m/s), and the progress of its closest
        point (m)."""
        point, tangent, progress = self.closest(tip)
        across = velocity - np.dot(velocity, tangent) * tangent
        force = self.k * (point - tip) - self.c * across
        size = float(np.linalg.norm(force))
        if size > self.settings.max_force:
            force *= self.settings.max_force / size
        return force, progress

    def wall_limit(self, progress: float) -> float | None:
        """The clearance the wall keeps at ``progress`` (m): the threshold outside critical regions, the critical
        clearance inside one; None: no wall (no threshold)."""
        if any(lo <= progress <= hi for lo, hi in self.critical):
            return self.settings.critical_clearance
        return self.threshold

    def wall(
        self, scene, fulcrum: np.ndarray, tip: np.ndarray, radius: float, limit: float | None
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """The wall's force (N), its point of application on the shaft from ``fulcrum`` to ``tip`` (of
        ``radius``), and the shaft's clearance (m, as the guide measures it)."""
        clearance = float(scene.segment_distance(fulcrum[None], tip[None])[0][0]) - radius
        if limit is None or clearance >= limit or self.settings.wall_stiffness == 0.0:
            return np.zeros(3), tip, clearance
        # the shaft's point nearest the obstacles (sampled), and the distance field's gradient there
        s = np.linspace(0.0, 1.0, 33)
        points = fulcrum + s[:, None] * (tip - fulcrum)
        point = points[int(np.argmin(scene.signed_distance(points)[0]))]
        h = 1e-5
        probes = point + np.concatenate([np.eye(3), -np.eye(3)]) * h
        d = scene.signed_distance(probes)[0]
        gradient = (d[:3] - d[3:]) / (2 * h)
        norm = float(np.linalg.norm(gradient))
        if not np.isfinite(norm) or norm == 0.0:
            return np.zeros(3), point, clearance
        return self.settings.wall_stiffness * (limit - clearance) * gradient / norm, point, clearance
