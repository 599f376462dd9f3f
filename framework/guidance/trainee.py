"""A synthetic trainee: follows a recommended tip path with proficiency-dependent deviation, hesitation and speed.

For rehearsing guidance without a trainee, and for tests with known
behaviour. Seeded and documented; each level of :data:`LEVELS` is a set of
parameters (all overridable):

* ``speed`` (m/s): the tip's mean speed along the path, varied by a slow
  random factor (``speed_variation``, relative, Ornstein-Uhlenbeck with the
  correlation time below);
* ``deviation`` (m): the standard deviation, per lateral axis, of the tip's
  offset from the path (perpendicular to it): a critically damped oscillator
  driven by white noise, with time constant ``correlation_time`` (s), so the
  offset wanders smoothly, as a hand drifts, rather than jittering. The
  levels' values make the 95th percentile of the radial deviation about
  paper 000's d_thresh for the level (1, 4 and 8 mm: 2.45 standard
  deviations of a Rayleigh distribution);
* ``hesitation_rate`` (per s) and ``hesitation`` (s): pauses start at random
  (Poisson) and last an exponentially distributed time of that mean; while
  hesitating the hand holds still (neither progress nor drift), and its
  drift starts again from rest;
* ``rate`` (Hz): samples per second.

The values are plausible for a laparoscopic box trainer (tens of mm/s,
millimetres of drift), chosen so an expert rarely leaves a 4 mm corridor and
a beginner often does; they are a model, not a measurement of people.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, NonNegativeFloat, PositiveFloat

from ..models import StrictModel
from ..units import Length, PositiveLength
from .analysis import Guide
from .source import PoseSample

#: parameters per level (SI)
LEVELS: dict[str, dict[str, float]] = {
    "expert": {"speed": 0.025, "deviation": 0.0004, "hesitation_rate": 0.0, "hesitation": 0.3},
    "intermediate": {"speed": 0.018, "deviation": 0.0016, "hesitation_rate": 0.1, "hesitation": 0.6},
    "beginner": {"speed": 0.012, "deviation": 0.0032, "hesitation_rate": 0.25, "hesitation": 1.0},
}


class TraineeModel(StrictModel):
    """A synthetic trainee's parameters (lengths in the pipeline's unit)."""

    level: Literal["expert", "intermediate", "beginner"] = "intermediate"
    speed: PositiveLength | None = None
    deviation: Length | None = None
    hesitation_rate: NonNegativeFloat | None = None
    hesitation: PositiveFloat | None = None
    speed_variation: float = Field(default=0.2, ge=0, lt=1)
    correlation_time: PositiveFloat = 0.5
    rate: PositiveFloat = 100.0
    seed: int = 0

    def parameter(self, name: str) -> float:
        value = getattr(self, name)
        return float(LEVELS[self.level][name] if value is None else value)


def synthetic_attempt(
    tips: np.ndarray, model: TraineeModel, bounds: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Times (s) and tip positions (n, 3) of a synthetic trainee following the tip path ``tips`` (m).

    ``bounds`` (the scene's workspace, min and max corners in m) are the walls of the trainer box: the drifting
    hand cannot take the tip through them, so a tip the drift would carry outside stops at the wall (a
    recommended path along the box's lid otherwise has half of its drift outside the scene)."""
    rng = np.random.default_rng(model.seed)
    tips = np.asarray(tips, float)
    steps = np.linalg.norm(np.diff(tips, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    length = float(arc[-1])
    dt = 1.0 / model.rate
    speed = model.parameter("speed")
    sigma = model.parameter("deviation")
    pause_rate = model.parameter("hesitation_rate")
    pause_mean = model.parameter("hesitation")
    decay = float(np.exp(-dt / model.correlation_time))
    noise = float(np.sqrt(1.0 - decay**2))
    # the offset: x'' + 2 w x' + w^2 x = white noise of intensity 4 w^3 sigma^2 (stationary std sigma), w = 1/tau;
    # integrated with steps of at most tau / 50 (semi-implicit Euler, stable)
    omega = 1.0 / model.correlation_time
    substeps = max(1, int(np.ceil(50 * dt / model.correlation_time)))
    h = dt / substeps
    drive = float(np.sqrt(4 * omega**3 * sigma**2 / h))
    offset = np.zeros(3)
    velocity = np.zeros(3)
    factor = 0.0
    s, t, paused_until = 0.0, 0.0, -1.0
    times, points = [], []
    limit = int(20 * max(length, 1e-9) / (speed * dt) + 1000 / dt)  # a bound: never loop for ever
    for _ in range(limit):
        along = [np.interp(s, arc, tips[:, k]) for k in range(3)]
        i = min(int(np.searchsorted(arc, s, side="right")) - 1, len(steps) - 1)
        tangent = (tips[i + 1] - tips[i]) / max(steps[i], 1e-15)
        lateral = offset - (offset @ tangent) * tangent
        # drift fades to nothing at the two ends: the trainee starts at the start and finishes at the goal
        fade = min(1.0, s / 0.005, (length - s) / 0.005) if length > 0 else 0.0
        times.append(t)
        points.append(np.asarray(along) + max(fade, 0.0) * lateral)
        if s >= length:
            break
        still = t < paused_until  # hesitating: the hand holds still, its drift too (the noise is drawn all the same)
        for _ in range(substeps):
            kick = rng.normal(0.0, 1.0, 3)
            if not still:
                velocity += h * (-2 * omega * velocity - omega**2 * offset + drive * kick)
                offset = offset + h * velocity
        if still:
            velocity = np.zeros(3)
        factor = factor * decay + rng.normal(0.0, model.speed_variation * noise)
        if t >= paused_until and pause_rate > 0 and rng.random() < pause_rate * dt:
            paused_until = t + rng.exponential(pause_mean)
        if t >= paused_until:
            s = min(length, s + speed * max(0.1, 1.0 + factor) * dt)
        t += dt
    points = np.asarray(points)
    if bounds is not None:
        points = np.clip(points, np.asarray(bounds[0], float), np.asarray(bounds[1], float))
    return np.asarray(times), points


def follow(guide: Guide, model: TraineeModel) -> Guide:
    """A synthetic trainee's attempt measured by ``guide`` sample by sample (tip positions), as fast as it runs;
    returns the guide, its events finished."""
    times, tips = synthetic_attempt(guide.tips, model, (guide.scene.bounds_min, guide.scene.bounds_max))
    for t, tip in zip(times, tips, strict=True):
        guide.measure(PoseSample(float(t), tip=tip))
    guide.finish()
    return guide
