"""safe_prm against OMPL's PRM on the block world (paper 000's query: entry -> target).

For 500, 2000 and 5000 milestones and 5 seeds each, in one run on one machine:

* roadmap build time (safe_prm builds R and R_safe together; OMPL's PRM one roadmap),
* query time (safe_prm: linking, search and repair; smoothing reported apart), for the
  expert (nothing to repair) and for the 4 mm and 8 mm thresholds (repairs, critical regions),
* path length after each planner's own smoothing (safe_prm: the corridor QP;
  OMPL: PathSimplifier.simplifyMax), and its minimum clearance, re-measured with coal,
* raw paths (before smoothing) that clip an obstacle, measured with coal,
* success with a 4 mm and an 8 mm margin (safe_prm: intermediate / beginner;
  OMPL: states and motions must keep the margin).

OMPL runs through the surgiplan bridge, so its validity checks are Python
callbacks into the same scene; margin 0 uses OMPL's own discrete motion
checker (its default, the one that can clip), the margins use the certified
one (OMPL has no notion of a margin otherwise).

    python benchmarks/bench_safe_prm.py [--quick]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from common import save, table
from helpers import coal_scene_segment_distance
from surgiplan import PlanningProblem, load_scene
from surgiplan.plugins.planners.safe_prm import query as prm_query
from surgiplan.plugins.planners.safe_prm.planner import SafePRM, SafePRMSettings
from surgiplan.spaces import R3Space

ROOT = Path(__file__).resolve().parent.parent
MARGINS = {"expert": 0.0, "intermediate": 0.004, "beginner": 0.008}


def measure_path(scene, path):
    if path is None or len(path) < 2:
        return None, None, None
    clearance = coal_scene_segment_distance(scene, path[:-1], path[1:])
    return (
        float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()),
        float(clearance.min()),
        bool(clearance.min() <= 0),
    )


def run_safe_prm(scene, space, milestones, seed, level):
    start, goal = scene.points["entry"], scene.points["target"]
    planner = SafePRM(SafePRMSettings(proficiency=level, milestones=milestones, seed=seed))
    t0 = time.perf_counter()
    artifact = planner.build(PlanningProblem(scene, space))
    build = time.perf_counter() - t0
    raw = prm_query.query(artifact.roadmap, start, goal)  # the roadmap answer, before smoothing
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        prm_query.query(artifact.roadmap, start, goal)
        times.append(time.perf_counter() - t0)
    result = planner.query(artifact, start, goal)
    length, clearance, _ = measure_path(scene, result.path if result.solved else None)
    _, _, raw_clips = measure_path(scene, raw.path if raw.found else None)
    return {
        "build_s": build,
        "query_s": statistics.median(times),
        "smooth_s": result.metrics.get("smooth_s"),
        "length_m": length,
        "min_clearance_m": clearance,
        "raw_clips": raw_clips,
        "solved": result.solved,
        "critical_regions": len(result.metrics.get("critical_regions", [])) if result.solved else None,
    }


def run_ompl(scene, space, milestones, margin):
    from surgiplan.plugins.planners.ompl_bridge.bridge import OmplPlanner, OmplSettings

    start, goal = scene.points["entry"], scene.points["target"]
    motion = "discrete" if margin == 0 else "certified"
    planner = OmplPlanner(
        OmplSettings(
            planner="PRM",
            milestones=milestones,
            margin=margin,
            motion_check=motion,
            resolution=0.01,
            time_limit=1.0,
            build_time=600,
            # OMPL's RNG is seeded once per process (the bridge keeps the first seed); later runs
            # continue its stream, so the runs still differ from seed to seed
            seed=1,
            simplify=False,
        )
    )
    t0 = time.perf_counter()
    artifact = planner.build(PlanningProblem(scene, space))
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    raw = planner.query(artifact, start, goal)
    query = time.perf_counter() - t0
    length = clearance = raw_clips = None
    if raw.solved:
        _, _, raw_clips = measure_path(scene, raw.path)
        from ompl import geometric as og

        path = og.PathGeometric(artifact.si)
        for q in raw.path:
            state = artifact.space.allocState()
            planner._to_state(q, state, space)
            path.append(state)
        og.PathSimplifier(artifact.si).simplifyMax(path)
        simplified = np.array([planner._to_numpy(path.getState(i), space) for i in range(path.getStateCount())])
        length, clearance, _ = measure_path(scene, simplified)
    return {
        "build_s": build,
        "query_s": query,
        "length_m": length,
        "min_clearance_m": clearance,
        "raw_clips": raw_clips,
        "solved": raw.solved,
    }


def summarise(records, planner, milestones):
    def med(key, margin="expert"):
        values = [r[key] for r in records[margin] if r.get(key) is not None]
        return statistics.median(values) if values else None

    def fmt(value, scale=1.0, digits=3):
        return "—" if value is None else f"{value * scale:.{digits}g}"

    clips = sum(1 for r in records["expert"] if r["raw_clips"])
    return {
        "planner": planner,
        "milestones": milestones,
        "seeds": len(records["expert"]),
        "build_s": fmt(med("build_s")),
        "query_ms": fmt(med("query_s"), 1e3),
        "query_ms_4mm": fmt(med("query_s", "intermediate"), 1e3) if planner == "safe_prm" else "—",
        "query_ms_8mm": fmt(med("query_s", "beginner"), 1e3) if planner == "safe_prm" else "—",
        "smooth_ms": fmt(med("smooth_s"), 1e3) if planner == "safe_prm" else "—",
        "length_mm": fmt(med("length_m"), 1e3, 4),
        "min_clear_mm": fmt(med("min_clearance_m"), 1e3),
        "raw_paths_clipping": f"{clips}/{len(records['expert'])}",
        "success_4mm": f"{sum(r['solved'] for r in records['intermediate'])}/{len(records['intermediate'])}",
        "success_8mm": f"{sum(r['solved'] for r in records['beginner'])}/{len(records['beginner'])}",
        "_build_median": med("build_s"),
        "_length_median": med("length_m"),
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="2 seeds, 500 and 2000 milestones")
    args = parser.parse_args()
    sizes = (500, 2000) if args.quick else (500, 2000, 5000)
    seeds = range(1, 3) if args.quick else range(1, 6)
    scene = load_scene(ROOT / "configs/scenes/block_world.yaml")
    space = R3Space(scene)
    rows = []
    for milestones in sizes:
        ours = {level: [] for level in MARGINS}
        theirs = {level: [] for level in MARGINS}
        for seed in seeds:
            for level, margin in MARGINS.items():
                ours[level].append(run_safe_prm(scene, space, milestones, seed, level))
                theirs[level].append(run_ompl(scene, space, milestones, margin))
            print(f"  {milestones} milestones, seed {seed} done", file=sys.stderr, flush=True)
        a = summarise(ours, "safe_prm", milestones)
        b = summarise(theirs, "ompl PRM", milestones)
        a["build_speedup"] = f"{b['_build_median'] / a['_build_median']:.0f}x"
        if a["_length_median"] and b["_length_median"]:
            a["length_vs_ompl"] = f"{100 * (a['_length_median'] / b['_length_median'] - 1):+.1f}%"
        rows += [a, b]
    for r in rows:
        r.pop("_build_median")
        r.pop("_length_median")
    columns = [
        "planner",
        "milestones",
        "seeds",
        "build_s",
        "build_speedup",
        "query_ms",
        "query_ms_4mm",
        "query_ms_8mm",
        "smooth_ms",
        "length_mm",
        "length_vs_ompl",
        "min_clear_mm",
        "raw_paths_clipping",
        "success_4mm",
        "success_8mm",
    ]
    print(table(rows, columns))
    notes = (
        "block world, entry -> target; medians over seeds; length and clearance of the expert (margin 0) "
        "path after each planner's smoothing; OMPL margin 0 with its discrete motion checker"
    )
    print(f"\nwritten: {save('safe_prm_vs_ompl', rows, notes)}")


if __name__ == "__main__":
    main()
