"""Sparse direct solvers for the tangent: Intel oneMKL PARDISO (through pypardiso), SuperLU as the fallback.

The tangent of a mesh keeps one sparsity pattern for the model's life
(:class:`~.assembly.TangentPattern`), so everything a direct solver does
from the pattern alone is done once:

* **PARDISO** (``pip install 'surgiplan[pardiso]'``: pypardiso, which loads
  the oneMKL runtime from the ``mkl`` wheel). A tangent is first factored
  as real symmetric positive definite (``mtype = 2``, Cholesky): that
  succeeds exactly when it is definite, which is all Newton's ``auto``
  policy needs to know, and costs about a seventh less than LDLᵀ (on the
  quadratic 40x4x4 cantilever 91 against 105 ms). Only where it fails and
  the caller wants the indefinite factor itself (``tangent: exact``, the
  surrogate) is it factored as real symmetric indefinite (``mtype = -2``):
  LDLᵀ with Bunch-Kaufman pivoting inside supernodes, which reports the
  inertia, the numbers of positive and negative pivots (``iparm[21]``,
  ``iparm[22]``); a perturbed pivot (``iparm[13]``, a pivot PARDISO could
  not take as it was) counts as indefinite, and a zero pivot as singular.
  The symbolic analysis (ordering: METIS or minimum degree, whichever
  fills less; supernodes, memory) is computed once per pattern and matrix
  type (phase 11) and every tangent after that, in any Newton step of any
  solve, is a numerical factorisation only (phase 22). Several
  factorisations of the same pattern live side by side (PARDISO's
  ``maxfct``/``mnum``: a solve keeps the factor at its start positions for
  later solves while it factors new tangents), each released when its
  :class:`PardisoFactor` is garbage-collected. One thread (``mkl_domain``
  PARDISO): answers are the same bits run after run, and the executor's
  worker processes, not threads, use the cores.
* **SuperLU** (scipy, needs nothing): LU without off-diagonal pivoting on
  the pattern pre-ordered by minimum degree (``permc_spec="NATURAL"``), so a
  factorisation does no ordering work; definiteness from the signs of U's
  diagonal (for a symmetric matrix factored on its diagonal, the pivots).

``linear_solver: auto`` picks PARDISO when pypardiso and oneMKL load, else
SuperLU. Measured on this project's tangents (``benchmarks/bench_fem_solvers.py``).
"""

from __future__ import annotations

import ctypes
import threading
import weakref

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from surgiplan.errors import SurgiplanError

#: real symmetric indefinite (LDLᵀ, inertia) and positive definite (Cholesky)
MTYPE = -2
CHOLESKY = 2
#: numerical factorisations one PARDISO handle (one symbolic analysis) keeps side by side
SLOTS = 16
#: free slots per handle whose factor memory is kept for reuse
KEPT = 2
_MKL_DOMAIN_PARDISO = 4

_LOCK = threading.Lock()
_NO_RHS = np.zeros(1)
_PARDISO_FUNCTION = None
_PARDISO_ERROR: str | None = None


def _load_pardiso():
    """oneMKL's ``pardiso`` as a ctypes function (via pypardiso's loader), or None and why not."""
    global _PARDISO_FUNCTION, _PARDISO_ERROR
    with _LOCK:
        if _PARDISO_FUNCTION is None and _PARDISO_ERROR is None:
            try:
                from pypardiso.pardiso_wrapper import PyPardisoSolver

                wrapper = PyPardisoSolver()
                function = wrapper._mkl_pardiso
                setter = getattr(wrapper.libmkl, "MKL_Domain_Set_Num_Threads", None)
                if setter is not None:
                    setter.argtypes = [ctypes.c_int, ctypes.c_int]
                    setter(1, _MKL_DOMAIN_PARDISO)
                _PARDISO_FUNCTION = function
            except Exception as exc:  # not installed, or oneMKL missing: SuperLU does the work
                _PARDISO_ERROR = f"{type(exc).__name__}: {exc}"
    return _PARDISO_FUNCTION, _PARDISO_ERROR


def pardiso_available() -> tuple[bool, str]:
    """Whether PARDISO can be used here, and why not."""
    function, error = _load_pardiso()
    return function is not None, error or ""


def resolve(name: str) -> str:
    """The solver ``linear_solver`` names: ``auto`` is PARDISO where it loads, else SuperLU."""
    if name == "auto":
        return "pardiso" if pardiso_available()[0] else "superlu"
    if name == "pardiso" and not pardiso_available()[0]:
        raise RuntimeError(
            "linear_solver 'pardiso' needs pypardiso and Intel oneMKL (pip install 'surgiplan[pardiso]'): "
            + pardiso_available()[1]
        )
    return name


class FactorizationError(SurgiplanError, RuntimeError):
    """A sparse factorisation failed: a numerical condition of the matrix, not a mistake in the user's input.

    The solver catches these and tries another tangent (they stay ``RuntimeError`` for callers that catch
    the solvers' failures as such); should one ever reach the command line, it exits with status 1, as a
    failed stage does (:class:`~surgiplan.errors.StageError`), not 2.
    """

    exit_code = 1


class SingularMatrix(FactorizationError):
    """The (constrained) tangent is singular: a zero pivot."""


class NotPositiveDefinite(FactorizationError):
    """A Cholesky factorisation met a pivot that is not positive: the matrix is not positive definite."""


# ----------------------------------------------------------------------------- SuperLU


class SuperLUFactor:
    """SuperLU's LU factors of a pre-ordered symmetric matrix; solves in the original numbering."""

    def __init__(self, lu, new_of_old: np.ndarray, old_of_new: np.ndarray) -> None:
        self._lu = lu
        self._new_of_old = new_of_old
        self._old_of_new = old_of_new

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return self._lu.solve(rhs[self._old_of_new])[self._new_of_old]

    def positive_pivots(self) -> bool:
        """All pivots (U's diagonal) positive: a symmetric matrix factored on its diagonal is then definite."""
        if not np.array_equal(self._lu.perm_r, np.arange(len(self._new_of_old))):
            return False  # SuperLU pivoted off the diagonal: the test does not apply
        return bool(np.all(self._lu.U.diagonal() > 0))


def superlu_factor(matrix: sp.csc_matrix, new_of_old, old_of_new) -> SuperLUFactor:
    try:
        lu = sla.splu(matrix, permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except RuntimeError as exc:  # "Factor is exactly singular"
        raise SingularMatrix(str(exc)) from None
    return SuperLUFactor(lu, new_of_old, old_of_new)


# ----------------------------------------------------------------------------- PARDISO


class PardisoHandle:
    """One PARDISO handle: the symbolic analysis of a pattern and up to ``SLOTS`` numerical factorisations.

    ``indptr``, ``indices``: the upper triangle of the symmetric pattern as
    CSR arrays (zero-based, sorted, the diagonal present); values are passed
    in that entry order.
    """

    def __init__(
        self, indptr: np.ndarray, indices: np.ndarray, ordering: int | None = None, mtype: int = MTYPE
    ) -> None:
        function, error = _load_pardiso()
        if function is None:
            raise RuntimeError(f"PARDISO is not available: {error}")
        self._function = function
        self.mtype = mtype
        self.n = len(indptr) - 1
        self.indptr = np.ascontiguousarray(indptr, dtype=np.int32)
        self.indices = np.ascontiguousarray(indices, dtype=np.int32)
        self.pt = np.zeros(64, dtype=np.int64)
        self.iparm = np.zeros(64, dtype=np.int32)
        iparm = self.iparm
        iparm[0] = 1  # these values, not the defaults
        iparm[1] = 2 if ordering is None else ordering  # 2: METIS nested dissection, 0: minimum degree
        iparm[9] = 8  # pivot perturbation 1e-8 (reported, and then the factor counts as indefinite)
        iparm[10] = 0  # no scaling
        iparm[12] = 0  # no weighted matching: the analysis depends on the pattern alone
        iparm[17] = -1  # report the factor's non-zeros
        iparm[20] = 1  # Bunch-Kaufman 1x1 and 2x2 pivots
        iparm[26] = 0  # no matrix checker
        iparm[34] = 1  # zero-based indices
        self.free = list(range(SLOTS, 0, -1))
        #: free slots whose memory is kept (a new factorisation there reuses it, see :meth:`_release`)
        self.kept: list[int] = []
        self.analysed = False
        self.closed = False
        self._lock = threading.RLock()  # re-entered: a failed factorisation releases its slot under the lock
        self._arguments: tuple | None = None  # see _call
        weakref.finalize(self, PardisoHandle._release_all, self._function, self.pt, self.iparm, self.n, mtype)

    def _call(self, phase: int, slot: int, values: np.ndarray, rhs: np.ndarray | None = None) -> np.ndarray | None:
        if rhs is None:
            b = x = _NO_RHS
        else:
            b = np.ascontiguousarray(rhs, dtype=float)
            x = np.empty_like(b)
        if self._arguments is None:  # the pointers that never change, built once (20 µs a call otherwise)
            c_int = ctypes.POINTER(ctypes.c_int32)
            self._phase, self._slot, self._error = ctypes.c_int32(0), ctypes.c_int32(0), ctypes.c_int32(0)
            self._arguments = (
                self.pt.ctypes.data_as(ctypes.POINTER(ctypes.c_int64)),
                ctypes.byref(ctypes.c_int32(SLOTS)),  # maxfct
                ctypes.byref(self._slot),  # mnum
                ctypes.byref(ctypes.c_int32(self.mtype)),
                ctypes.byref(self._phase),
                ctypes.byref(ctypes.c_int32(self.n)),
                self.indptr.ctypes.data_as(c_int),
                self.indices.ctypes.data_as(c_int),
                ctypes.byref(ctypes.c_int32(1)),  # nrhs
                self.iparm.ctypes.data_as(c_int),
                ctypes.byref(ctypes.c_int32(0)),  # msglvl
                ctypes.byref(self._error),
            )
        pt, maxfct, mnum, mtype, phase_, n, indptr, indices, nrhs, iparm, msglvl, error_ = self._arguments
        self._phase.value, self._slot.value, self._error.value = phase, slot, 0
        # values, b and x by address (the function's argument types take them as void pointers); no perm
        self._function(
            pt, maxfct, mnum, mtype, phase_, n, values.ctypes.data, indptr, indices, None, nrhs, iparm, msglvl,
            b.ctypes.data, x.ctypes.data, error_,
        )  # fmt: skip
        error = self._error
        if error.value == -4:
            if self.mtype == CHOLESKY:
                raise NotPositiveDefinite("PARDISO (Cholesky): a pivot is not positive")
            raise SingularMatrix("PARDISO: zero pivot")
        if error.value != 0:
            raise RuntimeError(f"PARDISO failed (phase {phase}, error {error.value})")
        return x if rhs is not None else None

    def factorize(self, values: np.ndarray) -> PardisoFactor | None:
        """A numerical factorisation of these values (upper-triangle order), or None when no slot is free."""
        values = np.ascontiguousarray(values, dtype=float)
        with self._lock:
            if not (self.kept or self.free):
                return None
            slot = self.kept.pop() if self.kept else self.free.pop()
            try:
                if not self.analysed:
                    self._analyse(slot, values)
                    self.analysed = True
                self._call(22, slot, values)
            except BaseException:
                self._release(slot)
                raise
            if self.mtype == CHOLESKY:  # it succeeded: every pivot positive
                positive, negative, perturbed = self.n, 0, 0
            else:
                positive, negative, perturbed = int(self.iparm[21]), int(self.iparm[22]), int(self.iparm[13])
        if positive + negative < self.n:
            self._release(slot)
            raise SingularMatrix(f"PARDISO: {self.n - positive - negative} zero pivots")
        return PardisoFactor(self, slot, values, positive, negative, perturbed)

    def _analyse(self, slot: int, values: np.ndarray) -> None:
        """The symbolic analysis (phase 11): once per pattern."""
        self._call(11, slot, values)

    def analyse(self, values: np.ndarray) -> int:
        """Analyse now (before any factorisation); returns the predicted non-zeros of the factor."""
        with self._lock:
            if not self.analysed:
                self._analyse((self.kept or self.free)[-1], values)
                self.analysed = True
            return int(self.iparm[17])

    @property
    def ordering(self) -> int:
        return int(self.iparm[1])

    def solve(self, slot: int, values: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        with self._lock:
            return self._call(33, slot, values, rhs)

    def _release(self, slot: int) -> None:
        """A factor is no longer used: its slot is free. The memory of up to ``KEPT`` slots is kept for the
        next factorisations (freeing a factor of 19,683 unknowns costs 3 ms, a tenth of a solve's
        Newton step); the rest is freed."""
        with self._lock:
            if not self.closed and len(self.kept) < KEPT:
                self.kept.append(slot)
                return
            if not self.closed:
                try:
                    self._call(0, slot, np.zeros(1))  # free this factor's memory
                except RuntimeError:
                    pass
            self.free.append(slot)

    @staticmethod
    def _release_all(function, pt, iparm, n, mtype) -> None:
        error = ctypes.c_int32(0)
        dummy = np.zeros(1)
        index = np.zeros(1, dtype=np.int32)
        c_int = ctypes.POINTER(ctypes.c_int32)
        c_double = ctypes.POINTER(ctypes.c_double)
        function(
            pt.ctypes.data_as(ctypes.POINTER(ctypes.c_int64)),
            ctypes.byref(ctypes.c_int32(SLOTS)),
            ctypes.byref(ctypes.c_int32(1)),
            ctypes.byref(ctypes.c_int32(mtype)),
            ctypes.byref(ctypes.c_int32(-1)),
            ctypes.byref(ctypes.c_int32(n)),
            dummy.ctypes.data_as(c_double),
            index.ctypes.data_as(c_int),
            index.ctypes.data_as(c_int),
            None,
            ctypes.byref(ctypes.c_int32(1)),
            iparm.ctypes.data_as(c_int),
            ctypes.byref(ctypes.c_int32(0)),
            dummy.ctypes.data_as(c_double),
            dummy.ctypes.data_as(c_double),
            ctypes.byref(error),
        )


class PardisoFactor:
    """One numerical factorisation held by a :class:`PardisoHandle`; released when collected."""

    def __init__(self, handle: PardisoHandle, slot: int, values, positive: int, negative: int, perturbed: int):
        self._handle = handle
        self._slot = slot
        self._values = values  # PARDISO's solve phase reads the matrix again (iterative refinement)
        #: (positive, negative, zero) pivots: Sylvester's inertia of the factored matrix
        self.inertia = (positive, negative, handle.n - positive - negative)
        self.perturbed = perturbed
        self._finalizer = weakref.finalize(self, handle._release, slot)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return self._handle.solve(self._slot, self._values, rhs)

    def positive_pivots(self) -> bool:
        """Positive definite: every pivot positive and none perturbed (from the factorisation itself)."""
        return self.inertia[0] == self._handle.n and self.perturbed == 0


class PardisoSolver:
    """PARDISO for one pattern: CSR upper triangle of its (symmetric) CSC arrays; Cholesky and LDLᵀ handles."""

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, entry_cols: np.ndarray) -> None:
        n = len(indptr) - 1
        # column j's rows i >= j of the CSC arrays are, read as CSR, row j's columns i >= j: the upper triangle
        lower = indices >= entry_cols
        self.positions = np.flatnonzero(lower)
        counts = np.bincount(entry_cols[lower], minlength=n)
        self.indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        self.indices = indices[lower].astype(np.int32)
        #: LDLᵀ (indefinite) handles and Cholesky handles, each with its analysis and slots
        self.handles: list[PardisoHandle] = []
        self.cholesky: list[PardisoHandle] = []
        #: the fill-reducing ordering chosen at the first analysis (2: METIS, 0: minimum degree)
        self.ordering: int | None = None

    def factorize(self, data: np.ndarray, definite_only: bool = False) -> PardisoFactor:
        """Cholesky when the matrix is positive definite, else LDLᵀ (with its inertia).

        ``definite_only``: the caller needs a factor only if the matrix is
        positive definite: raise :class:`NotPositiveDefinite` instead of
        factoring it again as indefinite.
        """
        values = data[self.positions]
        try:
            return self._factorize(self.cholesky, values, CHOLESKY)
        except NotPositiveDefinite:
            if definite_only:
                raise
        return self._factorize(self.handles, values, MTYPE)

    def _factorize(self, handles: list[PardisoHandle], values: np.ndarray, mtype: int) -> PardisoFactor:
        if not handles:
            if self.ordering is None:
                # nested dissection (METIS) or minimum degree, whichever predicts the smaller factor: a thin flap
                # fills less with minimum degree (0.29 against 0.34 million non-zeros), a solid cantilever with
                # METIS; the fill depends on the pattern alone, so the choice serves both matrix types
                trials = [PardisoHandle(self.indptr, self.indices, ordering, mtype) for ordering in (2, 0)]
                fill = [handle.analyse(values) for handle in trials]
                chosen = trials[int(np.argmin(fill))]
                self.ordering = chosen.ordering
                handles.append(chosen)
            else:
                handles.append(PardisoHandle(self.indptr, self.indices, self.ordering, mtype))
        for handle in handles:
            factor = handle.factorize(values)
            if factor is not None:
                return factor
        # every slot taken: another analysis, with the ordering the first one chose
        handles.append(PardisoHandle(self.indptr, self.indices, self.ordering, mtype))
        return handles[-1].factorize(values)
