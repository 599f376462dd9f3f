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

DOLFINx runs in every configuration a user might pick for speed, and is
compared in its best on each case: LU or Cholesky (LDLᵀ, MUMPS ``sym = 2``)
by MUMPS with PETSc reusing the symbolic analysis while the pattern is
unchanged (across Newton steps and across the repeated solves); line search
``basic`` (plain Newton), ``bt`` (backtracking on the residual norm, PETSc's
default merit), ``bt`` on the energy (the energy given to SNES as its
objective) or ``cp`` (critical point); a new Jacobian every iteration, or
modified Newton that keeps one Jacobian and its factorisation for 2 or 3
iterations (``snes_lag_jacobian`` 2, 3): 24 configurations
(``fenicsx_worker.CONFIGURATIONS``). Times are medians of ``--repeats``
solves after one warm-up solve (a configuration whose warm-up takes three
times the fastest warm-up so far is not repeated: it cannot be the best),
excluding what both sides do once (surgiplan: mesh, element data, sparsity
pattern and its symbolic analysis; DOLFINx: form compilation, mesh, function
spaces, sparsity pattern); surgiplan's self-intersection check of the
deformed surface (part of a state's validity, work DOLFINx does not do) is
off, its stresses are computed; surgiplan's factorisations kept from earlier
solves are dropped before each timed one (``clear_caches``), so a repeat
never starts with a factored tangent the first one lacked. One thread on
each side (OMP/MKL/OpenBLAS = 1). The whole comparison runs ``--runs`` times
(default 3), each case afresh on both sides each time; the target (DOLFINx's
best at least twice surgiplan's time) must hold in every run, so the row's
speed-up is the smallest of its runs. The machine has 2 cores shared with
other work: the load average is recorded at the start, after each case and
at the end. Each finished case of a run is kept in
``out/fem_vs_fenicsx.partial.json`` until the results are written: an
interrupted comparison, started again with the same settings on the same
commit, resumes where it stopped.

DOLFINx's wheel (``dolfinx-solver-real``, DOLFINx 0.11 with PETSc and
MUMPS) needs Python 3.12: this script makes its own virtual environment
under ``out/.fenicsx-venv`` (git-ignored) with a Python 3.12 it finds
(``$FENICSX_PYTHON``, ``python3.12`` on the path, pyenv), and is skipped
with the reason where it cannot.

    python benchmarks/bench_fem_vs_fenicsx.py [--quick] [--repeats 5] [--cases NAME ...]

The DOLFINx side is ``fenicsx_worker.py``, run in that environment (it imports
nothing of surgiplan).
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


def surgiplan_side(model, constraints, start, repeats: int, warm_up: bool = True, share: bool = True) -> dict:
    if warm_up:
        model.solve(constraints, initial=start)  # warm-up: the sparsity pattern and its analysis are built once
    times, state = [], None
    for _ in range(repeats):
        model.clear_caches()
        started = time.perf_counter()
        state = model.solve(constraints, initial=start)
        times.append(time.perf_counter() - started)
    assert state.converged and state.valid, state.message
    return {
        "state": state,
        "times": times,
        "linear_share": linear_solver_share(model, constraints, start) if share else None,
    }


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
    # surgiplan's solves are timed in two halves, before and after DOLFINx's process, so that a change of the
    # machine's load during the case weighs on both sides alike
    ours = surgiplan_side(model, constraints, start, (repeats + 1) // 2)
    with tempfile.TemporaryDirectory() as scratch:
        case_path, out_path = Path(scratch) / "case.npz", Path(scratch) / "out.npz"
        prescribed = export_case(case_path, model, constraints, start, tolerance, repeats)
        done = subprocess.run(
            [str(python), str(HERE / "fenicsx_worker.py"), str(case_path), str(out_path)],
            capture_output=True,
            text=True,
        )
        if done.returncode != 0:
            raise RuntimeError(f"the DOLFINx side failed on {name}:\n{done.stderr[-3000:]}")
        theirs = dict(np.load(out_path))
    after = surgiplan_side(model, constraints, start, max(repeats - (repeats + 1) // 2, 1), warm_up=False, share=False)
    ours["times"] += after["times"]
    state = ours["state"]
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


def combine(per_run: list[dict]) -> dict:
    """One case's row from its separate runs: the first run's description and detail, each run's figures, and
    the verdict that counts: the smallest speed-up of the runs (the target holds only if it holds in each)."""
    row = dict(per_run[0])
    runs = []
    for k, r in enumerate(per_run, 1):
        runs.append(
            {
                "run": k,
                "surgiplan_s": r["surgiplan_s"],
                "dolfinx_best": r.get("dolfinx_best"),
                "dolfinx_s": r.get("dolfinx_s"),
                "speedup": r.get("speedup"),
                "agreement": r.get("agreement"),
                "load_1min": r["load_1min"],
                # every configuration's median (None: did not converge)
                "dolfinx_medians_s": {
                    key[len("dolfinx_") :]: value.get("median_s")
                    for key, value in r.items()
                    if key.startswith("dolfinx_") and isinstance(value, dict)
                },
            }
        )
    speedups = [r["speedup"] for r in runs if r["speedup"] is not None]
    row.update(
        runs=runs,
        surgiplan_s=round(statistics.median(r["surgiplan_s"] for r in runs), 4),
        dolfinx_s=round(statistics.median(r["dolfinx_s"] for r in runs if r["dolfinx_s"] is not None), 4)
        if speedups
        else None,
        speedup=min(speedups) if len(speedups) == len(runs) else None,
        speedup_median=round(statistics.median(speedups), 2) if speedups else None,
        speedup_runs=speedups,
        holds_every_run=bool(len(speedups) == len(runs) and min(speedups) >= TARGET),
        agreement=max((r["agreement"] for r in runs if r["agreement"] is not None), default=None),
    )
    return row


#: the target: DOLFINx's best configuration takes at least this many times as long, in every run
TARGET = 2.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the small cases only, 1 repeat (checks the script)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--runs", type=int, default=3, help="separate runs of every case (default 3)")
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES), default=None)
    parser.add_argument("--residual-tol", type=float, default=1e-10)
    parser.add_argument("--step-tol", type=float, default=1e-4)
    args = parser.parse_args()
    cases = args.cases or (["cantilever-p2-2", "flap-step-p1"] if args.quick else list(CASES))
    repeats = 1 if args.quick else args.repeats
    runs = 1 if args.quick else args.runs
    python, reason = ensure_environment()
    if python is None:
        print(f"skipped: {reason}")
        return
    sys.path.insert(0, str(HERE))
    from common import START_LOAD, save, table
    from fenicsx_worker import CONFIGURATIONS, SKIP_FACTOR, config_name

    tolerance = {"residual_tol": args.residual_tol, "step_tol": args.step_tol}
    per_case: dict[str, list[dict]] = {name: [] for name in cases}
    versions = {}
    # a long job resumes: each finished (run, case) is kept until the results are written, for the same settings
    # and commit (an interrupted comparison picks up where it stopped)
    from common import START_GIT
    from surgiplan.storage import write_json_atomic

    checkpoint = HERE.parent / "out" / "fem_vs_fenicsx.partial.json"
    key = {"cases": cases, "runs": runs, "repeats": repeats, **tolerance, "commit": START_GIT.get("commit")}
    done: dict[str, dict] = {}
    if not (args.quick or args.cases) and checkpoint.exists():
        try:
            kept = json.loads(checkpoint.read_text())
        except (OSError, ValueError):
            kept = {}
        if kept.get("key") == key:
            done = kept.get("rows", {})
            print(f"resuming: {len(done)} of {runs * len(cases)} measurements from {checkpoint}", flush=True)
    for run in range(1, runs + 1):
        # a separate run: every case again, each side from scratch (a new model, a new DOLFINx process)
        for name in cases:
            if f"{run}/{name}" in done:
                row = done[f"{run}/{name}"]
                versions = {"dolfinx": row["dolfinx"], "petsc": row["petsc"]}
                per_case[name].append(row)
                continue
            model, constraints, start = build_case(name, tolerance)
            row = compare(name, model, constraints, start, tolerance, python, repeats)
            row["load_1min"] = round(os.getloadavg()[0], 2)
            versions = {"dolfinx": row["dolfinx"], "petsc": row["petsc"]}
            per_case[name].append(row)
            if not (args.quick or args.cases):
                done[f"{run}/{name}"] = row
                checkpoint.parent.mkdir(exist_ok=True)
                write_json_atomic(checkpoint, {"key": key, "rows": done})
            print(
                f"run {run}, {name}: surgiplan {row['surgiplan_s']} s, DOLFINx ({row.get('dolfinx_best')}) "
                f"{row.get('dolfinx_s')} s, {row.get('speedup')}x, agreement {row.get('agreement', float('nan')):.2g}",
                flush=True,
            )
    rows = [combine(per_case[name]) for name in cases]
    columns = ["case", "unknowns", "surgiplan_s", "dolfinx_s", "speedup_runs", "holds_every_run"]
    print(
        table([{**r, "agreement": f"{r.get('agreement') or float('nan'):.1e}"} for r in rows], [*columns, "agreement"])
    )
    note = (
        f"residual_tol {args.residual_tol:g}, step_tol {args.step_tol:g}; {runs} separate runs, each the medians of "
        f"{repeats} solves after a warm-up per side and configuration; one thread each side; load average at the "
        f"start {START_LOAD[0]:.2f} (1 min), {START_LOAD[1]:.2f} (5 min) on {os.cpu_count()} cores shared with other "
        f"work; target: DOLFINx's best configuration at least {TARGET:g}x surgiplan's time on every case in every run"
    )
    if args.quick or args.cases:
        print("(a partial run: results/fem_vs_fenicsx.json is written by full runs only)")
        return
    peers = {
        "DOLFINx": {
            "version": versions.get("dolfinx"),
            "petsc": versions.get("petsc"),
            "wheel": WHEEL,
            "solver": "PETSc SNES newtonls, KSP preonly, MUMPS; one thread",
            "configurations": [config_name(*c) for c in CONFIGURATIONS],
            "skipped_when_warmup_over": f"{SKIP_FACTOR:g}x the fastest warm-up",
        }
    }
    print(f"written: {save('fem_vs_fenicsx', rows, note, peers=peers)}")
    checkpoint.unlink(missing_ok=True)


if __name__ == "__main__":
    main()
