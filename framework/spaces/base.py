"""The configuration-space interface planners work in.

A :class:`Space` knows its coordinates (bounds, sampling, distance,
interpolation), how to place the moving body for a configuration, and how to
decide, *with a certificate*, that the body keeps a clearance margin along a
motion. Planners only ever talk to the scene through their space, so the same
planner plans for an instrument tip (:class:`~surgiplan.spaces.r3.R3Space`),
a whole laparoscopic shaft about a fulcrum
(:class:`~surgiplan.spaces.gimbal.CastGimbalSpace`) or a gripper pose
(:class:`~surgiplan.spaces.se3.SE3Space`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np
from pydantic import BaseModel

from ..geometry import boxes
from ..scene import Scene, meets_margin


class Space(ABC):
    """A configuration space over a scene.

    Subclasses declare ``Settings`` (a :class:`~surgiplan.models.StrictModel`: unknown keys are errors) and
    are built with ``Space.from_settings(settings, scene)``.
    """

    #: registered name (``space: {kind: ...}`` in a pipeline file)
    kind: ClassVar[str]
    Settings: ClassVar[type[BaseModel]]

    def __init__(self, scene: Scene) -> None:
        self.scene = scene

    @classmethod
    @abstractmethod
    def from_settings(cls, settings: BaseModel, scene: Scene) -> Space:
        """The space over ``scene`` that ``settings`` (a validated :attr:`Settings`, SI) describe."""

    # ------------------------------------------------------------------ coordinates
    @property
    @abstractmethod
    def dimension(self) -> int:
        """Number of coordinates of a configuration."""

    @property
    def coordinate_names(self) -> tuple[str, ...]:
        """The coordinates' names, in order (for files robots read: joint names); default q0, q1, ..."""
        return tuple(f"q{i}" for i in range(self.dimension))

    @property
    @abstractmethod
    def low(self) -> np.ndarray: ...

    @property
    @abstractmethod
    def high(self) -> np.ndarray: ...

    @abstractmethod
    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` configurations (n, dimension) drawn uniformly within the limits."""

    @abstractmethod
    def distance(self, q1, q2) -> np.ndarray:
        """Metric used for nearest neighbours and path cost (metre-like units)."""

    @abstractmethod
    def interpolate(self, q1, q2, t) -> np.ndarray:
        """Configurations a fraction ``t`` of the way from q1 to q2 (the local planner)."""

    #: True when :meth:`distance` is the plain Euclidean norm of ``q2 - q1`` (unit :attr:`coordinate_weights`) and
    #: :meth:`motion_speed_bound` equals it: a planner that measured that distance (a compiled neighbour search)
    #: may use it as a motion's cost and speed bound, without asking the space again
    euclidean_motions: ClassVar[bool] = False

    @property
    def coordinate_weights(self) -> np.ndarray | None:
        """Per-coordinate scales when :meth:`distance` is a weighted Euclidean metric, else None.

        Lets external planners (OMPL) that only know plain Euclidean distance
        plan in scaled coordinates with the same metric.
        """
        return None

    def within_limits(self, q) -> np.ndarray:
        """Per configuration (one, or (n, dimension)), whether every coordinate is within :attr:`low` and
        :attr:`high` (to 1e-12): a bool array of n."""
        return boxes.inside(np.atleast_2d(q), self.low - 1e-12, self.high + 1e-12)

    # ------------------------------------------------------------------ body placement
    @abstractmethod
    def tip(self, q) -> np.ndarray:
        """Workspace position (n, 3) of the instrument tip (or body origin), metres."""

    @abstractmethod
    def clearance(self, q, cutoff: float | np.ndarray = np.inf) -> np.ndarray:
        """Exact clearance (m) of the whole moving body at each configuration.

        Values below ``cutoff`` are exact; above it a lower bound that is at
        least ``cutoff`` may be returned (far obstacles are then skipped).
        """

    def motion_is_clear(self, q1, q2, margin: float = 0.0) -> np.ndarray:
        """Certified: True only if the body keeps ``margin`` along every motion q1[i] → q2[i].

        The default covers each motion with balls whose radius is the slack
        over :meth:`motion_speed_bound` (:func:`certify_by_covering`); spaces
        with an exact swept-volume test override it.
        """
        q1 = np.atleast_2d(np.asarray(q1, float))
        q2 = np.atleast_2d(np.asarray(q2, float))
        ok = self.within_limits(q1) & self.within_limits(q2)  # the limits are convex
        if np.any(ok):
            tiny = 1e-12 if margin <= 0 else 0.0  # margin 0: touching is not clear
            ok[ok] = certify_by_covering(
                lambda q, enough: self.motion_slack(q, margin, enough) + tiny,
                self.interpolate,
                q1[ok],
                q2[ok],
                self.motion_speed_bound(q1[ok], q2[ok]),
            )
        return ok

    def motion_slack(self, q, margin: float, enough: float | np.ndarray = np.inf) -> np.ndarray:
        """What must stay positive along a motion: clearance beyond ``margin`` (m).

        A slack of ``enough`` already finishes the motion in one step, so the
        value need only be exact below it. The body must also keep inside
        the workspace: :meth:`workspace_slack` bounds the slack too.
        """
        return np.minimum(self.clearance(q, cutoff=margin + enough) - margin, self.workspace_slack(q))

    def workspace_slack(self, q) -> np.ndarray:
        """How far (m) the body may move before leaving the workspace; inf where the limits already ensure it."""
        return np.full(len(np.atleast_2d(q)), np.inf)

    def motion_speed_bound(self, q1, q2) -> np.ndarray:
        """Bound (m per unit t) on the speed of any body point along the motions q1 → q2."""
        raise NotImplementedError(f"space '{self.kind}' must override motion_is_clear or motion_speed_bound")

    def is_valid(self, q, margin: float = 0.0) -> np.ndarray:
        """Within limits, inside the workspace, and clearance meeting ``margin``."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        ok = self.within_limits(q) & self.in_workspace(q)
        if np.any(ok):
            ok[ok] = meets_margin(self.clearance(q[ok]), margin)
        return ok

    def corridor_halfwidths(self, q, slack) -> np.ndarray:
        """Per-coordinate half-widths (n, dimension) of a box around each q inside which
        no body point moves farther than ``slack[i]`` (m): a configuration-space corridor
        that keeps a clearance known at q. Spaces that support path smoothing override it.
        """
        raise NotImplementedError(f"space '{self.kind}' does not define a clearance corridor")

    def nearest_obstacle(self, q) -> np.ndarray:
        """Index in ``scene.obstacles`` of the obstacle nearest to the body (-1: none)."""
        return self.scene.signed_distance(self.tip(q))[1]

    def in_workspace(self, q) -> np.ndarray:
        """Whether the tip is inside the scene bounds (the workspace)."""
        return self.scene.in_bounds(self.tip(q))

    @abstractmethod
    def configuration(self, value, *, what: str = "point") -> np.ndarray:
        """A configuration from user input: a workspace point (m) or explicit coordinates.

        Raises :class:`~surgiplan.errors.PlanningInputError` when the input
        cannot be a configuration of this space (e.g. out of reach).
        """

    # ------------------------------------------------------------------ paths
    def densify(self, path, resolution: float) -> np.ndarray:
        """The path with extra configurations so consecutive tips are at most ``resolution`` apart.

        Tip spacing is measured on the straight chord; subclasses whose local
        planner curves the tip refine further where needed.
        """
        path = np.atleast_2d(np.asarray(path, dtype=float))
        if len(path) < 2:
            return path
        tips = self.tip(path)
        out = [path[:1]]
        for i in range(len(path) - 1):
            chord = float(np.linalg.norm(tips[i + 1] - tips[i]))
            n = max(1, int(np.ceil(chord / resolution)))
            t = np.linspace(0.0, 1.0, n + 1)[1:]
            out.append(self.interpolate(path[i][None, :].repeat(n, 0), path[i + 1][None, :].repeat(n, 0), t))
        return np.concatenate(out)

    def tip_path_length(self, path) -> float:
        """Length (m) of the tip's trajectory along the path."""
        dense = self.densify(path, resolution=self._length_resolution())
        return float(np.sum(np.linalg.norm(np.diff(self.tip(dense), axis=0), axis=1)))

    def _length_resolution(self) -> float:
        return float(np.min(self.scene.extent)) / 2000.0

    def segment_clearance(self, q1, q2) -> np.ndarray:
        """Minimum clearance (m) of the body along each motion q1[i] → q2[i].

        Exact where the swept volume is known in closed form (R3); otherwise a
        certified lower bound, below the true value by at most
        :meth:`~surgiplan.spaces.Space.segment_clearance_tolerance`: each motion is sampled finely
        enough that no body point moves more than twice the tolerance between
        samples, and half that motion is subtracted.
        """
        q1 = np.atleast_2d(np.asarray(q1, float))
        q2 = np.atleast_2d(np.asarray(q2, float))
        tol = self.segment_clearance_tolerance()
        speed = self.motion_speed_bound(q1, q2)
        steps = np.maximum(1, np.ceil(speed / (2 * tol)).astype(int))
        owner = np.repeat(np.arange(len(q1)), steps + 1)
        start = np.concatenate([[0], np.cumsum(steps + 1)[:-1]])
        t = (np.arange(len(owner)) - start[owner]) / steps[owner]
        c = self.clearance(self.interpolate(q1[owner], q2[owner], t))
        return np.minimum.reduceat(c, start) - speed / steps / 2

    def segment_clearance_tolerance(self) -> float:
        """Largest amount (m) by which :meth:`segment_clearance` may underestimate."""
        return 1e-5

    def spec(self) -> dict:
        """Canonical description (JSON-able), used in artifact content hashes."""
        return {"kind": self.kind, **self.settings_spec()}

    @abstractmethod
    def settings_spec(self) -> dict:
        """The settings that shape the space, canonical and JSON-able (SI), for :meth:`~surgiplan.spaces.Space.spec`:
        two spaces with equal specs are the same space."""


def certify_by_covering(
    value,
    interpolate,
    q1: np.ndarray,
    q2: np.ndarray,
    lipschitz: np.ndarray,
    *,
    initial_samples: int = 5,
    min_gap: float = 1e-7,
    max_rounds: int = 60,
) -> np.ndarray:
    """Certify motions by covering each one with balls of known clearance.

    ``lipschitz[i]`` bounds how fast any point of the body moves, in metres
    per unit of the motion parameter t ∈ [0, 1]. At a sample t_k with slack
    c_k (clearance beyond the margin) the body cannot lose its margin within
    ``r_k = c_k / lipschitz`` of t_k. A motion is accepted when the intervals
    [t_k - r_k, t_k + r_k] cover [0, 1]: it is then clear everywhere, not only
    at the samples. Where two neighbouring intervals leave a gap, a sample is
    added in the gap, for all motions at once in each round, so the rounds
    number about log2(lipschitz / slack) and each is one vectorised call.

    ``value(q, enough)`` returns the slack (m) at configurations q; where the
    true slack exceeds ``enough`` it may return any lower bound of at least
    ``enough`` (far obstacles need not be measured exactly). A motion whose
    slack reaches zero at a sample is rejected; so is one whose gaps shrink
    below ``min_gap`` or that is not covered after ``max_rounds`` (a motion
    grazing its margin): conservative, never optimistic.
    """
    q1 = np.atleast_2d(q1)
    q2 = np.atleast_2d(q2)
    n = len(q1)
    lipschitz = np.maximum(np.asarray(lipschitz, dtype=float), 1e-300)
    ok = np.ones(n, dtype=bool)
    # samples to evaluate: motion index, parameter, and the reach that would be enough
    grid = np.linspace(0.0, 1.0, initial_samples)
    new_motion = np.repeat(np.arange(n), initial_samples)
    new_t = np.tile(grid, n)
    new_reach = np.full(len(new_t), grid[1] - grid[0])
    motion = np.empty(0, dtype=np.int64)
    t = np.empty(0)
    radius = np.empty(0)
    for _ in range(max_rounds):
        if not new_t.size:
            return ok
        slack = value(interpolate(q1[new_motion], q2[new_motion], new_t), lipschitz[new_motion] * new_reach)
        failed = new_motion[slack <= 0.0]
        ok[failed] = False
        motion = np.concatenate([motion, new_motion])
        t = np.concatenate([t, new_t])
        radius = np.concatenate([radius, np.maximum(slack, 0.0) / lipschitz[new_motion]])
        keep = ok[motion]
        motion, t, radius = motion[keep], t[keep], radius[keep]
        order = np.lexsort((t, motion))
        motion, t, radius = motion[order], t[order], radius[order]
        # a gap between consecutive samples of one motion that their balls do not cover
        same = motion[1:] == motion[:-1]
        right = t[:-1] + radius[:-1]
        left = t[1:] - radius[1:]
        gap = same & (right < left)
        too_fine = gap & (t[1:] - t[:-1] < min_gap)
        ok[motion[1:][too_fine]] = False
        gap &= ok[motion[1:]]
        new_motion = motion[1:][gap]
        new_t = 0.5 * (right[gap] + left[gap])
        new_reach = 0.5 * (left[gap] - right[gap])
    ok[new_motion] = False  # still uncovered after max_rounds
    return ok
