"""Compiled (numba) element tangents of :mod:`.stvk`: one pass over the output, every quadrature point summed in it.

The numpy formulation writes each element matrix entry five to six times
per quadrature point (one full-size temporary per term of the tangent);
for quadratic tetrahedra (30 x 30 entries, four points) that is about
twenty passes over an array of ``900 m`` numbers, and it was a third of a
Newton solve's time on the 40x4x4 quadratic cantilever. Here every entry
of the upper triangle is computed once, with the sum over the points and
the terms in registers, and mirrored (so the element matrices are exactly
symmetric). The inner loop runs over the elements, contiguously, as the
rest of the kernel's arrays are laid out (components first, elements
last).

Imported on the first tangent evaluation (compiling it, or loading numba's
cache, costs a few hundred milliseconds once per process).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import closed_forms

#: the numpy kernel's closed forms, compiled for one 3 x 3 matrix
_determinant = njit(cache=True, inline="always")(closed_forms.determinant)
_cofactor = njit(cache=True, inline="always")(closed_forms.cofactor)

#: elements per block: the block's rows of the inputs (about fifteen of 8 kB each) stay in cache
CHUNK = 1024


@njit(cache=True, nogil=True)
def element_tangents(out, data, element_map, vol, gg, fft, gsg, h, q, lam, mu, kappa, logj):  # pragma: no cover
    """The element tangents summed over the quadrature points: into ``out`` (k, 3, k, 3, m), or assembled.

    With ``element_map`` (k, 3, k, 3, m) not empty, each entry is added
    straight into the global tangent's values ``data`` (nnz,) at the
    position the map gives (the assembly, without the element matrices'
    buffer and a second pass over it) and ``out`` is not touched.

    Per point p (first axis) and element e (last axis): ``vol`` (P, m) the
    weights w det J, ``gg`` (P, k, k, m) g_a . g_b, ``fft`` (P, 3, 3, m)
    F F^T, ``gsg`` (P, k, k, m) g_a . S g_b, ``h`` (P, k, 3, m) F g_a,
    ``q`` (P, k, 3, m) F^-T g_a, ``logj`` (P, m) the coefficient of the
    swapped volume-penalty term (ln J; zero for the definite surrogate);
    ``lam``, ``mu``, ``kappa`` (m,). Entry (a, i, b, j):

        sum_p vol [ mu gg_ab fft_ij + delta_ij gsg_ab + lam h_ai h_bj + mu h_aj h_bi
                    + kappa (q_ai q_bj - ln J q_aj q_bi) ]
    """
    n_points, k, _, m = h.shape
    assemble = element_map.size > 0
    acc = np.empty(CHUNK)  # a local accumulator: no aliasing with the inputs, so the loops vectorise
    for start in range(0, m, CHUNK):  # a block of elements at a time: its inputs stay in cache
        n = min(CHUNK, m - start)
        stop = start + n
        v_mu, v_lam, v_kappa = mu[start:stop], lam[start:stop], kappa[start:stop]
        for a in range(k):
            for i in range(3):
                for b in range(a, k):
                    for j in range(0 if b > a else i, 3):
                        for e in range(n):
                            acc[e] = 0.0
                        for p in range(n_points):
                            v, w_gg, w_fft = vol[p, start:stop], gg[p, a, b, start:stop], fft[p, i, j, start:stop]
                            h_ai, h_bj = h[p, a, i, start:stop], h[p, b, j, start:stop]
                            h_aj, h_bi = h[p, a, j, start:stop], h[p, b, i, start:stop]
                            q_ai, q_bj = q[p, a, i, start:stop], q[p, b, j, start:stop]
                            q_aj, q_bi = q[p, a, j, start:stop], q[p, b, i, start:stop]
                            log_j = logj[p, start:stop]
                            if i == j:
                                w_gsg = gsg[p, a, b, start:stop]
                                for e in range(n):
                                    acc[e] += v[e] * (
                                        v_mu[e] * (w_gg[e] * w_fft[e] + h_aj[e] * h_bi[e])
                                        + v_lam[e] * h_ai[e] * h_bj[e]
                                        + v_kappa[e] * (q_ai[e] * q_bj[e] - log_j[e] * q_aj[e] * q_bi[e])
                                        + w_gsg[e]
                                    )
                            else:
                                for e in range(n):
                                    acc[e] += v[e] * (
                                        v_mu[e] * (w_gg[e] * w_fft[e] + h_aj[e] * h_bi[e])
                                        + v_lam[e] * h_ai[e] * h_bj[e]
                                        + v_kappa[e] * (q_ai[e] * q_bj[e] - log_j[e] * q_aj[e] * q_bi[e])
                                    )
                        if assemble:
                            rows, mirrors = element_map[a, i, b, j], element_map[b, j, a, i]
                            for e in range(n):
                                data[rows[start + e]] += acc[e]
                            if b != a or j != i:
                                for e in range(n):
                                    data[mirrors[start + e]] += acc[e]
                        else:
                            row, mirror = out[a, i, b, j], out[b, j, a, i]
                            for e in range(n):
                                row[start + e] = acc[e]
                                mirror[start + e] = acc[e]
    return out


@njit(cache=True, nogil=True)
def energy_and_gradient(u, grads, weights, checks, lam, mu, kappa, dofs, gradient, want_gradient):  # pragma: no cover
    """Elastic energy (J) of the displacements ``u`` (3n,), adding its gradient into ``gradient`` (3n,).

    Returns (energy, valid): valid is False, and nothing else meaningful,
    when det F <= 0 at a quadrature point or, for quadratic elements, at a
    vertex (``checks`` (m, C, k, 3): the shape gradients there). ``grads``
    (m, P, k, 3) and ``weights`` (m, P): the quadrature points' shape
    gradients and weights w det J; ``dofs`` (m, k, 3): each element's
    global degrees of freedom. Element-major arrays: everything one element
    reads is contiguous. The same closed forms as the numpy path of
    :meth:`.stvk.StVKElements.evaluate` (F = I + H with H = grad u, E from H
    without cancellation, ln J by log1p near J = 1); element by element.
    """
    m, n_points, k, _ = grads.shape
    n_checks = checks.shape[1]
    ue = np.empty((3, k))
    h = np.empty((3, 3))
    f = np.empty((3, 3))
    cof = np.empty((3, 3))
    e_ = np.empty((3, 3))
    p_ = np.empty((3, 3))
    energy = 0.0
    for el in range(m):
        for a in range(k):
            for i in range(3):
                ue[i, a] = u[dofs[el, a, i]]
        for c in range(n_checks):
            for i in range(3):
                for l in range(3):
                    total = 1.0 if i == l else 0.0
                    for a in range(k):
                        total += ue[i, a] * checks[el, c, a, l]
                    f[i, l] = total
            if not _determinant(f) > 0.0:
                return np.inf, False
        for q in range(n_points):
            for i in range(3):
                for l in range(3):
                    total = 0.0
                    for a in range(k):
                        total += ue[i, a] * grads[el, q, a, l]
                    h[i, l] = total
                    f[i, l] = total + (1.0 if i == l else 0.0)
            det = _cofactor(f, cof)
            if not det > 0.0:
                return np.inf, False
            # Green strain from H without cancellation: E = (H + H^T + H^T H) / 2
            for i in range(3):
                for j in range(3):
                    total = 0.0
                    for l in range(3):
                        total += h[l, i] * h[l, j]
                    e_[i, j] = 0.5 * (total + h[i, j] + h[j, i])
            tr = e_[0, 0] + e_[1, 1] + e_[2, 2]
            tr_h = h[0, 0] + h[1, 1] + h[2, 2]
            square = 0.0
            e_square = 0.0
            for i in range(3):
                for j in range(3):
                    square += h[i, j] * h[j, i]
                    e_square += e_[i, j] * e_[i, j]
            excess = tr_h + 0.5 * (tr_h * tr_h - square) + _determinant(h)  # J - 1
            log_j = np.log1p(excess) if abs(excess) < 0.5 else np.log(det)
            vol = weights[el, q]
            energy += vol * (0.5 * lam[el] * tr * tr + mu[el] * e_square + 0.5 * kappa[el] * log_j * log_j)
            if not want_gradient:
                continue
            # V P = V (F S) + kappa V ln J F^-T,  S = 2 mu E + lam tr E I
            penalty = kappa[el] * vol * log_j / det
            for i in range(3):
                for j in range(3):
                    total = 0.0
                    for l in range(3):
                        s_lj = 2.0 * mu[el] * e_[l, j] + (lam[el] * tr if l == j else 0.0)
                        total += f[i, l] * s_lj
                    p_[i, j] = vol * total + penalty * cof[i, j]
            for a in range(k):
                for i in range(3):
                    total = 0.0
                    for l in range(3):
                        total += p_[i, l] * grads[el, q, a, l]
                    gradient[dofs[el, a, i]] += total
    return energy, True
