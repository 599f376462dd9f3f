"""stvk's sparse direct solvers on its own tangents: why PARDISO, and what SuperLU (the fallback) costs.

The constrained tangent at an equilibrium of three problems (the paper's
flap, linear 20x20x2, 3,969 unknowns; the flap with quadratic tetrahedra
10x10x1, 3,669; the quadratic cantilever 40x4x4, 19,683), factored by

* SuperLU (scipy) as stvk uses it: the pattern pre-ordered by minimum
  degree once, each factorisation without ordering work; definiteness from
  U's diagonal (which builds U);
* PARDISO (oneMKL via pypardiso) as stvk uses it: Cholesky first (these
  tangents are definite, and its success is the definiteness test), LDLᵀ
  with the inertia from the factorisation where Cholesky fails; one
  symbolic analysis per pattern and matrix type, then numerical
  factorisations only;
* qdldl and cholespy when installed (``pip install '.[bench]'``: they
  are not dependencies): qdldl's numerical refactorisation, cholespy's
  analysis and factorisation (it has no refactorisation).

One thread each (OMP/MKL = 1). Medians of ``--repeats`` after a warm-up.
Not measurable here (recorded in the notes): python-mumps (its only cp311
wheel, 0.0.2, is built for numpy 1 and does not import with numpy 2;
later versions have no cp311 wheel), petsc4py (a source distribution that
builds PETSc, whose MUMPS is downloaded at build time), pymumps and
scikit-sparse (no wheels).

    python benchmarks/bench_fem_solvers.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

for _name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_fem_vs_fenicsx import build_case  # noqa: E402
from common import package_version, save, table  # noqa: E402
from surgiplan.plugins.fem import linear  # noqa: E402
from surgiplan.plugins.fem.assembly import TangentPattern  # noqa: E402

CASES = {
    "flap-lift": "flap, linear 20x20x2",
    "flap-step-p2": "flap, quadratic 10x10x1",
    "cantilever-p2-4": "cantilever, quadratic 40x4x4",
}


def median_time(fn, repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def tangent(name: str):
    model, constraints, start = build_case(name, {"residual_tol": 1e-6, "step_tol": 1e-4})
    state = model.solve(constraints, initial=start)
    prescribed, _ = model._prescribed(constraints)
    _, _, data = model.solver.tangent(state.positions.ravel(), False)
    return model, prescribed, data


def main() -> None:
    load = os.getloadavg()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    if not linear.pardiso_available()[0]:
        print(f"skipped: PARDISO is not installed ({linear.pardiso_available()[1]})")
        return
    rows = []
    for name, what in CASES.items():
        model, prescribed, data = tangent(name)
        dofs, n = model.kernel.dofs, 3 * model.mesh.n_nodes
        started = time.perf_counter()
        superlu = TangentPattern(dofs, n, "superlu")  # the minimum-degree ordering, once
        superlu_setup = time.perf_counter() - started
        pardiso = TangentPattern(dofs, n, "pardiso")
        own = model.solver.pattern  # the model's (PARDISO where installed: the identity numbering)
        matrix = own.matrix(own.constrain(data, prescribed))[np.ix_(own.new_of_old, own.new_of_old)].tocsc()
        values = {}
        for key, pattern in (("superlu", superlu), ("pardiso", pardiso)):  # each pattern's numbering and order
            permuted = matrix[np.ix_(pattern.old_of_new, pattern.old_of_new)].tocsc()
            permuted.sort_indices()
            assert np.array_equal(permuted.indices, pattern.indices) and np.array_equal(permuted.indptr, pattern.indptr)
            values[key] = permuted.data
        started = time.perf_counter()
        first = pardiso.factorize(values["pardiso"])  # the analysis (both orderings tried) and one factorisation
        pardiso_first = time.perf_counter() - started
        solver = pardiso._pardiso
        handle = (solver.cholesky + solver.handles)[0]  # these tangents are definite: Cholesky's handle
        # the same refactorisation as LDLT (Bunch-Kaufman), what stvk does where Cholesky fails
        ldlt = linear.PardisoHandle(solver.indptr, solver.indices, handle.ordering, linear.MTYPE)
        ldlt_values = values["pardiso"][solver.positions]
        ldlt.analyse(ldlt_values)
        row = {
            "matrix": what,
            "unknowns": n,
            "nonzeros": int(matrix.nnz),
            "superlu_ordering_s": round(superlu_setup, 4),
            "superlu_factor_s": round(median_time(lambda: superlu.factorize(values["superlu"]), args.repeats), 4),
            "superlu_factor_and_definiteness_s": round(
                median_time(lambda: superlu.factorize(values["superlu"]).positive_pivots(), args.repeats), 4
            ),
            "pardiso_analysis_and_first_factor_s": round(pardiso_first, 4),
            "pardiso_ordering": {0: "minimum degree", 2: "METIS"}[handle.ordering],
            "pardiso_factor_nonzeros": int(handle.iparm[17]),
            "pardiso_factor_s": round(median_time(lambda: pardiso.factorize(values["pardiso"]), args.repeats), 4),
            "pardiso_method": "Cholesky" if handle.mtype == linear.CHOLESKY else "LDLT",
            "pardiso_ldlt_factor_s": round(median_time(lambda: ldlt.factorize(ldlt_values), args.repeats), 4),
            "pardiso_solve_s": round(median_time(lambda: first.solve(np.ones(n)), args.repeats), 5),
            "pardiso_inertia": list(first.inertia),
        }
        row["pardiso_speedup"] = round(row["superlu_factor_and_definiteness_s"] / row["pardiso_factor_s"], 2)
        upper = sp.triu(matrix, format="csc")
        try:
            import qdldl

            solver = qdldl.Solver(upper, upper=True)
            row["qdldl_refactor_s"] = round(median_time(lambda: solver.update(upper, upper=True), args.repeats), 4)
        except ImportError:
            row["qdldl_refactor_s"] = "not installed"
        try:
            import cholespy

            coo = matrix.tocoo()
            rows_, cols_ = coo.row.astype(np.int32), coo.col.astype(np.int32)
            row["cholespy_analysis_and_factor_s"] = round(
                median_time(
                    lambda: cholespy.CholeskySolverD(n, rows_, cols_, coo.data, cholespy.MatrixType.COO), args.repeats
                ),
                4,
            )
        except ImportError:
            row["cholespy_analysis_and_factor_s"] = "not installed"
        rows.append(row)
        print(
            f"{what}: SuperLU {row['superlu_factor_and_definiteness_s']} s, PARDISO {row['pardiso_factor_s']} s",
            flush=True,
        )
    print(
        table(
            rows,
            [
                "matrix",
                "unknowns",
                "superlu_factor_and_definiteness_s",
                "pardiso_factor_s",
                "pardiso_speedup",
                "pardiso_ordering",
                "qdldl_refactor_s",
                "cholespy_analysis_and_factor_s",
            ],
        )
    )
    note = (
        f"medians of {args.repeats}, one thread; load average at the start {load[0]:.2f} (1 min) on "
        f"{os.cpu_count()} cores shared with other work. Not measurable here: python-mumps (0.0.2, its only cp311 "
        "wheel, is built for numpy 1 and fails to import with numpy 2), petsc4py (source only: builds PETSc, "
        "downloading MUMPS at build time), pymumps and scikit-sparse (no wheels for this platform)"
    )
    peers = {
        name: {"version": package_version(name), "configuration": what}
        for name, what in (
            ("scipy", "SuperLU, pre-ordered as stvk orders it"),
            ("pypardiso", "PARDISO (oneMKL) as stvk calls it: analysis once, refactorisations"),
            ("qdldl", "numerical refactorisation on the analysis"),
            ("cholespy", "Cholesky, no refactorisation"),
        )
    }
    print(f"written: {save('fem_solvers', rows, note, peers=peers)}")


if __name__ == "__main__":
    main()
