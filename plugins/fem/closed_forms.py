"""Determinant and cofactors of 3 x 3 matrices in closed form, components first.

``f`` is indexed ``f[i, j]`` and may carry any trailing axes (``(3, 3, m)``
for a batch of elements in :mod:`.stvk`'s numpy kernel, ``(3, 3)`` for one
matrix in :mod:`.kernels`' compiled one, which compiles these same
functions with numba): one source for the formulas both kernels use, with
the same operations in the same order, so both round alike.
"""

from __future__ import annotations


def determinant(f):
    """det F by cofactor expansion along the first row."""
    return (
        f[0, 0] * (f[1, 1] * f[2, 2] - f[1, 2] * f[2, 1])
        + f[0, 1] * (f[1, 2] * f[2, 0] - f[1, 0] * f[2, 2])
        + f[0, 2] * (f[1, 0] * f[2, 1] - f[1, 1] * f[2, 0])
    )


def cofactor(f, cof):
    """Write cof F = det(F) F^-T into ``cof`` (same shape as ``f``); returns det F (the same expansion)."""
    cof[0, 0] = f[1, 1] * f[2, 2] - f[1, 2] * f[2, 1]
    cof[0, 1] = f[1, 2] * f[2, 0] - f[1, 0] * f[2, 2]
    cof[0, 2] = f[1, 0] * f[2, 1] - f[1, 1] * f[2, 0]
    cof[1, 0] = f[0, 2] * f[2, 1] - f[0, 1] * f[2, 2]
    cof[1, 1] = f[0, 0] * f[2, 2] - f[0, 2] * f[2, 0]
    cof[1, 2] = f[0, 1] * f[2, 0] - f[0, 0] * f[2, 1]
    cof[2, 0] = f[0, 1] * f[1, 2] - f[0, 2] * f[1, 1]
    cof[2, 1] = f[0, 2] * f[1, 0] - f[0, 0] * f[1, 2]
    cof[2, 2] = f[0, 0] * f[1, 1] - f[0, 1] * f[1, 0]
    return f[0, 0] * cof[0, 0] + f[0, 1] * cof[0, 1] + f[0, 2] * cof[0, 2]
