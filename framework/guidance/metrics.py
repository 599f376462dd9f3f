"""Skill metrics of a guided attempt: the kinematic measures training programmes rate attempts on, and the score.

Every metric is computed from the attempt's samples (time, tip, and the guide's per-sample deviation, progress,
clearance, critical flag, lateral offset and insertion depth), so the same numbers come from a live attempt,
a replayed file and the trainee record. Definitions, sources and the score's formula: ``docs/assessment.md``.

=====================  =======  ==============================================================================
metric                 better   definition
=====================  =======  ==============================================================================
``duration_s``         lower    task time: last sample's time minus the first's
``path_length_m``      lower    the tip's path length (sum of the distances between consecutive samples)
``economy``            lower    economy of motion: path length / the recommended path's length
``idle_s``             lower    idle time: the intervals between samples in which the tip moved slower than
                                ``idle_speed`` (of the smoothed positions, with ``smoothing_window``)
``jerk``               lower    dimensionless jerk of the speed profile (Hogan & Sternad 2009, as
                                Balasubramanian et al. 2015 compute it): D^3 / v_peak^2 * integral (d^2v/dt^2)^2
``sparc``              higher   spectral arc length of the speed profile (Balasubramanian et al. 2012, 2015)
``corrections``        lower    direction reversals of the lateral offset along the path's two normals, each
                                a retreat of more than ``correction_distance`` from the last extreme
``depth_reversals``    lower    depth perception proxy: reversals of the insertion depth (distance from the
                                gimbal's fulcrum, or ``port``, to the tip) of more than ``depth_distance``
``deviation_rms_m``    lower    RMS of the deviation from the recommended path
``below_threshold_s``  lower    time below d_thresh outside critical regions (both ends of an interval below)
``below_threshold_m``  lower    length travelled below d_thresh outside critical regions
``contacts``           lower    stretches of consecutive samples with clearance <= 0
``completion``         higher   1 when the goal is reached, else final progress / recommended length
``score``              higher   100 x completion x the weighted mean of the terms (see :func:`score_terms`)
=====================  =======  ==============================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import Field, NonNegativeFloat, PositiveFloat

from ..models import StrictModel
from ..units import PositiveLength, Vec3


@dataclass(frozen=True)
class Metric:
    name: str
    #: "lower" or "higher" is better
    better: str
    #: "s", "m", "count" or "" (a ratio)
    unit: str
    label: str


#: the metrics every attempt gets (in the order tables list them)
METRICS: tuple[Metric, ...] = (
    Metric("score", "higher", "", "score (0-100)"),
    Metric("duration_s", "lower", "s", "task time"),
    Metric("path_length_m", "lower", "m", "path length"),
    Metric("economy", "lower", "", "economy of motion (path / recommended length)"),
    Metric("idle_s", "lower", "s", "idle time"),
    Metric("jerk", "lower", "", "dimensionless jerk"),
    Metric("sparc", "higher", "", "smoothness (SPARC)"),
    Metric("corrections", "lower", "count", "corrections (lateral reversals)"),
    Metric("depth_reversals", "lower", "count", "depth perception (insertion reversals)"),
    Metric("deviation_rms_m", "lower", "m", "deviation RMS"),
    Metric("below_threshold_s", "lower", "s", "time below d_thresh"),
    Metric("below_threshold_m", "lower", "m", "length below d_thresh"),
    Metric("contacts", "lower", "count", "contacts"),
    Metric("completion", "higher", "", "completion"),
)
METRIC_BY_NAME = {m.name: m for m in METRICS}

#: the score's terms, each in [0, 1] (1: as good as it gets), and what they are made of
TERMS = ("safety", "accuracy", "economy", "time", "idle", "smoothness", "corrections", "depth")


class ScoreWeights(StrictModel):
    """The weight of each term in the score (any non-negative numbers; the score divides by their sum over the
    terms the attempt has: ``depth`` only when an insertion depth is measured)."""

    safety: NonNegativeFloat = 0.30
    accuracy: NonNegativeFloat = 0.20
    economy: NonNegativeFloat = 0.10
    time: NonNegativeFloat = 0.10
    idle: NonNegativeFloat = 0.05
    smoothness: NonNegativeFloat = 0.10
    corrections: NonNegativeFloat = 0.10
    depth: NonNegativeFloat = 0.05


class AssessmentSettings(StrictModel):
    """The ``assessment:`` block of a guide stage (lengths in the pipeline's unit, speeds in that unit per s)."""

    #: an interval in which the tip moves slower than this is idle
    idle_speed: PositiveLength = 0.002
    #: the time term's pace: the attempt's time against recommended length / reference_speed
    reference_speed: PositiveLength = 0.025
    #: a lateral (insertion) reversal counts when the motion retreats this far from its last extreme
    correction_distance: PositiveLength = 0.001
    depth_distance: PositiveLength = 0.001
    #: Savitzky-Golay smoothing (s, cubic) of the tip positions for the speed profile (smoothness, and then idle
    #: time); 0: none (a noisy tracker needs some: its noise is speed, and jerk amplifies it)
    smoothing_window: NonNegativeFloat = 0.0
    #: SPARC's cut-off frequency (Hz) and amplitude threshold (Balasubramanian et al. 2015's defaults)
    sparc_cutoff: PositiveFloat = 10.0
    sparc_threshold: float = Field(default=0.05, gt=0, lt=1)
    #: where the instrument enters (a point or a scene point's name) for the depth metric when the space has
    #: no fulcrum of its own (the gimbal's fulcrum is used otherwise); none: no depth metric
    port: Vec3 | str | None = None
    #: the scales of the smoothness, corrections and depth terms (see docs/assessment.md)
    sparc_scale: PositiveFloat = 4.0
    corrections_scale: PositiveFloat = 100.0
    depth_scale: PositiveFloat = 100.0
    weights: ScoreWeights = Field(default_factory=ScoreWeights)


@dataclass
class AttemptSamples:
    """An attempt's samples (SI): what the metrics are computed from."""

    t: np.ndarray
    tip: np.ndarray
    deviation: np.ndarray
    progress: np.ndarray
    clearance: np.ndarray
    critical: np.ndarray
    #: the tip's offset from its closest path point along the path's two normals (n, 2); None: not recorded
    lateral: np.ndarray | None = None
    #: the insertion depth (n,); None (or all NaN): not measured
    insertion: np.ndarray | None = None


# ----------------------------------------------------------------------------- the measures


def interval_steps(tip: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(np.asarray(tip, float), axis=0), axis=1)


def idle_time(t: np.ndarray, tip: np.ndarray, idle_speed: float) -> float:
    """Seconds of the intervals between consecutive samples in which the tip moved slower than ``idle_speed``."""
    dt = np.diff(np.asarray(t, float))
    idle = interval_steps(tip) < idle_speed * dt
    return float(dt[idle].sum())


def speed_profile(t: np.ndarray, tip: np.ndarray, smoothing_window: float = 0.0) -> tuple[np.ndarray, float]:
    """The tip's speed (m/s) on a uniform grid at the median sampling rate, and that rate (Hz).

    Positions are interpolated linearly onto the grid (a no-op for uniform samples), optionally smoothed by a
    cubic Savitzky-Golay filter of ``smoothing_window`` seconds, and differenced: one speed per interval."""
    t = np.asarray(t, float)
    tip = np.asarray(tip, float)
    if len(t) < 2:
        return np.zeros(0), 1.0
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        return np.zeros(0), 1.0
    n = round((t[-1] - t[0]) / dt) + 1
    grid = t[0] + dt * np.arange(n)
    if n == len(t) and np.allclose(grid, t, rtol=0, atol=1e-9 * max(1.0, abs(t[-1]))):
        points = tip
    else:
        points = np.column_stack([np.interp(grid, t, tip[:, k]) for k in range(3)])
    window = round(smoothing_window / dt) | 1  # odd
    if smoothing_window > 0 and window >= 5 and window <= len(points):
        from scipy.signal import savgol_filter

        points = savgol_filter(points, window, 3, axis=0)
    return interval_steps(points) / dt, 1.0 / dt


def dimensionless_jerk(speed: np.ndarray, fs: float) -> float:
    """D^3 / v_peak^2 * integral of (d^2 v / dt^2)^2 dt over the speed profile (positive; 0 for constant speed).

    Discretised as Balasubramanian et al.'s reference: second differences of the samples, D = n / fs."""
    speed = np.asarray(speed, float)
    peak = float(np.max(np.abs(speed))) if len(speed) else 0.0
    if len(speed) < 3 or peak <= 0:
        return math.nan
    dt = 1.0 / fs
    jerk = np.diff(speed, 2) / dt**2
    duration = len(speed) * dt
    return float(duration**3 / peak**2 * np.sum(jerk**2) * dt)


def sparc(speed: np.ndarray, fs: float, padlevel: int = 4, cutoff: float = 10.0, threshold: float = 0.05) -> float:
    """The spectral arc length of a speed profile (Balasubramanian et al. 2015): the negative arc length of its
    normalised magnitude spectrum up to the adaptive cut-off (the last frequency below ``cutoff`` Hz where the
    spectrum is at least ``threshold``), frequency normalised by that band; about -1.4 to -1.6 for one smooth
    movement, more negative for less smooth ones."""
    speed = np.asarray(speed, float)
    if len(speed) < 2 or not np.any(speed != 0):
        return math.nan
    nfft = int(2 ** (math.ceil(math.log2(len(speed))) + padlevel))
    f = np.arange(nfft) * (fs / nfft)
    magnitude = np.abs(np.fft.fft(speed, nfft))
    magnitude = magnitude / magnitude.max()
    band = f <= cutoff
    f, magnitude = f[band], magnitude[band]
    above = np.flatnonzero(magnitude >= threshold)
    f, magnitude = f[above[0] : above[-1] + 1], magnitude[above[0] : above[-1] + 1]
    if len(f) < 2:
        return 0.0
    return float(-np.sum(np.sqrt((np.diff(f) / (f[-1] - f[0])) ** 2 + np.diff(magnitude) ** 2)))


def reversals(x: np.ndarray, distance: float) -> int:
    """How often a signal turns back by more than ``distance`` from its last extreme (a hysteresis, so noise
    smaller than ``distance`` never counts); NaNs are skipped."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)].tolist()
    if len(x) < 2:
        return 0
    count, direction = 0, 0
    high = low = extreme = float(x[0])
    for value in x[1:]:
        if direction == 0:
            high, low = max(high, value), min(low, value)
            if high - value > distance:  # the first clear motion: down after a rise, or a fall from the start
                direction, extreme = -1, value
                count += int(high > x[0] + distance)
            elif value - low > distance:
                direction, extreme = 1, value
                count += int(low < x[0] - distance)
        elif direction > 0:
            if value > extreme:
                extreme = value
            elif extreme - value > distance:
                count, direction, extreme = count + 1, -1, value
        elif value < extreme:
            extreme = value
        elif value - extreme > distance:
            count, direction, extreme = count + 1, 1, value
    return count


def runs(mask: np.ndarray) -> int:
    """The number of stretches of consecutive True."""
    mask = np.asarray(mask, bool)
    return int(np.count_nonzero(mask[1:] & ~mask[:-1]) + (1 if len(mask) and mask[0] else 0))


def below_threshold(samples: AttemptSamples, threshold: float) -> tuple[float, float]:
    """(seconds, metres) below ``threshold`` outside critical regions: the intervals whose two ends are."""
    if not threshold > 0 or len(samples.t) < 2:
        return 0.0, 0.0
    low = (np.asarray(samples.clearance) < threshold) & ~np.asarray(samples.critical, bool)
    both = low[:-1] & low[1:]
    return float(np.diff(samples.t)[both].sum()), float(interval_steps(samples.tip)[both].sum())


# ----------------------------------------------------------------------------- an attempt


def measure(
    samples: AttemptSamples,
    *,
    recommended_length: float,
    threshold: float,
    completion: float,
    settings: AssessmentSettings,
) -> dict[str, Any]:
    """Every metric of :data:`METRICS` but the score, from the samples (SI); None where it cannot be measured."""
    t, tip = np.asarray(samples.t, float), np.asarray(samples.tip, float)
    steps = interval_steps(tip)
    path_length = float(steps.sum())
    duration = float(t[-1] - t[0]) if len(t) else 0.0
    speed, fs = speed_profile(t, tip, settings.smoothing_window)
    below_s, below_m = below_threshold(samples, threshold)
    corrections = None
    if samples.lateral is not None and np.all(np.isfinite(samples.lateral)):
        lateral = np.asarray(samples.lateral, float).reshape(-1, 2)
        corrections = reversals(lateral[:, 0], settings.correction_distance) + reversals(
            lateral[:, 1], settings.correction_distance
        )
    depth = None
    if samples.insertion is not None and np.any(np.isfinite(samples.insertion)):
        depth = reversals(samples.insertion, settings.depth_distance)
    deviation = np.asarray(samples.deviation, float)
    return {
        "duration_s": duration,
        "path_length_m": path_length,
        "economy": path_length / recommended_length if recommended_length > 0 else None,
        # on the smoothed speed profile when there is smoothing (a noisy tracker's noise is speed), else exactly
        "idle_s": float(np.count_nonzero(speed < settings.idle_speed) / fs)
        if settings.smoothing_window > 0
        else idle_time(t, tip, settings.idle_speed),
        "jerk": _finite(dimensionless_jerk(speed, fs)),
        "sparc": _finite(sparc(speed, fs, cutoff=settings.sparc_cutoff, threshold=settings.sparc_threshold)),
        "corrections": corrections,
        "depth_reversals": depth,
        "deviation_rms_m": float(np.sqrt(np.mean(deviation**2))) if len(deviation) else None,
        "below_threshold_s": below_s,
        "below_threshold_m": below_m,
        "contacts": runs(np.asarray(samples.clearance) <= 0),
        "completion": float(completion),
    }


def score_terms(
    values: dict[str, Any], *, recommended_length: float, tolerance: float, settings: AssessmentSettings
) -> dict[str, float]:
    """Each term of the score in [0, 1] (1: as good as it gets), from the metrics; a term whose metric is not
    measured is left out:

    * safety = 1 - below_threshold_m / recommended length - 0.25 per contact (at least 0)
    * accuracy = exp(-deviation RMS / deviation tolerance)
    * economy = min(1, 1 / economy)
    * time = min(1, (recommended length / reference_speed) / task time)
    * idle = 1 - idle time / task time
    * smoothness = exp(-(|SPARC| - 1) / sparc_scale)  (1 for SPARC >= -1)
    * corrections = 1 / (1 + corrections / (corrections_scale x recommended length in m))
    * depth = 1 / (1 + depth reversals / (depth_scale x recommended length in m))
    """
    length = max(recommended_length, 1e-12)
    terms: dict[str, float] = {
        "safety": max(0.0, 1.0 - values["below_threshold_m"] / length - 0.25 * values["contacts"]),
    }
    if values.get("deviation_rms_m") is not None:
        terms["accuracy"] = math.exp(-values["deviation_rms_m"] / tolerance)
    if values.get("economy"):
        terms["economy"] = min(1.0, 1.0 / values["economy"])
    duration = values.get("duration_s") or 0.0
    if duration > 0:
        terms["time"] = min(1.0, length / settings.reference_speed / duration)
        terms["idle"] = max(0.0, 1.0 - values["idle_s"] / duration)
    if values.get("sparc") is not None:
        terms["smoothness"] = min(1.0, math.exp(-(abs(values["sparc"]) - 1.0) / settings.sparc_scale))
    if values.get("corrections") is not None:
        terms["corrections"] = 1.0 / (1.0 + values["corrections"] / (settings.corrections_scale * length))
    if values.get("depth_reversals") is not None:
        terms["depth"] = 1.0 / (1.0 + values["depth_reversals"] / (settings.depth_scale * length))
    return terms


def score(terms: dict[str, float], completion: float, weights: ScoreWeights) -> float:
    """100 x completion x the weighted mean of the terms present (weights renormalised over them)."""
    w = {k: getattr(weights, k) for k in terms}
    total = sum(w.values())
    if total <= 0:
        return 0.0
    return 100.0 * completion * sum(w[k] * terms[k] for k in terms) / total


def assess(
    samples: AttemptSamples,
    *,
    recommended_length: float,
    threshold: float,
    tolerance: float,
    completion: float,
    settings: AssessmentSettings,
) -> dict[str, Any]:
    """The attempt's metrics (:data:`METRICS`), its score, the score's terms and the weights used."""
    values = measure(
        samples, recommended_length=recommended_length, threshold=threshold, completion=completion, settings=settings
    )
    terms = score_terms(values, recommended_length=recommended_length, tolerance=tolerance, settings=settings)
    weights = {k: getattr(settings.weights, k) for k in terms}
    return {
        **values,
        "score": score(terms, completion, settings.weights),
        "score_terms": terms,
        "score_weights": weights,
    }


def _finite(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None
