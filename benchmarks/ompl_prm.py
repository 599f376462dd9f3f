"""OMPL's PRM as ``bench_safe_prm.py`` drives it, and the measures both planners share.

The state validity checkers we could give OMPL from Python (``scalar``, ``grid``, ``grid-certified``,
``vectorised``, ``certified``: see ``bench_safe_prm.py``'s docstring and :data:`DESCRIPTION`), the roadmap grown
with ``growRoadmap`` to a milestone count, its query and simplification; a path's length and clearance re-measured
with coal, and medians of repeated calls.
"""

from __future__ import annotations

import statistics
import time

import numpy as np
from helpers import coal_scene_segment_distance

#: repeats of each timed call (queries, simplification): the median is taken
QUERY_REPEATS = 21
OMPL_CONFIGS = ("scalar", "grid", "grid-certified", "vectorised", "certified")
#: the voxel table's cell (m) for the ``grid`` checkers
GRID_CELL = 0.001
DESCRIPTION = {
    "scalar": "pure-Python per-state test of the axis-aligned boxes; DiscreteMotionValidator, default resolution",
    "grid": "the scalar test behind a 1 mm voxel table (certainly clear / blocked cells answer at once, exact); "
    "DiscreteMotionValidator, default resolution",
    "grid-certified": "the grid checker with the boxes grown by half the motion resolution: the discrete motions "
    "certify the clearance",
    "vectorised": "one numpy query of all boxes per state; DiscreteMotionValidator, default resolution",
    "certified": "the vectorised checker; surgiplan's exact motion check as the motion validator",
}


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
    """Pure Python, box by box: the fastest exact per-state test for this scene's axis-aligned boxes."""
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


def grid_checker(scene, space, margin, cell=GRID_CELL):
    """:func:`scalar_checker` behind a voxel table: a cell whose centre's clearance, less half its diagonal, is
    beyond the margin is certainly valid, one whose clearance plus half its diagonal is within it certainly not;
    only the cells in between (an obstacle's surface crosses them) run the box test. Exact; made before the
    build (not timed)."""
    exact = scalar_checker(scene, space, margin)
    need = space.tip_radius + margin
    origin = scene.bounds_min
    shape = np.ceil((scene.bounds_max - origin) / cell).astype(int) + 1
    index = np.stack(np.meshgrid(*[np.arange(k) for k in shape], indexing="ij"), -1).reshape(-1, 3)
    distance = scene.signed_distance(origin + (index + 0.5) * cell)[0]
    half = 0.5 * np.sqrt(3.0) * cell
    code = np.full(len(index), 2, dtype=np.uint8)
    code[distance - half > need] = 1
    code[distance + half <= need] = 0
    cells = code.tobytes()
    inverse = 1.0 / cell
    ox, oy, oz = (float(v) for v in origin)
    ny, nz = int(shape[1]), int(shape[2])

    def valid(state):
        x, y, z = state[0], state[1], state[2]
        c = cells[(int((x - ox) * inverse) * ny + int((y - oy) * inverse)) * nz + int((z - oz) * inverse)]
        if c == 2:
            return exact(state)
        return c == 1

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
        # the default resolution: DiscreteMotionValidator at 1 % of the extent (set up once to read it)
        resolution = state_space.getLongestValidSegmentFraction() * state_space.getMaximumExtent()
        if config == "scalar":
            checker = scalar_checker(scene, space, margin)
        elif config == "grid":
            checker = grid_checker(scene, space, margin)
        elif config == "grid-certified":
            checker = grid_checker(scene, space, margin + 0.5 * resolution)
        else:
            checker = vectorised_checker(scene, space, margin)
        si.setStateValidityChecker(checker)
        if config == "certified":

            class CertifiedMotion(ob.MotionValidator):
                def checkMotion(self, s1, s2):
                    a = np.array([[s1[0], s1[1], s1[2]]])
                    b = np.array([[s2[0], s2[1], s2[2]]])
                    return bool(space.motion_is_clear(a, b, margin)[0])

            si.setMotionValidator(CertifiedMotion(si))
        si.setup()
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


def run_ompl(scene, space, milestones, margin, config, answer=True):
    """One OMPL roadmap grown to ``milestones``: its build time, and with ``answer`` its query, simplification
    and path (margin 0: the query; a margin: only whether it solves)."""
    start, goal = scene.points["entry"], scene.points["target"]
    prm = OmplPRM(scene, space, config, margin)
    t0 = time.perf_counter()
    prm.grow(milestones)
    build = time.perf_counter() - t0
    out = {"build_s": build, "edges": prm.planner.edgeCount(), "resolution_mm": 1e3 * prm.resolution_m}
    if not answer:
        return out
    raw = prm.query(start, goal, 1.0 if margin else 5.0)
    out["solved"] = raw is not None
    if raw is None or margin:
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


# ----------------------------------------------------------------------------- the pipeline
