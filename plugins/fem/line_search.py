"""The line search of the Newton corrector: a step that decreases Π enough, near the minimiser along it.

Nocedal & Wright, *Numerical Optimization*, 2nd ed.: Armijo's sufficient
decrease and the strong curvature condition, the minimiser closed in on by
cubic interpolation (Algorithm 3.6, "zoom", and eq. 3.59). Used by
:class:`~.newton.EquilibriumSolver` (see the module docstring of
:mod:`.newton`, "Corrector"); it needs only Π and its gradient along the step.
"""

from __future__ import annotations

import numpy as np

#: trials of one line search at most (the bracket shrinks by at least a tenth per trial)
MAX_TRIALS = 60


def free_residual(gradient: np.ndarray, held: np.ndarray) -> float:
    """The largest residual force |g| on a free degree of freedom (N); ``held``: the prescribed ones' indices
    (fewer than the free ones: zeroing them beats gathering the rest)."""
    forces = np.abs(gradient)
    forces[held] = 0.0
    return float(forces.max(initial=0.0))


def line_search(gradient, x, energy, grad, direction, held, options, result, max_trials: int = MAX_TRIALS):
    """A step along ``direction`` that decreases Π enough: the accepted fraction and (Π, gradient)
    there, or (``None``, ``None``). Every trial computes the gradient with Π in one pass over the
    elements (the accepted trial's is needed next, and the others' give the slope of Π).

    The whole step is taken when it satisfies Armijo's condition (a
    Newton step near the solution always does). Otherwise the minimiser
    along the step lies in [0, 1] and is closed in on (Nocedal & Wright,
    *Numerical Optimization*, 2nd ed., Algorithm 3.6, "zoom"): each
    trial is the minimiser of the cubic through Π and its slope at the
    bracket's ends (their eq. 3.59), kept within the inner 80 % of the
    bracket, until a trial satisfies Armijo's condition and the strong
    curvature condition ``|Π'(t)| <= curvature |Π'(0)|``. On a thin
    cantilever bent by its tip load, Π grows like the fourth power of a
    Newton step from rest; backtracking then stopped at a tenth of the
    step where the minimiser lies at a fifth, and the zoom saves two of
    seven factorisations. A trial that inverts an element (Π = inf,
    no slope) quarters the bracket. Where Π's change is within its
    rounding error, a step is accepted when it reduces the largest
    residual force instead.

    ``gradient(x)`` gives Π and its gradient at x ((inf, None) where an
    element is inverted); ``held``: the prescribed degrees of freedom's indices;
    ``result.line_search_cuts`` counts the trials after the first.
    """
    slope = float(np.dot(grad, direction))
    residual = free_residual(grad, held)
    low, low_value, low_slope = 0.0, energy, slope  # Armijo holds here and Π decreases beyond
    high, high_value, high_slope = 1.0, np.inf, None  # the minimiser lies before here
    best = None  # (fraction, Π, gradient) of the lowest trial that satisfies Armijo
    fraction = 1.0
    for trial_count in range(max_trials):
        if trial_count:
            result.line_search_cuts += 1
            width = high - low
            if width < options.min_step_fraction:
                break
            fraction = None
            if high_slope is not None:
                fraction = _cubic_minimiser(low, low_value, low_slope, high, high_value, high_slope)
            if fraction is None:
                fraction = low + 0.25 * width
            fraction = min(max(fraction, low + 0.1 * width), high - 0.1 * width)
        value, trial_grad = gradient(x + fraction * direction)
        if np.isfinite(value) and abs(value - energy) <= 1e-12 * max(abs(energy), 1e-30) + 1e-300:
            # near the solution Π changes less than its rounding error and cannot judge a step (its
            # noise could pass Armijo's test): accept a step that reduces the residual, and only that
            if trial_grad is not None and free_residual(trial_grad, held) < residual:
                return fraction, (value, trial_grad)
            high, high_value, high_slope = fraction, value, None
            continue
        if not np.isfinite(value) or trial_grad is None:
            high, high_value, high_slope = fraction, np.inf, None
            continue
        trial_slope = float(np.dot(trial_grad, direction))
        armijo = value <= energy + options.armijo * fraction * slope
        if armijo and (fraction == 1.0 or abs(trial_slope) <= options.curvature * abs(slope)):
            return fraction, (value, trial_grad)
        if armijo and (best is None or value < best[1]):
            best = (fraction, value, trial_grad)
        if not armijo or value >= low_value or trial_slope > 0:
            high, high_value, high_slope = fraction, value, trial_slope
        else:
            low, low_value, low_slope = fraction, value, trial_slope
    if best is not None:
        return best[0], (best[1], best[2])
    return None, None


def _cubic_minimiser(a: float, fa: float, da: float, b: float, fb: float, db: float) -> float | None:
    """The minimiser of the cubic with values fa, fb and slopes da, db at a and b (Nocedal & Wright eq. 3.59),
    or None when the cubic has none."""
    d1 = da + db - 3.0 * (fa - fb) / (a - b)
    radicand = d1 * d1 - da * db
    if not np.isfinite(radicand) or radicand < 0.0:
        return None
    d2 = np.copysign(np.sqrt(radicand), b - a)
    denominator = db - da + 2.0 * d2
    if denominator == 0.0:
        return None
    value = b - (b - a) * (db + d2 - d1) / denominator
    return float(value) if np.isfinite(value) else None
