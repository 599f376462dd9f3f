"""Sparse tangent assembly by precomputed index arrays, and its direct solver.

The global tangent of a mesh always has the same sparsity pattern, whatever
the deformation and whatever nodes are held. :class:`TangentPattern`
computes once:

* for SuperLU, a fill-reducing ordering of the degrees of freedom
  (minimum degree on A^T + A), applied to the pattern itself, so that every
  later factorisation skips the ordering (``permc_spec="NATURAL"``); for
  PARDISO, its symbolic analysis, on the first factorisation
  (:mod:`.linear`);
* the compressed-column pattern in that order, and for each of the 144
  (linear) or 900 (quadratic) entries of every element tangent the position
  it adds to (assembly is one ``np.bincount``);
* the positions of the diagonal and of each node's 3 x 3 diagonal block
  (nodal terms such as base contact).

Prescribed degrees of freedom keep the pattern: their rows and columns are
zeroed and their diagonal set to a typical stiffness (:meth:`constrain`), so
one ordering serves every grasp. Entry masks are cached per constraint set.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .linear import PardisoSolver, resolve, superlu_factor


class TangentPattern:
    """The fixed sparsity pattern of a mesh's tangent, and how to fill and factor it.

    ``dofs`` (k, 3, m): global degree of freedom of each element's node and
    axis (``3 node + axis``), k = 4 or 10 nodes per element; ``n_dofs``: 3 n;
    ``solver``: ``auto``, ``pardiso`` or ``superlu`` (:func:`.linear.resolve`).
    """

    def __init__(self, dofs: np.ndarray, n_dofs: int, solver: str = "auto") -> None:
        self.n_dofs = n_dofs
        #: the sparse direct solver that factors this pattern's matrices: "pardiso" or "superlu"
        self.solver = resolve(solver)
        size = 3 * dofs.shape[0]
        d = dofs.reshape(size, -1)
        m = d.shape[1]
        rows = np.broadcast_to(d[:, None, :], (size, size, m)).ravel()
        cols = np.broadcast_to(d[None, :, :], (size, size, m)).ravel()
        # order[old] = new: SuperLU factors in this order; PARDISO orders the matrix itself (METIS)
        order = self._ordering(rows, cols, n_dofs) if self.solver == "superlu" else np.arange(n_dofs)
        self.new_of_old = order
        self.old_of_new = np.argsort(order)
        key = order[cols].astype(np.int64) * n_dofs + order[rows]  # column-major: CSC
        unique, self.element_map = np.unique(key, return_inverse=True)
        self._keys = unique
        self.nnz = len(unique)
        self.indices = (unique % n_dofs).astype(np.int32)  # row of each entry (new numbering)
        self.entry_cols = (unique // n_dofs).astype(np.int32)
        self.indptr = np.searchsorted(self.entry_cols, np.arange(n_dofs + 1)).astype(np.int32)
        self.diagonal = self._positions(np.arange(n_dofs), np.arange(n_dofs))
        node_dofs = np.arange(n_dofs).reshape(-1, 3)
        r = np.broadcast_to(node_dofs[:, :, None], (len(node_dofs), 3, 3))
        c = np.broadcast_to(node_dofs[:, None, :], (len(node_dofs), 3, 3))
        #: (n, 3, 3) positions of each node's diagonal block
        self.node_blocks = self._positions(r.ravel(), c.ravel()).reshape(-1, 3, 3)
        self._masks: OrderedDict[bytes, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._pardiso: PardisoSolver | None = None

    @staticmethod
    def _ordering(rows, cols, n: int) -> np.ndarray:
        """A fill-reducing symmetric ordering: ``order[old dof] = new dof``."""
        pattern = sp.csc_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
        pattern.sum_duplicates()
        # any values with this pattern will do for SuperLU to compute its ordering: make it safely definite
        pattern.data[:] = -1.0
        pattern.setdiag(np.asarray(abs(pattern).sum(axis=1)).ravel() + 1.0)
        lu = sla.splu(pattern, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        return np.asarray(lu.perm_c)

    def _positions(self, rows_old, cols_old) -> np.ndarray:
        key = self.new_of_old[cols_old].astype(np.int64) * self.n_dofs + self.new_of_old[rows_old]
        pos = np.searchsorted(self._keys, key)
        if np.any(pos >= self.nnz) or np.any(self._keys[np.minimum(pos, self.nnz - 1)] != key):
            raise ValueError("entry not in the tangent's pattern")
        return pos

    # ------------------------------------------------------------------ assembly
    def assemble(self, element_matrices: np.ndarray) -> np.ndarray:
        """CSC values (nnz,) of the sum of element matrices (3k, 3k, m)."""
        return np.bincount(self.element_map, weights=element_matrices.ravel(), minlength=self.nnz)

    def add_node_blocks(self, data: np.ndarray, nodes: np.ndarray, blocks: np.ndarray) -> None:
        """Add 3 x 3 blocks (k, 3, 3) on the diagonal of the given nodes (k,), in place."""
        np.add.at(data, self.node_blocks[nodes].ravel(), blocks.ravel())

    def matrix(self, data: np.ndarray) -> sp.csc_matrix:
        """The tangent in the pattern's (permuted) numbering."""
        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.n_dofs, self.n_dofs))

    def matvec(self, data: np.ndarray, vector: np.ndarray) -> np.ndarray:
        """K @ v with v and the result in the original numbering."""
        return (self.matrix(data) @ vector[self.old_of_new])[self.new_of_old]

    # ------------------------------------------------------------------ constraints
    def constrain(self, data: np.ndarray, prescribed: np.ndarray) -> np.ndarray:
        """A copy of ``data`` with prescribed dofs (bool (3n,), original numbering) decoupled.

        Their rows and columns are zero and their diagonal is the mean
        diagonal of the free ones (to keep the matrix well scaled).
        """
        entries, diag = self._mask(prescribed)
        out = data.copy()
        out[entries] = 0.0
        free_diag = data[self.diagonal[~prescribed]]
        out[diag] = np.abs(free_diag).mean() if len(free_diag) else 1.0
        return out

    def _mask(self, prescribed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = np.packbits(prescribed).tobytes()
        if key in self._masks:
            self._masks.move_to_end(key)
            return self._masks[key]
        new = np.zeros(self.n_dofs, dtype=bool)
        new[self.new_of_old[prescribed]] = True
        entries = np.flatnonzero(new[self.indices] | new[self.entry_cols])
        value = (entries, self.diagonal[prescribed])
        self._masks[key] = value
        if len(self._masks) > 8:
            self._masks.popitem(last=False)
        return value

    def factorize(self, data: np.ndarray, definite_only: bool = False):
        """Factors of the (constrained) tangent: ``solve(rhs)``, ``positive_pivots()``.

        Raises :class:`~.linear.SingularMatrix` (a ``RuntimeError``) when it
        is singular; with ``definite_only``, PARDISO raises
        :class:`~.linear.NotPositiveDefinite` (a ``RuntimeError``) instead of
        factoring an indefinite matrix (SuperLU returns the factor, whose
        ``positive_pivots()`` says so).
        """
        if self.solver == "pardiso":
            if self._pardiso is None:
                self._pardiso = PardisoSolver(self.indptr, self.indices, self.entry_cols)
            return self._pardiso.factorize(data, definite_only)
        return superlu_factor(self.matrix(data), self.new_of_old, self.old_of_new)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_masks"] = OrderedDict()
        state["_pardiso"] = None  # a solver handle lives in one process: analysed again on first use
        return state
