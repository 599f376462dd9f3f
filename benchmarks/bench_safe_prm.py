"""safe_prm against every configuration of OMPL's PRM we could give it, on the block world (entry -> target).

For 500, 2,000 and 5,000 milestones and 5 seeds each, in one run on one
machine, the peer side by side:

* **safe_prm**: R and R_safe built together, every edge certified (exact or
  covering balls); the query (linking, A* in R, PathRepair through R_safe);
  smoothing (the corridor QP) timed apart. The query is timed as the plan
  stage reports it (``query_s``: linking, search and repair).
* **OMPL 2.0's PRM**, grown with ``growRoadmap`` and a termination condition
  on the milestone count (not a time budget) to the same number of
  milestones, in every configuration below; the **strongest** at a size is
  the one that builds fastest there, and safe_prm's build is compared with
  it. OMPL's own C++ state validity checkers cannot be written from Python;
  these are the fastest Python ones we could write:

  - ``scalar``: a pure-Python per-state test of the scene's axis-aligned
    boxes (the "boolean box checker"), OMPL's ``DiscreteMotionValidator`` at
    its default resolution (1 % of the space's extent: 1.85 mm between
    checked states in the block world, every point of a motion within 0.92 mm
    of one). It checks states, so a motion may clip an obstacle between them
    (counted below);
  - ``grid``: the same test behind a 1 mm voxel table made before the build
    (not timed): a cell certainly clear or certainly blocked answers at once,
    only the cells an obstacle's surface crosses run the box test; exact, the
    fastest checker here; discrete motions as ``scalar``;
  - ``grid-certified``: ``grid`` with the boxes grown by half the motion
    resolution, so that the discrete motions certify what safe_prm's edges
    do (every point of a motion within half a resolution of a checked state
    that keeps that much more);
  - ``vectorised``: one numpy query of all boxes per state (a general scene
    query's cost), discrete motions;
  - ``certified``: surgiplan's exact motion check as OMPL's motion
    validator (no corner cutting, like safe_prm's edges).

OMPL's query (``solve`` on the grown roadmap: it adds the start and goal as
milestones and searches) and its simplification (``PathSimplifier.
simplifyMax`` on a copy of the raw path) are timed for the strongest
configuration, like safe_prm's query and smoothing: medians of repeated runs
on the same roadmap. Path lengths and clearances are re-measured with coal.
OMPL with a 4 or 8 mm margin (states and motions must keep it) fails here:
the target lies behind a 6 mm gap (run with the strongest configuration).
OMPL's PRM connects each milestone to its 10 nearest (its default), safe_prm
to at most 15 within a radius (K-S); the roadmaps differ, the milestone
count is the same.

Last, the same 5,000-milestone plans run as pipelines (``surgiplan run``, one
plan stage per level): the build and query times the plan stage reports,
beside this benchmark's. Results carry their provenance (commit, load before
and after, OMPL's version and each configuration; ``benchmarks/common.py``).

A target holds only if it holds in every run: ``--runs N`` measures all of
it N times in a row (OMPL's builds too) and records each run's build ratio
and queries (rows ``safe_prm, every run``, with the ticks the host stole);
the README judges the targets on the worst run, and shows the last.

    python benchmarks/bench_safe_prm.py [--quick] [--runs N]   (--quick: 2 seeds, 500 and 2,000; writes nothing)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from common import package_version, save, steal_ticks, table
from ompl_prm import DESCRIPTION, OMPL_CONFIGS, QUERY_REPEATS, OmplPRM, measure_path, run_ompl
from surgiplan import PlanningProblem, load_scene
from surgiplan.allocator import keep_freed_memory
from surgiplan.plugins.planners.safe_prm.planner import SafePRM, SafePRMSettings
from surgiplan.spaces import R3Space
from surgiplan.threads import cpu_threads

ROOT = Path(__file__).resolve().parent.parent
MARGINS = {"expert": 0.0, "intermediate": 0.004, "beginner": 0.008}
# ----------------------------------------------------------------------------- safe_prm


def run_safe_prm(scene, space, milestones, seed, level):
    start, goal = scene.points["entry"], scene.points["target"]
    planner = SafePRM(SafePRMSettings(proficiency=level, milestones=milestones, seed=seed))
    t0 = time.perf_counter()
    artifact = planner.build(PlanningProblem(scene, space))
    build = time.perf_counter() - t0
    # the same build on one thread (the default uses two where it may: the roadmaps are the same)
    one = SafePRM(SafePRMSettings(proficiency=level, milestones=milestones, seed=seed, threads=1))
    t0 = time.perf_counter()
    one.build(PlanningProblem(scene, space))
    build_one_thread = time.perf_counter() - t0
    raw = planner.query(artifact, start, goal)  # the first query, as a pipeline's plan stage makes it
    first_query = raw.metrics["query_s"]
    queries, smooth = [], []
    for _ in range(QUERY_REPEATS):
        result = planner.query(artifact, start, goal)
        queries.append(result.metrics["query_s"])  # linking, search, repair: what the plan stage reports
        smooth.append(result.metrics.get("smooth_s", float("nan")))
    length, clearance, _ = measure_path(scene, result.path if result.solved else None)
    from surgiplan.plugins.planners.safe_prm import query as prm_query

    roadmap_path = prm_query.query(artifact.roadmap, start, goal)  # the roadmap answer, before smoothing
    # the query alone, back to back (caches warm: how VAMP's 35 us and OMPL's solve here are measured); the plan
    # stage's query above follows the previous query's smoothing, which leaves the roadmap's arrays out of cache
    warm = []
    for _ in range(QUERY_REPEATS):
        t0 = time.perf_counter()
        prm_query.query(artifact.roadmap, start, goal)
        warm.append(time.perf_counter() - t0)
    _, _, raw_clips = measure_path(scene, roadmap_path.path if roadmap_path.found else None)
    return {
        "build_s": build,
        "build_one_thread_s": build_one_thread,
        "query_ms": 1e3 * statistics.median(queries),
        "query_warm_ms": 1e3 * statistics.median(warm),
        "first_query_ms": 1e3 * first_query,
        "simplify_ms": 1e3 * statistics.median(smooth),
        "length_m": length,
        "min_clearance_m": clearance,
        "raw_clips": raw_clips,
        "solved": result.solved,
        "settled": roadmap_path.settled,
    }


def pipeline_times(milestones: int, seed: int) -> dict:
    """The plan stage's own build_s and query_s for the three levels: ``surgiplan run`` on a pipeline of three
    plan stages in a scratch directory (no stored roadmap: each stage builds)."""
    from surgiplan.cli import main as cli

    stages = "\n".join(
        f"  - {{stage: plan, name: {level}, plugin: safe_prm, start: entry, goal: target,\n"
        f"     settings: {{proficiency: {level}, milestones: {milestones}, k: 15, seed: {seed}}}}}"
        for level in MARGINS
    )
    with tempfile.TemporaryDirectory() as scratch:
        config = Path(scratch) / "pipeline.yaml"
        config.write_text(
            f"name: bench-safe-prm\nlength_unit: mm\nscene: {ROOT / 'configs/scenes/block_world.yaml'}\n"
            f"pipeline:\n{stages}\noutput: {{dir: {scratch}/out, figures: false, gltf: false}}\n"
        )
        code = cli(["run", str(config), "--quiet"])
        if code != 0:
            raise SystemExit(f"the pipeline failed (exit {code})")
        stages_out = json.loads((Path(scratch) / "out" / "result.json").read_text())["stages"]
    return {s["name"]: {k: s["metrics"][k] for k in ("build_s", "query_s", "search_settled")} for s in stages_out}


# ----------------------------------------------------------------------------- summary


def med(records, key):
    values = [r[key] for r in records if r.get(key) is not None]
    return statistics.median(values) if values else None


def fmt(value, scale=1.0, digits=3):
    return "—" if value is None else f"{value * scale:.{digits}g}"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="2 seeds, 500 and 2000 milestones; writes no results")
    parser.add_argument(
        "--runs",
        type=int,
        default=1,
        help="measure everything this many times in a row (the table: the last run; each run's build ratio and "
        "queries are recorded, and the targets are judged on the worst)",
    )
    args = parser.parse_args()
    if args.runs < 1:
        parser.error(f"--runs {args.runs}: at least 1")
    keep_freed_memory()  # as ``surgiplan`` does; for the whole process, so OMPL's runs too (surgiplan.allocator)
    load = os.getloadavg()
    started = time.perf_counter()
    sizes = (500, 2000) if args.quick else (500, 2000, 5000)
    seeds = range(1, 3) if args.quick else range(1, 6)
    scene = load_scene(ROOT / "configs/scenes/block_world.yaml")
    space = R3Space(scene)
    from ompl import util as ou

    ou.setLogLevel(ou.LOG_WARN)
    ou.RNG.setSeed(1)  # once per process; later builds continue the stream, so every run differs
    every_run = []  # each run's build ratio and queries at each size (the targets hold only if they hold in all)
    for run in range(1, args.runs + 1):
        stolen = steal_ticks()
        rows, strongest_by_size, arena = measure(scene, space, sizes, seeds)
        stolen = steal_ticks() - stolen
        for row in rows:
            if row["planner"].startswith("safe_prm ("):
                every_run.append(
                    {
                        "planner": "safe_prm, every run",
                        "run": run,
                        "milestones": row["milestones"],
                        "strongest_ompl": row["strongest_ompl"],
                        "build_ratio_vs_strongest": row["build_ratio_vs_strongest"],
                        "query_warm_ms": row["query_warm_ms"],
                        "query_repair_warm_ms_4mm": row["query_repair_warm_ms_4mm"],
                        "query_repair_warm_ms_8mm": row["query_repair_warm_ms_8mm"],
                        "query_repair_ms_4mm": row["query_repair_ms_4mm"],
                        "query_repair_ms_8mm": row["query_repair_ms_8mm"],
                        "steal_ticks": stolen,
                    }
                )
        print(f"  run {run} of {args.runs} done ({stolen} ticks stolen)", file=sys.stderr, flush=True)
    columns = [
        "planner",
        "milestones",
        "seeds",
        "build_s",
        "build_ratio",
        "query_ms",
        "query_repair_ms_4mm",
        "query_repair_ms_8mm",
        "query_ratio",
        "simplify_ms",
        "length_mm",
        "length_vs_ompl",
        "min_clear_mm",
        "raw_paths_clipping",
        "success_0_4_8mm",
    ]
    print(table(rows, columns))
    if args.runs > 1:
        print(table(every_run, list(every_run[0])))
    rows += every_run
    finish(args, scene, space, sizes, rows, strongest_by_size, arena, load, started)


def measure(scene, space, sizes, seeds) -> tuple[list, dict, dict]:
    """One run: every size and seed, ours and every OMPL configuration. Returns (rows, the strongest OMPL
    configuration at each size, every measured run per size for Planner Arena)."""
    rows = []
    strongest_by_size = {}
    arena = {}  # per size, every measured run, for Planner Arena
    for milestones in sizes:
        ours = {level: [] for level in MARGINS}
        theirs = {config: [] for config in OMPL_CONFIGS}
        for seed in seeds:
            for level in MARGINS:
                ours[level].append(run_safe_prm(scene, space, milestones, seed, level))
            for config in OMPL_CONFIGS:
                theirs[config].append(run_ompl(scene, space, milestones, 0.0, config, answer=False))
            print(f"  {milestones} milestones, seed {seed} done", file=sys.stderr, flush=True)
        builds = {config: med(theirs[config], "build_s") for config in OMPL_CONFIGS}
        strongest = min(builds, key=builds.get)
        strongest_by_size[milestones] = strongest
        # the strongest configuration answers the query (margin 0) and tries the margins
        answered = {level: [] for level in MARGINS}
        for _ in seeds:
            for level, margin in MARGINS.items():
                answered[level].append(run_ompl(scene, space, milestones, margin, strongest))
        n_seeds = len(seeds)
        arena[milestones] = {f"safe_prm ({level})": ours[level] for level in MARGINS}
        arena[milestones] |= {f"OMPL PRM ({c})": theirs[c] for c in OMPL_CONFIGS if c != strongest}
        arena[milestones][f"OMPL PRM ({strongest})"] = answered["expert"]  # its own build, and the query
        # R + R_safe: the intermediate and beginner builds (the expert's R_safe is R)
        ours_build = med(ours["intermediate"] + ours["beginner"], "build_s")
        ours_one_thread = med(ours["intermediate"] + ours["beginner"], "build_one_thread_s")
        ours_query = med(ours["intermediate"] + ours["beginner"], "query_ms")
        expert = answered["expert"]
        row = {
            "planner": "safe_prm (R + R_safe, certified)",
            "milestones": milestones,
            "seeds": n_seeds,
            "build_s": fmt(ours_build),
            "threads": cpu_threads(),
            "build_one_thread_s": fmt(ours_one_thread),
            "query_ms": fmt(med(ours["expert"], "query_ms")),
            "query_repair_ms_4mm": fmt(med(ours["intermediate"], "query_ms")),
            "query_repair_ms_8mm": fmt(med(ours["beginner"], "query_ms")),
            "first_query_ms": fmt(med(ours["intermediate"] + ours["beginner"], "first_query_ms")),
            "query_warm_ms": fmt(med(ours["expert"], "query_warm_ms")),
            "query_repair_warm_ms_4mm": fmt(med(ours["intermediate"], "query_warm_ms")),
            "query_repair_warm_ms_8mm": fmt(med(ours["beginner"], "query_warm_ms")),
            "simplify_ms": fmt(med(ours["expert"], "simplify_ms")),
            "length_mm": fmt(med(ours["expert"], "length_m"), 1e3, 4),
            "min_clear_mm": fmt(med(ours["expert"], "min_clearance_m"), 1e3),
            "raw_paths_clipping": f"{sum(bool(r['raw_clips']) for r in ours['expert'])}/{n_seeds}",
            "success_0_4_8mm": "/".join(f"{sum(r['solved'] for r in ours[lv])}" for lv in MARGINS) + f" of {n_seeds}",
            "settled_median": fmt(med(ours["beginner"], "settled"), 1, 4),
            "strongest_ompl": strongest,
            "build_ratio_vs_strongest": f"{builds[strongest] / ours_build:.1f}x",
            "build_ratio_vs_strongest_one_thread": f"{builds[strongest] / ours_one_thread:.1f}x",
        }
        ref = med(expert, "length_m")
        if ref and med(ours["expert"], "length_m"):
            row["length_vs_ompl"] = f"{100 * (med(ours['expert'], 'length_m') / ref - 1):+.1f}%"
        rows.append(row)
        for config in OMPL_CONFIGS:
            build = builds[config]
            entry = {
                "planner": f"OMPL PRM ({config})",
                "milestones": milestones,
                "seeds": n_seeds,
                "build_s": fmt(build),
                "build_ratio": f"{build / ours_build:.1f}x",
                "strongest": config == strongest,
                "edges_median": fmt(med(theirs[config], "edges"), 1, 5),
            }
            if config == strongest:
                entry.update(
                    query_ms=fmt(med(expert, "query_ms")),
                    query_ratio=f"{med(expert, 'query_ms') / ours_query:.1f}x" if med(expert, "query_ms") else "—",
                    simplify_ms=fmt(med(expert, "simplify_ms")),
                    length_mm=fmt(med(expert, "length_m"), 1e3, 4),
                    min_clear_mm=fmt(med(expert, "min_clearance_m"), 1e3),
                    raw_paths_clipping=f"{sum(bool(r.get('raw_clips')) for r in expert)}/{n_seeds}",
                    success_0_4_8mm="/".join(f"{sum(r['solved'] for r in answered[lv])}" for lv in MARGINS)
                    + f" of {n_seeds}",
                )
            rows.append(entry)
    return rows, strongest_by_size, arena


def finish(args, scene, space, sizes, rows, strongest_by_size, arena, load, started) -> None:
    """The plan stage's own times, then the results file and Planner Arena's (the last run's)."""
    largest = sizes[-1]
    pipeline = pipeline_times(largest, 1)
    ours_seed1 = {
        level: run_safe_prm(scene, space, largest, 1, level) for level in MARGINS
    }  # the same plans, as this benchmark times them
    for level, stage in pipeline.items():
        rows.append(
            {
                "planner": "safe_prm, plan stage (surgiplan run)",
                "milestones": largest,
                "level": level,
                "seed": 1,
                "pipeline_build_s": round(stage["build_s"], 5),
                "pipeline_query_ms": round(1e3 * stage["query_s"], 4),
                "benchmark_build_s": round(ours_seed1[level]["build_s"], 5),
                "benchmark_first_query_ms": round(ours_seed1[level]["first_query_ms"], 4),
                "benchmark_query_ms": round(ours_seed1[level]["query_ms"], 4),
                "settled": stage["search_settled"],
            }
        )
        print(rows[-1])
    resolution = 1e3 * OmplPRM(scene, space, "scalar", 0.0).resolution_m
    notes = (
        f"block world, entry -> target; medians over seeds (build) and over {QUERY_REPEATS} repeats per seed "
        "(query, simplification), then over seeds. build_ratio = OMPL's build of its one roadmap / safe_prm's "
        "build of R + R_safe (median of the 4 and 8 mm builds; on the threads surgiplan.threads.cpu_threads gives, "
        "and, for the record, on one: build_one_thread_s; OMPL's PRM grows its roadmap on one); the strongest OMPL "
        "configuration at a size is the "
        "fastest to build there (it alone answers the query and tries the margins); query_ratio = its query (solve "
        "on the grown roadmap) / safe_prm's query with repair (4 and 8 mm), safe_prm's query as the plan stage "
        f"reports it (query_s: linking, search, repair). OMPL's DiscreteMotionValidator at {resolution:.3g} mm "
        "between states (its default). Length and clearance of the margin-0 path after each planner's own "
        "simplification (safe_prm: corridor QP; OMPL: simplifyMax), re-measured with coal. Load average at start "
        f"{load[0]:.2f}/{load[1]:.2f}/{load[2]:.2f} on {os.cpu_count()} cores (shared machine); run took "
        f"{time.perf_counter() - started:.0f} s"
        + (
            f"; {args.runs} runs in a row, the table from the last, each run's figures in the rows "
            "'safe_prm, every run'"
            if args.runs > 1
            else ""
        )
    )
    if args.quick:
        print(f"\n(quick run: nothing written) {notes}")
        return
    peers = {
        "OMPL": {
            "version": package_version("ompl"),
            "planner": "geometric PRM (10 nearest neighbours), growRoadmap to the milestone count",
            "configurations": DESCRIPTION,
            "motion_resolution_mm": round(resolution, 4),
            "strongest": {str(m): c for m, c in strongest_by_size.items()},
        }
    }
    print(f"\nwritten: {save('safe_prm_vs_ompl', rows, notes, peers=peers)}")
    from bench_plannerarena import write_arena

    for milestones, planners in arena.items():  # the same runs, for Planner Arena
        log, database = write_arena(f"safe_prm-block-world-{milestones}", planners, {"milestones INTEGER": milestones})
        print(f"written: {log}, {database}")


if __name__ == "__main__":
    main()
