"""Static equilibrium by Newton's method with a line search, warm start and predictor.

Patil & Alterovitz §V ("Solving for static equilibrium") solve the reduced
system ``Phi(u~) = f~_ext`` over the free nodes with nonlinear conjugate
gradients. We minimise the same total potential energy

    Π(x) = U_elastic(x) + V_ext(x)      (J; see stvk.py and loads.py)

over the free degrees of freedom with Newton's method, which converges in a
handful of iterations where nonlinear CG needs hundreds:

* **Predictor.** Prescribed degrees of freedom move from where the start
  state has them to their targets inside the Newton step itself: the step
  solves ``K_ff d_f = -(g_f + K_fc d_c)`` with ``d_c`` the remaining motion,
  i.e. the free nodes follow the linearised response instead of the grasped
  nodes jumping alone (which would crush the elements around them). The
  step is cut (halved) while it would invert an element; what remains of the
  motion is applied by the next step.
* **Corrector.** With the prescribed nodes in place, Newton steps
  ``K_ff d = -g_f`` with a backtracking (Armijo) line search on Π: the
  energy never increases, and a step that would invert an element has
  infinite energy and is cut.
* **Indefinite tangents.** ``tangent="auto"`` uses the exact tangent while
  it is positive definite and, where it is not (a buckling or snapping flap
  on its way to equilibrium), the exact tangent plus the smallest multiple
  of its mean diagonal that makes it definite (:meth:`EquilibriumSolver._factor`),
  so that the step is a descent direction that keeps the exact curvature;
  the positive semi-definite surrogate (:meth:`StVKElements._tangent`) is
  the last resort. ``"definite"`` always uses the surrogate; ``"exact"``
  never modifies the tangent.
* **Stopping.** Converged when the largest residual force on a free degree
  of freedom is at most ``residual_tol`` times the force scale (the largest
  applied nodal force or support reaction), or at most the forces' rounding
  error ``eps max(|K| |x|)`` when that is larger (a tolerance below it cannot
  be reached), and the last corrector step moved no node more than
  ``step_tol`` times the mean edge length. Otherwise, after
  ``max_iterations`` or a failed line search, the result says it did not
  converge and why.

Linear algebra: SuperLU on the fixed, pre-ordered pattern of
:class:`~.assembly.TangentPattern` (no ordering work per factorisation).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .assembly import Factorization, TangentPattern
from .loads import ExternalLoads
from .stvk import StVKElements


@dataclass
class SolverOptions:
    """Newton's stopping rules and tangent policy (dimensionless unless stated)."""

    #: residual force tolerance, relative to the force scale
    residual_tol: float = 1e-6
    #: last corrector step's largest node displacement, relative to the mean edge length
    step_tol: float = 1e-4
    max_iterations: int = 60
    tangent: Literal["auto", "definite", "exact"] = "auto"
    #: Armijo's sufficient-decrease constant
    armijo: float = 1e-4
    #: smallest line-search fraction before giving up
    min_step_fraction: float = 1e-8
    #: a reused factorisation is refreshed when a step shrinks the residual by less than this factor
    chord_contraction: float = 0.25
    #: steps with one factorisation at most
    max_chord_steps: int = 12


@dataclass
class NewtonResult:
    """What a solve found (SI)."""

    x: np.ndarray  # (3n,) positions, flat
    converged: bool
    iterations: int
    residual: float  # N, largest residual force on a free dof
    residual_scale: float  # N, the force scale the tolerance is relative to
    energy: float  # J, total potential energy Π
    message: str = ""
    predictor_steps: int = 0
    definite_steps: int = 0
    line_search_cuts: int = 0
    factorizations: int = 0
    #: (step kind, line-search fraction, residual after the step) per iteration
    trace: list[tuple[str, float, float]] = field(default_factory=list)
    #: the last factored tangent, for warm-started solves
    factor: CachedFactor | None = None
    #: (3n,) gradient of Π at x, N (on prescribed dofs: the reactions)
    gradient: np.ndarray | None = None
    #: Π after each corrector step (constraints fixed); never increases
    energy_history: list[float] = field(default_factory=list)
    seconds: float = 0.0


class EquilibriumSolver:
    """Newton's method on Π for a mesh's elements and loads (see the module docstring)."""

    def __init__(
        self,
        elements: StVKElements,
        loads: ExternalLoads,
        pattern: TangentPattern,
        length_scale: float,
        force_floor: float,
    ) -> None:
        self.elements = elements
        self.loads = loads
        self.pattern = pattern
        #: metres: the mean edge length, for the step criterion
        self.length_scale = length_scale
        #: newtons: smallest force scale (a problem with no forces at all converges at once)
        self.force_floor = force_floor

    # ------------------------------------------------------------------ Π and its derivatives
    def energy(self, x: np.ndarray) -> float:
        """Π (J) at flat positions x; ``inf`` if an element is inverted."""
        xs = x.reshape(-1, 3)
        elastic = self.elements.evaluate(xs, gradient=False)
        if not elastic.valid:
            return np.inf
        return elastic.energy + self.loads.evaluate(xs, gradient=False).energy

    def gradient(self, x: np.ndarray) -> tuple[float, np.ndarray | None]:
        xs = x.reshape(-1, 3)
        elastic = self.elements.evaluate(xs, gradient=True)
        if not elastic.valid:
            return np.inf, None
        loads = self.loads.evaluate(xs, gradient=True)
        return elastic.energy + loads.energy, elastic.gradient + loads.gradient

    def tangent(self, x: np.ndarray, definite: bool) -> tuple[float, np.ndarray, np.ndarray]:
        """Π, its gradient (3n,) and the assembled tangent's values (pattern order)."""
        xs = x.reshape(-1, 3)
        elastic = self.elements.evaluate(xs, gradient=True, hessian=True, definite=definite)
        if not elastic.valid:
            raise ValueError("the state has an inverted element")
        loads = self.loads.evaluate(xs, gradient=True)
        data = self.pattern.assemble(elastic.hessian)
        if len(loads.contact_nodes):
            self.pattern.add_node_blocks(data, loads.contact_nodes, loads.contact_blocks)
        return elastic.energy + loads.energy, elastic.gradient + loads.gradient, data

    # ------------------------------------------------------------------ the solve
    def solve(
        self,
        x0: np.ndarray,
        prescribed: np.ndarray,
        targets: np.ndarray,
        options: SolverOptions | None = None,
        factor: CachedFactor | None = None,
    ) -> NewtonResult:
        """Equilibrium from flat positions ``x0`` (3n,) with dofs ``prescribed`` (bool (3n,)) at ``targets``.

        ``targets`` (3n,) is read only where ``prescribed``. ``factor``: a
        factored tangent of a nearby state with the same prescribed dofs
        (e.g. :attr:`NewtonResult.factor` of the solve this one is
        warm-started from), used until it stops paying off.
        """
        options = options or SolverOptions()
        started = time.perf_counter()
        x = np.array(x0, dtype=float).ravel()
        prescribed = np.asarray(prescribed, dtype=bool)
        free = ~prescribed
        goal = np.asarray(targets, dtype=float).ravel()[prescribed]
        result = NewtonResult(x, False, 0, np.inf, np.nan, np.inf)
        energy, grad = self.gradient(x)
        if grad is None:
            result.message = "the start state has an inverted element"
            return result
        if factor is not None and not np.array_equal(factor.prescribed, prescribed):
            factor = None
        refresh = factor is None
        chord_steps = 0
        last_step = 0.0 if np.array_equal(x[prescribed], goal) else np.inf
        step_limit = options.step_tol * self.length_scale
        while True:
            pending = goal - x[prescribed]
            moving = bool(np.any(pending != 0.0))
            scale = max(
                float(np.abs(self.loads.total_forces).max(initial=0.0)),
                float(np.abs(grad[prescribed]).max(initial=0.0)),
                self.force_floor,
            )
            residual = float(np.abs(grad[free]).max(initial=0.0))
            result.residual, result.residual_scale, result.energy = residual, scale, energy
            if not moving:
                if not result.energy_history or result.energy_history[-1] != energy:
                    result.energy_history.append(energy)
                # forces cannot be resolved below their rounding error: a tolerance under it is unreachable
                floor = factor.rounding if factor is not None else 0.0
                if residual <= max(options.residual_tol * scale, floor) and last_step <= step_limit:
                    result.converged = True
                    result.message = f"converged in {result.iterations} Newton iterations"
                    if residual > options.residual_tol * scale:
                        result.message += f" (residual at the rounding floor of the forces, {floor:.2g} N)"
                    break
            if result.iterations >= options.max_iterations:
                result.message = (
                    f"did not converge in {options.max_iterations} Newton iterations: residual force "
                    f"{residual:.3g} N, tolerance {options.residual_tol * scale:.3g} N"
                )
                break
            result.iterations += 1
            direction = None
            if not refresh and factor is not None and chord_steps < options.max_chord_steps:
                direction = self._chord_direction(factor, grad, prescribed, pending)
                chord = direction is not None
            if direction is None:
                factor = self._factor(x, prescribed, options, result)
                if factor is None:
                    result.message = "the tangent stiffness matrix is singular even after regularisation"
                    break
                result.factorizations += 1
                chord_steps = 0
                direction = self._chord_direction(factor, grad, prescribed, pending)
                chord = False
                if direction is None:  # not a descent direction even with the surrogate
                    result.message = "no descent direction: the tangent is not positive definite"
                    break
            refresh = False
            if moving:
                fraction = self._cut_to_valid(x, direction, result)
                if fraction is None:
                    result.message = (
                        "the prescribed motion cannot be applied without inverting elements "
                        f"({float(np.abs(pending).max()):.3g} m left)"
                    )
                    break
                x = x + fraction * direction
                x[prescribed] = goal - (1.0 - fraction) * pending if fraction < 1.0 else goal
                result.predictor_steps += 1
                last_step = np.inf
                refresh = fraction < 1.0
            else:
                fraction = self._line_search(x, energy, grad, direction, free, options, result)
                if fraction is None:
                    if chord:  # a stale tangent may be to blame: retry with a fresh one
                        refresh = True
                        continue
                    result.message = (
                        f"the line search failed after {result.iterations} Newton iterations: residual force "
                        f"{residual:.3g} N, tolerance {options.residual_tol * scale:.3g} N"
                    )
                    break
                x = x + fraction * direction
                last_step = fraction * float(np.abs(direction).max())
                if chord:
                    chord_steps += 1
            new_energy, new_grad = self.gradient(x)
            if new_grad is None:  # cannot happen after the checks above; be safe
                result.message = "a step inverted an element"
                break
            new_residual = float(np.abs(new_grad[free]).max(initial=0.0))
            result.trace.append(
                (("chord" if chord else "newton") + (" predictor" if moving else ""), fraction, new_residual)
            )
            # a reused factorisation must keep shrinking the residual fast, or be refreshed
            if chord and not moving and new_residual > options.chord_contraction * residual:
                refresh = True
            energy, grad = new_energy, new_grad
        result.x = x
        result.gradient = grad
        result.factor = factor
        result.seconds = time.perf_counter() - started
        return result

    def _factor(self, x, prescribed, options, result) -> CachedFactor | None:
        """Factor the tangent at x (see ``tangent`` in the module docstring); ``None`` if nothing factors.

        ``auto``: the exact tangent when it is positive definite (positive
        pivots); otherwise the exact tangent plus ``tau`` times its mean free
        diagonal, tau growing eightfold until the factorisation is definite
        (Nocedal & Wright, *Numerical Optimization*, 2nd ed., Algorithm 3.3:
        the step keeps the exact curvature where it is positive and is
        damped only as much as needed), remembering tau for the next time;
        the surrogate tangent is the last resort.
        """
        if options.tangent == "definite":
            return self._try_factor(x, prescribed, True) or self._try_factor(x, prescribed, True, regularise=1e-8)
        _, _, data = self.tangent(x, False)
        constrained = self.pattern.constrain(data, prescribed)
        factor = self._try_factor(x, prescribed, False, data=data, constrained=constrained)
        if options.tangent == "exact" or (factor is not None and factor.positive_pivots()):
            return factor
        result.definite_steps += 1
        free_diagonal = self.pattern.diagonal[~prescribed]
        scale = float(np.abs(constrained[free_diagonal]).mean()) if len(free_diagonal) else 1.0
        tau = self._shift
        while tau <= 1.0:
            shifted = constrained.copy()
            shifted[free_diagonal] += tau * scale
            factor = self._try_factor(x, prescribed, True, data=data, constrained=shifted)
            if factor is not None and factor.positive_pivots():
                self._shift = max(tau / 8.0, self.MIN_SHIFT)  # start lower next time: the need passes
                return factor
            tau *= 8.0
        return self._try_factor(x, prescribed, True) or self._try_factor(x, prescribed, True, regularise=1e-8)

    #: smallest relative diagonal shift tried for an indefinite tangent
    MIN_SHIFT = 1e-4
    _shift = MIN_SHIFT

    def _try_factor(
        self, x, prescribed, definite: bool, data=None, constrained=None, regularise: float = 0.0
    ) -> CachedFactor | None:
        """Factor ``constrained`` (default: the tangent at x, the surrogate if ``definite``)."""
        if data is None:
            _, _, data = self.tangent(x, definite)
            if regularise:
                data[self.pattern.diagonal] += regularise * np.abs(data[self.pattern.diagonal]).max()
        if constrained is None:
            constrained = self.pattern.constrain(data, prescribed)
        try:
            lu = self.pattern.factorize(constrained)
        except RuntimeError:
            return None
        # rounding error of the internal forces, about eps |K| |x| (N): F = x g loses eps |x| |g|
        rounding = float(np.finfo(float).eps) * float(
            np.max(self.pattern.matvec(np.abs(data), np.abs(x))[~prescribed], initial=0.0)
        )
        return CachedFactor(lu, data, constrained[self.pattern.diagonal], prescribed.copy(), definite, rounding)

    def _chord_direction(self, factor: CachedFactor, grad, prescribed, pending) -> np.ndarray | None:
        """The step (3n,) with a factored tangent: free part solved, prescribed part the pending motion."""
        rhs = -grad
        if np.any(pending != 0.0):
            motion = np.zeros_like(grad)
            motion[prescribed] = pending
            rhs = rhs - self.pattern.matvec(factor.data, motion)
        rhs[prescribed] = factor.diagonal[prescribed] * pending  # scaled identity rows: returns the motion
        direction = factor.lu.solve(rhs)
        if not np.all(np.isfinite(direction)):
            return None
        if not np.any(pending != 0.0) and float(np.dot(grad, direction)) >= 0.0:
            return None
        return direction

    def _cut_to_valid(self, x, direction, result) -> float | None:
        fraction = 1.0
        while fraction >= 1e-4:
            if np.isfinite(self.energy(x + fraction * direction)):
                return fraction
            fraction *= 0.5
            result.line_search_cuts += 1
        return None

    def _line_search(self, x, energy, grad, direction, free, options, result) -> float | None:
        slope = float(np.dot(grad, direction))
        fraction = 1.0
        residual = float(np.abs(grad[free]).max(initial=0.0))
        while fraction >= options.min_step_fraction:
            trial = x + fraction * direction
            value = self.energy(trial)
            if value <= energy + options.armijo * fraction * slope:
                return fraction
            # near the solution Π changes less than its rounding error: accept a step that reduces the residual
            if np.isfinite(value) and abs(value - energy) <= 1e-12 * max(abs(energy), 1e-30) + 1e-300:
                _, trial_grad = self.gradient(trial)
                if trial_grad is not None and float(np.abs(trial_grad[free]).max(initial=0.0)) < residual:
                    return fraction
            fraction *= 0.5
            result.line_search_cuts += 1
        return None


@dataclass
class CachedFactor:
    """A factored, constrained tangent and what it was built from (reusable by later steps and solves)."""

    lu: Factorization
    data: np.ndarray  # the unconstrained tangent's values (pattern order), for K_fc products
    diagonal: np.ndarray  # (3n,) diagonal of the constrained matrix, original numbering
    prescribed: np.ndarray  # (3n,) bool
    definite: bool
    #: N: the rounding error of the internal forces near this state, a floor for the residual
    rounding: float = 0.0

    def positive_pivots(self) -> bool:
        """Whether every pivot is positive: for a symmetric matrix factored without pivoting, definiteness."""
        return self.lu.positive_pivots()
