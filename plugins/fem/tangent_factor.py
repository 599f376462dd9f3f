"""Factorisations of the tangent for the Newton solver: definite when they must be, kept for reuse.

:class:`CachedFactor` is a factored, constrained tangent with what it was
built from, reused by the quasi-Newton steps that follow it and by later
solves from the same state. :class:`TangentFactoring` is a mix-in of
:class:`~.newton.EquilibriumSolver` (it uses the solver's ``pattern``,
``loads`` and ``_tangent``), kept apart because it is the part that decides
*which* matrix is factored: the exact tangent, the exact tangent shifted
until it is positive definite, or the positive semi-definite surrogate (see
"Indefinite tangents" in :mod:`.newton`), and the rounding floor of the
residual forces near a factored state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .linear import PardisoFactor, SuperLUFactor


@dataclass
class CachedFactor:
    """A factored, constrained tangent and what it was built from (reusable by later steps and solves)."""

    lu: PardisoFactor | SuperLUFactor
    data: np.ndarray  # the unconstrained tangent's values (pattern order), for K_fc products
    diagonal: np.ndarray  # (3n,) diagonal of the constrained matrix, original numbering
    prescribed: np.ndarray  # (3n,) bool
    definite: bool
    #: (3n,) m: the displacements from the rest positions it was factored at
    x: np.ndarray
    #: N: the rounding error of the internal forces near this state, a floor for the residual (when computed)
    rounding: float | None = None
    #: the tangent policy it was built under (``SolverOptions.tangent``)
    policy: str = "auto"
    #: the relative diagonal shift the next indefinite tangent starts from (see ``EquilibriumSolver._factor``)
    shift: float = 1e-4

    def positive_pivots(self) -> bool:
        """Whether the factored matrix is positive definite, read from the factorisation (its pivots)."""
        return self.lu.positive_pivots()


class TangentFactoring:
    """How :class:`~.newton.EquilibriumSolver` factors its tangent (a mix-in; see the module docstring)."""

    #: smallest relative diagonal shift tried for an indefinite tangent
    MIN_SHIFT = 1e-4
    #: how far above eps (|K| |u| + |f|) the rounding error of the assembled forces reaches (measured: Newton
    #: stalls at 0.1 to 2 times it on the flap and the cantilevers, linear and quadratic)
    ROUNDING_SPREAD = 4.0

    def _factor(self, x, prescribed, options, result, shift: float) -> tuple[CachedFactor | None, float]:
        """Factor the tangent at x (see "Indefinite tangents" in :mod:`.newton`); ``None`` if nothing factors.

        ``auto``: the exact tangent when it is positive definite (positive
        pivots); otherwise the exact tangent plus ``tau`` times its mean free
        diagonal, tau growing eightfold from ``shift`` until the
        factorisation is definite (Nocedal & Wright, *Numerical
        Optimization*, 2nd ed., Algorithm 3.3: the step keeps the exact
        curvature where it is positive and is damped only as much as
        needed); the surrogate tangent is the last resort. Returns the
        factor and the shift to start from next time within this solve.
        """
        factor = None
        if options.tangent == "definite":
            factor = self._try_factor(x, prescribed, True) or self._try_factor(x, prescribed, True, regularise=1e-8)
            return self._finish(factor, options, shift)
        _, _, data = self._tangent(x, False)
        constrained = self.pattern.constrain(data, prescribed)
        exact = options.tangent == "exact"  # otherwise an indefinite factor is of no use: only definiteness counts
        factor = self._try_factor(x, prescribed, False, data=data, constrained=constrained, definite_only=not exact)
        if exact or (factor is not None and factor.positive_pivots()):
            return self._finish(factor, options, shift)
        result.definite_steps += 1
        free_diagonal = self.pattern.diagonal[~prescribed]
        scale = float(np.abs(constrained[free_diagonal]).mean()) if len(free_diagonal) else 1.0
        tau = shift
        while tau <= 1.0:
            shifted = constrained.copy()
            shifted[free_diagonal] += tau * scale
            factor = self._try_factor(x, prescribed, True, data=data, constrained=shifted, definite_only=True)
            if factor is not None and factor.positive_pivots():
                # for a following solve: the level that was needed, or lower when it sufficed at once
                result.shift = tau if tau > shift else max(tau / 8.0, self.MIN_SHIFT)
                return self._finish(factor, options, max(tau / 8.0, self.MIN_SHIFT))  # the need passes: start lower
            tau *= 8.0
        factor = self._try_factor(x, prescribed, True) or self._try_factor(x, prescribed, True, regularise=1e-8)
        return self._finish(factor, options, shift)

    @staticmethod
    def _finish(factor: CachedFactor | None, options, shift: float) -> tuple[CachedFactor | None, float]:
        if factor is not None:
            factor.policy, factor.shift = options.tangent, shift
        return factor, shift

    def _try_factor(
        self,
        x,
        prescribed,
        definite: bool,
        data=None,
        constrained=None,
        regularise: float = 0.0,
        definite_only: bool = False,
    ) -> CachedFactor | None:
        """Factor ``constrained`` (default: the tangent at x, the surrogate if ``definite``); ``None`` when it
        is singular, or with ``definite_only`` when it is not positive definite."""
        if data is None:
            _, _, data = self._tangent(x, definite)
            if regularise:
                data[self.pattern.diagonal] += regularise * np.abs(data[self.pattern.diagonal]).max()
        if constrained is None:
            constrained = self.pattern.constrain(data, prescribed)
        try:
            lu = self.pattern.factorize(constrained, definite_only)
        except RuntimeError:  # SingularMatrix, NotPositiveDefinite
            return None
        return CachedFactor(lu, data, constrained[self.pattern.diagonal], prescribed.copy(), definite, x)

    def _rounding(self, factor: CachedFactor) -> float:
        """The rounding error of the residual forces near the factor's state, about eps (|K| |u| + |f|) (N).

        Relative: the solve iterates on the displacements u (not on the
        positions, whose rounding grows with the distance from the origin),
        the kernel computes the strain from grad u without cancellation, so
        the forces are the sum of element forces of size about |K| |u| and
        of the applied forces f, each rounded to eps of its size: a residual
        below that cannot be reached. Computed when first needed (near
        convergence), once per factor.
        """
        if factor.rounding is None:
            magnitude = self.pattern.matvec(np.abs(factor.data), np.abs(factor.x))
            magnitude += np.abs(self.loads.total_forces).ravel()
            # eps (|K| |u| + |f|) is the error of one product; the forces sum several (elements, quadrature points)
            factor.rounding = (
                self.ROUNDING_SPREAD
                * float(np.finfo(float).eps)
                * float(np.max(magnitude[~factor.prescribed], initial=0.0))
            )
        return factor.rounding
