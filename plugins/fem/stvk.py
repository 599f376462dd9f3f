"""St. Venant-Kirchhoff linear tetrahedra: energy, forces and tangent, vectorised over elements.

Patil & Alterovitz §V: tissue is isotropic, nearly incompressible St.
Venant-Kirchhoff (refs. [22], [23]). With the deformation gradient F of a
linear tetrahedron (constant per element), the Green strain
``E = (F^T F - I) / 2`` and ``J = det F``, the energy density (J/m^3) is

    W(F) = lambda/2 (tr E)^2 + mu tr(E^2)  +  kappa/2 (ln J)^2,

the StVK energy plus a penalty on the change of volume (Teschner et al.
2004, the paper's ref. [23]). The penalty is ``kappa/2 (J - 1)^2`` to first
order, like Teschner's, but grows without bound as J -> 0, so no finite
energy inverts an element. Its second Piola-Kirchhoff stress is

    S = lambda tr(E) I + 2 mu E + kappa ln(J) C^-1,   C = F^T F,

and the first, ``P = F S``. An element's nodal forces are ``V P g_a`` (V
the rest volume, g_a the rest gradients of the shape functions), and its
12 x 12 tangent, blocks (a, b) of 3 x 3:

    K_ab = V [ (g_a . S_stvk g_b) I + lambda (F g_a)(F g_b)^T + mu (g_a . g_b) F F^T
               + mu (F g_b)(F g_a)^T + kappa (q_a q_b^T - ln J q_b q_a^T) ],   q_a = F^-T g_a.

For quadratic (10-node) tetrahedra F varies inside the element: the
energy, forces and tangent are integrated with the four-point rule of
:mod:`.shape` (``V`` above becomes each point's weight ``w_q det J_q``) and
an element is inverted when ``det F <= 0`` at a quadrature point or at a
vertex.

Everything is computed for all elements at once with numpy; no Python loop
runs over elements (only over an element's quadrature points: one for
linear, four for quadratic tetrahedra). The element tangents themselves are
summed by a compiled kernel (:mod:`.kernels`) from small per-point factors
computed here, each entry written once. ``definite=True`` gives a positive
semi-definite surrogate tangent (for Newton far from equilibrium, where
StVK under compression is not convex; see :meth:`StVKElements._tangent_terms`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .closed_forms import cofactor, determinant
from .shape import VERTICES, physical_gradients, reference_element

_EYE = np.eye(3)


@dataclass
class ElementEvaluation:
    """Results of one pass over the elements at positions x (all SI)."""

    energy: float  # J, elastic energy including the volume penalty
    valid: bool  # every element has J > 0
    gradient: np.ndarray | None = None  # (3n,) N: minus the internal forces
    #: element tangents (3k, 3k, m) in N/m, rows and columns (node a, axis i), elements last;
    #: a work buffer of the kernel, overwritten by its next tangent evaluation
    hessian: np.ndarray | None = None
    #: the element tangents assembled into the global tangent's values (nnz,) (``evaluate(element_map=...)``)
    assembled: np.ndarray | None = None


def _matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched product of components-first arrays: (p, q, m) @ (q, r, m) -> (p, r, m).

    Accumulated over q in place (q = 3 or 4 here): the same sums in the same
    order as reducing the (p, q, r, m) product, without that temporary
    (about a quarter faster on the paper's flap; these products are a tenth
    of the solver's time).
    """
    out = a[:, 0, None, :] * b[None, 0, :, :]
    for j in range(1, a.shape[1]):
        out += a[:, j, None, :] * b[None, j, :, :]
    return out


@dataclass
class QuadraturePoint:
    """One integration point of every element: shape gradients (nodes, 3, m) in 1/m, weights (m,) in m^3."""

    grad: np.ndarray
    weight: np.ndarray
    #: (nodes, nodes, m): g_a . g_b
    gg: np.ndarray


class StVKElements:
    """Tetrahedra of a rest mesh with per-element Lamé parameters and penalty modulus.

    ``nodes`` (n, 3) m and ``tets`` (m, 4) linear or (m, 10) quadratic
    (VTK order), positively oriented; ``lam``, ``mu``, ``kappa`` (m,) or
    scalars in Pa.

    Per-element arrays are stored components first and elements last
    ((k, 3, m) for shape gradients, (3, 3, m) for F), so that every numpy
    operation runs its inner loop over the elements, contiguously.
    """

    def __init__(self, nodes: np.ndarray, tets: np.ndarray, lam, mu, kappa) -> None:
        nodes = np.asarray(nodes, dtype=float)
        self.tets = np.asarray(tets, dtype=np.int64)
        self.n_nodes = len(nodes)
        m, k = self.tets.shape
        self.reference = reference_element(k)
        self.nodes_per_element = k
        rest = nodes[self.tets]  # (m, k, 3)
        derivatives = self.reference.derivatives(self.reference.points)
        self.points: list[QuadraturePoint] = []
        for dn, w in zip(derivatives, self.reference.weights, strict=True):
            grad, det = physical_gradients(rest, dn)
            if np.any(det <= 0):
                raise ValueError("every tetrahedron must have a positive rest volume (Jacobian)")
            g = np.ascontiguousarray(grad.transpose(1, 2, 0))  # (k, 3, m)
            self.points.append(QuadraturePoint(g, w * det, _matmul(g, g.transpose(1, 0, 2))))
        #: shape gradients at the vertices (quadratic elements only): where inversion is also checked
        self._checks = []
        if k == 10:
            for dn in self.reference.derivatives(VERTICES):
                self._checks.append(np.ascontiguousarray(physical_gradients(rest, dn)[0].transpose(1, 2, 0)))
        #: rest volume (m,) in m^3
        self.volume = np.sum([p.weight for p in self.points], axis=0)
        self.grad = self.points[0].grad  # linear elements: the (constant) shape gradients (4, 3, m)
        self._gg = self.points[0].gg
        self.lam = np.broadcast_to(np.asarray(lam, dtype=float), (m,)).copy()
        self.mu = np.broadcast_to(np.asarray(mu, dtype=float), (m,)).copy()
        self.kappa = np.broadcast_to(np.asarray(kappa, dtype=float), (m,)).copy()
        self._tets_t = np.ascontiguousarray(self.tets.T)  # (k, m)
        #: global degrees of freedom (k, 3, m) of each element's nodes: 3 node + axis
        self.dofs = 3 * self._tets_t[:, None, :] + np.arange(3)[None, :, None]
        self._dofs_flat = self.dofs.ravel()
        self._gather = np.ascontiguousarray(self.dofs.transpose(1, 0, 2))  # (3, k, m): axis, node, element
        #: (3n,) m: the rest positions, flat; (3, k, m) per element
        self.rest = nodes.ravel().copy()
        self._rest_elements = self.rest[self._gather]

    @property
    def n_elements(self) -> int:
        return len(self.tets)

    @property
    def n_points(self) -> int:
        """Quadrature points per element (1 linear, 4 quadratic)."""
        return len(self.points)

    # ------------------------------------------------------------------ kinematics
    def _element_positions(self, x: np.ndarray) -> np.ndarray:
        """Node positions per element (3, k, m), gathered straight from the flat positions (one take)."""
        return np.asarray(x, dtype=float).ravel()[self._gather]

    def _element_displacements(self, x: np.ndarray, displacement: bool) -> np.ndarray:
        """Node displacements per element (3, k, m): ``x`` is u itself (``displacement``) or positions X + u."""
        gathered = np.asarray(x, dtype=float).ravel()[self._gather]
        return gathered if displacement else gathered - self._rest_elements

    def deformation_gradient(self, x: np.ndarray, point: int = 0) -> np.ndarray:
        """F (3, 3, m) at node positions x (n, 3), at quadrature point ``point`` (linear: the only one)."""
        return _matmul(self._element_positions(x), self.points[point].grad)

    def deformation_gradients(self, x: np.ndarray) -> np.ndarray:
        """F (p, 3, 3, m) at every quadrature point."""
        xe = self._element_positions(x)
        return np.stack([_matmul(xe, p.grad) for p in self.points])

    @staticmethod
    def _det_and_cofactor(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """det F and cof F = J F^-T, components first, by closed forms."""
        det, rows = cofactor(f)
        return det, np.array(rows)

    _det = staticmethod(determinant)

    def volume_ratio(self, x: np.ndarray) -> np.ndarray:
        """J = det F (m,): deformed over rest volume; <= 0 means inverted.

        Quadratic elements: the smallest J over the quadrature points and
        the vertices (the local volume ratio most at risk of inversion).
        """
        xe = self._element_positions(x)
        dets = [self._det(_matmul(xe, p.grad)) for p in self.points]
        dets += [self._det(_matmul(xe, g)) for g in self._checks]
        return np.min(dets, axis=0) if len(dets) > 1 else dets[0]

    def upright(self, x: np.ndarray) -> bool:
        """Whether every element has a positive volume ratio at positions x (n, 3) or (3n,): all of
        :meth:`volume_ratio` positive, by one compiled pass that stops at the first that is not."""
        from .kernels import upright

        grads, checks, _, dofs = self._compiled_inputs()
        return bool(upright(np.ascontiguousarray(x, dtype=float).ravel(), grads, checks, dofs))

    def _strain(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Green strain E (3, 3, m) and tr E from F (loses eps |F|^2: see :meth:`_strain_h`)."""
        e = _matmul(f.transpose(1, 0, 2), f)
        e[_DIAG, _DIAG] -= 1.0
        e *= 0.5
        return e, e[0, 0] + e[1, 1] + e[2, 2]

    @staticmethod
    def _gradient_of_deformation(h: np.ndarray, xe: np.ndarray | None, grad: np.ndarray) -> np.ndarray:
        """F (3, 3, m): from the positions when given (keeps J of an element crushed to 1e-100 of its
        volume, which I + H rounds to 0), else I + H."""
        if xe is not None:
            return _matmul(xe, grad)
        f = h.copy()
        f[_DIAG, _DIAG] += 1.0
        return f

    @staticmethod
    def _strain_h(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Green strain E = (H + H^T + H^T H) / 2 (3, 3, m) and tr E from the displacement gradient H.

        No cancellation: E is as accurate relative to the strain as H is, where ``(F^T F - I) / 2`` loses
        eps |F|^2 whatever the strain; with it the residual forces resolve down to eps times the
        element forces, which is what lets a tolerance be honoured far below the weight of a node.
        """
        ht = h.transpose(1, 0, 2)
        e = _matmul(ht, h)
        e += h
        e += ht
        e *= 0.5
        return e, e[0, 0] + e[1, 1] + e[2, 2]

    @staticmethod
    def _log_volume_ratio(h: np.ndarray, det: np.ndarray) -> np.ndarray:
        """ln J: log1p(J - 1) with J - 1 = tr H + (tr^2 H - tr H^2) / 2 + det H (accurate for small strains),
        ln(det F) where J is far from 1 (there the sum cancels and det F is the accurate one)."""
        tr = h[0, 0] + h[1, 1] + h[2, 2]
        square = (h * h.transpose(1, 0, 2)).sum(axis=(0, 1))
        excess = tr + 0.5 * (tr * tr - square) + StVKElements._det(h)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(np.abs(excess) < 0.5, np.log1p(excess), np.log(det))

    def _stvk_stress(self, e: np.ndarray, tr: np.ndarray) -> np.ndarray:
        s = 2.0 * self.mu * e
        s[_DIAG, _DIAG] += self.lam * tr
        return s

    # ------------------------------------------------------------------ energy, forces, tangent
    def evaluate(
        self,
        x: np.ndarray,
        gradient: bool = True,
        hessian: bool = False,
        definite: bool = False,
        displacement: bool = False,
        element_map: np.ndarray | None = None,
        nnz: int = 0,
    ) -> ElementEvaluation:
        """Elastic energy (J), optionally its gradient (3n,) and the element tangents (3k, 3k, m).

        ``x``: positions (n, 3) or (3n,), or with ``displacement`` the
        displacements u = x - X from the rest positions (the solver's
        unknowns: rounding then stays relative to u, not to where the mesh
        lies). The kinematics are computed from the displacement gradient
        H = grad u (F = I + H, E from H, ln J by log1p).
        ``element_map`` (with ``hessian``): the position in the global
        tangent's values (``nnz`` of them) of every element matrix entry,
        (3k * 3k * m,) as :class:`~.assembly.TangentPattern` numbers them;
        the tangents are then assembled as they are computed
        (``assembled``) instead of returned per element.
        ``definite``: the positive semi-definite surrogate tangent (see
        :meth:`_tangent_terms`). An inverted or flat element (J <= 0) makes the
        state invalid: energy ``inf`` and nothing else computed.
        """
        if displacement and not hessian:  # the Newton solve's energy and forces: the compiled kernel
            return self._evaluate_compiled(x, gradient)
        if displacement and element_map is not None:  # the Newton solve's tangent: compiled, assembled at once
            return self._assemble_compiled(x, definite, element_map, nnz, gradient)
        ue = self._element_displacements(x, displacement)
        xe = None if displacement else self._element_positions(x)
        kinematics = []
        for point in self.points:
            h = _matmul(ue, point.grad)
            f = self._gradient_of_deformation(h, xe, point.grad)
            det, cof = self._det_and_cofactor(f)
            if not np.all(det > 0):
                return ElementEvaluation(np.inf, False)
            kinematics.append((f, h, det, cof))
        for g in self._checks:
            if not np.all(self._det(self._gradient_of_deformation(_matmul(ue, g), xe, g)) > 0):
                return ElementEvaluation(np.inf, False)
        energy = 0.0
        forces = None
        terms = []  # per quadrature point: what the tangent is built from
        for point, (f, h, det, cof) in zip(self.points, kinematics, strict=True):
            vol = point.weight
            e, tr = self._strain_h(h)
            log_j = self._log_volume_ratio(h, det)
            w = 0.5 * self.lam * tr**2 + self.mu * (e * e).sum(axis=(0, 1)) + 0.5 * self.kappa * log_j**2
            energy += float(np.dot(vol, w))
            if not (gradient or hessian):
                continue
            s = self._stvk_stress(e, tr)
            inv_t = cof / det  # F^-T
            p = _matmul(f, s)
            p *= vol
            p += (self.kappa * vol * log_j) * inv_t  # V P
            part = _matmul(point.grad, p.transpose(1, 0, 2))  # (k, 3, m): V P g_a
            forces = part if forces is None else forces + part
            if hessian:
                terms.append(self._tangent_terms(f, s, inv_t, log_j, definite, point))
        result = ElementEvaluation(energy, True)
        if forces is not None:
            result.gradient = np.bincount(self._dofs_flat, weights=forces.ravel(), minlength=3 * self.n_nodes)
        if hessian:
            if element_map is None:
                result.hessian = self._tangent(terms)
            else:
                result.assembled = self._tangent(terms, element_map, nnz)
        return result

    def _compiled_inputs(self) -> tuple:
        """The compiled kernels' constant inputs, element-major, laid out once."""
        if getattr(self, "_compiled", None) is None:  # the kernel's constant inputs, element-major, laid out once
            k = self.nodes_per_element
            grads = np.stack([p.grad for p in self.points]).transpose(3, 0, 1, 2)  # (m, P, k, 3)
            checks = np.stack(self._checks) if self._checks else np.empty((0, k, 3, self.n_elements))
            weights = np.stack([p.weight for p in self.points]).T  # (m, P)
            dofs = self.dofs.transpose(2, 0, 1)  # (m, k, 3)
            self._compiled = tuple(
                np.ascontiguousarray(a) for a in (grads, checks.transpose(3, 0, 1, 2), weights, dofs)
            )
        return self._compiled

    def _evaluate_compiled(self, u: np.ndarray, gradient: bool) -> ElementEvaluation:
        """Energy and gradient from the displacements (3n,) by :func:`.kernels.energy_and_gradient` (the
        same closed forms as the numpy path below, element by element)."""
        from .kernels import energy_and_gradient

        grads, checks, weights, dofs = self._compiled_inputs()
        out = np.zeros(3 * self.n_nodes)
        energy, valid = energy_and_gradient(
            np.ascontiguousarray(u, dtype=float).ravel(),
            grads,
            weights,
            checks,
            self.lam,
            self.mu,
            self.kappa,
            dofs,
            out,
            gradient,
        )
        if not valid:
            return ElementEvaluation(np.inf, False)
        return ElementEvaluation(float(energy), True, out if gradient else None)

    def summary(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """What a solved state reports, in one compiled pass (:func:`.kernels.state_summary`): the volume
        ratio (m,) as :meth:`volume_ratio`, the largest principal stress magnitude (m,) in Pa as
        :meth:`max_principal_stress` (meaningful where no element is inverted) and the elastic energy in J
        (inf when an element is inverted or flat), at positions x (n, 3) or (3n,)."""
        from .kernels import state_summary

        grads, checks, weights, dofs = self._compiled_inputs()
        flat = np.ascontiguousarray(x, dtype=float).ravel()
        ratio = np.empty(self.n_elements)
        stress = np.empty(self.n_elements)
        energy = state_summary(
            flat, flat - self.rest, grads, weights, checks, self.lam, self.mu, self.kappa, dofs, ratio, stress
        )
        return ratio, stress, float(energy)

    def _assemble_compiled(
        self, u: np.ndarray, definite: bool, element_map: np.ndarray, nnz: int, gradient: bool = True
    ) -> ElementEvaluation:
        """Energy, gradient and assembled tangent from the displacements (3n,) by
        :func:`.kernels.assembled_tangent`: the same terms as the numpy path (:meth:`_tangent_terms` and
        :func:`.kernels.element_tangents`), element by element, without their per-point arrays."""
        from .kernels import assembled_tangent

        grads, checks, weights, dofs = self._compiled_inputs()
        cached = getattr(self, "_positions", None)
        if cached is None or cached[0] is not element_map:
            size = 3 * self.nodes_per_element
            # element-major: one element's entries contiguous (32 bits: half the memory traffic of the map)
            major = np.asarray(element_map).reshape(size * size, self.n_elements).T
            cached = self._positions = (element_map, np.ascontiguousarray(major, dtype=np.uint32))
        data = np.zeros(nnz)
        out = np.zeros(3 * self.n_nodes)
        energy, valid = assembled_tangent(
            np.ascontiguousarray(u, dtype=float).ravel(),
            grads,
            weights,
            checks,
            self.lam,
            self.mu,
            self.kappa,
            dofs,
            cached[1],
            data,
            out,
            definite,
            gradient,
        )
        if not valid:
            return ElementEvaluation(np.inf, False)
        return ElementEvaluation(float(energy), True, out if gradient else None, assembled=data)

    def _tangent_terms(self, f, s, inv_t, log_j, definite: bool, point: QuadraturePoint) -> tuple:
        """What the tangent of one quadrature point is built from (see :func:`.kernels.element_tangents`).

        ``definite``: a positive semi-definite surrogate, much cheaper than
        clamping the eigenvalues of every element matrix: the geometric
        stiffness uses S shifted by its most compressive principal stress
        (``S - min(s_min, 0) I``, never negative), and the volume penalty
        keeps only its Gauss-Newton part ``kappa q q^T``. What remains of the
        material part is the second variation of W at fixed S,
        ``lambda (F:dF)^2 + 2 mu |sym(F^T dF)|^2``, never negative either.
        """
        grad = point.grad
        if definite:
            s = s - np.minimum(symmetric_eigenvalues(s)[0], 0.0) * _EYE[:, :, None]
        fft = _matmul(f, f.transpose(1, 0, 2))  # F F^T
        gsg = _matmul(grad, _matmul(s, grad.transpose(1, 0, 2)))  # (k, k, m): g_a . S g_b
        h = _matmul(grad, f.transpose(1, 0, 2))  # (k, 3, m): F g_a
        q = _matmul(grad, inv_t.transpose(1, 0, 2))  # (k, 3, m): F^-T g_a
        swapped = np.zeros_like(log_j) if definite else log_j
        return fft, gsg, h, q, swapped

    def _tangent(self, terms: list[tuple], element_map: np.ndarray | None = None, nnz: int = 0) -> np.ndarray:
        """Element tangents (3k, 3k, m) summed over the quadrature points' ``terms`` (compiled kernel), or
        with ``element_map`` their assembly (nnz,).

        The element tangents are a view of a work buffer: valid until the next tangent evaluation.
        """
        from .kernels import element_tangents

        n = self.nodes_per_element
        m = self.n_elements
        if getattr(self, "_weights", None) is None:  # the quadrature weights and g_a . g_b, stacked once
            self._weights = (np.stack([p.weight for p in self.points]), np.stack([p.gg for p in self.points]))
        vol, gg = self._weights
        fft, gsg, h, q, log_j = (np.stack(column) for column in zip(*terms, strict=True))
        if element_map is None:
            out = self._buffer(m)
            element_tangents(out, _NO_DATA, _NO_MAP, vol, gg, fft, gsg, h, q, self.lam, self.mu, self.kappa, log_j)
            return out.reshape(3 * n, 3 * n, m)
        data = np.zeros(nnz)
        blocks = np.ascontiguousarray(element_map, dtype=np.int64).reshape(n, 3, n, 3, m)
        element_tangents(_NO_OUT, data, blocks, vol, gg, fft, gsg, h, q, self.lam, self.mu, self.kappa, log_j)
        return data

    def _buffer(self, m: int) -> np.ndarray:
        """The work array (k, 3, k, 3, m) reused between calls (a fresh large array costs page faults every time)."""
        n = self.nodes_per_element
        if getattr(self, "_work", None) is None or self._work.shape[-1] != m:
            self._work = np.empty((n, 3, n, 3, m))
        return self._work

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_work"] = None
        state["_weights"] = None
        state["_compiled"] = None
        state["_positions"] = None
        return state

    # ------------------------------------------------------------------ stress
    def second_piola_kirchhoff_at_points(self, x: np.ndarray) -> np.ndarray:
        """S (p, m, 3, 3) in Pa at every quadrature point, including the volume penalty's ``kappa ln J C^-1``."""
        out = []
        ue = self._element_displacements(x, False)
        xe = self._element_positions(x)
        for point in self.points:
            h = _matmul(ue, point.grad)
            f = _matmul(xe, point.grad)
            det, cof = self._det_and_cofactor(f)
            e, tr = self._strain_h(h)
            s = self._stvk_stress(e, tr)
            # C^-1 = F^-1 F^-T from the cofactors in closed form: a degenerate element (det F = 0, or
            # underflowing pivots) gives inf or nan here, never a LinAlgError from a batched inverse
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                inv_t = cof / det
                log_j = self._log_volume_ratio(h, det)
                s += (self.kappa * log_j) * _matmul(inv_t.transpose(1, 0, 2), inv_t)
            out.append(s.transpose(2, 0, 1))
        return np.stack(out)

    def second_piola_kirchhoff(self, x: np.ndarray) -> np.ndarray:
        """S (m, 3, 3) in Pa; quadratic elements: the volume-weighted mean over the quadrature points."""
        s = self.second_piola_kirchhoff_at_points(x)
        if len(s) == 1:
            return s[0]
        weights = np.stack([p.weight for p in self.points])[:, :, None, None]
        return (weights * s).sum(axis=0) / self.volume[:, None, None]

    def max_principal_stress(self, x: np.ndarray) -> np.ndarray:
        """max |eigenvalue of S| (m,) in Pa per element, over its quadrature points (paper §IV-D)."""
        out = None
        for s in self.second_piola_kirchhoff_at_points(x):
            s = s.transpose(1, 2, 0)
            bad = ~np.all(np.isfinite(s), axis=(0, 1))
            s[:, :, bad] = 0.0
            with np.errstate(over="ignore", invalid="ignore"):
                low, _, high = symmetric_eigenvalues(s)
                value = np.maximum(np.abs(low), np.abs(high))
            value[bad | ~np.isfinite(value)] = np.inf  # a degenerate element: unbounded stress
            out = value if out is None else np.maximum(out, value)
        return out


def symmetric_eigenvalues(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigenvalues (low, middle, high) of symmetric 3 x 3 matrices (3, 3, m), in closed form.

    The trigonometric solution of the characteristic cubic (Smith, CACM 4(4)
    1961); about ten times faster than LAPACK on many small matrices.
    """
    q = (a[0, 0] + a[1, 1] + a[2, 2]) / 3.0
    off = a[0, 1] ** 2 + a[0, 2] ** 2 + a[1, 2] ** 2
    d0, d1, d2 = a[0, 0] - q, a[1, 1] - q, a[2, 2] - q
    p = np.sqrt((d0**2 + d1**2 + d2**2 + 2.0 * off) / 6.0)
    safe = np.where(p > 0, p, 1.0)
    b00, b11, b22 = d0 / safe, d1 / safe, d2 / safe
    b01, b02, b12 = a[0, 1] / safe, a[0, 2] / safe, a[1, 2] / safe
    r = 0.5 * (b00 * (b11 * b22 - b12**2) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    phi = np.arccos(np.clip(r, -1.0, 1.0)) / 3.0
    high = q + 2.0 * p * np.cos(phi)
    low = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    return low, 3.0 * q - high - low, high


_DIAG = np.arange(3)
#: placeholders for the kernel's unused outputs
_NO_DATA = np.empty(0)
_NO_MAP = np.empty((0, 0, 0, 0, 0), dtype=np.int64)
_NO_OUT = np.empty((0, 0, 0, 0, 0))
