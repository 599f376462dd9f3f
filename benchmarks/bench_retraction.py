"""retraction: the paper's Tables I and II on its two scenarios (paper 002, Patil & Alterovitz, §VI).

Table I: per initial grasp, 1,000 random samples of the paper's flap (1,323
nodes, 4,000 tetrahedra), their generation time (equilibria with the
rotation's local optimisation, checks, visibility, roadmap; the executor's
2 workers), then the lazy planning time split like the paper's columns:
collision detection, mesh validation (inverted elements, self-intersection),
FEM along edges, and the total (median of repeated queries, each from
scratch: no edge validated). The paper: 1.2 h / 3.0 h on 8 cores, 33 s / 83 s
of serial planning. Our targets: generation <= 5 minutes here, planning <= 5 s.

Table II (published unfilled): random sampling (1,000) against user-guided
sampling (200 samples around the straight line from the grasp to the
surgeon's estimate of the final gripper position, Fig. 4): generation time,
and the RMS over grasps of the relative error of the optimised metric
(min-max energy, min-max stress) with respect to random sampling.

Scenarios are the shipped configs: ``configs/retraction_incision.yaml``
(left flap) and ``configs/retraction_veins.yaml``; ``--grasps`` of each
config's candidates are used (the stage's start first).

    python benchmarks/bench_retraction.py [--quick] [--grasps 2] [--samples 1000] [--guided 200] [--store DIR]
    python benchmarks/bench_retraction.py --compare REF [--rounds 1] [--scenarios 1 2]

``--store DIR`` keeps the checkpointed equilibria between runs (resumable);
timings of a resumed run are not generation times.

``--compare REF`` measures sample generation (1,000 random samples, one
grasp, the executor's 2 workers) of this tree and of the git revision REF
(e.g. the commit before a speed-up) in the same run, alternating which goes
first, each in a fresh process with an empty task store, and compares the
plans both find (the optimised costs of both metrics on the roadmap):
``results/retraction_speed.json``. The machine is shared, so both sides of a
comparison meet the same load, which is recorded (1-minute load average at
the start and end of each generation).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core per worker process
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import save, table
from surgiplan import load_pipeline
from surgiplan.executors import LocalExecutor
from surgiplan.planning import PlanningProblem
from surgiplan.plugins.planners.retraction.lazy import LazyPlanner
from surgiplan.plugins.planners.retraction.planner import RetractionPlanner
from surgiplan.progress import RichProgress

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
#: (config, stage, the surgeon's estimate of the final gripper position in mm, paper's Table I row)
SCENARIOS = {
    1: (
        "retraction_incision.yaml",
        "left-flap",
        [30, 25, 14],
        {"hours": 1.212, "cd": 0.563, "mv": 24.94, "fem": 7.113, "total": 32.713},
    ),
    2: (
        "retraction_veins.yaml",
        "min-stress",
        [36, 36, 20],
        {"hours": 3.027, "cd": 1.803, "mv": 32.85, "fem": 48.147, "total": 83.316},
    ),
}


def stage_data(config: str, stage: str) -> dict:
    data = yaml.safe_load((CONFIGS / config).read_text())
    data["pipeline"] = [s for s in data["pipeline"] if s["name"] == stage]
    for s in data["pipeline"]:
        s.pop("artifact", None)
        material = s["settings"]["deformable"]["settings"].get("material", {})
        for region in material.get("regions", []):
            if "image" in region:
                region["image"]["file"] = str(CONFIGS / region["image"]["file"])
    return data


def plan_once(data: dict, grasp_xyz, sampling: dict, goal, executor, store: Path, repeats: int) -> dict:
    """Build (timed once) and query (median of ``repeats``) one grasp; both metrics on the same roadmap."""
    stage = data["pipeline"][0]
    stage["start"] = {"xyz": list(grasp_xyz)}
    stage["settings"]["grasps"] = {}
    stage["settings"]["sampling"].update(sampling)
    stage["settings"]["figures"] = False
    if goal is not None:
        stage["goal"] = list(goal)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "p.yaml"
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        spec = load_pipeline(path).stages[0]
    problem = PlanningProblem(
        spec.scene, spec.space, executor, RichProgress(), store / "stage", start=spec.start, goal=spec.goal
    )
    planner = RetractionPlanner(spec.settings)
    started = time.perf_counter()
    artifact = planner.build(problem)
    generation = time.perf_counter() - started
    row = {"generation_s": generation, "samples": sum(r.samples for r in artifact.roadmaps)}
    roadmap = artifact.roadmaps[0]
    row["valid"] = int(roadmap.ok[1:].sum())
    row["goals"] = int((roadmap.ok & (roadmap.visible >= spec.settings.visibility.threshold - 1e-12)).sum())
    row["edges"] = len(roadmap.edges)
    row["fem_cpu_s"] = roadmap.timing.get("fem_s", 0.0)
    row["build_timing"] = {k: round(float(v), 3) for k, v in roadmap.timing.items()}
    for metric in ("max_energy", "max_stress"):
        runs = []
        for _ in range(repeats):
            artifact.setup.settings = spec.settings.model_copy(update={"metric": metric})
            lazy = LazyPlanner(artifact.setup, artifact.roadmaps)
            lazy.settings = artifact.setup.settings
            lazy.metric = metric
            started = time.perf_counter()
            outcome = lazy.plan()
            total = time.perf_counter() - started
            runs.append((total, dict(lazy.timing), outcome))
        totals = [r[0] for r in runs]
        median = sorted(range(len(runs)), key=lambda i: totals[i])[len(runs) // 2]
        total, timing, outcome = runs[median]
        path = outcome.grasps[0].path
        row[metric] = {
            "cost": path.value if path is not None else None,
            "total_s": statistics.median(totals),
            "collision_s": timing["collision_s"],
            "mesh_validation_s": timing["validation_s"],
            "fem_s": timing["fem_s"],
            "search_s": timing["search_s"],
            "smoothing_s": timing["smoothing_s"],
            "edges_validated": outcome.validated_edges,
            "status": "solved" if outcome.trajectory is not None else outcome.message[:120],
        }
    return row


def generation_worker(root: str, out: str, scenario: int, samples: int) -> None:
    """One generation (random samples, the stage's start grasp) with the tree ``root``'s own plan_once."""
    import importlib.util
    import json

    spec = importlib.util.spec_from_file_location("tree_bench", Path(root) / "benchmarks" / "bench_retraction.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    config, stage, _, _ = bench.SCENARIOS[scenario]
    data = bench.stage_data(config, stage)
    grasp = data["pipeline"][0]["start"]["xyz"]
    executor = LocalExecutor(2)
    load = os.getloadavg()[0]
    try:
        with tempfile.TemporaryDirectory() as store:
            row = bench.plan_once(data, grasp, {"kind": "uniform", "samples": samples}, None, executor, Path(store), 1)
    finally:
        executor.close()
    result = {
        "generation_s": row["generation_s"],
        "load_start": load,
        "load_end": os.getloadavg()[0],
        "valid": row["valid"],
        "goals": row["goals"],
        "edges": row["edges"],
        "fem_cpu_s": row["fem_cpu_s"],
        "cost_max_energy": row["max_energy"]["cost"],
        "cost_max_stress": row["max_stress"]["cost"],
        "status": [row["max_energy"]["status"], row["max_stress"]["status"]],
        "build_timing": row.get("build_timing"),
    }
    Path(out).write_text(json.dumps(result))


def export_tree(ref: str, where: Path) -> Path:
    """``git archive REF`` unpacked in ``where``, importable as ``surgiplan`` (PYTHONPATH=where/src)."""
    root = Path(__file__).resolve().parent.parent
    archive = subprocess.run(["git", "-C", str(root), "archive", ref], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(where)], input=archive, check=True)
    (where / "src").mkdir()
    (where / "src" / "surgiplan").symlink_to(where / "framework")
    (where / "framework" / "plugins").symlink_to(where / "plugins")
    return where


def compare(ref: str, scenarios: list[int], rounds: int, samples: int) -> None:
    """Generation time and plans of this tree against revision ``ref``, alternating, in the same run."""
    import json

    root = Path(__file__).resolve().parent.parent
    commit = subprocess.run(["git", "-C", str(root), "rev-parse", ref], capture_output=True, text=True, check=True)
    here = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, check=True)
    dirty = subprocess.run(
        ["git", "-C", str(root), "status", "--porcelain", "--", "plugins", "framework"], capture_output=True, text=True
    ).stdout.strip()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-retraction-ref-") as scratch:
        baseline = export_tree(ref, Path(scratch))
        trees = {"baseline": (baseline, str(baseline / "src")), "current": (root, "")}
        for scenario in scenarios:
            for round_ in range(rounds):
                order = ["baseline", "current"] if round_ % 2 == 0 else ["current", "baseline"]
                for name in order:
                    tree, path = trees[name]
                    out = Path(scratch) / f"{name}-{scenario}-{round_}.json"
                    env = dict(os.environ, PYTHONPATH=path) if path else dict(os.environ)
                    if not path:
                        env.pop("PYTHONPATH", None)
                    command = [
                        sys.executable,
                        str(Path(__file__).resolve()),
                        "--generation-worker",
                        str(tree),
                        str(out),
                        str(scenario),
                        str(samples),
                    ]
                    subprocess.run(command, env=env, check=True, cwd=scratch)
                    result = json.loads(out.read_text())
                    rows.append({"scenario": scenario, "round": round_, "tree": name, **result})
                    print(
                        f"scenario {scenario} round {round_} {name}: {result['generation_s']:.1f} s "
                        f"(load {result['load_start']:.1f} -> {result['load_end']:.1f}), costs "
                        f"{result['cost_max_energy']:.6g} J, {result['cost_max_stress']:.6g} Pa",
                        flush=True,
                    )
    summary = []
    for scenario in scenarios:
        mine = [r for r in rows if r["scenario"] == scenario]
        base = [r for r in mine if r["tree"] == "baseline"]
        new = [r for r in mine if r["tree"] == "current"]
        b, c = statistics.median(r["generation_s"] for r in base), statistics.median(r["generation_s"] for r in new)
        summary.append(
            {
                "scenario": scenario,
                "samples": samples,
                "baseline_generation_s": round(b, 1),
                "current_generation_s": round(c, 1),
                "target_s": 150,
                "speedup": round(b / c, 2),
                "cost_change_max_energy": (new[0]["cost_max_energy"] - base[0]["cost_max_energy"])
                / base[0]["cost_max_energy"],
                "cost_change_max_stress": (new[0]["cost_max_stress"] - base[0]["cost_max_stress"])
                / base[0]["cost_max_stress"],
                "valid_baseline_current": [base[0]["valid"], new[0]["valid"]],
                "goals_baseline_current": [base[0]["goals"], new[0]["goals"]],
            }
        )
    print(table(summary, list(summary[0])))
    notes = (
        f"baseline {ref} = {commit.stdout.strip()[:12]}, current HEAD {here.stdout.strip()[:12]}"
        + (" with uncommitted changes" if dirty else "")
        + f"; {samples} random samples, the stage's start grasp, local executor with 2 workers, "
        f"OMP_NUM_THREADS=1, {rounds} round(s) alternating which tree goes first; each generation in a fresh "
        f"process with an empty task store; {os.cpu_count()} cores shared with other work: load averages per run "
        "in the rows"
    )
    peers = {
        "surgiplan (baseline)": {
            "version": commit.stdout.strip(),
            "configuration": f"git archive {ref}, run the same way in a fresh process, alternating with this tree",
        }
    }
    path = save("retraction_speed", rows, notes, peers=peers, extra={"summary": summary})
    print(f"wrote {path}")


def main() -> None:
    load_at_start = os.getloadavg()[0]  # the notes say whether the timings are upper bounds
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="reduced sizes (checks the script, not the numbers)")
    parser.add_argument("--grasps", type=int, default=2)
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--guided", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scenarios", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--store", type=Path, default=None)
    parser.add_argument("--compare", metavar="REF", help="generation time and plans against git revision REF")
    parser.add_argument("--rounds", type=int, default=1, help="with --compare: rounds, alternating the order")
    args = parser.parse_args()
    if args.compare:
        compare(args.compare, args.scenarios, args.rounds, args.samples)
        return
    if args.quick:
        args.samples, args.guided, args.grasps, args.repeats = 60, 20, 1, 1
    executor = LocalExecutor(2)
    rows, detail = [], []
    store_root = args.store or Path(tempfile.mkdtemp(prefix="bench-retraction-"))
    try:
        for scenario in args.scenarios:
            config, stage, estimate, paper = SCENARIOS[scenario]
            data = stage_data(config, stage)
            settings = data["pipeline"][0]["settings"]
            start = data["pipeline"][0]["start"]["xyz"]
            grasps = [start]
            for edge in settings.get("grasps", {}).get("edges", []):
                a, b = np.asarray(edge["start"], float), np.asarray(edge["end"], float)
                grasps += [[float(v) for v in a + f * (b - a)] for f in np.linspace(0, 1, edge["count"])]
            unique = []
            for g in grasps:
                if not any(np.allclose(g, u) for u in unique):
                    unique.append(g)
            results = {"random": [], "guided": []}
            for g in unique[: args.grasps]:
                for kind, sampling, goal in (
                    ("random", {"kind": "uniform", "samples": args.samples}, None),
                    ("guided", {"kind": "guided", "samples": args.guided, "spread": 4}, estimate),
                ):
                    row = plan_once(
                        stage_data(config, stage),
                        g,
                        sampling,
                        goal,
                        executor,
                        store_root / f"s{scenario}",
                        args.repeats,
                    )
                    row.update({"scenario": scenario, "sampling": kind, "grasp_mm": g})
                    results[kind].append(row)
                    detail.append(row)
                    print(
                        f"scenario {scenario} grasp {g} {kind}: {row['samples']} samples in "
                        f"{row['generation_s']:.0f} s; energy {row['max_energy']}; stress {row['max_stress']}",
                        flush=True,
                    )
            gen = [r["generation_s"] for r in results["random"]]
            metric = "max_energy" if scenario == 1 else "max_stress"
            planning = [r[metric]["total_s"] for r in results["random"]]

            def mean(rs, key, metric=metric):
                return float(np.mean([r[metric][key] for r in rs]))

            rows.append(
                {
                    "table": "I",
                    "scenario": scenario,
                    "metric": metric,
                    "samples": args.samples,
                    "generation_s": round(float(np.mean(gen)), 1),
                    "generation_sd_s": round(float(np.std(gen)), 1),
                    "generation_target_s": 300,
                    "collision_s": round(mean(results["random"], "collision_s"), 3),
                    "mesh_validation_s": round(mean(results["random"], "mesh_validation_s"), 3),
                    "fem_s": round(mean(results["random"], "fem_s"), 3),
                    "planning_s": round(float(np.mean(planning)), 3),
                    "planning_sd_s": round(float(np.std(planning)), 3),
                    "planning_target_s": 5,
                    "paper_generation_s": paper["hours"] * 3600,
                    "paper_cores": 8,
                    "paper_collision_s": paper["cd"],
                    "paper_mesh_validation_s": paper["mv"],
                    "paper_fem_s": paper["fem"],
                    "paper_planning_s": paper["total"],
                }
            )
            errors = {}
            for m in ("max_energy", "max_stress"):
                rel = [
                    (g[m]["cost"] - r[m]["cost"]) / r[m]["cost"]
                    for r, g in zip(results["random"], results["guided"], strict=True)
                    if r[m]["cost"] and g[m]["cost"] is not None
                ]
                errors[m] = round(float(np.sqrt(np.mean(np.square(rel)))), 4) if rel else None
                errors[m + "_solved"] = f"{len(rel)}/{len(results['random'])}"
            guided_gen = [r["generation_s"] for r in results["guided"]]
            rows.append(
                {
                    "table": "II",
                    "scenario": scenario,
                    "random_samples": args.samples,
                    "random_generation_s": round(float(np.mean(gen)), 1),
                    "guided_samples": args.guided,
                    "guided_generation_s": round(float(np.mean(guided_gen)), 1),
                    "guided_generation_sd_s": round(float(np.std(guided_gen)), 1),
                    "rms_rel_error_max_energy": errors["max_energy"],
                    "rms_rel_error_max_stress": errors["max_stress"],
                    "guided_plans_found_energy": errors["max_energy_solved"],
                    "guided_plans_found_stress": errors["max_stress_solved"],
                }
            )
    finally:
        executor.close()
    print(
        table(
            [r for r in rows if r["table"] == "I"],
            [
                "scenario",
                "samples",
                "generation_s",
                "collision_s",
                "mesh_validation_s",
                "fem_s",
                "planning_s",
                "paper_generation_s",
                "paper_planning_s",
            ],
        )
    )
    print(
        table(
            [r for r in rows if r["table"] == "II"],
            [
                "scenario",
                "random_samples",
                "random_generation_s",
                "guided_samples",
                "guided_generation_s",
                "rms_rel_error_max_energy",
                "rms_rel_error_max_stress",
            ],
        )
    )
    notes = (
        f"{'quick sizes; ' if args.quick else ''}{args.samples} random and {args.guided} user-guided samples, "
        f"{args.grasps} grasp(s) per scenario, local executor with 2 workers, "
        f"OMP_NUM_THREADS=1; planning = median of {args.repeats} lazy queries from scratch; load average "
        f"at the start {load_at_start:.1f} on {os.cpu_count()} cores (timings are upper bounds when it is high)"
    )
    if args.quick:
        return  # a check of the script: results/retraction.json holds full runs only
    path = save("retraction", rows + [{"table": "detail", **d} for d in detail], notes)
    print(f"wrote {path}")


if __name__ == "__main__":
    if len(sys.argv) == 6 and sys.argv[1] == "--generation-worker":
        generation_worker(sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5]))
    else:
        main()
