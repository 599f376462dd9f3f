"""OMPL bridge: OMPL's PRM, PRM*, RRT-Connect and RRT* behind surgiplan's Planner interface.

Useful on its own, and the reference our planners are benchmarked against.
OMPL plans in the stage's space (R3, the CAST gimbal as a 4-D real vector
space, or SE(3)) and asks surgiplan whether states and motions are valid:

* states: the space's exact clearance against ``margin``;
* motions: ``motion_check: certified`` (default) uses the space's certified
  check, so no edge of OMPL's roadmap or tree cuts a corner;
  ``motion_check: discrete`` uses OMPL's own DiscreteMotionValidator
  (states every ``resolution`` of the space's extent), which is what OMPL
  users get by default and may clip obstacles between checked states. The
  result's ``clipped_segments`` metric counts that, measured exactly.

Build / query: for PRM and PRM* the roadmap is grown in ``build`` until it
has ``milestones`` milestones (or ``build_time`` runs out) and reused by
every query; RRT planners do all their work in ``query``. The roadmap lives
in OMPL's memory: this planner does not store artifacts.

Needs the optional extra: ``pip install 'surgiplan[ompl]'``. Notes on the
``ompl`` 2.0 wheel: a PlannerTerminationCondition built from a Python function
hangs inside ``PRM.solve()``, so queries use ``timedPlannerTerminationCondition``;
``growRoadmapPtc`` accepts a Python one. OMPL's random seed can be set once
per process (before its first planner): a second seeded stage in the same
run logs a warning and is not reproducible.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from pydantic import Field, PositiveFloat, PositiveInt
from surgiplan.models import StrictModel
from surgiplan.planning import Planner, PlanningProblem, PlanResult, PlanStatus
from surgiplan.resources import ResourceEstimate
from surgiplan.units import Length

log = logging.getLogger(__name__)

_seeded: int | None = None


class OmplSettings(StrictModel):
    planner: Literal["PRM", "PRMstar", "RRTConnect", "RRTstar"] = "PRM"
    #: PRM and PRM*: milestones grown in the build phase
    milestones: PositiveInt = 1000
    #: seconds the build phase may take at most
    build_time: PositiveFloat = 60.0
    #: seconds each query may take (RRT* uses all of it to improve its path)
    time_limit: PositiveFloat = 5.0
    #: clearance (m) states and motions must keep; 0 is collision-free only
    margin: Length = 0.0
    motion_check: Literal["certified", "discrete"] = "certified"
    #: discrete motion checking: state spacing as a fraction of the space's extent
    resolution: float = Field(default=0.01, gt=0, le=0.5)
    #: run OMPL's path simplifier (shortcutting + smoothing, kept valid) on the result
    simplify: bool = True
    seed: int | None = None


@dataclass
class _Session:
    """OMPL objects for one problem; kept together so they are freed together."""

    space: Any
    si: Any
    planner: Any
    problem: PlanningProblem
    counters: dict[str, int]


def _weights(space) -> np.ndarray:
    return np.asarray(space.coordinate_weights, dtype=float)


def _ompl():
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    return ob, og, ou


class OmplPlanner(Planner):
    @classmethod
    def estimate_resources(cls, settings, problem):
        if settings.planner not in ("PRM", "PRMstar"):
            return []
        # OMPL's boost graph: a state, vertex properties and ~10 neighbours' edges per milestone (~1.5 kB)
        n = settings.milestones
        return [ResourceEstimate(n * 1500, f"OMPL's roadmap of {n:,} milestones", "milestones")]

    Settings = OmplSettings
    #: the older spelling of the stage's clearance_threshold: a margin every state and motion keeps
    threshold_setting = "margin"

    # ------------------------------------------------------------------ conversions
    def _state_space(self, space):
        ob, _, _ = _ompl()
        if space.kind == "se3":
            state_space = ob.SE3StateSpace()
            bounds = ob.RealVectorBounds(3)
            for i in range(3):
                bounds.setLow(i, float(space.low[i]))
                bounds.setHigh(i, float(space.high[i]))
            state_space.setBounds(bounds)
            return state_space
        if space.coordinate_weights is None:
            raise ValueError(f"the OMPL bridge cannot plan in the '{space.kind}' space (no Euclidean coordinates)")
        dim = space.dimension
        weights = _weights(space)
        state_space = ob.RealVectorStateSpace(dim)
        bounds = ob.RealVectorBounds(dim)
        for i in range(dim):
            bounds.setLow(i, float(space.low[i] * weights[i]))
            bounds.setHigh(i, float(space.high[i] * weights[i]))
        state_space.setBounds(bounds)
        return state_space

    @staticmethod
    def _to_numpy(state, space) -> np.ndarray:
        if space.kind == "se3":
            r = state.rotation()
            return np.array([state.getX(), state.getY(), state.getZ(), r.x, r.y, r.z, r.w])
        # OMPL's coordinates are scaled so that its Euclidean metric is the space's
        return np.array([state[i] for i in range(space.dimension)]) / _weights(space)

    @staticmethod
    def _to_state(q, state, space) -> None:
        if space.kind == "se3":
            state.setXYZ(float(q[0]), float(q[1]), float(q[2]))
            r = state.rotation()
            r.x, r.y, r.z, r.w = (float(v) for v in q[3:7])
            return
        scaled = np.asarray(q, float) * _weights(space)
        for i in range(space.dimension):
            state[i] = float(scaled[i])

    # ------------------------------------------------------------------ phases
    def build(self, problem: PlanningProblem) -> _Session:
        global _seeded
        ob, og, ou = _ompl()
        ou.setLogLevel(ou.LOG_WARN)
        settings = self.settings
        if settings.seed is not None:
            if _seeded is None:
                ou.RNG.setSeed(int(settings.seed))
                _seeded = settings.seed
            elif _seeded != settings.seed:
                log.warning(
                    "OMPL's seed was already set to %s in this process; seed %s is ignored", _seeded, settings.seed
                )
        space = problem.space
        state_space = self._state_space(space)
        si = ob.SpaceInformation(state_space)
        counters = {"states": 0, "motions": 0}
        margin = float(settings.margin)
        to_numpy = self._to_numpy

        class Validity(ob.StateValidityChecker):
            def isValid(self, state):
                counters["states"] += 1
                return bool(space.is_valid(to_numpy(state, space)[None, :], margin)[0])

            def clearance(self, state):
                return float(space.clearance(to_numpy(state, space)[None, :])[0])

        si.setStateValidityChecker(Validity(si))
        if settings.motion_check == "certified":

            class CertifiedMotion(ob.MotionValidator):
                def checkMotion(self, s1, s2):
                    counters["motions"] += 1
                    return bool(
                        space.motion_is_clear(to_numpy(s1, space)[None, :], to_numpy(s2, space)[None, :], margin)[0]
                    )

            si.setMotionValidator(CertifiedMotion(si))
        else:
            si.setStateValidityCheckingResolution(float(settings.resolution))
        si.setup()

        planner = getattr(og, settings.planner)(si)
        planner.setProblemDefinition(ob.ProblemDefinition(si))
        planner.setup()
        session = _Session(state_space, si, planner, problem, counters)
        if settings.planner in ("PRM", "PRMstar"):
            deadline = time.monotonic() + settings.build_time
            target = settings.milestones
            with problem.progress.task(f"OMPL {settings.planner} roadmap", total=target) as task:

                def done():
                    count = planner.milestoneCount()
                    task.update(min(count, target))
                    return count >= target or time.monotonic() > deadline

                planner.growRoadmapPtc(ob.PlannerTerminationCondition(done))
        return session

    def query(self, artifact: _Session, start, goal) -> PlanResult:
        ob, og, _ = _ompl()
        space = artifact.problem.space
        settings = self.settings
        failure = self.check_endpoints(space, start, goal, settings.margin)
        if failure is not None:
            return failure
        si = artifact.si
        start_state = artifact.space.allocState()
        goal_state = artifact.space.allocState()
        self._to_state(start, start_state, space)
        self._to_state(goal, goal_state, space)
        definition = ob.ProblemDefinition(si)
        definition.setStartAndGoalStates(start_state, goal_state)
        planner = artifact.planner
        if settings.planner not in ("PRM", "PRMstar"):
            planner.clear()
        else:
            planner.clearQuery()
        planner.setProblemDefinition(definition)
        status = planner.solve(ob.timedPlannerTerminationCondition(float(settings.time_limit)))
        name = status.asString()
        metrics: dict[str, Any] = {"ompl_status": name}
        if settings.planner in ("PRM", "PRMstar"):
            metrics["milestones"] = int(planner.milestoneCount())
            metrics["edges"] = int(planner.edgeCount())
        if name != "Exact solution":
            kind = PlanStatus.TIMEOUT if name == "Timeout" else PlanStatus.NO_PATH
            return PlanResult.failure(kind, space.dimension, f"OMPL {settings.planner}: {name}", **metrics)
        path = definition.getSolutionPath()
        metrics["raw_waypoints"] = int(path.getStateCount())
        if settings.simplify:
            og.PathSimplifier(si).simplifyMax(path)
        waypoints = np.array([self._to_numpy(path.getState(i), space) for i in range(path.getStateCount())])
        clipped = ~space.motion_is_clear(waypoints[:-1], waypoints[1:], 0.0)
        metrics["clipped_segments"] = int(np.count_nonzero(clipped))
        metrics["state_checks"] = artifact.counters["states"]
        metrics["motion_checks"] = artifact.counters["motions"]
        message = ""
        if metrics["clipped_segments"]:
            message = (
                f"{metrics['clipped_segments']} path segments pass through obstacles between OMPL's "
                "discretely checked states (motion_check: discrete)"
            )
        return PlanResult(PlanStatus.SOLVED, waypoints, metrics, message)
