"""The Newton solver's steps: the predictor and corrector directions, and where a predictor step may go.

:class:`NewtonSteps` is a mix-in of :class:`~.newton.EquilibriumSolver` (it
uses the solver's ``pattern``, ``_energy`` and ``_gradient``), kept apart
because it is the part that turns a factored tangent into a step (see
"Predictor" and "Quasi-Newton reuse of a factorisation" in :mod:`.newton`):
the predictor ``K_ff d_f = -(g_f + K_fc d_c)`` that carries the prescribed
motion, the Newton or chord step, the L-BFGS step on top of the factored
tangent with the secant pairs it keeps, and the cut or split of a predictor
step that would invert an element or leave too large a residual.
"""

from __future__ import annotations

import numpy as np

from .line_search import free_residual
from .tangent_factor import CachedFactor


class NewtonSteps:
    """How :class:`~.newton.EquilibriumSolver` steps (a mix-in; see the module docstring)."""

    @staticmethod
    def _remember(pairs, step, change, held, history: int) -> None:
        """Keep the secant pair (s, y) of a corrector step (free dofs: ``held`` the prescribed ones' indices)
        when its curvature s.y is positive."""
        y = change.copy()
        y[held] = 0.0
        s = step.copy()
        s[held] = 0.0
        sy = float(s @ y)
        if sy > 1e-12 * float(np.sqrt((s @ s) * (y @ y))):  # otherwise the update would not stay definite
            pairs.append((s, y, 1.0 / sy))
            if len(pairs) > history:
                pairs.pop(0)

    def _direction(self, factor: CachedFactor, grad, held, pending, pairs) -> np.ndarray | None:
        """The step (3n,): with the pending prescribed motion, the predictor ``K_ff d_f = -(g_f + K_fc d_c)``;
        else the L-BFGS step on top of the factored tangent (``pairs`` empty: ``K d = -g``, a Newton or
        chord step). ``held``: the prescribed dofs' indices. ``None`` when it is not finite or, in the corrector,
        not a descent direction."""
        moving = bool(np.any(pending != 0.0))
        if moving or not pairs:
            rhs = -grad
            if moving:
                motion = np.zeros_like(grad)
                motion[held] = pending
                rhs = rhs - self.pattern.matvec(factor.data, motion)
            rhs[held] = factor.diagonal[held] * pending  # scaled identity rows: returns the motion
            direction = factor.lu.solve(rhs)
            direction[held] = pending  # exactly, not as rounded by the solve
        else:  # the two-loop recursion (Nocedal & Wright, Algorithm 7.4) with H0 = K^-1
            q = grad.copy()
            q[held] = 0.0
            alphas = []
            for s, y, rho in reversed(pairs):
                alpha = rho * float(s @ q)
                q -= alpha * y
                alphas.append(alpha)
            r = factor.lu.solve(q)
            r[held] = 0.0
            for (s, y, rho), alpha in zip(pairs, reversed(alphas), strict=True):
                r += (alpha - rho * float(y @ r)) * s
            direction = -r
        if not np.all(np.isfinite(direction)):
            return None
        if not moving and float(np.dot(grad, direction)) >= 0.0:
            return None
        return direction

    def _cut_to_valid(self, x, direction, held, goal, pending, result):
        """The largest fraction (halving from 1) of a predictor step that inverts no element, that state,
        and (Π, gradient) there (computed anyway to test it, and needed next).

        The prescribed dofs land exactly on ``goal - (1 - fraction) pending``
        (the state tested is the state taken: ``x + d`` would round them).
        """
        fraction = 1.0
        while fraction >= 1e-4:
            trial = x + fraction * direction
            trial[held] = goal - (1.0 - fraction) * pending if fraction < 1.0 else goal
            evaluated = self._gradient(trial)
            if evaluated[1] is not None:
                return fraction, trial, evaluated
            fraction *= 0.5
            result.line_search_cuts += 1
        return None, x, None

    def _split_predictor(self, x, x_full, evaluated, direction, held, goal, pending, limit: float):
        """Half the first predictor step when the whole one would leave a residual force above ``limit`` (N).

        ``evaluated``: (Π, gradient) at ``x_full``. Returns (fraction, state, (Π, gradient) at the state if
        computed).
        The linearised response is poor for a large motion of the held
        nodes (a turn of the gripper by tens of degrees, a sample several
        edge lengths away): from the midpoint, with the tangent factored
        there, the second half lands much closer to the equilibrium (an
        Euler predictor with two steps). On the paper's flap this saves a
        quarter of the Newton iterations of a retraction sample and most of
        its indefinite tangents, at one factorisation; a small step, whose
        linear prediction is good, is taken whole.
        """
        energy, grad = evaluated
        if grad is None or free_residual(grad, held) <= limit:
            return 1.0, x_full, (energy, grad)
        half = x + 0.5 * direction
        half[held] = goal - 0.5 * pending
        if not np.isfinite(self._energy(half)):
            return 1.0, x_full, (energy, grad)
        return 0.5, half, None
