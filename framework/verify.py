"""The framework checks every plugin answer before anything uses it.

A plan stage's path goes to figures, to ``result.json`` and to devices that
move motors; a third-party planner may be wrong, so the runner never takes
its word for it. :func:`verify_plan_result` checks a :class:`~surgiplan.planning.PlanResult`
against the stage:

* it *is* a :class:`~surgiplan.planning.PlanResult` whose status is a
  :class:`~surgiplan.status.PlanStatus`;
* a solved path is a finite ``(n, dimension)`` array with ``n >= 2``;
* its first waypoint is the stage's start and (when the stage has a goal)
  its last is the goal, within :data:`ENDPOINT_TOLERANCE` in the space's
  metric (a planner whose settings redirect the query, such as replanning to
  a new goal, declares where it ends: ``PlanResult.final_goal``);
* every waypoint is inside the space's limits and the tip inside the scene's
  bounds;
* every waypoint is collision free, and every motion between consecutive
  waypoints is certified clear by the space's own certified check
  (:meth:`~surgiplan.spaces.Space.motion_is_clear`, the check the
  built-in planners use), so no segment passes through an obstacle anywhere
  between its waypoints.

A violation is a :class:`InvalidResult` whose message names the waypoint or
segment and the clearance measured on the scene, in the pipeline's length
unit. The runner turns it into a stage with status ``invalid_result``.
"""

from __future__ import annotations

import numpy as np

from .errors import SurgiplanError
from .planning import PlanResult
from .spaces.base import Space
from .status import PlanStatus

#: how far (in the space's metric, m) a path's first/last waypoint may be from the stage's start/goal
ENDPOINT_TOLERANCE = 1e-6


class InvalidResult(SurgiplanError):
    """A plugin's answer the framework refuses; the message says what is wrong with it (the stage becomes
    ``invalid_result``)."""

    exit_code = 1


class _Units:
    def __init__(self, unit: str, scale: float) -> None:
        self.unit = unit
        self.k = 1.0 / scale

    def length(self, value: float) -> str:
        return f"{value * self.k:.4g} {self.unit}"

    def point(self, p) -> str:
        return "(" + ", ".join(f"{v * self.k:.4g}" for v in np.asarray(p, float)) + f") {self.unit}"


def verify_plan_result(
    result: object,
    space: Space,
    start: np.ndarray,
    goal: np.ndarray | None,
    *,
    unit: str = "m",
    unit_scale: float = 1.0,
) -> np.ndarray | None:
    """Check a planner's answer; returns the solved path as a float array (None if not solved).

    Raises :class:`InvalidResult` naming what is wrong.
    """
    units = _Units(unit, unit_scale)
    if not isinstance(result, PlanResult):
        raise InvalidResult(f"query returned a {type(result).__name__}, not a PlanResult")
    try:
        status = PlanStatus(result.status)
    except ValueError:
        choices = ", ".join(s.value for s in PlanStatus)
        raise InvalidResult(f"status {result.status!r} is not a plan status ({choices})") from None
    if status is not PlanStatus.SOLVED:
        return None
    try:
        path = np.array(result.path, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidResult(f"the path is not an array of numbers: {exc}") from None
    d = space.dimension
    if path.ndim != 2 or path.shape[1] != d:
        raise InvalidResult(f"the path has shape {path.shape}; a {space.kind} path is (n, {d})")
    if len(path) < 2:
        raise InvalidResult(f"the path has {len(path)} waypoint(s); a solved path has at least 2 (start and goal)")
    bad = np.flatnonzero(~np.all(np.isfinite(path), axis=1))
    if bad.size:
        raise InvalidResult(f"waypoint {bad[0]} of {len(path)} is not finite: {path[bad[0]].tolist()}")
    gap = float(space.distance(path[0], start))
    if gap > ENDPOINT_TOLERANCE:
        raise InvalidResult(
            f"the path starts at {units.point(space.tip(path[:1])[0])}, {units.length(gap)} from the stage's start "
            f"{units.point(space.tip(start[None])[0])} (tolerance {units.length(ENDPOINT_TOLERANCE)})"
        )
    if result.final_goal is not None:  # a redirected query (replanning): it must end where it says
        try:
            goal = np.asarray(result.final_goal, dtype=float).reshape(d)
        except (TypeError, ValueError):
            raise InvalidResult(f"final_goal {result.final_goal!r} is not a ({d},) configuration") from None
        if not np.all(np.isfinite(goal)):
            raise InvalidResult(f"final_goal {goal.tolist()} is not finite")
    if goal is not None:
        gap = float(space.distance(path[-1], goal))
        if gap > ENDPOINT_TOLERANCE:
            raise InvalidResult(
                f"the path ends at {units.point(space.tip(path[-1:])[0])}, {units.length(gap)} from the stage's "
                f"goal {units.point(space.tip(goal[None])[0])} (tolerance {units.length(ENDPOINT_TOLERANCE)})"
            )
    tips = space.tip(path)
    outside = np.flatnonzero(~space.in_workspace(path))
    if outside.size:
        i = int(outside[0])
        scene = space.scene
        raise InvalidResult(
            f"waypoint {i} of {len(path)} puts the tip at {units.point(tips[i])}, outside the scene bounds "
            f"{units.point(scene.bounds_min)} to {units.point(scene.bounds_max)}"
        )
    outside = np.flatnonzero(~space.within_limits(path))
    if outside.size:
        i = int(outside[0])
        raise InvalidResult(
            f"waypoint {i} of {len(path)} ({np.round(path[i], 6).tolist()}) is outside the limits of the "
            f"{space.kind} space"
        )
    clearance = space.clearance(path)
    hit = np.flatnonzero(~(clearance > 0))
    if hit.size:
        i = int(hit[0])
        raise InvalidResult(
            f"waypoint {i} of {len(path)} at {units.point(tips[i])} collides with {_obstacle(space, path[i])} "
            f"(clearance {units.length(float(clearance[i]))})"
        )
    clear = space.motion_is_clear(path[:-1], path[1:], 0.0)
    blocked = np.flatnonzero(~clear)
    if blocked.size:
        i = int(blocked[0])
        measured = float(space.segment_clearance(path[i : i + 1], path[i + 1 : i + 2])[0])
        more = f" ({blocked.size} segments in all)" if blocked.size > 1 else ""
        raise InvalidResult(
            f"segment {i} of {len(path) - 1}, from {units.point(tips[i])} to {units.point(tips[i + 1])}, is not "
            f"certified clear: its clearance is {units.length(measured)} "
            f"({_obstacle_along(space, path[i], path[i + 1])}){more}"
        )
    return path


def _obstacle(space: Space, q: np.ndarray) -> str:
    index = int(space.nearest_obstacle(q[None])[0])
    return f"obstacle '{space.scene.obstacles[index].name}'" if index >= 0 else "the scene's bounds"


def _obstacle_along(space: Space, q1: np.ndarray, q2: np.ndarray) -> str:
    """The obstacle nearest to the body where the motion comes closest to one."""
    t = np.linspace(0.0, 1.0, 65)
    samples = space.interpolate(np.repeat(q1[None], len(t), 0), np.repeat(q2[None], len(t), 0), t)
    worst = int(np.argmin(space.clearance(samples)))
    return _obstacle(space, samples[worst])
