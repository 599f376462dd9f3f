"""The ``via_point`` planner (an example planner plugin).

It is deliberately small but real: the build phase samples valid "via
points" and stores them; a query returns the straight motion when it is
certified clear, otherwise the shortest two-leg path through one via point
whose both legs are clear, otherwise ``no_path``. It works in any space,
keeps the stage's ``clearance_threshold`` on every motion (the framework
passes it in ``PlanningProblem.clearance_threshold``, and refuses a path that
goes below it) and stores its artifact, so it exercises every part of the
Planner interface. Copy it to start your own planner.
"""

from __future__ import annotations

import numpy as np
from pydantic import PositiveInt
from surgiplan import Length, Planner, PlanningProblem, PlanResult, PlanStatus, ResourceEstimate, StrictModel


class ViaPointSettings(StrictModel):  # StrictModel: a misspelt setting is an error naming it, not ignored
    via_points: PositiveInt = 200
    seed: int = 0
    #: the older spelling of the stage's clearance_threshold (kept for one release; see threshold_setting)
    margin: Length = 0.0


class ViaPointPlanner(Planner):
    """Straight line if clear, else the best detour through one stored via point."""

    Settings = ViaPointSettings
    threshold_setting = "margin"  # settings.margin still works, reported as deprecated

    @classmethod
    def estimate_resources(cls, settings, problem):
        # build() samples up to 4 x via_points configurations at once, plus a validity mask
        n, d = settings.via_points, problem.space.dimension
        return [ResourceEstimate(n * (4 * d * 8 + 8), f"{n:,} via points", "via_points")]

    def build(self, problem: PlanningProblem) -> dict:
        space = problem.space
        margin = self.planning_threshold(problem)  # the stage's clearance_threshold (m), 0 when it has none
        rng = np.random.default_rng(self.settings.seed)
        found = []
        with problem.progress.task("sampling via points", total=self.settings.via_points) as task:
            while sum(len(f) for f in found) < self.settings.via_points:
                batch = space.sample(rng, 4 * self.settings.via_points)
                found.append(batch[space.is_valid(batch, margin)])
                task.update(min(sum(len(f) for f in found), self.settings.via_points))
        via = np.concatenate(found)[: self.settings.via_points]
        return {"space": space, "via": via, "margin": margin}

    def save_artifact(self, artifact):
        return {"via": artifact["via"], "margin": artifact["margin"]}

    def load_artifact(self, data, problem):
        return {"space": problem.space, "via": np.asarray(data["via"], dtype=float), "margin": float(data["margin"])}

    def query(self, artifact, start, goal) -> PlanResult:
        space, via, margin = artifact["space"], artifact["via"], artifact["margin"]
        failure = self.check_endpoints(space, start, goal, margin)
        if failure is not None:
            return failure
        if space.motion_is_clear(start[None], goal[None], margin)[0]:
            return PlanResult(PlanStatus.SOLVED, np.stack([start, goal]), {"legs": 1})
        n = len(via)
        first = space.motion_is_clear(np.repeat(start[None], n, 0), via, margin)
        second = space.motion_is_clear(via, np.repeat(goal[None], n, 0), margin)
        both = np.flatnonzero(first & second)
        if both.size == 0:
            return PlanResult.failure(
                PlanStatus.NO_PATH,
                space.dimension,
                f"no clear straight path and none of {n} via points connects",
                legs=0,
            )
        cost = space.distance(start, via[both]) + space.distance(via[both], goal)
        best = via[both[np.argmin(cost)]]
        return PlanResult(PlanStatus.SOLVED, np.stack([start, best, goal]), {"legs": 2})
