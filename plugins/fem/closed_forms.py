"""Determinant and cofactors of 3 x 3 matrices in closed form, indexed ``f[i][j]``.

``f`` may be a components-first array with trailing axes (``(3, 3, m)`` for
a batch of elements in :mod:`.stvk`'s numpy kernel) or one matrix as rows of
scalars (a 3-tuple of 3-tuples in :mod:`.kernels`' compiled one, which
compiles these same functions with numba and keeps the entries in
registers): one source for the formulas both kernels use, with the same
operations in the same order, so both round alike.
"""

from __future__ import annotations


def determinant(f):
    """det F by cofactor expansion along the first row."""
    return (
        f[0][0] * (f[1][1] * f[2][2] - f[1][2] * f[2][1])
        + f[0][1] * (f[1][2] * f[2][0] - f[1][0] * f[2][2])
        + f[0][2] * (f[1][0] * f[2][1] - f[1][1] * f[2][0])
    )


def cofactor(f):
    """det F (the same expansion as :func:`determinant`) and cof F = det(F) F^-T as rows ``c[i][j]``."""
    c00 = f[1][1] * f[2][2] - f[1][2] * f[2][1]
    c01 = f[1][2] * f[2][0] - f[1][0] * f[2][2]
    c02 = f[1][0] * f[2][1] - f[1][1] * f[2][0]
    c10 = f[0][2] * f[2][1] - f[0][1] * f[2][2]
    c11 = f[0][0] * f[2][2] - f[0][2] * f[2][0]
    c12 = f[0][1] * f[2][0] - f[0][0] * f[2][1]
    c20 = f[0][1] * f[1][2] - f[0][2] * f[1][1]
    c21 = f[0][2] * f[1][0] - f[0][0] * f[1][2]
    c22 = f[0][0] * f[1][1] - f[0][1] * f[1][0]
    det = f[0][0] * c00 + f[0][1] * c01 + f[0][2] * c02
    return det, ((c00, c01, c02), (c10, c11, c12), (c20, c21, c22))
