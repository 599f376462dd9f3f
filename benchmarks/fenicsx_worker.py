"""The DOLFINx side of ``bench_fem_vs_fenicsx.py``: one case solved with DOLFINx in every candidate configuration.

Runs under the Python 3.12 of the benchmark's own virtual environment (DOLFINx's wheel needs it) and imports
nothing of surgiplan::

    out/.fenicsx-venv/bin/python benchmarks/fenicsx_worker.py CASE.npz OUT.npz

The case (mesh, materials, loads, base plane, constraints, start, stopping rule) comes from
``bench_fem_vs_fenicsx.export_case``; the positions, energies, reactions and times of every configuration go
back in ``OUT.npz``.
"""

from __future__ import annotations

import json
import os
import sys
import time

for _name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

#: DOLFINx's candidate configurations (factorisation, line search, Jacobian lag): MUMPS LU or Cholesky (LDLᵀ);
#: plain Newton (``basic``), backtracking on the residual norm (``bt``, PETSc's default merit) or on the energy
#: (``bt-energy``: the energy as SNES's objective), the critical-point line search (``cp``); a new Jacobian every
#: iteration (lag 1) or modified Newton, keeping one Jacobian and its factorisation for 2 or 3 iterations
#: (``snes_lag_jacobian``)
CONFIGURATIONS = [
    (factor, search, lag)
    for factor in ("cholesky", "lu")
    for lag in (1, 2, 3)
    for search in ("basic", "bt", "bt-energy", "cp")
]
MAX_ITERATIONS = 60
#: a configuration whose warm-up solve takes this many times the fastest warm-up so far is not repeated
SKIP_FACTOR = 3.0


def config_name(factor: str, search: str, lag: int) -> str:
    return f"{factor}+{search}" + (f"+lag{lag}" if lag > 1 else "")


# ----------------------------------------------------------------------------- the DOLFINx side (Python 3.12)


def dolfinx_worker(case_path: str, out_path: str) -> None:
    """Solve one case with DOLFINx in every configuration; write positions, energy, reactions, times."""
    import dolfinx_solver  # noqa: F401, I001  (the wheel's bootstrap: MPI before the bindings)
    import basix.ufl
    import dolfinx
    import dolfinx.fem.petsc as fpetsc
    import ufl
    from dolfinx import fem
    from mpi4py import MPI
    from petsc4py import PETSc

    case = dict(np.load(case_path))
    nodes, cells = case["nodes"], case["cells"].astype(np.int64)
    degree = 1 if cells.shape[1] == 4 else 2
    n = len(nodes)
    if degree == 2:  # VTK's tetra10 node order to DOLFINx's
        cells = cells[:, dolfinx.io.utils.cell_perm_vtk(dolfinx.mesh.CellType.tetrahedron, 10)]
    domain = ufl.Mesh(basix.ufl.element("Lagrange", "tetrahedron", degree, shape=(3,)))
    msh = dolfinx.mesh.create_mesh(MPI.COMM_SELF, cells, domain, nodes)
    V = fem.functionspace(msh, ("Lagrange", degree, (3,)))
    # DOLFINx's dof of each input node: same element on the geometry and the space, position by position
    geometry = msh.geometry.dofmap
    original = np.asarray(msh.geometry.input_global_indices, dtype=np.int64)
    space = V.dofmap.list
    node_of_dof = np.full(V.dofmap.index_map.size_local, -1, dtype=np.int64)
    node_of_dof[space.ravel()] = original[geometry.ravel()]
    assert np.all(node_of_dof >= 0) and len(node_of_dof) == n
    dof_of_node = np.empty(n, dtype=np.int64)
    dof_of_node[node_of_dof] = np.arange(n)
    coordinates = V.tabulate_dof_coordinates()[:, :3]
    assert np.abs(coordinates - nodes[node_of_dof]).max() <= 1e-12 * np.abs(nodes).max()
    # per-cell material, in DOLFINx's cell order
    cell_index = np.asarray(msh.topology.original_cell_index, dtype=np.int64)
    Q = fem.functionspace(msh, ("DG", 0))

    def cellwise(values):
        f = fem.Function(Q)
        f.x.array[:] = np.asarray(values, dtype=float)[cell_index]
        return f

    lam, mu, kappa, rho = (cellwise(case[k]) for k in ("lam", "mu", "kappa", "rho"))
    u = fem.Function(V)
    v, du = ufl.TestFunction(V), ufl.TrialFunction(V)
    identity = ufl.Identity(3)
    F = identity + ufl.grad(u)
    E = 0.5 * (F.T * F - identity)
    J = ufl.det(F)
    W = 0.5 * lam * ufl.tr(E) ** 2 + mu * ufl.inner(E, E) + 0.5 * kappa * ufl.ln(J) ** 2
    dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": degree})
    g = fem.Constant(msh, np.asarray(case["gravity"], dtype=float))
    energy_form = W * dx - rho * ufl.dot(g, u) * dx
    residual = ufl.derivative(energy_form, u, v)
    jacobian = ufl.derivative(residual, u, du)
    residual_c, jacobian_c, energy_c = fem.form(residual), fem.form(jacobian), fem.form(energy_form)

    # nodal terms in DOLFINx's numbering: dead loads, base plane
    dead = np.zeros((n, 3))
    dead[dof_of_node] = case["dead_loads"]
    dead = dead.ravel()
    has_plane = bool(case["plane_stiffness"] > 0)
    plane_point, plane_normal, plane_k = case["plane_point"], case["plane_normal"], float(case["plane_stiffness"])
    rest = np.zeros((n, 3))
    rest[dof_of_node] = nodes
    # prescribed nodes (all three axes) and their targets, as displacements
    held = np.asarray(case["prescribed_nodes"], dtype=np.int64)
    held_dofs = np.sort(dof_of_node[held]).astype(np.int32)
    target = np.zeros((n, 3))
    target[dof_of_node] = case["targets"] - nodes
    u_bc = fem.Function(V)
    u_bc.x.array[:] = target.ravel()
    bcs = [fem.dirichletbc(u_bc, held_dofs)]
    held_flat = (3 * held_dofs[:, None] + np.arange(3)).ravel()
    free_flat = np.setdiff1d(np.arange(3 * n), held_flat)
    start = np.zeros((n, 3))
    start[dof_of_node] = case["start"] - nodes
    start = start.ravel()
    applied = float(case["applied_scale"])
    floor, residual_tol = float(case["force_floor"]), float(case["residual_tol"])
    step_limit = float(case["step_tol"]) * float(case["length_scale"])

    A = fpetsc.create_matrix(jacobian_c)
    A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
    b = fpetsc.create_vector(V)
    x = fpetsc.create_vector(V)
    monitor = {}

    def nodal(positions_disp, gradient=None, blocks=False):
        """Base-plane penalty at displacements (3n,): energy, and its gradient added to ``gradient``."""
        if not has_plane:
            return 0.0, np.empty(0, dtype=np.int64)
        xs = rest + positions_disp.reshape(-1, 3)
        depth = (xs - plane_point) @ plane_normal
        below = np.flatnonzero(depth < 0)
        if gradient is not None and len(below):
            gradient.reshape(-1, 3)[below] += (plane_k * depth[below])[:, None] * plane_normal
        return 0.5 * plane_k * float(depth[below] @ depth[below]), below

    def form_residual(snes, xv, bv):
        xv.copy(u.x.petsc_vec)
        u.x.scatter_forward()
        with bv.localForm() as local:
            local.set(0.0)
        fpetsc.assemble_vector(bv, residual_c)
        values = bv.getArray()
        values -= dead
        nodal(u.x.array, values)
        monitor["reaction"] = float(np.abs(values[held_flat]).max(initial=0.0))
        monitor["gradient"] = values.copy()
        fpetsc.apply_lifting(bv, [jacobian_c], [bcs], x0=[xv], alpha=-1.0)
        fpetsc.set_bc(bv, bcs, xv, -1.0)
        finite = np.all(np.isfinite(bv.getArray(readonly=True)))
        if not finite and hasattr(snes, "setFunctionDomainError"):
            snes.setFunctionDomainError()  # else the non-finite residual itself stops the step (PETSc checks norms)

    def form_jacobian(snes, xv, Amat, Pmat):
        xv.copy(u.x.petsc_vec)
        u.x.scatter_forward()
        Amat.zeroEntries()
        fpetsc.assemble_matrix(Amat, jacobian_c, bcs, diag=1.0)
        monitor["jacobians"] += 1
        if has_plane:
            _, below = nodal(u.x.array)
            held_nodes = np.zeros(n, dtype=bool)
            held_nodes[held_dofs] = True
            below = below[~held_nodes[below]]
            # the Dirichlet diagonal was inserted: flush before adding
            Amat.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
            Amat.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
            block = plane_k * np.outer(plane_normal, plane_normal)
            for node in below:
                rows = (3 * node + np.arange(3)).astype(np.int32)
                Amat.setValues(rows, rows, block, addv=PETSc.InsertMode.ADD_VALUES)
        Amat.assemble()

    def converged(snes, iteration, norms):
        values = b.getArray(readonly=True)
        residual_now = float(np.abs(values[free_flat]).max(initial=0.0))
        pending = float(np.abs(values[held_flat]).max(initial=0.0))  # (g - x) on prescribed dofs
        current = x.getArray(readonly=True)
        step = np.inf if monitor["previous"] is None else float(np.abs(current - monitor["previous"]).max())
        monitor["previous"] = current.copy()
        scale = max(applied, monitor["reaction"], floor)
        monitor["residual"], monitor["scale"] = residual_now, scale
        if not np.isfinite(residual_now):
            return PETSc.SNES.ConvergedReason.DIVERGED_FNORM_NAN
        if pending == 0.0 and residual_now <= residual_tol * scale and step <= step_limit:
            return PETSc.SNES.ConvergedReason.CONVERGED_FNORM_ABS
        if iteration >= MAX_ITERATIONS:
            return PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT
        return PETSc.SNES.ConvergedReason.ITERATING

    def objective(snes, xv):
        """The energy at x: what ``bt`` backtracks on when it is given an objective (PETSc's SNESSetObjective)."""
        xv.copy(u.x.petsc_vec)
        u.x.scatter_forward()
        contact, _ = nodal(u.x.array)
        return fem.assemble_scalar(energy_c) - float(dead @ u.x.array) + contact

    results = {}
    repeats = int(case["repeats"])
    fastest_warmup = np.inf
    options = PETSc.Options()
    for index, (factor, search, lag) in enumerate(CONFIGURATIONS):
        name = config_name(factor, search, lag)
        snes = PETSc.SNES().create(MPI.COMM_SELF)
        # modified Newton: a new Jacobian (and factorisation) every ``lag`` iterations (petsc4py has no setter for
        # it: the options database, under a prefix of this solver's own); each solve starts with a new one
        prefix = f"c{index}_"
        snes.setOptionsPrefix(prefix)
        options[f"{prefix}snes_lag_jacobian"] = lag
        snes.setFromOptions()
        snes.setFunction(form_residual, b)
        snes.setJacobian(form_jacobian, A)
        if search == "bt-energy":
            snes.setObjective(objective)
        snes.setType("newtonls")
        snes.getLineSearch().setType("bt" if search == "bt-energy" else search)
        snes.setTolerances(rtol=0.0, atol=0.0, stol=0.0, max_it=MAX_ITERATIONS)
        snes.setConvergenceTest(converged)
        ksp = snes.getKSP()
        ksp.setType("preonly")
        pc = ksp.getPC()
        pc.setType(factor)
        pc.setFactorSolverType("mumps")
        times, outcome, skipped = [], None, False
        for run in range(repeats + 1):  # the first is the warm-up
            x.getArray()[:] = start
            monitor.update(previous=None, jacobians=0, reaction=0.0)
            started = time.perf_counter()
            snes.solve(None, x)
            elapsed = time.perf_counter() - started
            reason = snes.getConvergedReason()
            outcome = (reason, snes.getIterationNumber(), monitor["jacobians"])
            if reason <= 0:
                break
            if run == 0:
                # a configuration whose warm-up takes several times the fastest warm-up so far cannot be the
                # fastest: its repeats are skipped (the warm-up time is kept, marked)
                if elapsed > SKIP_FACTOR * fastest_warmup:
                    times, skipped = [elapsed], True
                    break
                fastest_warmup = min(fastest_warmup, elapsed)
            else:
                times.append(elapsed)
        reason, iterations, jacobians = outcome
        entry = {"converged": bool(reason > 0), "reason": int(reason), "iterations": int(iterations)}
        entry["factorizations"] = int(jacobians)
        entry["times"] = times
        entry["skipped"] = skipped  # times = [the warm-up]: several times slower than the fastest
        if reason > 0:
            x.copy(u.x.petsc_vec)
            u.x.scatter_forward()
            contact, _ = nodal(u.x.array)
            energy = fem.assemble_scalar(energy_c) - float(dead @ u.x.array) + contact
            displacement = u.x.array.reshape(-1, 3)[dof_of_node]
            gradient = monitor["gradient"].reshape(-1, 3)[dof_of_node]
            entry.update(energy=float(energy), residual=monitor["residual"], scale=monitor["scale"])
            results[name] = (entry, nodes + displacement, gradient)
        else:
            results[name] = (entry, None, None)
        snes.destroy()
    payload = {"configs": json.dumps({k: v[0] for k, v in results.items()}), "dolfinx": dolfinx.__version__}
    payload["petsc"] = ".".join(map(str, PETSc.Sys.getVersion()))
    for name, (_, positions, gradient) in results.items():
        if positions is not None:
            payload[f"positions:{name}"] = positions
            payload[f"gradient:{name}"] = gradient
    np.savez(out_path, **payload)


if __name__ == "__main__":
    dolfinx_worker(sys.argv[1], sys.argv[2])
