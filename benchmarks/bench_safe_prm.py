"""safe_prm against OMPL's PRM in its strongest Python configuration, on the block world (entry -> target).

For 500, 2,000 and 5,000 milestones and 5 seeds each, in one run on one
machine, the peer side by side:

* **safe_prm**: R and R_safe built together, every edge certified (exact or
  covering balls); the query (linking, A* in R, PathRepair through R_safe);
  smoothing (the corridor QP) timed apart.
* **OMPL PRM, vectorised checker + discrete motions** (the peer's strongest
  general configuration): OMPL 2.0's PRM grown with ``growRoadmap`` and a
  termination condition on the milestone count (not a time budget) to the
  same number of milestones; the state validity checker is one vectorised
  numpy query of the scene's boxes per state (about 4 us a call, the
  fastest general scene query we could write in Python); motions by OMPL's
  own ``DiscreteMotionValidator`` at its default resolution (1 % of the
  space's extent: 1.85 mm between checked states in the block world, every
  point of a motion within 0.92 mm of one). It checks states, so a motion
  may clip an obstacle between them (counted below).
* **OMPL PRM, certified motions**: the same, with surgiplan's certified
  motion check (``space.motion_is_clear``, exact for R3) as OMPL's motion
  validator: no edge cuts a corner, like safe_prm's.
* **OMPL PRM, scalar checker** (for the record): a pure-Python per-state
  test hand-written for this scene's axis-aligned boxes (0.3 us a call),
  with the discrete motions. It is not a general scene query (no rotated
  boxes, spheres, cylinders or meshes), but a user with only boxes could
  write it, and with it OMPL's C++ core builds about as fast as safe_prm.

OMPL's query (``solve`` on the grown roadmap: it adds the start and goal as
milestones and searches) and its simplification (``PathSimplifier.
simplifyMax`` on a copy of the raw path) are timed like safe_prm's query and
smoothing: medians of repeated runs on the same roadmap. Path lengths and
clearances are re-measured with coal. OMPL with a 4 or 8 mm margin (states
and motions must keep it) fails here: the target lies behind a 6 mm gap.
OMPL's PRM connects each milestone to its 10 nearest (its default), safe_prm
to at most 15 within a radius (K-S); the roadmaps differ, the milestone
count is the same.

The load average at the start is recorded: the machine is shared. The
ratios come from one run, side by side.

    python benchmarks/bench_safe_prm.py [--quick]   (--quick: 2 seeds, 500 and 2,000; writes nothing)
"""

from __future__ import annotations

import argparse
import os
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
QUERY_REPEATS = 21
OMPL_CONFIGS = ("vectorised", "certified", "scalar")


def measure_path(scene, path):
    if path is None or len(path) < 2:
        return None, None, None
    clearance = coal_scene_segment_distance(scene, path[:-1], path[1:])
    return (
        float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()),
        float(clearance.min()),
        bool(clearance.min() <= 0),
    )


def median_ms(fn, repeat=QUERY_REPEATS):
    fn()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


# ----------------------------------------------------------------------------- safe_prm


def run_safe_prm(scene, space, milestones, seed, level):
    start, goal = scene.points["entry"], scene.points["target"]
    planner = SafePRM(SafePRMSettings(proficiency=level, milestones=milestones, seed=seed))
    t0 = time.perf_counter()
    artifact = planner.build(PlanningProblem(scene, space))
    build = time.perf_counter() - t0
    raw = prm_query.query(artifact.roadmap, start, goal)  # the roadmap answer, before smoothing
    query_ms = median_ms(lambda: prm_query.query(artifact.roadmap, start, goal))
    smooth = []
    for _ in range(5):
        result = planner.query(artifact, start, goal)
        smooth.append(result.metrics.get("smooth_s", float("nan")))
    length, clearance, _ = measure_path(scene, result.path if result.solved else None)
    _, _, raw_clips = measure_path(scene, raw.path if raw.found else None)
    return {
        "build_s": build,
        "query_ms": query_ms,
        "simplify_ms": 1e3 * statistics.median(smooth),
        "length_m": length,
        "min_clearance_m": clearance,
        "raw_clips": raw_clips,
        "solved": result.solved,
        "settled": raw.settled,
    }


# ----------------------------------------------------------------------------- OMPL


def box_arrays(scene):
    """The scene's boxes as axis-aligned (lo, hi) arrays; this benchmark's checkers need exactly that."""
    lo, hi = [], []
    for o in scene.obstacles:
        if o.kind != "box" or not np.allclose(o.pose.rotation, np.eye(3)):
            raise SystemExit(f"the OMPL checkers here handle axis-aligned boxes only; '{o.name}' is not one")
        a, b = o.aabb()
        lo.append(a)
        hi.append(b)
    return np.array(lo), np.array(hi)


def vectorised_checker(scene, space, margin):
    """One numpy query of all boxes per state: the squared distance outside every box against the margin."""
    lo, hi = box_arrays(scene)
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    need = space.tip_radius + margin
    need2 = need * need
    p = np.empty(3)
    absolute, maximum = np.abs, np.maximum

    def valid(state):
        p[0], p[1], p[2] = state[0], state[1], state[2]
        q = absolute(p - centre) - half
        maximum(q, 0.0, out=q)
        return bool((q * q).sum(1).min() > need2)

    return valid


def scalar_checker(scene, space, margin):
    """Pure Python, box by box: the fastest per-state test for this scene's axis-aligned boxes."""
    lo, hi = box_arrays(scene)
    boxes = [(*a, *b) for a, b in zip(lo.tolist(), hi.tolist(), strict=True)]
    need = space.tip_radius + margin
    need2 = need * need

    def valid(state):
        x, y, z = state[0], state[1], state[2]
        for x0, y0, z0, x1, y1, z1 in boxes:
            dx = x0 - x if x < x0 else (x - x1 if x > x1 else 0.0)
            dy = y0 - y if y < y0 else (y - y1 if y > y1 else 0.0)
            dz = z0 - z if z < z0 else (z - z1 if z > z1 else 0.0)
            if dx * dx + dy * dy + dz * dz <= need2:
                return False
        return True

    return valid


class OmplPRM:
    """OMPL's PRM on the scene, grown to a milestone count; one configuration of checker and motion validator."""

    def __init__(self, scene, space, config, margin):
        from ompl import base as ob
        from ompl import geometric as og

        self.ob, self.og = ob, og
        self.scene, self.space = scene, space
        state_space = ob.RealVectorStateSpace(3)
        bounds = ob.RealVectorBounds(3)
        for i in range(3):
            bounds.setLow(i, float(scene.bounds_min[i]))
            bounds.setHigh(i, float(scene.bounds_max[i]))
        state_space.setBounds(bounds)
        si = ob.SpaceInformation(state_space)
        checker = scalar_checker if config == "scalar" else vectorised_checker
        si.setStateValidityChecker(checker(scene, space, margin))
        if config == "certified":

            class CertifiedMotion(ob.MotionValidator):
                def checkMotion(self, s1, s2):
                    a = np.array([[s1[0], s1[1], s1[2]]])
                    b = np.array([[s2[0], s2[1], s2[2]]])
                    return bool(space.motion_is_clear(a, b, margin)[0])

            si.setMotionValidator(CertifiedMotion(si))
        si.setup()  # the default resolution: DiscreteMotionValidator at 1 % of the extent
        self.state_space, self.si = state_space, si
        self.resolution_m = state_space.getLongestValidSegmentLength()
        self.planner = og.PRM(si)
        self.planner.setProblemDefinition(ob.ProblemDefinition(si))
        self.planner.setup()

    def grow(self, milestones):
        planner = self.planner
        planner.growRoadmapPtc(self.ob.PlannerTerminationCondition(lambda: planner.milestoneCount() >= milestones))

    def _state(self, q):
        state = self.state_space.allocState()
        for i in range(3):
            state[i] = float(q[i])
        return state

    def query(self, start, goal, time_limit):
        ob = self.ob
        definition = ob.ProblemDefinition(self.si)
        definition.setStartAndGoalStates(self._state(start), self._state(goal))
        self.planner.clearQuery()
        self.planner.setProblemDefinition(definition)
        status = self.planner.solve(ob.timedPlannerTerminationCondition(time_limit))
        if status.asString() != "Exact solution":
            return None
        path = definition.getSolutionPath()
        return np.array([[path.getState(i)[k] for k in range(3)] for i in range(path.getStateCount())])

    def simplify(self, raw):
        path = self.og.PathGeometric(self.si)
        for q in raw:
            path.append(self._state(q))
        t0 = time.perf_counter()
        self.og.PathSimplifier(self.si).simplifyMax(path)
        elapsed = time.perf_counter() - t0
        return np.array([[path.getState(i)[k] for k in range(3)] for i in range(path.getStateCount())]), elapsed


def run_ompl(scene, space, milestones, margin, config):
    start, goal = scene.points["entry"], scene.points["target"]
    prm = OmplPRM(scene, space, config, margin)
    t0 = time.perf_counter()
    prm.grow(milestones)
    build = time.perf_counter() - t0
    edges = prm.planner.edgeCount()
    out = {"build_s": build, "edges": edges, "resolution_mm": 1e3 * prm.resolution_m}
    raw = prm.query(start, goal, 1.0 if margin else 5.0)
    out["solved"] = raw is not None
    if raw is None:
        return out
    query_ms = median_ms(lambda: prm.query(start, goal, 5.0))
    simplify = []
    for _ in range(QUERY_REPEATS):
        simplified, elapsed = prm.simplify(raw)
        simplify.append(elapsed)
    length, clearance, _ = measure_path(scene, simplified)
    _, _, raw_clips = measure_path(scene, raw)
    out.update(
        query_ms=query_ms,
        simplify_ms=1e3 * statistics.median(simplify),
        length_m=length,
        min_clearance_m=clearance,
        raw_clips=raw_clips,
    )
    return out


# ----------------------------------------------------------------------------- summary


def med(records, key):
    values = [r[key] for r in records if r.get(key) is not None]
    return statistics.median(values) if values else None


def fmt(value, scale=1.0, digits=3):
    return "—" if value is None else f"{value * scale:.{digits}g}"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="2 seeds, 500 and 2000 milestones; writes no results")
    args = parser.parse_args()
    load = os.getloadavg()
    started = time.perf_counter()
    sizes = (500, 2000) if args.quick else (500, 2000, 5000)
    seeds = range(1, 3) if args.quick else range(1, 6)
    scene = load_scene(ROOT / "configs/scenes/block_world.yaml")
    space = R3Space(scene)
    from ompl import util as ou

    ou.setLogLevel(ou.LOG_WARN)
    ou.RNG.setSeed(1)  # once per process; later builds continue the stream, so every run differs
    rows = []
    for milestones in sizes:
        ours = {level: [] for level in MARGINS}
        theirs = {(config, level): [] for config in OMPL_CONFIGS for level in MARGINS}
        for seed in seeds:
            for level, margin in MARGINS.items():
                ours[level].append(run_safe_prm(scene, space, milestones, seed, level))
                for config in OMPL_CONFIGS:
                    theirs[config, level].append(run_ompl(scene, space, milestones, margin, config))
            print(f"  {milestones} milestones, seed {seed} done", file=sys.stderr, flush=True)
        n_seeds = len(seeds)
        # R + R_safe: the intermediate and beginner builds (the expert's R_safe is R)
        ours_build = med(ours["intermediate"] + ours["beginner"], "build_s")
        ours_query = med(ours["intermediate"] + ours["beginner"], "query_ms")
        row = {
            "planner": "safe_prm (R + R_safe, certified)",
            "milestones": milestones,
            "seeds": n_seeds,
            "build_s": fmt(ours_build),
            "query_ms": fmt(med(ours["expert"], "query_ms")),
            "query_repair_ms_4mm": fmt(med(ours["intermediate"], "query_ms")),
            "query_repair_ms_8mm": fmt(med(ours["beginner"], "query_ms")),
            "simplify_ms": fmt(med(ours["expert"], "simplify_ms")),
            "length_mm": fmt(med(ours["expert"], "length_m"), 1e3, 4),
            "min_clear_mm": fmt(med(ours["expert"], "min_clearance_m"), 1e3),
            "raw_paths_clipping": f"{sum(bool(r['raw_clips']) for r in ours['expert'])}/{n_seeds}",
            "success_0_4_8mm": "/".join(f"{sum(r['solved'] for r in ours[lv])}" for lv in MARGINS) + f" of {n_seeds}",
            "settled_median": fmt(med(ours["beginner"], "settled"), 1, 4),
        }
        rows.append(row)
        for config in OMPL_CONFIGS:
            expert = theirs[config, "expert"]
            build = med(expert, "build_s")
            rows.append(
                {
                    "planner": f"OMPL PRM ({config})",
                    "milestones": milestones,
                    "seeds": n_seeds,
                    "build_s": fmt(build),
                    "build_ratio": f"{build / ours_build:.1f}x" if build and ours_build else "—",
                    "query_ms": fmt(med(expert, "query_ms")),
                    "query_ratio": (f"{med(expert, 'query_ms') / ours_query:.1f}x" if med(expert, "query_ms") else "—"),
                    "simplify_ms": fmt(med(expert, "simplify_ms")),
                    "length_mm": fmt(med(expert, "length_m"), 1e3, 4),
                    "min_clear_mm": fmt(med(expert, "min_clearance_m"), 1e3),
                    "raw_paths_clipping": f"{sum(bool(r.get('raw_clips')) for r in expert)}/{n_seeds}",
                    "success_0_4_8mm": "/".join(f"{sum(r['solved'] for r in theirs[config, lv])}" for lv in MARGINS)
                    + f" of {n_seeds}",
                    "edges_median": fmt(med(expert, "edges"), 1, 5),
                }
            )
        # safe_prm's length against OMPL's simplified path (vectorised configuration)
        ref = med(theirs["vectorised", "expert"], "length_m")
        if ref and med(ours["expert"], "length_m"):
            row["length_vs_ompl"] = f"{100 * (med(ours['expert'], 'length_m') / ref - 1):+.1f}%"
        row["edges_median"] = "—"
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
    resolution = 1e3 * OmplPRM(scene, space, "vectorised", 0.0).resolution_m
    notes = (
        f"block world, entry -> target; medians over seeds (build) and over {QUERY_REPEATS} repeats per seed "
        "(query, simplification), then over seeds. build_ratio = OMPL's build of its one roadmap / safe_prm's "
        "build of R + R_safe (median of the 4 and 8 mm builds); query_ratio = OMPL's query (solve on the grown "
        "roadmap) / safe_prm's query with repair (4 and 8 mm). OMPL 2.0 PRM grown by growRoadmap with a "
        "termination condition on the milestone count; 'vectorised': one numpy query of the scene's boxes per "
        f"state, OMPL's DiscreteMotionValidator at its default resolution ({resolution:.3g} mm between states); "
        "'certified': the same states, surgiplan's exact motion check as OMPL's motion validator; 'scalar': a "
        "pure-Python per-state test specialised to axis-aligned boxes, discrete motions. Length and clearance of "
        "the margin-0 path after each planner's own simplification (safe_prm: corridor QP; OMPL: simplifyMax), "
        f"re-measured with coal. Load average at start {load[0]:.2f}/{load[1]:.2f}/{load[2]:.2f} on "
        f"{os.cpu_count()} cores (shared machine); run took {time.perf_counter() - started:.0f} s"
    )
    if args.quick:
        print(f"\n(quick run: nothing written) {notes}")
        return
    print(f"\nwritten: {save('safe_prm_vs_ompl', rows, notes)}")


if __name__ == "__main__":
    main()
