"""Compiled (numba) kernels of :mod:`.stvk`: energy, forces and tangents without numpy's temporaries.

* :func:`assembled_tangent` (the Newton solve's tangent): element by
  element, the kinematics of each quadrature point, then the upper
  triangle of the element matrix summed over the points in a local array
  that stays in the first-level cache, added into the global tangent's
  values at once. It replaces a numpy preparation of per-point arrays
  (F F^T, F g_a, F^-T g_a, g_a . S g_b for every element) and a second
  kernel over them: on the 40x4x4 quadratic cantilever a tangent went from
  about 31 to 19 ms, energy and forces included.
* :func:`element_tangents` (the element matrices of the numpy path, e.g.
  for a caller that wants them per element): every entry of the upper
  triangle computed once per element block, vectorised over the elements,
  from the per-point arrays the numpy kernel prepares.
* :func:`energy_and_gradient` (every line-search trial): energy and forces
  element by element.

The same closed forms as the numpy kernel (:mod:`.closed_forms` is
compiled from the same source); tests keep the paths within 1e-12.
Imported on first use (compiling, or loading numba's cache, costs a few
hundred milliseconds once per process).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import closed_forms

#: the numpy kernel's closed forms, compiled for one 3 x 3 matrix
_determinant = njit(cache=True, inline="always")(closed_forms.determinant)
_cofactor = njit(cache=True, inline="always")(closed_forms.cofactor)


@njit(cache=True, inline="always")
def _gather(values, dofs, el, out):  # pragma: no cover
    """An element's nodal values (3, k) from the flat (3n,) ``values``."""
    for a in range(out.shape[1]):
        for i in range(3):
            out[i, a] = values[dofs[el, a, i]]


@njit(cache=True, inline="always")
def _gradient(values, g, out, diagonal):  # pragma: no cover
    """``diagonal`` I + sum_a values[:, a] g[a]^T into ``out`` (3, 3): F = I + grad u from displacements
    (``diagonal`` 1), grad x from positions or grad u (0); summed starting from the identity's entry."""
    k = values.shape[1]
    for i in range(3):
        for l in range(3):
            total = diagonal if i == l else 0.0
            for a in range(k):
                total += values[i, a] * g[a, l]
            out[i, l] = total


@njit(cache=True, inline="always")
def _vertices_upright(ue, checks, el, f):  # pragma: no cover
    """det F > 0 at the vertices of a quadratic element (``checks[el]``: the shape gradients there)."""
    for c in range(checks.shape[1]):
        _gradient(ue, checks[el, c], f, 1.0)
        if not _determinant(f) > 0.0:
            return False
    return True


@njit(cache=True, inline="always")
def _displacement_gradient(ue, g, h, f):  # pragma: no cover
    """H = grad u (into ``h``) and F = I + H (into ``f``) from the element's displacements and shape gradients."""
    _gradient(ue, g, h, 0.0)
    for i in range(3):
        for l in range(3):
            f[i, l] = h[i, l] + (1.0 if i == l else 0.0)


@njit(cache=True, inline="always")
def _strain(h, e_):  # pragma: no cover
    """Green strain E = (H + H^T + H^T H) / 2 from H without cancellation (into ``e_``); returns tr E, E : E and
    J - 1 = tr H + (tr^2 H - tr H^2) / 2 + det H (accurate for small strains)."""
    for i in range(3):
        for j in range(3):
            total = 0.0
            for l in range(3):
                total += h[l, i] * h[l, j]
            e_[i, j] = 0.5 * (total + h[i, j] + h[j, i])
    tr_h = h[0, 0] + h[1, 1] + h[2, 2]
    square = 0.0
    e_square = 0.0
    for i in range(3):
        for j in range(3):
            square += h[i, j] * h[j, i]
            e_square += e_[i, j] * e_[i, j]
    excess = tr_h + 0.5 * (tr_h * tr_h - square) + _determinant(h)
    return e_[0, 0] + e_[1, 1] + e_[2, 2], e_square, excess


@njit(cache=True, inline="always")
def _log_volume_ratio(excess, det):  # pragma: no cover
    """ln J: log1p(J - 1) near J = 1, ln det F where J is far from 1 (NaN where det F <= 0)."""
    if abs(excess) < 0.5:
        return np.log1p(excess)
    return np.log(det) if det > 0.0 else np.nan


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
    h = np.empty((3, 3))
    f = np.empty((3, 3))
    cof = np.empty((3, 3))
    e_ = np.empty((3, 3))
    p_ = np.empty((3, 3))
    energy = 0.0
    for el in range(m):
        _gather(u, dofs, el, ue)
        if not _vertices_upright(ue, checks, el, f):
            return np.inf, False
        for q in range(n_points):
            _displacement_gradient(ue, grads[el, q], h, f)
            det = _cofactor(f, cof)
            if not det > 0.0:
                return np.inf, False
            tr, e_square, excess = _strain(h, e_)
            log_j = _log_volume_ratio(excess, det)
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


@njit(cache=True, inline="always")
def _lowest_eigenvalue(s):  # pragma: no cover
    """The smallest eigenvalue of a symmetric 3 x 3 matrix (Smith's closed form, as
    :func:`.stvk.symmetric_eigenvalues`)."""
    q = (s[0, 0] + s[1, 1] + s[2, 2]) / 3.0
    off = s[0, 1] ** 2 + s[0, 2] ** 2 + s[1, 2] ** 2
    d0, d1, d2 = s[0, 0] - q, s[1, 1] - q, s[2, 2] - q
    p = np.sqrt((d0**2 + d1**2 + d2**2 + 2.0 * off) / 6.0)
    safe = p if p > 0 else 1.0
    b00, b11, b22 = d0 / safe, d1 / safe, d2 / safe
    b01, b02, b12 = s[0, 1] / safe, s[0, 2] / safe, s[1, 2] / safe
    r = 0.5 * (b00 * (b11 * b22 - b12**2) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    r = min(max(r, -1.0), 1.0)
    phi = np.arccos(r) / 3.0
    return q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)


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
    h = np.empty((3, 3))
    f = np.empty((3, 3))
    cof = np.empty((3, 3))
    e_ = np.empty((3, 3))
    s_ = np.empty((3, 3))
    fft = np.empty((3, 3))
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
        if not _vertices_upright(ue, checks, el, f):
            return np.inf, False
        for r in range(size):
            for c in range(r, size):
                ke[r, c] = 0.0
        mu_e, lam_e, kappa_e = mu[el], lam[el], kappa[el]
        for q in range(n_points):
            g = grads[el, q]
            _displacement_gradient(ue, g, h, f)
            det = _cofactor(f, cof)
            if not det > 0.0:
                return np.inf, False
            tr, e_square, excess = _strain(h, e_)
            log_j = _log_volume_ratio(excess, det)
            vol = weights[el, q]
            energy += vol * (0.5 * lam_e * tr * tr + mu_e * e_square + 0.5 * kappa_e * log_j * log_j)
            for i in range(3):
                for j in range(3):
                    s_[i, j] = 2.0 * mu_e * e_[i, j] + (lam_e * tr if i == j else 0.0)
            if want_gradient:  # the forces: V P = V (F S) + kappa V ln J F^-T
                penalty = kappa_e * vol * log_j / det
                for i in range(3):
                    for j in range(3):
                        total = 0.0
                        for l in range(3):
                            total += f[i, l] * s_[l, j]
                        fft[i, j] = vol * total + penalty * cof[i, j]  # (V P, in fft until the forces are added)
                for a in range(k):
                    for i in range(3):
                        total = 0.0
                        for l in range(3):
                            total += fft[i, l] * g[a, l]
                        gradient[dofs[el, a, i]] += total
            swapped = log_j
            if definite:
                lowest = _lowest_eigenvalue(s_)
                if lowest < 0.0:
                    for i in range(3):
                        s_[i, i] -= lowest
                swapped = 0.0
            for i in range(3):
                for j in range(3):
                    total = 0.0
                    for l in range(3):
                        total += f[i, l] * f[j, l]
                    fft[i, j] = total
            inv_det = 1.0 / det
            for a in range(k):
                for i in range(3):
                    t_f = 0.0
                    t_q = 0.0
                    t_s = 0.0
                    for l in range(3):
                        t_f += f[i, l] * g[a, l]
                        t_q += cof[i, l] * g[a, l]
                        t_s += s_[i, l] * g[a, l]
                    fg[a, i] = t_f
                    qg[a, i] = t_q * inv_det
                    sg[a, i] = t_s
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
                for b in range(a, k):
                    w_gg = v_mu * (g[a, 0] * g[b, 0] + g[a, 1] * g[b, 1] + g[a, 2] * g[b, 2])
                    w_gsg = vol * (g[a, 0] * sg[b, 0] + g[a, 1] * sg[b, 1] + g[a, 2] * sg[b, 2])
                    # the whole 3 x 3 block, also on the diagonal (constant trip counts: unrolled; the lower
                    # half of a diagonal block is computed and never read)
                    for i in range(3):
                        for j in range(3):
                            ke[3 * a + i, 3 * b + j] += (
                                w_gg * fft[i, j]
                                + mu_fg[a, j] * fg[b, i]
                                + lam_fg[a, i] * fg[b, j]
                                + kappa_qg[a, i] * qg[b, j]
                                - swapped_qg[a, j] * qg[b, i]
                            )
                        ke[3 * a + i, 3 * b + i] += w_gsg
        for r in range(size):  # mirrored in the local array, then added in one contiguous sweep
            for c in range(r + 1, size):
                ke[c, r] = ke[r, c]
        flat = ke.ravel()
        where = positions[el]
        for t in range(size * size):
            data[where[t]] += flat[t]
    return energy, True


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
    n_checks = checks.shape[1]
    xe = np.empty((3, k))
    ue = np.empty((3, k))
    h = np.empty((3, 3))
    f = np.empty((3, 3))
    cof = np.empty((3, 3))
    e_ = np.empty((3, 3))
    s_ = np.empty((3, 3))
    energy = 0.0
    for el in range(m):
        _gather(x, dofs, el, xe)
        _gather(u, dofs, el, ue)
        lowest = np.inf
        for c in range(n_checks):
            _gradient(xe, checks[el, c], f, 0.0)
            lowest = _smaller(lowest, _determinant(f))
        largest = 0.0
        for q in range(n_points):
            _gradient(ue, grads[el, q], h, 0.0)  # H = grad u
            _gradient(xe, grads[el, q], f, 0.0)  # F = grad x
            det = _cofactor(f, cof)
            lowest = _smaller(lowest, det)
            tr, e_square, excess = _strain(h, e_)
            log_j = _log_volume_ratio(excess, det)
            energy += weights[el, q] * (0.5 * lam[el] * tr * tr + mu[el] * e_square + 0.5 * kappa[el] * log_j * log_j)
            # S = lam tr E I + 2 mu E + kappa ln J C^-1, C^-1 = F^-1 F^-T = (cof / det)^T (cof / det)
            penalty = kappa[el] * log_j / (det * det)
            finite = True
            for i in range(3):
                for j in range(3):
                    total = 0.0
                    for l in range(3):
                        total += cof[l, i] * cof[l, j]
                    s_[i, j] = 2.0 * mu[el] * e_[i, j] + (lam[el] * tr if i == j else 0.0) + penalty * total
                    if not np.isfinite(s_[i, j]):
                        finite = False
            if not finite:
                largest = np.inf
                continue
            low = _lowest_eigenvalue(s_)
            trace = s_[0, 0] + s_[1, 1] + s_[2, 2]
            # the highest eigenvalue: the lowest of -S
            for i in range(3):
                for j in range(3):
                    s_[i, j] = -s_[i, j]
            high = -_lowest_eigenvalue(s_)
            value = max(abs(low), abs(high))
            if not np.isfinite(value) or not np.isfinite(trace):
                value = np.inf
            largest = max(largest, value)
        ratio[el] = lowest
        stress[el] = largest
        if not lowest > 0.0:
            energy = np.inf
    return energy
