"""Interactive tissue: one warm-started quasi-static step of the flap after a 1 mm move of the grasp.

For a trainee to retract tissue live, the flap's equilibrium must follow the grasp at the display's rate:
the target (issue 34) is one step in at most 33 ms median (30 Hz) on one core. The flap is the left flap of
the shipped retraction config (``configs/retraction_incision.yaml``: its stvk settings, anchored edges and
jaws, loaded through ``load_pipeline``, so the benchmark follows the config), grasped at the stage's start.

The grasp moves 1 mm at a time along a retraction path (lift 20 mm, pull back 10 mm while lifting another
10 mm and tilting 20 degrees: 40 steps), each step's equilibrium solved from the previous one (warm start,
the factorisations the solver keeps between solves reused, as a live simulation would), ``--paths`` times
(default 5); the first step from rest is not counted (it is not a 1 mm move). Every step is the model's whole
``solve``: Newton and the validity checks of the state it reaches (no inverted element, no self-intersection
of the surface, as the config asks), with the Newton part reported apart. Linear tetrahedra (the config's
20 x 20 x 2 mesh: 1,323 nodes, 4,000 elements) and, for the record, quadratic ones (10 x 10 x 1, the same
flap). One thread (OMP_NUM_THREADS=1); the load average is in the results' provenance.

    python benchmarks/bench_tissue.py [--quick] [--paths N]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import ROOT, save, table

CONFIG = ROOT / "configs" / "retraction_incision.yaml"
TARGET_S = 1.0 / 30.0
STEP_M = 0.001


def flap(order: int):
    """(model, grasp frame) of the config's left flap; ``order`` 2: the same flap in quadratic tetrahedra."""
    from surgiplan import load_pipeline
    from surgiplan.plugins.fem import StVKModel, StVKSettings
    from surgiplan.plugins.planners.retraction.grasp import grasp_frame

    stage = load_pipeline(CONFIG).stages[0]
    settings = dict(stage.settings.deformable.settings)
    if order == 2:
        mesh = dict(settings["mesh"])
        mesh["box"] = {**mesh["box"], "divisions": [10, 10, 1]}
        settings["mesh"] = {**mesh, "order": 2}
    model = StVKModel(StVKSettings.model_validate(settings))
    frame = grasp_frame(model.rest_nodes, stage.settings.anchored, stage.settings.jaws, stage.start, "start")
    return model, frame


def grasp_path(q0: np.ndarray, steps: int) -> np.ndarray:
    """Gripper configurations (steps, 7) 1 mm apart (the jaws' centre): lift 20 mm, then pull back 10 mm while
    lifting 10 mm more and tilting 20 degrees about y."""
    from scipy.spatial.transform import Rotation

    lift = [np.array([0.0, 0.0, STEP_M * k]) for k in range(1, 21)]
    diagonal = np.array([-1.0, 0.0, 1.0]) / np.sqrt(2.0)
    pull = [lift[-1] + STEP_M * k * diagonal for k in range(1, 21)]
    out = []
    for k, offset in enumerate(lift + pull):
        tilt = 0.0 if k < 20 else np.radians(20.0) * (k - 19) / 20
        quaternion = (Rotation.from_euler("y", -tilt) * Rotation.from_quat(q0[3:])).as_quat()
        out.append(np.concatenate([q0[:3] + offset, quaternion]))
    return np.array(out[:steps])


def steps_of(order: int, paths: int, steps: int) -> list[dict]:
    model, frame = flap(order)
    path = grasp_path(np.asarray(frame.q0, float), steps)
    records = []
    for run in range(paths):
        model.clear_caches()  # each path from a cold start: nothing kept from the last one
        state = model.solve(frame.constraints(frame.q0))  # the grasp, from rest (not counted)
        assert state.converged and state.valid, state.message
        for k, q in enumerate(path):
            constraints = frame.constraints(q)
            started = time.perf_counter()
            state = model.solve(constraints, initial=state)
            elapsed = time.perf_counter() - started
            if not (state.converged and state.valid):
                raise SystemExit(f"step {k + 1} of path {run + 1} ({order=}): {state.message}")
            records.append(
                {
                    "path": run + 1,
                    "step": k + 1,
                    "time_s": elapsed,
                    "newton_s": float(state.data.get("newton_s", elapsed)),
                    "iterations": int(state.iterations),
                    "factorizations": int(state.data.get("factorizations", 0)),
                    "solver": state.data.get("linear_solver", "superlu"),
                }
            )
    return records


def summary(order: int, records: list[dict], model) -> dict:
    times = [r["time_s"] for r in records]
    newton = [r["newton_s"] for r in records]
    return {
        "elements": "linear 20x20x2 (the config's)" if order == 1 else "quadratic 10x10x1",
        "nodes": int(model.mesh.n_nodes),
        "tetrahedra": int(model.mesh.n_elements),
        "steps": len(records),
        "median_ms": round(1e3 * statistics.median(times), 2),
        "p90_ms": round(1e3 * float(np.percentile(times, 90)), 2),
        "max_ms": round(1e3 * max(times), 2),
        "newton_median_ms": round(1e3 * statistics.median(newton), 2),
        "rate_hz_at_median": round(1.0 / statistics.median(times), 1),
        "median_iterations": statistics.median(r["iterations"] for r in records),
        "median_factorizations": statistics.median(r["factorizations"] for r in records),
        "within_target": statistics.median(times) <= TARGET_S,
        "linear_solver": records[0]["solver"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1 path of 10 steps (checks the script; writes nothing)")
    parser.add_argument("--paths", type=int, default=5)
    args = parser.parse_args()
    paths, steps = (1, 10) if args.quick else (args.paths, 40)
    started = time.perf_counter()
    rows = []
    for order in (1, 2):
        records = steps_of(order, paths, steps)
        model, _ = flap(order)
        rows.append({"part": "steps", **summary(order, records, model)})
        print(table([rows[-1]], ["elements", "steps", "median_ms", "p90_ms", "max_ms", "newton_median_ms"]))
    notes = (
        f"{paths} paths of {steps} steps of {STEP_M * 1e3:g} mm (lift, then pull back and tilt), each warm-started "
        f"from the last, the solver's factorisations reused; target {TARGET_S * 1e3:.1f} ms median (30 Hz); one "
        f"thread; run took {time.perf_counter() - started:.0f} s"
    )
    if args.quick:
        print(f"(quick run: nothing written) {notes}")
        return
    # no peer: the target is the display's rate
    print(f"written: {save('tissue', rows, notes)}")


if __name__ == "__main__":
    main()
