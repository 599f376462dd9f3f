"""The FEM blocks: the stvk model measured.

Its speed and bending locking (``bench_fem.py``), its sparse solver (``bench_fem_solvers.py``), and stvk
against DOLFINx (``bench_fem_vs_fenicsx.py``).
"""

from __future__ import annotations

import re
from pathlib import Path

from .formatting import dims, find, load, secs, section, span, table, words, wrap


def _ms(seconds) -> str:
    """A peer's time in ms, or what the benchmark wrote instead (``not installed``)."""
    return f"{1e3 * seconds:.1f} ms" if isinstance(seconds, int | float) else str(seconds)


def render_fem_vs_fenicsx(results: Path) -> str:
    data = load(results, "fem_vs_fenicsx")
    rows = data["rows"]
    target = float(find(r"at least ([\d.]+)x surgiplan", data["notes"], "fem_vs_fenicsx.json notes").group(1))

    def what(r: dict) -> str:
        text = dims(r["what"]).replace("->", "→")
        return re.sub(r" \(three edges anchored\)| \(gravity, base plane\)| \d+×\d+×\d+$", "", text)

    def configuration(name: str) -> str:
        factor, search, *lag = name.split("+")
        search = {"bt-energy": "bt on the energy"}.get(search, search)
        return f"{factor.upper() if factor == 'lu' else factor}, {search}" + (
            f", Jacobian every {lag[0][3:]}" if lag else ""
        )

    def best_of(r: dict) -> str:
        return "; ".join(sorted({configuration(x["dolfinx_best"]) for x in r["runs"]}))

    def ratios(r: dict) -> str:
        return " / ".join(f"{v:.2f}" for v in r["speedup_runs"])

    body = table(
        ["case", "unknowns", "surgiplan", "DOLFINx's best (its configuration)", "DOLFINx / surgiplan", "agreement"],
        [
            [
                what(r),
                f"{r['unknowns']:,}",
                f"{secs(r['surgiplan_s'])} s",
                f"{secs(r['dolfinx_s'])} s ({best_of(r)})",
                ratios(r),
                f"{r['agreement']:.1e}",
            ]
            for r in rows
        ],
    )
    notes = data["notes"]
    solves = find(r"medians of (\d+) solves", notes, "fem_vs_fenicsx.json notes").group(1)
    runs = find(r"(\d+) separate runs", notes, "fem_vs_fenicsx.json notes").group(1)
    tol = find(r"residual_tol ([\de.-]+)", notes, "fem_vs_fenicsx.json notes").group(1)
    loads = [x["load_1min"] for r in rows for x in r["runs"]]
    head = (
        f"Both stop by the same rule at `residual_tol` {tol}; {words(int(runs))} separate runs of every case, each "
        f"the medians of {solves} solves after a warm-up per side and configuration, one thread each; DOLFINx in its "
        f"fastest of 24 configurations on each case and run; load average {span(loads, lambda v: f'{v:.1f}')} "
        f"(1 min) during the runs. The times are the medians over the runs; the ratios each run's. Agreement (the "
        f"largest of the relative differences of displacements, energy and reactions) and time:"
    )
    held = [r for r in rows if r["holds_every_run"]]
    missed = [r for r in rows if not r["holds_every_run"]]
    every = [x for r in rows for x in r["runs"]]
    modified = [x for x in every if "+lag" in (x["dolfinx_best"] or "")]
    verdict = (
        f"The target of at most {1 / target:g}× DOLFINx's best time holds on every case in every run (the smallest "
        f"ratio {min(r['speedup'] for r in rows):.2f}, {what(min(rows, key=lambda r: r['speedup']))})."
        if not missed
        else f"The target of at most {1 / target:g}× DOLFINx's best time holds in every run on {words(len(held))} of "
        f"the {words(len(rows))} cases and not on " + "; ".join(f"{what(r)} ({ratios(r)})" for r in missed) + "."
    )
    tail = (
        f"The answers agree to {min(r['agreement'] for r in rows):.0e}-{max(r['agreement'] for r in rows):.0e}. "
        f"DOLFINx's best was modified Newton in {len(modified)} of the {len(every)} case runs"
        + (f" ({'; '.join(sorted({what(r) for r in rows for x in r['runs'] if x in modified}))})" if modified else "")
        + ". "
        + verdict
    )
    return section(head, body, tail)


def render_fem(results: Path) -> str:
    data = load(results, "fem")
    rows = data["rows"]
    steps = [r for r in rows if r["part"] == "gripper steps"]

    def step(path: str, case: str, elements: str = "linear 20x20x2") -> dict:
        return next(r for r in steps if r["path"] == path and r["case"] == case and r["elements"] == elements)

    lift = step("lift", "warm start + factorisation reuse")
    retract = step("retraction", "warm start + factorisation reuse")
    cold = [step("lift", "cold (from rest)"), step("retraction", "cold (from rest)")]
    quad = step("lift", "warm start + factorisation reuse", "quadratic 10x10x1")
    first = next(r for r in rows if r["part"] == "gripper step detail" and r["path"] == "lift" and r["step"] == 1)
    sampled = next(r for r in rows if r["part"] == "sampled equilibria")
    pieces = {r["piece"]: r["median_ms"] for r in rows if r["part"] == "iteration pieces"}
    load_avg = find(r"load average at the start ([\d.]+)", data["notes"], "fem.json notes").group(1)
    factor = next(k for k in pieces if k.startswith("factorisation"))
    solver = find(r"\((\w+)\)", factor, "fem.json iteration pieces").group(1)
    iterations = [lift["median_iterations"], retract["median_iterations"]]
    text = (
        f"Speed (`benchmarks/bench_fem.py`, the paper's flap: 1,323 nodes, 4,000 tetrahedra, one core per solve, "
        f"{solver.upper()}; the machine shared with other work, load average {float(load_avg):.1f} on its 2 cores at "
        f"the start, `benchmarks/results/fem.json`): a warm-started equilibrium for a 2 mm gripper step takes "
        f"{lift['median_s']:.3f} s median along a lift and {retract['median_s']:.3f} s along a retraction path "
        f"({span(iterations, lambda v: f'{v:g}')} Newton iterations, "
        f"{words(round(lift['median_factorizations']))} factorisation; the first step from rest "
        f"{first['time_s']:.3f} s), against {span([c['median_s'] for c in cold], lambda v: f'{v:.3f}')} s solved "
        f"cold from rest each time; quadratic tetrahedra (10 × 10 × 1) {quad['median_s']:.3f} s. "
        f"{sampled['samples']:,} sampled grasp poses through `run_tasks` on the local executor "
        f"({sampled['workers']} workers, {sampled['tasks']} tasks) take {sampled['wall_s']:.1f} s wall, "
        f"{'all' if sampled['converged'] == sampled['valid'] == sampled['samples'] else 'not all'} converged and "
        f"valid ({sampled['converged']:,} and {sampled['valid']:,}), at {sampled['core_s_per_sample']:.3f} "
        f"core-seconds each ({sampled['median_iterations']:.0f} Newton iterations, "
        f"{sampled['median_factorizations']:.0f} factorisations median), against the paper's "
        f"{sampled['paper_wall_s'] / 3600:.1f} h on {sampled['paper_cores']} cores. A Newton iteration's pieces: "
        f"energy {pieces['energy (line search)']:.2f} ms, energy and gradient {pieces['energy + gradient']:.2f} ms, "
        f"the tangent with its energy and gradient, assembled, {pieces['tangent, assembled (exact)']:.2f} ms, "
        f"{solver.upper()} factorisation {pieces[factor]:.2f} ms, solves "
        f"{pieces['triangular solves']:.2f} ms; the self-intersection check of a state "
        f"{pieces['self-intersection check']:.1f} ms."
    )
    return wrap(text)


def render_fem_locking(results: Path) -> str:
    data = load(results, "fem")
    rows = data["rows"]
    locking = [r for r in rows if r["part"] == "bending locking"]
    linear = sorted((r for r in locking if r["elements"] == "linear"), key=lambda r: r["layers"])
    quadratic = sorted((r for r in locking if r["elements"] == "quadratic"), key=lambda r: r["nodes"])
    one_layer = [r for r in quadratic if r["layers"] == 1]
    beam = [r for r in rows if r["part"] == "cantilever convergence"]
    lin_beam = [r for r in beam if r["elements"] == "linear"]
    quad_beam = [r for r in beam if r["elements"] == "quadratic"]
    coarsest = quad_beam[0]

    def pct(x: float) -> str:
        return f"{x:+.1f} %".replace("-", "−") if abs(x) < 10 else f"{x:+.0f} %".replace("-", "−")

    def cells(r: dict) -> str:
        return r["cells"].replace(" x ", "×")

    sags = [f"{100 * r['sag_over_beam_theory']:.0f} %" for r in linear]
    spread = max(abs(r["sag_over_beam_theory"] - 1) for r in quadratic)
    text = (
        f"**Bending locking.** Linear tetrahedra are too stiff in bending (`benchmarks/bench_fem.py`, "
        f"`benchmarks/results/fem.json`). A strip of the flap (50 × 10 × 2.5 mm) sagging under its own weight "
        f"reaches {', '.join(sags[:-1])} and {sags[-1]} of the beam-theory sag with "
        f"{', '.join(str(r['layers']) for r in linear[:-1])} and {linear[-1]['layers']} layers of linear tetrahedra "
        f"({linear[0]['nodes']:,} to {linear[-1]['nodes']:,} nodes); one layer of quadratic tetrahedra reaches "
        f"{100 * one_layer[0]['sag_over_beam_theory']:.0f} % (within {100 * spread:.1f} %, from "
        f"{quadratic[0]['nodes']:,} nodes). The paper's flap mesh (two linear layers) is therefore about "
        f"{1 / linear[1]['sag_over_beam_theory']:.1f} times too stiff where the flap *bends* (sagging, draping over "
        f"the base); where it is *stretched* by the gripper, which dominates retraction, locking matters much less. "
        f"For accurate bending use `order: 2` (e.g. `[10, 10, 1]` cells for the flap), or refine and check that the "
        f"answer stops changing. The large-deflection cantilever against the elastica (Bisshopp & Drucker) shows "
        f"the same: linear tetrahedra converge from below ({', '.join(pct(r['error_pct']) for r in lin_beam)} at "
        f"{', '.join(cells(r) for r in lin_beam)} cells), quadratic ones are within "
        f"{max(abs(r['error_pct']) for r in quad_beam):.1f} % on every mesh from the coarsest "
        f"({pct(coarsest['error_pct'])} at {cells(coarsest)}: the continuum's shear, which the elastica leaves "
        f"out; `benchmarks/results/fem_convergence.png`)."
    )
    return wrap(text)


def render_fem_solvers(results: Path) -> str:
    data = load(results, "fem_solvers")
    rows = data["rows"]
    body = table(
        [
            "tangent",
            "unknowns",
            "SuperLU factor (+ definiteness)",
            "PARDISO analysis + first factor / refactor (inertia included)",
            "PARDISO ordering",
            "speed-up",
            "qdldl refactor / cholespy (no inertia)",
        ],
        [
            [
                dims(r["matrix"]),
                f"{r['unknowns']:,}",
                f"{1e3 * r['superlu_factor_s']:.1f} ms ({1e3 * r['superlu_factor_and_definiteness_s']:.1f} ms)",
                f"{1e3 * r['pardiso_analysis_and_first_factor_s']:.1f} / {1e3 * r['pardiso_factor_s']:.1f} ms",
                r["pardiso_ordering"],
                f"{r['pardiso_speedup']:.1f}×",
                f"{_ms(r['qdldl_refactor_s'])} / {_ms(r['cholespy_analysis_and_factor_s'])}",
            ]
            for r in rows
        ],
    )
    load_avg = find(r"load average at the start ([\d.]+)", data["notes"], "fem_solvers.json notes").group(1)
    head = (
        f"The sparse solver (`benchmarks/bench_fem_solvers.py`, `benchmarks/results/fem_solvers.json`; stvk's "
        f"tangents, one thread, medians of 5, load average {float(load_avg):.2f} (1 min) at the start); the speed-up "
        f"is SuperLU's factorisation with its definiteness check against PARDISO's refactorisation as stvk calls it "
        f"(Cholesky first: these tangents are definite, and its success is the definiteness test; LDLᵀ, which "
        f"reads the inertia from the factors, only where Cholesky fails):"
    )
    slower = all(
        r["qdldl_refactor_s"] > r["pardiso_factor_s"] and r["cholespy_analysis_and_factor_s"] > r["pardiso_factor_s"]
        for r in rows
    )
    tail = (
        f"qdldl (a refactorisation reusing its analysis) and cholespy (Cholesky only, no refactorisation) are "
        f"{'slower on every tangent' if slower else 'not slower everywhere'} and report no inertia."
    )
    if all("pardiso_ldlt_factor_s" in r for r in rows):
        tail += (
            " PARDISO's LDLᵀ (what stvk falls back to for an indefinite tangent) refactors the same tangents in "
            + ", ".join(f"{1e3 * r['pardiso_ldlt_factor_s']:.1f}" for r in rows)
            + " ms."
        )
    return section(head, body, tail)
