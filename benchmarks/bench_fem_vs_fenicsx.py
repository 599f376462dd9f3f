"""stvk against DOLFINx (FEniCSx): the same equilibria, side by side, agreement and time.

Each case is built by surgiplan (``StVKModel``) and handed to DOLFINx
unchanged: the nodes and tetrahedra (linear, or quadratic in VTK order),
the per-element Lamé parameters and volume-penalty modulus, the density and
gravity, the dead loads as nodal forces, the base-plane penalty as a nodal
term, the prescribed degrees of freedom and their targets, and the start
positions. DOLFINx writes the same energy in UFL,

    W = λ/2 (tr E)² + μ tr(E²) + κ/2 (ln J)²,  minus ∫ ρ g · u, minus f · u, plus k/2 Σ min(n·(x-p), 0)²,

integrated with the same quadrature (basix's degree-1 and degree-2 rules on
tetrahedra are surgiplan's one- and four-point rules), its residual and
Jacobian by UFL differentiation (FFCx-compiled kernels), and solves with
PETSc SNES (``newtonls``) and MUMPS. Both stop by the same rule: the
largest residual force on a free degree of freedom at most
``residual_tol`` times the force scale (the largest applied nodal force or
reaction, at least ``1e-9 E h²``), the prescribed motion complete, and the
last step moving no node more than ``step_tol`` times the mean edge length.

DOLFINx runs in the configuration a user would pick, each of: LU or
Cholesky (LDLᵀ, MUMPS ``sym = 2``) by MUMPS with PETSc reusing the symbolic
analysis while the pattern is unchanged (across Newton steps and across
the repeated solves), line search ``basic`` (plain Newton) or ``bt``
(backtracking); the table reports each and compares surgiplan with the
fastest that converged. Times are medians of ``--repeats`` solves after one
warm-up solve, excluding what both sides do once (surgiplan: mesh, element
data, sparsity pattern and its symbolic analysis; DOLFINx: form
compilation, mesh, function spaces, sparsity pattern); surgiplan's
self-intersection check of the deformed surface (part of a state's
validity, work DOLFINx does not do) is off, its stresses are computed;
surgiplan's
factorisations kept from earlier solves are dropped before each timed one
(``clear_caches``), so a repeat never starts with a factored tangent the
first one lacked. One thread on each side (OMP/MKL/OpenBLAS = 1): the
machine has 2 cores shared with other work, so the load average at the
start is recorded.

DOLFINx's wheel (``dolfinx-solver-real``, DOLFINx 0.11 with PETSc and
MUMPS) needs Python 3.12: this script makes its own virtual environment
under ``out/.fenicsx-venv`` (git-ignored) with a Python 3.12 it finds
(``$FENICSX_PYTHON``, ``python3.12`` on the path, pyenv), and is skipped
with the reason where it cannot.

    python benchmarks/bench_fem_vs_fenicsx.py [--quick] [--repeats 5] [--cases NAME ...]

Run as ``python3.12 bench_fem_vs_fenicsx.py --dolfinx-worker CASE.npz OUT.npz`` it is
the DOLFINx side (it then imports nothing of surgiplan).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

for _name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")  # one thread on each side (the DOLFINx process inherits this)

import numpy as np  # noqa: E402  (after the thread counts: BLAS reads them when it loads)

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
VENV = ROOT / "out" / ".fenicsx-venv"
WHEEL = "dolfinx-solver-real==0.11.0.post0"

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


# ----------------------------------------------------------------------------- the environment


def find_python312() -> str | None:
    candidates = [os.environ.get("FENICSX_PYTHON"), shutil.which("python3.12")]
    pyenv = Path(os.environ.get("PYENV_ROOT", Path.home() / ".pyenv")) / "versions"
    candidates += [str(p / "bin" / "python") for p in sorted(pyenv.glob("3.12*"), reverse=True)]
    for candidate in candidates:
        if not candidate or not Path(candidate).exists():
            continue
        probe = subprocess.run(
            [candidate, "-c", "import sys; print(sys.version_info[:2] == (3, 12))"], capture_output=True, text=True
        )
        if probe.returncode == 0 and probe.stdout.strip() == "True":  # a pyenv shim may answer with an error
            return candidate
    return None


def ensure_environment() -> tuple[Path | None, str]:
    """The Python of a 3.12 virtual environment with DOLFINx, or None and why not."""
    python = VENV / "bin" / "python"
    marker = VENV / ".installed"
    if marker.exists() and marker.read_text().strip() == WHEEL:
        return python, ""
    base = find_python312()
    if base is None:
        return (
            None,
            "no Python 3.12 found (set FENICSX_PYTHON, or put python3.12 on the path): DOLFINx's wheel needs it",
        )
    steps = [[base, "-m", "venv", "--clear", str(VENV)], [str(python), "-m", "pip", "install", "--quiet", WHEEL]]
    for step in steps:
        print("fenicsx environment:", " ".join(step), flush=True)
        done = subprocess.run(step, capture_output=True, text=True)
        if done.returncode != 0:
            tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
            return None, f"'{' '.join(step)}' failed: {' / '.join(tail)}"
    check = subprocess.run(
        [str(python), "-c", "import dolfinx_solver, dolfinx; print(dolfinx.__version__)"],
        capture_output=True,
        text=True,
    )
    if check.returncode != 0:
        return None, f"DOLFINx does not import: {check.stderr.strip().splitlines()[-1:]}"
    marker.write_text(WHEEL)
    return python, ""


# ----------------------------------------------------------------------------- the cases (surgiplan side)

L, H = 0.05, 0.0025
FLAP = {
    "mesh": {"box": {"size": [L, L, H], "divisions": [20, 20, 2], "pattern": "five"}},
    "material": {"youngs_modulus": 1.0e6, "poisson_ratio": 0.45, "density": 1000.0},
    "gravity": [0.0, 0.0, -9.8],
    "anchored": [
        {"region": {"min": [0, 0, 0], "max": [L, 0, H]}},
        {"region": {"min": [0, 0, 0], "max": [0, L, H]}},
        {"region": {"min": [0, L, 0], "max": [L, L, H]}},
    ],
    "grasp": {"region": {"min": [L - 0.0025, 0.0225, 0], "max": [L, 0.0275, H]}},
    "base_plane": {"point": [0, 0, 0]},
}
QUADRATIC_FLAP_MESH = {"box": {"size": [L, L, H], "divisions": [10, 10, 1], "pattern": "five"}, "order": 2}


def cantilever_settings(cells: int, order: int) -> dict:
    """100 x 10 x 10 mm, E = 1 MPa, nu = 0, clamped at x = 0, a dead tip load with P L^2 / EI = 1."""
    length, height = 0.1, 0.01
    load = 1e6 * height**4 / 12 / length**2
    return {
        "mesh": {"box": {"size": [length, height, height], "divisions": [10 * cells, cells, cells]}, "order": order},
        "material": {"youngs_modulus": 1e6, "poisson_ratio": 0.0, "volume_penalty": 0.0},
        "gravity": [0, 0, 0],
        "anchored": [{"region": {"min": [0, 0, 0], "max": [0, height, height]}}],
        "loads": [{"region": {"min": [length, 0, 0], "max": [length, height, height]}, "total_force": [0, 0, -load]}],
    }


def lift(dz: float) -> np.ndarray:
    pose = np.eye(4)
    pose[2, 3] = dz
    return pose


def build_case(name: str, tolerance: dict, self_intersection: bool = False):
    """(model, constraints, start state or None, description) of a case."""
    from surgiplan.plugins.fem import StVKModel, StVKSettings

    def make(settings):
        # the check of the deformed surface for self-intersection (part of a state's validity) is work a
        # DOLFINx solve does not do: off, so both sides time the equilibrium alone
        return StVKModel(
            StVKSettings.model_validate({**settings, "solver": tolerance, "self_intersection": self_intersection})
        )

    if name.startswith("cantilever"):
        _, order, cells = name.split("-")  # cantilever-p1-4
        model = make(cantilever_settings(int(cells), 1 if order == "p1" else 2))
        return model, model.stage_constraints(), None
    if name == "flap-gravity":  # three edges anchored, sagging under its weight (no base plane, nothing grasped)
        model = make({k: v for k, v in FLAP.items() if k not in ("grasp", "base_plane")})
        return model, model.stage_constraints(), None
    quadratic = name.endswith("p2")
    model = make({**FLAP, "mesh": QUADRATIC_FLAP_MESH} if quadratic else FLAP)
    jaws = model.grasped_nodes()
    if name == "flap-lift":
        return model, model.grasp_constraints(jaws, lift(0.010)), None
    # a warm-started 2 mm step: from the equilibrium at 10 mm to 12 mm
    start = model.solve(model.grasp_constraints(jaws, lift(0.010)))
    assert start.converged, start.message
    return model, model.grasp_constraints(jaws, lift(0.012)), start


CASES = {
    "cantilever-p1-4": "linear cantilever 40x4x4, from rest",
    "cantilever-p2-2": "quadratic cantilever 20x2x2, from rest",
    "cantilever-p2-4": "quadratic cantilever 40x4x4, from rest",
    "flap-gravity": "flap under gravity (three edges anchored), from rest",
    "flap-lift": "flap lifted 10 mm (gravity, base plane), from rest",
    "flap-step-p1": "flap 10 -> 12 mm, warm-started, linear 20x20x2",
    "flap-step-p2": "flap 10 -> 12 mm, warm-started, quadratic 10x10x1",
}


def export_case(path: Path, model, constraints, start, tolerance: dict, repeats: int) -> np.ndarray:
    """The case as arrays for the DOLFINx side; returns the prescribed mask (3n,)."""
    prescribed, goal = model._prescribed(constraints)
    held_nodes = np.flatnonzero(prescribed.reshape(-1, 3).any(axis=1))
    assert np.all(prescribed.reshape(-1, 3)[held_nodes]), "the DOLFINx side holds whole nodes"
    kernel, loads = model.kernel, model.loads
    plane = loads.base
    dead = np.zeros((model.mesh.n_nodes, 3))
    if constraints.external_forces is not None:
        dead += np.asarray(constraints.external_forces, dtype=float).reshape(-1, 3)
    np.savez(
        path,
        nodes=model.mesh.nodes,
        cells=model.mesh.tets,
        lam=kernel.lam,
        mu=kernel.mu,
        kappa=kernel.kappa,
        rho=model.material.density,
        gravity=np.asarray(model.settings.gravity, dtype=float),
        dead_loads=dead,
        plane_point=plane.point if plane is not None else np.zeros(3),
        plane_normal=plane.normal if plane is not None else np.array([0.0, 0.0, 1.0]),
        plane_stiffness=plane.stiffness if plane is not None else 0.0,
        prescribed_nodes=held_nodes,
        targets=goal.reshape(-1, 3),
        start=model.mesh.nodes if start is None else start.positions,
        applied_scale=float(np.abs(loads.body_forces + dead).max(initial=0.0)),
        force_floor=model.solver.force_floor,
        length_scale=model.edge_length,
        residual_tol=tolerance["residual_tol"],
        step_tol=tolerance["step_tol"],
        repeats=repeats,
    )
    return prescribed


def surgiplan_side(model, constraints, start, repeats: int) -> dict:
    model.solve(constraints, initial=start)  # warm-up: the sparsity pattern and its analysis are built once
    times, state = [], None
    for _ in range(repeats):
        model.clear_caches()
        started = time.perf_counter()
        state = model.solve(constraints, initial=start)
        times.append(time.perf_counter() - started)
    assert state.converged and state.valid, state.message
    return {"state": state, "times": times, "linear_share": linear_solver_share(model, constraints, start)}


def linear_solver_share(model, constraints, start) -> float | None:
    """The fraction of one more solve's time spent inside PARDISO (factorisations and solves), or None."""
    from surgiplan.plugins.fem import linear

    if not linear.pardiso_available()[0]:
        return None
    spent = [0.0]
    original = linear.PardisoHandle._call

    def timed(self, *args, **kwargs):
        started = time.perf_counter()
        try:
            return original(self, *args, **kwargs)
        finally:
            spent[0] += time.perf_counter() - started

    linear.PardisoHandle._call = timed
    try:
        model.clear_caches()
        started = time.perf_counter()
        model.solve(constraints, initial=start)
        total = time.perf_counter() - started
    finally:
        linear.PardisoHandle._call = original
    return round(spent[0] / total, 3)


def compare(name: str, model, constraints, start, tolerance: dict, python: Path, repeats: int) -> dict:
    ours = surgiplan_side(model, constraints, start, repeats)
    state = ours["state"]
    with tempfile.TemporaryDirectory() as scratch:
        case_path, out_path = Path(scratch) / "case.npz", Path(scratch) / "out.npz"
        prescribed = export_case(case_path, model, constraints, start, tolerance, repeats)
        done = subprocess.run(
            [str(python), str(Path(__file__).resolve()), "--dolfinx-worker", str(case_path), str(out_path)],
            capture_output=True,
            text=True,
        )
        if done.returncode != 0:
            raise RuntimeError(f"the DOLFINx side failed on {name}:\n{done.stderr[-3000:]}")
        theirs = dict(np.load(out_path))
    configs = json.loads(str(theirs["configs"]))
    displacement = state.positions - model.rest_nodes
    reactions = state.data["reaction_field"]
    held = prescribed.reshape(-1, 3).any(axis=1)
    row = {
        "case": name,
        "what": CASES[name],
        "unknowns": 3 * model.mesh.n_nodes,
        "elements": model.mesh.n_elements,
        "surgiplan_s": round(statistics.median(ours["times"]), 4),
        "surgiplan_times_s": [round(t, 4) for t in ours["times"]],
        "surgiplan_iterations": state.iterations,
        "surgiplan_factorizations": state.data["factorizations"],
        "surgiplan_solver": state.data.get("linear_solver", "superlu"),
        "surgiplan_linear_solver_share": ours["linear_share"],
        "dolfinx": str(theirs["dolfinx"]),
        "petsc": str(theirs["petsc"]),
    }
    best = None
    for config, entry in configs.items():
        summary = {"converged": entry["converged"], "iterations": entry["iterations"]}
        summary["factorizations"] = entry["factorizations"]
        if entry["converged"] and entry["times"]:
            summary["median_s"] = round(statistics.median(entry["times"]), 4)
            positions = theirs[f"positions:{config}"]
            gradient = theirs[f"gradient:{config}"]
            summary["displacement_rel"] = float(np.abs(positions - state.positions).max() / np.abs(displacement).max())
            summary["energy_rel"] = float(abs(entry["energy"] - state.energy) / abs(state.energy))
            summary["reaction_rel"] = float(
                np.abs(gradient[held] - reactions[held]).max() / np.abs(reactions[held]).max()
            )
            if best is None or summary["median_s"] < row[f"dolfinx_{best}"]["median_s"]:
                best = config
        else:
            summary["reason"] = entry.get("reason")
        row[f"dolfinx_{config}"] = summary
    if best is not None:
        chosen = row[f"dolfinx_{best}"]
        row.update(
            dolfinx_best=best,
            dolfinx_s=chosen["median_s"],
            speedup=round(chosen["median_s"] / row["surgiplan_s"], 2),
            agreement=max(chosen["displacement_rel"], chosen["energy_rel"], chosen["reaction_rel"]),
        )
    return row


def main() -> None:
    load_at_start = os.getloadavg()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the small cases only, 1 repeat (checks the script)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES), default=None)
    parser.add_argument("--residual-tol", type=float, default=1e-10)
    parser.add_argument("--step-tol", type=float, default=1e-4)
    args = parser.parse_args()
    cases = args.cases or (["cantilever-p2-2", "flap-step-p1"] if args.quick else list(CASES))
    repeats = 1 if args.quick else args.repeats
    python, reason = ensure_environment()
    if python is None:
        print(f"skipped: {reason}")
        return
    sys.path.insert(0, str(HERE))
    from common import save, table

    tolerance = {"residual_tol": args.residual_tol, "step_tol": args.step_tol}
    rows = []
    for name in cases:
        model, constraints, start = build_case(name, tolerance)
        row = compare(name, model, constraints, start, tolerance, python, repeats)
        rows.append(row)
        print(
            f"{name}: surgiplan {row['surgiplan_s']} s, DOLFINx ({row.get('dolfinx_best')}) {row.get('dolfinx_s')} s, "
            f"agreement {row.get('agreement', float('nan')):.2g}",
            flush=True,
        )
    columns = ["case", "unknowns", "surgiplan_s", "surgiplan_factorizations", "dolfinx_best", "dolfinx_s", "speedup"]
    print(table([{**r, "agreement": f"{r.get('agreement', float('nan')):.1e}"} for r in rows], [*columns, "agreement"]))
    note = (
        f"residual_tol {args.residual_tol:g}, step_tol {args.step_tol:g}; medians of {repeats} solves after a warm-up; "
        f"one thread each side; load average at the start {load_at_start[0]:.2f} (1 min), {load_at_start[1]:.2f} "
        f"(5 min) on {os.cpu_count()} cores shared with other work"
    )
    if args.quick or args.cases:
        print("(a partial run: results/fem_vs_fenicsx.json is written by full runs only)")
        return
    print(f"written: {save('fem_vs_fenicsx', rows, note)}")


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--dolfinx-worker":
        dolfinx_worker(sys.argv[2], sys.argv[3])
    else:
        main()
