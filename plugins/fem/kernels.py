"""Compiled (numba) kernels of :mod:`.stvk`: energy, forces and tangents without numpy's temporaries.

* :func:`assembled_tangent` (the Newton solve's tangent): element by
  element, the kinematics of each quadrature point, then the upper
  triangle of the element matrix summed over the points in a local array
  that stays in the first-level cache, added into the global tangent's
  values at once. It replaces a numpy preparation of per-point arrays
  (F F^T, F g_a, F^-T g_a, g_a . S g_b for every element) and a second
  kernel over them: on the 40x4x4 quadratic cantilever a tangent went from
  about 31 to 19 ms, energy and forces included. An element with one
  quadrature point (linear) adds each block straight into the global
  values instead: it is final when computed.
* :func:`element_tangents` (the element matrices of the numpy path, e.g.
  for a caller that wants them per element): every entry of the upper
  triangle computed once per element block, vectorised over the elements,
  from the per-point arrays the numpy kernel prepares.
* :func:`energy_and_gradient` (every line-search trial): energy and forces
  element by element.
* :func:`state_summary` (a solved state's volume ratios, stresses and
  energy) and :func:`upright` (a warm start's check that no element is
  inverted), one pass each.

The same closed forms as the numpy kernel (:mod:`.closed_forms` is
compiled from the same source); tests keep the paths within 1e-12.
Imported on first use (compiling, or loading numba's cache, costs a few
hundred milliseconds once per process).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import closed_forms

#: the numpy kernel's closed forms, compiled for one 3 x 3 matrix held as rows of scalars (registers, not memory)
_determinant = njit(cache=True, inline="always")(closed_forms.determinant)
_cofactor = njit(cache=True, inline="always")(closed_forms.cofactor)

# The helpers below pass 3 x 3 matrices as rows of scalars (3-tuples of 3-tuples), which LLVM keeps in
# registers: written into small work arrays instead, every store may alias every later load, and the energy
# and forces of the paper's flap took 1.8 times as long (0.64 against 0.35 ms for 4,000 linear tetrahedra),
# the energy alone 2.3 times. Each entry is the same operations in the same order as the numpy kernel's.


@njit(cache=True, inline="always")
def _gather(values, dofs, el, out):  # pragma: no cover
    """An element's nodal values (3, k) from the flat (3n,) ``values``."""
    for a in range(out.shape[1]):
        for i in range(3):
            out[i, a] = values[dofs[el, a, i]]


@njit(cache=True, inline="always")
def _gradient(values, g, diagonal):  # pragma: no cover
    """``diagonal`` I + sum_a values[:, a] g[a]^T (rows): F = I + grad u from displacements (``diagonal`` 1),
    grad x from positions or grad u (0); each entry summed starting from the identity's."""
    t00 = t11 = t22 = diagonal
    t01 = t02 = t10 = t12 = t20 = t21 = 0.0
    for a in range(values.shape[1]):
        g0, g1, g2 = g[a, 0], g[a, 1], g[a, 2]
        v0, v1, v2 = values[0, a], values[1, a], values[2, a]
        t00 += v0 * g0
        t01 += v0 * g1
        t02 += v0 * g2
        t10 += v1 * g0
        t11 += v1 * g1
        t12 += v1 * g2
        t20 += v2 * g0
        t21 += v2 * g1
        t22 += v2 * g2
    return (t00, t01, t02), (t10, t11, t12), (t20, t21, t22)


@njit(cache=True, inline="always")
def _vertices_upright(ue, checks, el):  # pragma: no cover
    """det F > 0 at the vertices of a quadratic element (``checks[el]``: the shape gradients there)."""
    for c in range(checks.shape[1]):
        if not _determinant(_gradient(ue, checks[el, c], 1.0)) > 0.0:
            return False
    return True


@njit(cache=True, inline="always")
def _displacement_gradient(ue, g):  # pragma: no cover
    """H = grad u and F = I + H (rows) from the element's displacements and shape gradients."""
    h = _gradient(ue, g, 0.0)
    f = (h[0][0] + 1.0, h[0][1], h[0][2]), (h[1][0], h[1][1] + 1.0, h[1][2]), (h[2][0], h[2][1], h[2][2] + 1.0)
    return h, f


@njit(cache=True, inline="always")
def _strain_entry(h, i, j):  # pragma: no cover
    """E_ij = (sum_l H_li H_lj + H_ij + H_ji) / 2."""
    return 0.5 * (h[0][i] * h[0][j] + h[1][i] * h[1][j] + h[2][i] * h[2][j] + h[i][j] + h[j][i])


@njit(cache=True, inline="always")
def _strain(h):  # pragma: no cover
    """Green strain E = (H + H^T + H^T H) / 2 from H without cancellation (rows), tr E, E : E and
    J - 1 = tr H + (tr^2 H - tr H^2) / 2 + det H (accurate for small strains)."""
    e = (
        (_strain_entry(h, 0, 0), _strain_entry(h, 0, 1), _strain_entry(h, 0, 2)),
        (_strain_entry(h, 1, 0), _strain_entry(h, 1, 1), _strain_entry(h, 1, 2)),
        (_strain_entry(h, 2, 0), _strain_entry(h, 2, 1), _strain_entry(h, 2, 2)),
    )
    tr_h = h[0][0] + h[1][1] + h[2][2]
    square = (
        h[0][0] * h[0][0] + h[0][1] * h[1][0] + h[0][2] * h[2][0]
        + h[1][0] * h[0][1] + h[1][1] * h[1][1] + h[1][2] * h[2][1]
        + h[2][0] * h[0][2] + h[2][1] * h[1][2] + h[2][2] * h[2][2]
    )  # fmt: skip
    e_square = (
        e[0][0] * e[0][0] + e[0][1] * e[0][1] + e[0][2] * e[0][2]
        + e[1][0] * e[1][0] + e[1][1] * e[1][1] + e[1][2] * e[1][2]
        + e[2][0] * e[2][0] + e[2][1] * e[2][1] + e[2][2] * e[2][2]
    )  # fmt: skip
    excess = tr_h + 0.5 * (tr_h * tr_h - square) + _determinant(h)
    return e, e[0][0] + e[1][1] + e[2][2], e_square, excess


@njit(cache=True, inline="always")
def _log_volume_ratio(excess, det):  # pragma: no cover
    """ln J: log1p(J - 1) near J = 1, ln det F where J is far from 1 (NaN where det F <= 0)."""
    if abs(excess) < 0.5:
        return np.log1p(excess)
    return np.log(det) if det > 0.0 else np.nan


@njit(cache=True, inline="always")
def _stvk_stress(e, tr, mu, lam):  # pragma: no cover
    """The StVK part of the second Piola-Kirchhoff stress, S = 2 mu E + lam tr(E) I (rows)."""
    d = lam * tr
    return (
        (2.0 * mu * e[0][0] + d, 2.0 * mu * e[0][1], 2.0 * mu * e[0][2]),
        (2.0 * mu * e[1][0], 2.0 * mu * e[1][1] + d, 2.0 * mu * e[1][2]),
        (2.0 * mu * e[2][0], 2.0 * mu * e[2][1], 2.0 * mu * e[2][2] + d),
    )


@njit(cache=True, inline="always")
def _piola_entry(f, s, cof, vol, penalty, i, j):  # pragma: no cover
    return vol * (f[i][0] * s[0][j] + f[i][1] * s[1][j] + f[i][2] * s[2][j]) + penalty * cof[i][j]


@njit(cache=True, inline="always")
def _weighted_piola(f, s, cof, vol, penalty):  # pragma: no cover
    """V P = V (F S) + kappa V ln J F^-T (rows), ``penalty`` = kappa V ln J / det F (so that it multiplies cof F)."""
    return (
        (_piola_entry(f, s, cof, vol, penalty, 0, 0), _piola_entry(f, s, cof, vol, penalty, 0, 1),
         _piola_entry(f, s, cof, vol, penalty, 0, 2)),
        (_piola_entry(f, s, cof, vol, penalty, 1, 0), _piola_entry(f, s, cof, vol, penalty, 1, 1),
         _piola_entry(f, s, cof, vol, penalty, 1, 2)),
        (_piola_entry(f, s, cof, vol, penalty, 2, 0), _piola_entry(f, s, cof, vol, penalty, 2, 1),
         _piola_entry(f, s, cof, vol, penalty, 2, 2)),
    )  # fmt: skip


@njit(cache=True, inline="always")
def _add_forces(p, g, dofs, el, gradient):  # pragma: no cover
    """The element's nodal forces V P g_a added into ``gradient`` (3n,)."""
    for a in range(g.shape[0]):
        g0, g1, g2 = g[a, 0], g[a, 1], g[a, 2]
        gradient[dofs[el, a, 0]] += p[0][0] * g0 + p[0][1] * g1 + p[0][2] * g2
        gradient[dofs[el, a, 1]] += p[1][0] * g0 + p[1][1] * g1 + p[1][2] * g2
        gradient[dofs[el, a, 2]] += p[2][0] * g0 + p[2][1] * g1 + p[2][2] * g2


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
    ue = np.empty((3, k))
    energy = 0.0
    for el in range(m):
        _gather(u, dofs, el, ue)
        if not _vertices_upright(ue, checks, el):
            return np.inf, False
        for q in range(n_points):
            g = grads[el, q]
            h, f = _displacement_gradient(ue, g)
            det, cof = _cofactor(f)
            if not det > 0.0:
                return np.inf, False
            e, tr, e_square, excess = _strain(h)
            log_j = _log_volume_ratio(excess, det)
            vol = weights[el, q]
            energy += vol * (0.5 * lam[el] * tr * tr + mu[el] * e_square + 0.5 * kappa[el] * log_j * log_j)
            if want_gradient:
                s = _stvk_stress(e, tr, mu[el], lam[el])
                _add_forces(_weighted_piola(f, s, cof, vol, kappa[el] * vol * log_j / det), g, dofs, el, gradient)
    return energy, True


@njit(cache=True, inline="always")
def _extreme_eigenvalues(s):  # pragma: no cover
    """The smallest and the largest eigenvalue of a symmetric 3 x 3 matrix (rows), by Smith's closed form
    (as :func:`.stvk.symmetric_eigenvalues`: one arccos for both)."""
    q = (s[0][0] + s[1][1] + s[2][2]) / 3.0
    off = s[0][1] ** 2 + s[0][2] ** 2 + s[1][2] ** 2
    d0, d1, d2 = s[0][0] - q, s[1][1] - q, s[2][2] - q
    p = np.sqrt((d0**2 + d1**2 + d2**2 + 2.0 * off) / 6.0)
    safe = p if p > 0 else 1.0
    b00, b11, b22 = d0 / safe, d1 / safe, d2 / safe
    b01, b02, b12 = s[0][1] / safe, s[0][2] / safe, s[1][2] / safe
    r = 0.5 * (b00 * (b11 * b22 - b12**2) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    r = min(max(r, -1.0), 1.0)
    phi = np.arccos(r) / 3.0
    return q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0), q + 2.0 * p * np.cos(phi)


@njit(cache=True, inline="always")
def _shifted(s, shift):  # pragma: no cover
    """S + shift I (rows)."""
    return (s[0][0] + shift, s[0][1], s[0][2]), (s[1][0], s[1][1] + shift, s[1][2]), (s[2][0], s[2][1], s[2][2] + shift)


@njit(cache=True, inline="always")
def _outer_rows(f):  # pragma: no cover
    """F F^T (rows): (F F^T)_ij = F_i . F_j, F_i the rows of F."""
    return _row_products(f[0], f), _row_products(f[1], f), _row_products(f[2], f)


@njit(cache=True, inline="always")
def _row_products(row, f):  # pragma: no cover
    return (
        row[0] * f[0][0] + row[1] * f[0][1] + row[2] * f[0][2],
        row[0] * f[1][0] + row[1] * f[1][1] + row[2] * f[1][2],
        row[0] * f[2][0] + row[1] * f[2][1] + row[2] * f[2][2],
    )


@njit(cache=True, inline="always")
def _tangent_entry(factors, i, j):  # pragma: no cover
    """Entry (i, j) of block (a, b) of one point's element tangent, without its delta_ij (g_a . S g_b) term:
    w_gg (F F^T)_ij + mu V (F g_a)_j (F g_b)_i + lam V (F g_a)_i (F g_b)_j + kappa V (q_ai q_bj - ln J q_aj q_bi),
    the factors pre-scaled by V and the moduli (five multiply-adds)."""
    w_gg, fft, mu_fg_a, lam_fg_a, kappa_qg_a, swapped_qg_a, fg_b, qg_b = factors
    return (
        w_gg * fft[i][j]
        + mu_fg_a[j] * fg_b[i]
        + lam_fg_a[i] * fg_b[j]
        + kappa_qg_a[i] * qg_b[j]
        - swapped_qg_a[j] * qg_b[i]
    )


@njit(cache=True, inline="always")
def _tangent_block(factors):  # pragma: no cover
    """The block's nine entries (rows) by :func:`_tangent_entry`."""
    return (
        (_tangent_entry(factors, 0, 0), _tangent_entry(factors, 0, 1), _tangent_entry(factors, 0, 2)),
        (_tangent_entry(factors, 1, 0), _tangent_entry(factors, 1, 1), _tangent_entry(factors, 1, 2)),
        (_tangent_entry(factors, 2, 0), _tangent_entry(factors, 2, 1), _tangent_entry(factors, 2, 2)),
    )


@njit(cache=True, inline="always")
def _add_block(block, w_gsg, data, where, size, row, col):  # pragma: no cover
    """A final block (of an element with one quadrature point), its delta_ij term ``w_gsg`` included, added into
    the global values ``data`` at ``where`` (the element's entry (r, c) at ``where[size r + c]``) and mirrored;
    of a diagonal block (row == col) the upper half."""
    for i in range(3):
        for j in range(3):
            r, c = row + i, col + j
            if c >= r:
                value = block[i][j] + w_gsg if i == j else block[i][j]
                data[where[r * size + c]] += value
                if c != r:
                    data[where[c * size + r]] += value


@njit(cache=True, nogil=True)
def assembled_tangent(  # pragma: no cover
    u, grads, weights, checks, lam, mu, kappa, dofs, positions, data, gradient, definite, want_gradient
):
    """Energy, gradient and the tangent assembled, in one pass over the elements from the displacements ``u``.

    The element-major counterpart of :meth:`.stvk.StVKElements.evaluate`
    with ``hessian`` and an ``element_map``: per element, the kinematics of
    each quadrature point (as :func:`energy_and_gradient`), then F g_a,
    F^-T g_a and S g_a for its nodes, and the upper triangle of the element
    matrix summed over the points in a local 3k x 3k array that stays in
    the first-level cache; its entries are then added into the global
    tangent's values ``data`` (nnz,) at ``positions`` (m, 3k * 3k), the
    element's entry (r, c) at ``positions[e, 3k r + c]`` (and mirrored).
    With one point the blocks are added as they are computed.
    Entry (a, i, b, j), as :func:`element_tangents`:

        sum_p vol [ mu (g_a . g_b) (F F^T)_ij + delta_ij g_a . S g_b + lam (F g_a)_i (F g_b)_j
                    + mu (F g_a)_j (F g_b)_i + kappa (q_ai q_bj - ln J q_aj q_bi) ],  q_a = F^-T g_a

    ``definite``: the surrogate (S shifted by its most compressive
    principal stress, no swapped penalty term); ``want_gradient``: add the
    forces into ``gradient`` (3n,) (a Newton step's factorisation has them
    from its line search already). Returns (energy, valid); an
    inverted element (det F <= 0 at a point or, quadratic, at a vertex)
    leaves ``data`` and ``gradient`` partly written and valid False.
    """
    m, n_points, k, _ = grads.shape
    size = 3 * k
    ke = np.empty((size, size))
    ue = np.empty((3, k))
    fg = np.empty((k, 3))
    qg = np.empty((k, 3))
    sg = np.empty((k, 3))
    mu_fg = np.empty((k, 3))
    lam_fg = np.empty((k, 3))
    kappa_qg = np.empty((k, 3))
    swapped_qg = np.empty((k, 3))
    energy = 0.0
    for el in range(m):
        _gather(u, dofs, el, ue)
        if not _vertices_upright(ue, checks, el):
            return np.inf, False
        for r in range(size):
            for c in range(r, size):
                ke[r, c] = 0.0
        mu_e, lam_e, kappa_e = mu[el], lam[el], kappa[el]
        for q in range(n_points):
            g = grads[el, q]
            h, f = _displacement_gradient(ue, g)
            det, cof = _cofactor(f)
            if not det > 0.0:
                return np.inf, False
            e, tr, e_square, excess = _strain(h)
            log_j = _log_volume_ratio(excess, det)
            vol = weights[el, q]
            energy += vol * (0.5 * lam_e * tr * tr + mu_e * e_square + 0.5 * kappa_e * log_j * log_j)
            s = _stvk_stress(e, tr, mu_e, lam_e)
            if want_gradient:
                _add_forces(_weighted_piola(f, s, cof, vol, kappa_e * vol * log_j / det), g, dofs, el, gradient)
            swapped = log_j
            if definite:
                lowest = _extreme_eigenvalues(s)[0]
                if lowest < 0.0:
                    s = _shifted(s, -lowest)
                swapped = 0.0
            fft = _outer_rows(f)  # F F^T
            inv_det = 1.0 / det
            for a in range(k):
                g0, g1, g2 = g[a, 0], g[a, 1], g[a, 2]
                fg[a, 0] = f[0][0] * g0 + f[0][1] * g1 + f[0][2] * g2
                fg[a, 1] = f[1][0] * g0 + f[1][1] * g1 + f[1][2] * g2
                fg[a, 2] = f[2][0] * g0 + f[2][1] * g1 + f[2][2] * g2
                qg[a, 0] = (cof[0][0] * g0 + cof[0][1] * g1 + cof[0][2] * g2) * inv_det
                qg[a, 1] = (cof[1][0] * g0 + cof[1][1] * g1 + cof[1][2] * g2) * inv_det
                qg[a, 2] = (cof[2][0] * g0 + cof[2][1] * g1 + cof[2][2] * g2) * inv_det
                sg[a, 0] = s[0][0] * g0 + s[0][1] * g1 + s[0][2] * g2
                sg[a, 1] = s[1][0] * g0 + s[1][1] * g1 + s[1][2] * g2
                sg[a, 2] = s[2][0] * g0 + s[2][1] * g1 + s[2][2] * g2
            # pre-scaled rows: each entry of a 3 x 3 block is then five fused multiply-adds
            v_mu, v_lam, v_kappa = vol * mu_e, vol * lam_e, vol * kappa_e
            v_swapped = v_kappa * swapped
            for a in range(k):
                for i in range(3):
                    mu_fg[a, i] = v_mu * fg[a, i]
                    lam_fg[a, i] = v_lam * fg[a, i]
                    kappa_qg[a, i] = v_kappa * qg[a, i]
                    swapped_qg[a, i] = v_swapped * qg[a, i]
            for a in range(k):
                # row a's factors and then row b's as scalars: loads the stores into ``ke`` cannot alias
                g_a = (g[a, 0], g[a, 1], g[a, 2])
                mu_fg_a = (mu_fg[a, 0], mu_fg[a, 1], mu_fg[a, 2])
                lam_fg_a = (lam_fg[a, 0], lam_fg[a, 1], lam_fg[a, 2])
                kappa_qg_a = (kappa_qg[a, 0], kappa_qg[a, 1], kappa_qg[a, 2])
                swapped_qg_a = (swapped_qg[a, 0], swapped_qg[a, 1], swapped_qg[a, 2])
                for b in range(a, k):
                    fg_b = (fg[b, 0], fg[b, 1], fg[b, 2])
                    qg_b = (qg[b, 0], qg[b, 1], qg[b, 2])
                    w_gg = v_mu * (g_a[0] * g[b, 0] + g_a[1] * g[b, 1] + g_a[2] * g[b, 2])
                    w_gsg = vol * (g_a[0] * sg[b, 0] + g_a[1] * sg[b, 1] + g_a[2] * sg[b, 2])
                    factors = (w_gg, fft, mu_fg_a, lam_fg_a, kappa_qg_a, swapped_qg_a, fg_b, qg_b)
                    if n_points == 1:  # the block is final: added straight into the global values, and mirrored
                        _add_block(_tangent_block(factors), w_gsg, data, positions[el], size, 3 * a, 3 * b)
                        continue
                    # the whole 3 x 3 block, also on the diagonal (constant trip counts: unrolled; the lower half
                    # of a diagonal block is computed and never read)
                    for i in range(3):
                        for j in range(3):
                            ke[3 * a + i, 3 * b + j] += _tangent_entry(factors, i, j)
                        ke[3 * a + i, 3 * b + i] += w_gsg
        if n_points == 1:
            continue
        for r in range(size):  # mirrored in the local array, then added in one contiguous sweep
            for c in range(r + 1, size):
                ke[c, r] = ke[r, c]
        flat = ke.ravel()
        where = positions[el]
        for t in range(size * size):
            data[where[t]] += flat[t]
    return energy, True


@njit(cache=True, nogil=True)
def upright(x, grads, checks, dofs):  # pragma: no cover
    """Whether det F > 0 (F from the positions ``x`` (3n,)) at every quadrature point and, quadratic, every
    vertex of every element: :meth:`.stvk.StVKElements.volume_ratio` all positive, without the ratios."""
    m, n_points, k, _ = grads.shape
    xe = np.empty((3, k))
    for el in range(m):
        _gather(x, dofs, el, xe)
        for q in range(n_points):
            if not _determinant(_gradient(xe, grads[el, q], 0.0)) > 0.0:
                return False
        for c in range(checks.shape[1]):
            if not _determinant(_gradient(xe, checks[el, c], 0.0)) > 0.0:
                return False
    return True


@njit(cache=True, inline="always")
def _smaller(a, b):  # pragma: no cover
    """min(a, b), NaN when either is (as ``np.min``)."""
    if a != a or b != b:
        return np.nan
    return a if a < b else b


@njit(cache=True, nogil=True)
def state_summary(x, u, grads, weights, checks, lam, mu, kappa, dofs, ratio, stress):  # pragma: no cover
    """What a solved state reports per element, in one pass: the volume ratio ``ratio`` (m,) (the smallest
    det F over the quadrature points and, quadratic, the vertices), the largest principal stress magnitude
    ``stress`` (m,) in Pa (of S with the volume penalty's kappa ln J C^-1, over the points; inf where S is not
    finite) and the elastic energy (returned; inf when an element is inverted or flat).

    As the numpy path (:meth:`.stvk.StVKElements.volume_ratio`, :meth:`~.stvk.StVKElements.max_principal_stress`,
    ``evaluate(x, gradient=False)``): F from the positions ``x`` (3n,) (the determinant of an element crushed to
    a sliver stays resolved), the strain from the displacements ``u`` (3n,) without cancellation.
    """
    m, n_points, k, _ = grads.shape
    xe = np.empty((3, k))
    ue = np.empty((3, k))
    energy = 0.0
    for el in range(m):
        _gather(x, dofs, el, xe)
        _gather(u, dofs, el, ue)
        lowest = np.inf
        for c in range(checks.shape[1]):
            lowest = _smaller(lowest, _determinant(_gradient(xe, checks[el, c], 0.0)))
        largest = 0.0
        for q in range(n_points):
            h = _gradient(ue, grads[el, q], 0.0)  # H = grad u
            f = _gradient(xe, grads[el, q], 0.0)  # F = grad x
            det, cof = _cofactor(f)
            lowest = _smaller(lowest, det)
            e, tr, e_square, excess = _strain(h)
            log_j = _log_volume_ratio(excess, det)
            energy += weights[el, q] * (0.5 * lam[el] * tr * tr + mu[el] * e_square + 0.5 * kappa[el] * log_j * log_j)
            # S = lam tr E I + 2 mu E + kappa ln J C^-1, C^-1 = F^-1 F^-T = (cof / det)^T (cof / det)
            s = _stvk_stress(e, tr, mu[el], lam[el])
            penalty = kappa[el] * log_j / (det * det)
            s = (
                (s[0][0] + penalty * _column_product(cof, 0, 0), s[0][1] + penalty * _column_product(cof, 0, 1),
                 s[0][2] + penalty * _column_product(cof, 0, 2)),
                (s[1][0] + penalty * _column_product(cof, 1, 0), s[1][1] + penalty * _column_product(cof, 1, 1),
                 s[1][2] + penalty * _column_product(cof, 1, 2)),
                (s[2][0] + penalty * _column_product(cof, 2, 0), s[2][1] + penalty * _column_product(cof, 2, 1),
                 s[2][2] + penalty * _column_product(cof, 2, 2)),
            )  # fmt: skip
            if not _finite(s):
                largest = np.inf
                continue
            low, high = _extreme_eigenvalues(s)
            trace = s[0][0] + s[1][1] + s[2][2]
            value = max(abs(low), abs(high))
            if not np.isfinite(value) or not np.isfinite(trace):
                value = np.inf
            largest = max(largest, value)
        ratio[el] = lowest
        stress[el] = largest
        if not lowest > 0.0:
            energy = np.inf
    return energy


@njit(cache=True, inline="always")
def _column_product(c, i, j):  # pragma: no cover
    """(C^T C)_ij: the product of columns i and j of C."""
    return c[0][i] * c[0][j] + c[1][i] * c[1][j] + c[2][i] * c[2][j]


@njit(cache=True, inline="always")
def _finite(s):  # pragma: no cover
    """Every entry of the 3 x 3 rows ``s`` finite."""
    return (
        np.isfinite(s[0][0]) and np.isfinite(s[0][1]) and np.isfinite(s[0][2])
        and np.isfinite(s[1][0]) and np.isfinite(s[1][1]) and np.isfinite(s[1][2])
        and np.isfinite(s[2][0]) and np.isfinite(s[2][1]) and np.isfinite(s[2][2])
    )  # fmt: skip
