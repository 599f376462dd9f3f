"""Static equilibrium by Newton's method with a line search, warm start, predictor and quasi-Newton reuse.

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
  motion is applied by the next step. A large motion is applied in two
  Euler steps, the tangent factored again at the midpoint, when the whole
  first step would leave a residual force above ``predictor_residual``
  times the force scale (:meth:`EquilibriumSolver._split_predictor`).
* **Corrector.** With the prescribed nodes in place, steps ``d = -H g_f``
  with a line search on Π: the energy never increases, and a step that
  would invert an element has infinite energy and is cut. The whole step is
  taken when it decreases Π enough (Armijo); otherwise the minimiser along
  it is closed in on by cubic interpolation of Π and its slope (every trial
  computes the gradient anyway) until Armijo's and the strong curvature
  condition hold (Nocedal & Wright, *Numerical Optimization*, 2nd ed.,
  Algorithm 3.6 and eq. 3.59), so a poor first trial costs one or two
  evaluations and the step lands near the minimiser, not at a tenth of it.
* **Quasi-Newton reuse of a factorisation.** A factorisation costs about
  ten energy evaluations, and on a thin flap far from its equilibrium a
  Newton step only shrinks the residual two- to fivefold, so refactoring at
  every step is wasteful. After a factorisation of the tangent K at x_k,
  the following steps use ``H = `` the L-BFGS inverse built on ``K^-1``
  from the secant pairs (s, y) of the steps since x_k (the two-loop
  recursion, Nocedal & Wright Algorithm 7.4, with the factored tangent as
  the initial matrix instead of a multiple of the identity, as Liu, Bouaziz
  & Kavan do for hyperelastic simulation, ACM TOG 36(3) 2017): one
  triangular solve and a few dot products a step, and curvature learnt
  along the way. The tangent is factored again when such a step shrinks
  the residual less, per unit of cost, than the last Newton step did
  (``rho_qn > rho_newton^(1 / (1 + c))``, c = ``refactor_cost``: near the
  solution, where Newton converges quadratically, that is at once), when
  it does not shrink it at all, when its line search fails, or after
  ``max_reuse_steps`` steps; and, near the equilibrium (residual below
  ``near_residual`` times the force scale), when the steps still needed
  at the rate the quasi-Newton steps have kept since the factorisation
  would cost more than a factorisation and the steps after it at Newton's
  rate (a strict tolerance far below the residual, on a tangent factored
  before a large prescribed move: a fresh tangent there converges about
  three times as fast per step; the DOLFINx comparison's warm-started
  2 mm step of the flap at 1e-10 went from 21 steps and 1 factorisation
  to 8 and 2). Newton's quadratic convergence
  is kept near the solution (a fresh factorisation is a Newton step) and
  the answer is the same equilibrium to the same tolerances.
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
  error (about ``4 eps max(|K| |u| + |f|)``, u the displacements, f the
  applied forces: the solve iterates on u and the kernel computes strains
  from grad u, so the floor is relative to the deformation and a tolerance
  of 1e-10 is honoured, with contact and gravity) when that is larger, and the last corrector step moved no node
  more than ``step_tol`` times the mean edge length. After a quasi-Newton
  step the residual must be ``quasi_newton_margin`` times smaller: Newton's
  last step usually overshoots the tolerance by orders of magnitude, and
  quantities summed over many nodes (the reactions that balance a weight)
  need that margin. Otherwise, after ``max_iterations`` or a failed line
  search, the result says it did not converge and why.
* **Determinism.** A solve is a function of its start positions, its
  constraints and its options alone: it keeps no memory between solves. A
  warm start may be handed the factorisation of the tangent *at its start
  positions* (:attr:`NewtonResult.start_factor` of an earlier solve from
  the same positions), which it would otherwise compute as its first step:
  that saves the time and changes no bit of the answer.

Linear algebra: the fixed pattern of :class:`~.assembly.TangentPattern`,
factored by PARDISO (symbolic analysis once per pattern, inertia from the
factorisation) or SuperLU (pre-ordered), see :mod:`.linear`.

This module holds the solve itself (:class:`EquilibriumSolver`, its options
and result); the parts it is made of live beside it: which tangent is
factored and the rounding floor of the residual in :mod:`.tangent_factor`,
the predictor, Newton, chord and L-BFGS directions in :mod:`.newton_steps`
(both mix-ins of the solver), and the line search in :mod:`.line_search`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .assembly import TangentPattern
from .line_search import MAX_TRIALS, free_residual, line_search
from .loads import ExternalLoads
from .newton_steps import NewtonSteps
from .stvk import StVKElements
from .tangent_factor import CachedFactor, TangentFactoring


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
    #: the line search's strong curvature condition |Π'(t)| <= curvature |Π'(0)| (Nocedal & Wright's c2)
    curvature: float = 0.9
    #: a factorisation and its tangent cost about this many quasi-Newton steps (1 triangular solve, 2-3 Π evaluations)
    refactor_cost: float = 6.0
    #: the contraction a Newton step is credited with before a full one has been measured in the solve
    nominal_contraction: float = 0.1
    #: a quasi-Newton step converges only this many times within the tolerance (see the module docstring)
    quasi_newton_margin: float = 100.0
    #: quasi-Newton steps with one factorisation at most
    max_reuse_steps: int = 30
    #: secant pairs the L-BFGS update keeps on top of the factored tangent (0: plain chord steps)
    history: int = 4
    #: a reused factorisation is replaced when the quasi-Newton steps still needed, at their rate so far, would cost
    #: more than a factorisation and the steps after it at Newton's rate; considered once the residual is below
    #: this times the force scale (nearer the equilibrium, where a fresh tangent converges at that rate)
    near_residual: float = 0.1
    #: the first predictor step is halved (and the tangent factored again at the midpoint) when the whole
    #: step would leave a residual force above this times the force scale (0: never; see the module docstring)
    predictor_residual: float = 0.1


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
    #: corrector steps taken with a reused factorisation (L-BFGS on top of it)
    quasi_newton_steps: int = 0
    #: (step kind, line-search fraction, residual after the step) per iteration
    trace: list[tuple[str, float, float]] = field(default_factory=list)
    #: the factored tangent at the start positions (given or computed), for later solves from there
    start_factor: CachedFactor | None = None
    #: (3n,) gradient of Π at x, N (on prescribed dofs: the reactions)
    gradient: np.ndarray | None = None
    #: Π after each corrector step (constraints fixed); never increases
    energy_history: list[float] = field(default_factory=list)
    #: the relative diagonal shift a next indefinite tangent would start from (a hint for a following solve)
    shift: float = 1e-4
    seconds: float = 0.0


class EquilibriumSolver(NewtonSteps, TangentFactoring):
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
    def energy(self, x: np.ndarray, displacement: bool = False) -> float:
        """Π (J) at flat positions x (or displacements u = x - X); ``inf`` if an element is inverted."""
        xs = x.reshape(-1, 3)
        elastic = self.elements.evaluate(xs, gradient=False, displacement=displacement)
        if not elastic.valid:
            return np.inf
        return elastic.energy + self.loads.evaluate(xs, gradient=False, displacement=displacement).energy

    def gradient(self, x: np.ndarray, displacement: bool = False) -> tuple[float, np.ndarray | None]:
        """Π (J) and its gradient (3n,) N at flat positions x (or displacements); (inf, None) if inverted."""
        xs = x.reshape(-1, 3)
        elastic = self.elements.evaluate(xs, gradient=True, displacement=displacement)
        if not elastic.valid:
            return np.inf, None
        loads = self.loads.evaluate(xs, gradient=True, displacement=displacement)
        return elastic.energy + loads.energy, elastic.gradient + loads.gradient

    def tangent(
        self, x: np.ndarray, definite: bool, displacement: bool = False, forces: bool = True
    ) -> tuple[float, np.ndarray | None, np.ndarray]:
        """Π, its gradient (3n,) (None without ``forces``) and the assembled tangent's values (pattern order)."""
        xs = x.reshape(-1, 3)
        elastic = self.elements.evaluate(
            xs,
            gradient=forces,
            hessian=True,
            definite=definite,
            displacement=displacement,
            element_map=self.pattern.element_map,
            nnz=self.pattern.nnz,
        )
        if not elastic.valid:
            raise ValueError("the state has an inverted element")
        loads = self.loads.evaluate(xs, gradient=True, displacement=displacement)
        data = elastic.assembled
        if len(loads.contact_nodes):
            self.pattern.add_node_blocks(data, loads.contact_nodes, loads.contact_blocks)
        gradient = elastic.gradient + loads.gradient if forces else None
        return elastic.energy + loads.energy, gradient, data

    # the solve iterates on the displacements u = x - X: rounding stays relative to u (see _rounding)
    def _energy(self, u: np.ndarray) -> float:
        return self.energy(u, displacement=True)

    def _gradient(self, u: np.ndarray) -> tuple[float, np.ndarray | None]:
        return self.gradient(u, displacement=True)

    def _tangent(self, u: np.ndarray, definite: bool) -> tuple[float, np.ndarray | None, np.ndarray]:
        """The tangent for a factorisation: the forces there are known already (not computed again)."""
        return self.tangent(u, definite, displacement=True, forces=False)

    # ------------------------------------------------------------------ the solve
    def solve(
        self,
        x0: np.ndarray,
        prescribed: np.ndarray,
        targets: np.ndarray,
        options: SolverOptions | None = None,
        factor: CachedFactor | None = None,
        shift: float | None = None,
    ) -> NewtonResult:
        """Equilibrium from flat positions ``x0`` (3n,) with dofs ``prescribed`` (bool (3n,)) at ``targets``.

        ``targets`` (3n,) is read only where ``prescribed``. ``factor``: the
        factored tangent *at x0* with the same prescribed dofs and tangent
        policy (:attr:`NewtonResult.start_factor` of an earlier solve that
        started from exactly these positions); the solve would compute it
        as its first step, so passing it saves that time and nothing else
        changes. A factorisation of any other state must not be passed.
        ``shift``: the relative diagonal shift an indefinite tangent is
        first tried with (default ``MIN_SHIFT``), e.g. the
        :attr:`NewtonResult.shift` of the solve this one continues (a
        chain of nearby states tends to need the same shift: starting
        there saves the factorisations of the levels below it). A given
        ``factor`` must have been computed under the same ``shift``.
        """
        options = options or SolverOptions()
        started = time.perf_counter()
        # the diagonal shift an indefinite tangent starts from: the caller's hint, then what this solve needed
        start_shift = self.MIN_SHIFT if shift is None else min(max(float(shift), self.MIN_SHIFT), 1.0)
        rest = self.elements.rest
        x = np.array(x0, dtype=float).ravel() - rest  # the unknowns: displacements from the rest positions
        prescribed = np.asarray(prescribed, dtype=bool)
        held = np.flatnonzero(prescribed)  # their indices: reading and writing them is cheaper than by the mask
        goal = np.asarray(targets, dtype=float).ravel()[held] - rest[held]
        result = NewtonResult(x + rest, False, 0, np.inf, np.nan, np.inf)
        result.shift = start_shift
        if len(held) == len(x):  # nothing is free: the prescribed positions are the answer (as given, not X + u)
            return self._all_prescribed(np.asarray(targets, dtype=float).ravel(), prescribed, result, started)
        energy, grad = self._gradient(x)
        if grad is None:
            result.message = "the start state has an inverted element"
            return result
        if factor is not None and not (
            np.array_equal(factor.prescribed, prescribed) and factor.policy == options.tangent
        ):
            factor = None
        result.start_factor = factor
        shift = factor.shift if factor is not None else start_shift
        refresh = factor is None
        newton = True  # the kind of the last step
        given = factor is not None  # its first step is the Newton step a computed one would give
        reuse_steps = 0
        chord_decades = 0.0  # log10 of the residual's contraction over the quasi-Newton steps since the factorisation
        newton_contraction = options.nominal_contraction  # residual after / before the last Newton corrector step
        pairs: list[tuple[np.ndarray, np.ndarray, float]] = []  # L-BFGS (s, y, 1 / s.y) since the factorisation
        last_step = 0.0 if np.array_equal(x[held], goal) else np.inf
        step_limit = options.step_tol * self.length_scale
        evaluated = None  # (Π, gradient) at x when already computed
        applied = float(np.abs(self.loads.total_forces).max(initial=0.0))
        while True:
            pending = goal - x[held]
            moving = bool(np.any(pending != 0.0))
            scale = max(applied, float(np.abs(grad[held]).max(initial=0.0)), self.force_floor)
            residual = free_residual(grad, held)
            result.residual, result.residual_scale, result.energy = residual, scale, energy
            tolerance = options.residual_tol * scale
            if not newton:
                tolerance /= options.quasi_newton_margin
            if not moving:
                if not result.energy_history or result.energy_history[-1] != energy:
                    result.energy_history.append(energy)
                # forces cannot be resolved below their rounding error: a tolerance under it is unreachable
                settled = last_step <= step_limit
                floor = 0.0
                if residual > tolerance and settled and factor is not None:
                    floor = self._rounding(factor)
                if residual <= max(tolerance, floor) and settled:
                    result.converged = True
                    result.message = f"converged in {result.iterations} Newton iterations"
                    if residual > tolerance:
                        result.message += f" (residual at the rounding floor of the forces, {floor:.2g} N)"
                    break
            if result.iterations >= options.max_iterations:
                result.message = f"did not converge in {options.max_iterations} Newton iterations: " + (
                    f"{float(np.abs(pending).max()):.3g} m of the prescribed motion left (each step "
                    "towards it would invert an element)"
                    if moving
                    else f"residual force {residual:.3g} N, tolerance {options.residual_tol * scale:.3g} N"
                )
                break
            result.iterations += 1
            direction = None
            newton = False
            if not refresh and factor is not None and (given or reuse_steps < options.max_reuse_steps):
                direction = self._direction(factor, grad, held, pending, pairs)
                newton = given
                if direction is None and newton:
                    result.message = "no descent direction: the tangent is not positive definite"
                    break
            given = False
            if direction is None:
                # the old factor is done with: released first, so the new one reuses its memory
                factor = None
                factor, shift = self._factor(x, prescribed, options, result, shift)
                if factor is None:
                    result.message = "the tangent stiffness matrix is singular even after regularisation"
                    break
                if result.start_factor is None and result.iterations == 1:
                    result.start_factor = factor  # x is still x0
                result.factorizations += 1
                reuse_steps, pairs, newton, chord_decades = 0, [], True, 0.0
                direction = self._direction(factor, grad, held, pending, pairs)
                if direction is None:  # not a descent direction even with the surrogate
                    result.message = "no descent direction: the tangent is not positive definite"
                    break
            refresh = False
            if moving:
                fraction, x_new, evaluated = self._cut_to_valid(x, direction, held, goal, pending, result)
                if fraction is None:
                    result.message = (
                        "the prescribed motion cannot be applied without inverting elements "
                        f"({float(np.abs(pending).max()):.3g} m left)"
                    )
                    break
                if fraction == 1.0 and result.predictor_steps == 0 and options.predictor_residual > 0:
                    fraction, x_new, evaluated = self._split_predictor(
                        x,
                        x_new,
                        evaluated,
                        direction,
                        held,
                        goal,
                        pending,
                        options.predictor_residual * scale,
                    )
                x = x_new
                result.predictor_steps += 1
                last_step = np.inf
                refresh = fraction < 1.0
            else:
                fraction, evaluated = self._line_search(x, energy, grad, direction, held, options, result)
                if fraction is None:
                    if not newton:  # the reused tangent may be to blame: retry with a fresh one
                        refresh = True
                        continue
                    if residual <= options.residual_tol * scale and last_step <= step_limit:
                        # within the tolerance, and not even a Newton step on a fresh tangent reduces Π or the
                        # residual: the forces are at their rounding floor (the margin asked of quasi-Newton
                        # steps cannot be met, and needs no meeting: this is a Newton step's verdict)
                        result.converged = True
                        result.message = (
                            f"converged in {result.iterations} Newton iterations (residual {residual:.2g} N at "
                            "the rounding floor: a Newton step could not reduce it)"
                        )
                        break
                    result.message = (
                        f"the line search failed after {result.iterations} Newton iterations: residual force "
                        f"{residual:.3g} N, tolerance {options.residual_tol * scale:.3g} N"
                    )
                    break
                step = fraction * direction
                x = x + step
                last_step = float(np.abs(step).max())
                if not newton:
                    reuse_steps += 1
                    result.quasi_newton_steps += 1
            new_energy, new_grad = evaluated if evaluated is not None else self._gradient(x)
            evaluated = None
            if new_grad is None:  # cannot happen after the checks above; be safe
                result.message = "a step inverted an element"
                break
            new_residual = free_residual(new_grad, held)
            result.trace.append(
                (("newton" if newton else "quasi-newton") + (" predictor" if moving else ""), fraction, new_residual)
            )
            if not moving:
                if options.history:
                    self._remember(pairs, step, new_grad - grad, held, options.history)
                contraction = new_residual / residual if residual > 0 else 0.0
                if newton:
                    # a damped Newton step says little about what a full one near the solution achieves
                    newton_contraction = contraction if fraction == 1.0 else options.nominal_contraction
                elif contraction > min(1.0, max(newton_contraction, 1e-16) ** (1.0 / (1.0 + options.refactor_cost))):
                    # per unit of cost the last Newton step shrank the residual faster: factor again
                    refresh = True
                else:
                    chord_decades += float(np.log10(max(contraction, 1e-300)))
                    # the rate of one or two steps says little (they alternate fast and slow); far from the
                    # equilibrium a fresh tangent is no faster, so only near it
                    if reuse_steps >= 3 and new_residual <= options.near_residual * scale:
                        target = options.residual_tol * scale / options.quasi_newton_margin
                        refresh = self._refactor_pays(
                            new_residual, target, chord_decades / reuse_steps, newton_contraction, options
                        )
            energy, grad = new_energy, new_grad
        result.x = rest + x
        if not np.any(goal - x[held]):  # the prescribed dofs reached: exactly their targets, not X + u rounded
            result.x[held] = np.asarray(targets, dtype=float).ravel()[held]
        result.gradient = grad
        result.seconds = time.perf_counter() - started
        return result

    @staticmethod
    def _refactor_pays(residual: float, target: float, rate: float, newton_contraction: float, options) -> bool:
        """Whether a factorisation now reaches ``target`` (N) sooner than more quasi-Newton steps on the old one.

        ``rate``: the mean log10 contraction of the residual per quasi-Newton step since the factorisation.
        At that rate the steps still needed cost ``decades / -rate``; factoring again costs ``1 +
        refactor_cost`` and then about one step per factor ``newton_contraction`` (a fresh tangent near the
        solution: the Newton step and the quasi-Newton steps on it).
        """
        decades = float(np.log10(residual / target)) if residual > 0 and target > 0 else 0.0
        if decades <= 0.0 or rate >= 0.0:
            return False
        newton_rate = -float(np.log10(min(max(newton_contraction, 1e-16), 0.5)))
        return decades / -rate > 1.0 + options.refactor_cost + decades / newton_rate

    def _all_prescribed(self, x: np.ndarray, prescribed, result: NewtonResult, started: float) -> NewtonResult:
        energy, grad = self.gradient(x)  # from the positions: an element crushed to 1e-100 of its volume stays valid
        result.x, result.gradient, result.energy = x.copy(), grad, energy
        result.residual = 0.0
        result.residual_scale = max(
            float(np.abs(self.loads.total_forces).max(initial=0.0)),
            float(np.abs(grad[prescribed]).max(initial=0.0)) if grad is not None else 0.0,
            self.force_floor,
        )
        result.converged = grad is not None
        result.message = (
            "converged in 0 Newton iterations (every degree of freedom is prescribed)"
            if grad is not None
            else "the prescribed positions invert an element"
        )
        result.energy_history.append(energy)
        result.seconds = time.perf_counter() - started
        return result

    def _line_search(self, x, energy, grad, direction, held, options, result):
        """:func:`~.line_search.line_search` along ``direction`` on Π (its fraction and (Π, gradient) there)."""
        return line_search(
            self._gradient, x, energy, grad, direction, held, options, result, self.MAX_LINE_SEARCH_TRIALS
        )

    #: trials of one line search at most (the bracket shrinks by at least a tenth per trial)
    MAX_LINE_SEARCH_TRIALS = MAX_TRIALS
