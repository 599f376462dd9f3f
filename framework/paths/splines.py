"""Cubic-spline smoothing of waypoint paths, certified piece by piece (paper 001 §3.1, §4.2).

optMIS smooths each shortest path with a cubic spline and checks the result
against every obstacle (paper 001 §3.1: "a brute-force collision check with
all the obstacles present in the space"). Here:

* the spline is a *natural* cubic spline (paper 001 §4.2, Hagan & West 2006)
  through the path's knots, parameterised by chord length;
* each knot interval is sampled at spacing at most ``resolution``; the
  samples, joined by straight motions, are the stored path, and *every* one
  of those motions is certified clear for the tip sphere (keeping
  ``margin``) with the scene's exact swept-sphere check, and every sample
  must lie inside the workspace bounds;
* an interval whose samples fail falls back to a natural spline through a
  shorter window of knots around it (``window`` knots on each side), and if
  that fails too, to the straight chord between its two knots, which lies on
  a certified motion of the search space already.

The returned path therefore never collides. Certification is batched: all
intervals of all paths in one vectorised call per fallback level.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

#: how each knot interval of a smoothed path was drawn
GLOBAL, WINDOW, CHORD = 0, 1, 2


@dataclass
class SmoothedPath:
    """A certified dense polyline and how each of its knot intervals was drawn."""

    points: np.ndarray  # (n, 3) m
    kinds: np.ndarray  # per knot interval: GLOBAL, WINDOW or CHORD
    knot_index: np.ndarray  # index in ``points`` of every knot

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())


def _parameters(knots: np.ndarray) -> np.ndarray:
    chord = np.maximum(np.linalg.norm(np.diff(knots, axis=0), axis=1), 1e-12)
    return np.concatenate([[0.0], np.cumsum(chord)])


def _spline(knots: np.ndarray) -> tuple[CubicSpline, np.ndarray]:
    t = _parameters(knots)
    return CubicSpline(t, knots, bc_type="natural"), t


def _counts(knots: np.ndarray, resolution: float) -> np.ndarray:
    chord = np.linalg.norm(np.diff(knots, axis=0), axis=1)
    return np.maximum(1, np.ceil(chord / resolution - 1e-9).astype(np.int64))


def _interval_samples(
    curve, t0: float, t1: float, count: int, k0: np.ndarray, k1: np.ndarray, resolution: float
) -> np.ndarray:
    """Points of ``curve`` from t0 to t1, at most ``resolution`` apart; the ends are the knots k0 and k1 exactly.

    (The spline interpolates the knots; setting them exactly makes neighbouring
    intervals meet bit for bit, so what is certified is what is stored.) The
    arc can be longer than the chord, so the count starts from the chord and
    grows until every step is short enough.
    """
    for _ in range(8):
        samples = curve(np.linspace(t0, t1, count + 1))
        samples[0], samples[-1] = k0, k1
        step = float(np.max(np.linalg.norm(np.diff(samples, axis=0), axis=1)))
        if step <= resolution:
            break
        count = int(np.ceil(count * step / resolution * 1.01))
    return samples


def _certify(space, pieces: list[np.ndarray], margin: float) -> np.ndarray:
    """Per piece (a short polyline): every sample in bounds and every motion certified."""
    if not pieces:
        return np.zeros(0, dtype=bool)
    a = np.concatenate([p[:-1] for p in pieces])
    b = np.concatenate([p[1:] for p in pieces])
    ok = space.motion_is_clear(a, b, margin) & space.scene.in_bounds(a) & space.scene.in_bounds(b)
    owner = np.repeat(np.arange(len(pieces)), [len(p) - 1 for p in pieces])
    return np.bincount(owner, weights=~ok, minlength=len(pieces)) == 0


def smooth_paths(
    space, paths: list[np.ndarray], resolution: float, margin: float = 0.0, window: int = 2, enabled: bool = True
) -> list[SmoothedPath]:
    """Certified smooth paths through the knots of each path in ``paths`` ((n_i, 3) arrays, m).

    Consecutive knots must be joined by certified straight motions (edges of
    the search space or sub-motions of them). ``resolution`` (m): the largest
    spacing of the stored samples. ``enabled=False`` keeps the polylines,
    sampled at the same resolution.
    """
    counts = [_counts(np.asarray(p, float), resolution) if len(p) >= 2 else np.zeros(0, np.int64) for p in paths]
    kinds = [np.full(len(c), GLOBAL if enabled else CHORD, dtype=np.int8) for c in counts]
    intervals: list[list[np.ndarray]] = []
    for knots, count, kind in zip(paths, counts, kinds, strict=True):
        knots = np.asarray(knots, float)
        if len(knots) < 3 or not enabled:
            kind[:] = CHORD
            intervals.append([_chord(knots, i, count[i]) for i in range(len(count))])
            continue
        curve, t = _spline(knots)
        intervals.append(
            [
                _interval_samples(curve, t[i], t[i + 1], count[i], knots[i], knots[i + 1], resolution)
                for i in range(len(count))
            ]
        )

    # level 1: the global splines
    todo = [(p, i) for p, kind in enumerate(kinds) for i in np.flatnonzero(kind == GLOBAL)]
    ok = _certify(space, [intervals[p][i] for p, i in todo], margin)
    failed = [todo[k] for k in np.flatnonzero(~ok)]
    # level 2: a natural spline through a shorter window of knots around the interval
    retry = []
    for p, i in failed:
        knots = np.asarray(paths[p], float)
        lo, hi = max(0, i - window + 1), min(len(knots), i + window + 1)
        if hi - lo >= 3:
            curve, t = _spline(knots[lo:hi])
            j = i - lo
            intervals[p][i] = _interval_samples(curve, t[j], t[j + 1], counts[p][i], knots[i], knots[i + 1], resolution)
            kinds[p][i] = WINDOW
            retry.append((p, i))
        else:
            intervals[p][i] = _chord(knots, i, counts[p][i])
            kinds[p][i] = CHORD
    ok = _certify(space, [intervals[p][i] for p, i in retry], margin)
    # level 3: the straight chord (a sub-motion of a certified motion)
    for k in np.flatnonzero(~ok):
        p, i = retry[k]
        intervals[p][i] = _chord(np.asarray(paths[p], float), i, counts[p][i])
        kinds[p][i] = CHORD

    out = []
    for knots, kind, pieces in zip(paths, kinds, intervals, strict=True):
        knots = np.asarray(knots, float)
        if len(knots) < 2:
            out.append(SmoothedPath(knots.reshape(-1, 3).copy(), kind, np.zeros(len(knots), dtype=np.int64)))
            continue
        # consecutive intervals share their knot: keep it once
        dense = np.concatenate([pieces[0]] + [piece[1:] for piece in pieces[1:]])
        knot_index = np.concatenate([[0], np.cumsum([len(piece) - 1 for piece in pieces])])
        out.append(SmoothedPath(dense, kind, knot_index))
    return out


def _chord(knots: np.ndarray, i: int, count: int) -> np.ndarray:
    t = np.linspace(0.0, 1.0, count + 1)[:, None]
    samples = knots[i] + t * (knots[i + 1] - knots[i])
    samples[0], samples[-1] = knots[i], knots[i + 1]
    return samples
