"""stvk: equilibria of the paper's tissue flap, sampled equilibria in parallel, cantilever convergence.

Patil & Alterovitz (paper 002, §VI): a 5 x 5 x 0.25 cm flap, about 1,300
nodes and 4,000 tetrahedra (here 20 x 20 x 2 cells of five: 1,323 and
4,000), E = 1 MPa, nu = 0.45, rho = 1000 kg/m^3, gravity 9.8 m/s^2, on a
base plane, anchored along three edges and grasped at its free edge.

1. Warm-started equilibria for 2 mm gripper steps (lifting 2 mm at a time
   to 30 mm), on one core; the issue's target is a median <= 0.3 s. Shown
   with and without reusing factorisations between steps, and the cost of
   the pieces of one Newton iteration.
2. 1,000 sampled grasp poses (lift, pull, tilt) solved through ``run_tasks``
   on the local executor (2 workers): the poses are put on one greedy
   nearest-neighbour tour, cut into 40 tasks of 25 consecutive poses, each
   pose warm-started from the one before (the first of a task from rest);
   target <= 5 minutes here (the paper: 1.2 h on 8 cores for scenario 1).
3. A cantilever (alpha = P L^2 / EI = 1) converging to the elastica
   (Bisshopp & Drucker) under mesh refinement: linear tetrahedra lock.

    python benchmarks/bench_fem.py [--quick]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core per process, as the targets say
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from common import median_time, save, table
from fem_support import elastica_tip
from scipy.spatial.transform import Rotation
from surgiplan.executors import LocalExecutor, TaskStore, run_tasks
from surgiplan.plugins.fem import StVKModel, StVKSettings
from surgiplan.plugins.fem.tasks import grasp_sequence_task

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


def flap() -> StVKModel:
    return StVKModel(StVKSettings.model_validate(FLAP))


def lift(dz: float) -> np.ndarray:
    pose = np.eye(4)
    pose[2, 3] = dz
    return pose


def gripper_steps(reuse: bool, repeats: int) -> tuple[dict, list[dict]]:
    """Lift the free edge 2 mm at a time to 30 mm; every step warm-started from the one before."""
    rows, times, iterations, factorizations = [], [], [], []
    for _ in range(repeats):
        model = flap()
        jaws = model.grasped_nodes()
        state = model.solve(model.grasp_constraints(jaws, None))
        for k in range(1, 16):
            if not reuse:
                model._factor = None
            started = time.perf_counter()
            state = model.solve(model.grasp_constraints(jaws, lift(0.002 * k)), initial=state)
            elapsed = time.perf_counter() - started
            assert state.converged and state.valid, state.message
            times.append(elapsed)
            iterations.append(state.iterations)
            factorizations.append(state.data["factorizations"])
            if len(rows) < 15:
                rows.append(
                    {
                        "lift_mm": 2 * k,
                        "time_s": round(elapsed, 3),
                        "newton_iterations": state.iterations,
                        "factorizations": state.data["factorizations"],
                        "residual_N": f"{state.residual:.1e}",
                        "energy_mJ": round(state.energy * 1e3, 4),
                        "max_stress_kPa": round(float(state.stress.max()) / 1e3, 1),
                        "grasp_force_N": round(float(np.linalg.norm(state.data["reaction_field"][jaws].sum(0))), 4),
                    }
                )
    summary = {
        "case": f"2 mm steps, factorisation reuse {'on' if reuse else 'off'}",
        "median_s": round(statistics.median(times), 3),
        "median_excluding_first_s": round(statistics.median([t for i, t in enumerate(times) if i % 15]), 3),
        "max_s": round(max(times), 3),
        "median_iterations": statistics.median(iterations),
        "median_factorizations": statistics.median(factorizations),
        "steps": len(times),
    }
    return summary, rows


def iteration_pieces() -> list[dict]:
    """Median cost of the parts of one Newton iteration on the flap."""
    model = flap()
    jaws = model.grasped_nodes()
    state = model.solve(model.grasp_constraints(jaws, lift(0.01)))
    solver = model.solver
    x = state.positions.ravel()
    prescribed, _ = model._prescribed(model.grasp_constraints(jaws, lift(0.01)))
    kernel = model.kernel
    data = solver.tangent(x, False)[2]
    constrained = solver.pattern.constrain(data, prescribed)
    factor = solver.pattern.factorize(constrained)
    hessian = kernel.evaluate(state.positions, hessian=True).hessian.copy()
    pieces = {
        "energy (line search)": lambda: solver.energy(x),
        "energy + gradient": lambda: solver.gradient(x),
        "element tangents (exact)": lambda: kernel.evaluate(state.positions, hessian=True),
        "element tangents (definite surrogate)": lambda: kernel.evaluate(state.positions, hessian=True, definite=True),
        "assembly (bincount)": lambda: solver.pattern.assemble(hessian),
        "constraints": lambda: solver.pattern.constrain(data, prescribed),
        "LU factorisation (SuperLU, pre-ordered)": lambda: solver.pattern.factorize(constrained),
        "triangular solves": lambda: factor.solve(x),
        "self-intersection check": lambda: model.evaluate_state(state.positions),
    }
    return [{"piece": name, "median_ms": round(median_time(fn, repeat=9)[0] * 1e3, 2)} for name, fn in pieces.items()]


def sample_poses(n: int, rng: np.random.Generator, centre: np.ndarray) -> np.ndarray:
    """Random gripper motions (4 x 4) of the jaws: lift 0-25 mm, pull -10-5 mm, side +-5 mm, tilt."""
    translation = rng.uniform([-0.010, -0.005, 0.0], [0.005, 0.005, 0.025], (n, 3))
    rpy = np.column_stack([rng.uniform(-0.26, 0.26, n), rng.uniform(-0.79, 0.17, n), rng.uniform(-0.26, 0.26, n)])
    rotation = Rotation.from_euler("xyz", rpy).as_matrix()
    poses = np.repeat(np.eye(4)[None], n, axis=0)
    poses[:, :3, :3] = rotation
    poses[:, :3, 3] = centre + translation - rotation @ centre
    return poses


def nearest_neighbour_tour(poses: np.ndarray) -> np.ndarray:
    """Order of the poses along a greedy nearest-neighbour tour from the identity (m + 0.02 m/rad)."""
    translation = poses[:, :3, 3]
    quaternion = Rotation.from_matrix(poses[:, :3, :3]).as_quat()
    left = np.ones(len(poses), dtype=bool)
    current_t, current_q = np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])
    order = []
    for _ in range(len(poses)):
        angle = 2 * np.arccos(np.clip(np.abs(quaternion @ current_q), 0, 1))
        distance = np.linalg.norm(translation - current_t, axis=1) + 0.02 * angle
        distance[~left] = np.inf
        i = int(np.argmin(distance))
        left[i] = False
        order.append(i)
        current_t, current_q = translation[i], quaternion[i]
    return np.array(order)


def sampled_equilibria(n: int, chunk: int, workers: int) -> dict:
    """Solve n sampled poses: one nearest-neighbour tour, cut into chunks (tasks) of consecutive poses."""
    model = flap()
    centre = model.rest_nodes[model.grasped_nodes()].mean(axis=0)
    poses = sample_poses(n, np.random.default_rng(2024), centre)
    poses = poses[nearest_neighbour_tour(poses)]
    settings = model.settings.model_dump(mode="json")
    tasks = {
        f"chunk-{k:03d}": {"settings": settings, "transforms": poses[k * chunk : (k + 1) * chunk], "positions": True}
        for k in range(n // chunk)
    }
    with tempfile.TemporaryDirectory() as store, LocalExecutor(workers) as executor:
        started = time.perf_counter()
        results = run_tasks(executor, grasp_sequence_task, tasks, store=TaskStore(store))
        wall = time.perf_counter() - started
    cat = {k: np.concatenate([r[k] for r in results.values()]) for k in ("converged", "valid", "iterations", "solve_s")}
    return {
        "samples": n,
        "tasks": len(tasks),
        "workers": workers,
        "wall_s": round(wall, 1),
        "converged": int(cat["converged"].sum()),
        "valid": int((cat["converged"] & cat["valid"]).sum()),
        "median_iterations": float(np.median(cat["iterations"])),
        "median_solve_s": round(float(np.median(cat["solve_s"])), 3),
        "p90_solve_s": round(float(np.percentile(cat["solve_s"], 90)), 3),
        "max_solve_s": round(float(np.max(cat["solve_s"])), 3),
    }


def cantilever(levels: list[int]) -> list[dict]:
    length, height, e, alpha = 0.1, 0.01, 1e6, 1.0
    load = alpha * e * height**4 / 12 / length**2
    reference, _ = elastica_tip(alpha)
    rows = []
    for k in levels:
        size = [length, height, height]
        model = StVKModel(
            StVKSettings.model_validate(
                {
                    "mesh": {"box": {"size": size, "divisions": [10 * k, k, k]}},
                    "material": {"youngs_modulus": e, "poisson_ratio": 0.0, "volume_penalty": 0.0},
                    "gravity": [0, 0, 0],
                    "anchored": [{"region": {"min": [0, 0, 0], "max": [0, height, height]}}],
                    "loads": [
                        {"region": {"min": [length, 0, 0], "max": size}, "total_force": [0, 0, -load]},
                    ],
                }
            )
        )
        started = time.perf_counter()
        state = model.solve(model.stage_constraints())
        elapsed = time.perf_counter() - started
        tip = model.nodes_in_region([length, 0, 0], size)
        deflection = -(state.positions[tip, 2] - model.rest_nodes[tip, 2]).mean() / length
        rows.append(
            {
                "cells": f"{10 * k} x {k} x {k}",
                "nodes": model.mesh.n_nodes,
                "tets": model.mesh.n_elements,
                "tip_deflection_over_L": round(deflection, 4),
                "elastica": round(reference, 4),
                "error_pct": round(100 * (reference - deflection) / reference, 2),
                "newton_iterations": state.iterations,
                "time_s": round(elapsed, 2),
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer samples and repeats (a smoke run)")
    args = parser.parse_args()
    repeats, samples, levels = (1, 100, [1, 2, 4]) if args.quick else (3, 1000, [1, 2, 4, 8])

    steps = []
    details = []
    for reuse in (True, False):
        summary, rows = gripper_steps(reuse, repeats)
        steps.append(summary)
        details = details or rows
    print("Flap (1,323 nodes, 4,000 tets): warm-started equilibria for 2 mm gripper steps, one core")
    print(table(steps, list(steps[0])))
    print()
    print(table(details, list(details[0])))
    pieces = iteration_pieces()
    print("\nOne Newton iteration, by piece (median of 9)")
    print(table(pieces, ["piece", "median_ms"]))

    sampled = sampled_equilibria(samples, 25, 2)
    print(f"\n{samples} sampled grasp equilibria through run_tasks (local executor, 2 workers)")
    print(table([sampled], list(sampled)))

    convergence = cantilever(levels)
    print("\nCantilever, alpha = 1: tip deflection against the elastica (Bisshopp & Drucker)")
    print(table(convergence, list(convergence[0])))

    rows = (
        [{"part": "gripper steps", **r} for r in steps]
        + [{"part": "gripper step detail", **r} for r in details]
        + [{"part": "iteration pieces", **r} for r in pieces]
        + [{"part": "sampled equilibria", **sampled}]
        + [{"part": "cantilever convergence", **r} for r in convergence]
    )
    note = "flap 20x20x2 cells x5 tets; OMP_NUM_THREADS=1; medians over steps" + (" (quick)" if args.quick else "")
    print(f"\nwritten: {save('fem', rows, note)}")


if __name__ == "__main__":
    main()
