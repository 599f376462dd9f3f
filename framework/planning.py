"""The planner interface: an expensive, storable ``build`` and a cheap ``query``.

Both methods of paper 000 (PRM's learning and query phases) and paper 001
(optMIS's offline repository and online A*) split planning this way, and so
does OMPL's PRM. :class:`Planner` makes the split explicit:

* ``build(problem) -> artifact`` — roadmaps, path repositories; run once and
  stored (``artifact:`` in a plan stage) so that many queries reuse it;
* ``query(artifact, start, goal) -> PlanResult`` — the online answer.

The stage's clearance threshold (paper 000's d_thresh, :mod:`surgiplan.clearance`) reaches the planner in
``PlanningProblem.clearance_threshold``; :meth:`Planner.planning_threshold` is the value to plan with.
A planner declares how it keeps it (:attr:`Planner.clearance_policy`) and, when its settings ask for one
(safe_prm's ``proficiency``), says which in :meth:`Planner.clearance_threshold_from`.

A planner that stores its artifact implements :meth:`Planner.save_artifact`
and :meth:`Planner.load_artifact` with plain arrays and JSON values (never
pickle: a stored file must not be able to run code when loaded). The
framework writes the file atomically, with a content hash of the scene,
space, plugin and settings, and rebuilds when they change.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel

from .clearance import ClearancePolicy, ClearanceThreshold
from .executors import Executor, InlineExecutor
from .progress import NullProgress, Progress
from .resources import ResourceEstimate
from .scene import Scene
from .spaces.base import Space
from .status import PlanStatus


@dataclass
class PlanningProblem:
    """What a planner's build phase gets: the scene, the space, and how to run work."""

    scene: Scene
    space: Space
    executor: Executor = field(default_factory=InlineExecutor)
    progress: Progress = field(default_factory=NullProgress)
    #: a directory the planner may use to checkpoint long offline work (resumable)
    workdir: Path | None = None
    #: the stage's start and goal (SI), for planners whose build depends on them (e.g. the
    #: retraction planner samples equilibria for the grasp at ``start``); such a planner must
    #: also check them when it loads a stored artifact (the artifact key does not hash them)
    start: np.ndarray | None = None
    goal: np.ndarray | None = None
    #: the run's output directory, for planners that write files of their own (see PlanResult.files)
    output_dir: Path | None = None
    #: the clearance the path keeps (paper 000's d_thresh), resolved from the stage or the planner's settings;
    #: None when the stage has none
    clearance_threshold: ClearanceThreshold | None = None


@dataclass
class PlanResult:
    """The answer to a query.

    ``path``: waypoints (n, space.dimension) in SI; consecutive waypoints are
    joined by the space's local planner (straight lines in R3).
    ``metrics``: plugin-specific numbers (JSON-able); the framework measures the
    common ones (``length_m``, ``min_clearance_m``, ...) itself.
    ``clearance_threshold``: deprecated and ignored (the threshold goes *into* the
    planner, ``PlanningProblem.clearance_threshold``); a value that differs from
    the stage's is reported as a warning. The framework measures the path's
    critical regions itself (:func:`surgiplan.clearance.critical_regions`).
    """

    status: PlanStatus
    path: np.ndarray
    metrics: dict[str, Any] = field(default_factory=dict)
    message: str = ""
    clearance_threshold: float | None = None
    #: extra data for figures and readers of result.json, e.g. {"detours": [...]} (JSON-able)
    annotations: dict[str, Any] = field(default_factory=dict)
    #: files the planner wrote into ``PlanningProblem.output_dir`` (relative to it)
    files: list[str] = field(default_factory=list)
    #: where the path ends when the planner's settings redirected the query (replanning to a new
    #: goal); the framework then checks the path ends here instead of at the stage's goal, and
    #: reports it (``metrics.final_goal``)
    final_goal: np.ndarray | None = None

    @property
    def solved(self) -> bool:
        return self.status == PlanStatus.SOLVED

    @classmethod
    def failure(cls, status: PlanStatus, dimension: int, message: str, **metrics) -> PlanResult:
        """A result without a path (an empty (0, ``dimension``) array) with ``status`` and ``message`` saying
        why, and any ``metrics`` measured before it failed."""
        return cls(status, np.empty((0, dimension)), dict(metrics), message)


class Planner(ABC):
    """Base class of planner plugins.

    Subclasses set ``Settings`` (a :class:`~surgiplan.models.StrictModel`: unknown keys are errors) and
    implement :meth:`build` and :meth:`query`.
    """

    Settings: ClassVar[type[BaseModel]]
    #: bump when the stored artifact layout changes, so old files are rebuilt
    artifact_version: ClassVar[int] = 1
    #: False for planners whose goal is a condition rather than a configuration (the retraction
    #: planner's goal is "the area of interest is visible"): a plan stage may then omit ``goal``,
    #: and ``query`` gets ``goal=None``
    requires_goal: ClassVar[bool] = True
    #: how the planner keeps the stage's clearance threshold (:class:`~surgiplan.clearance.ClearancePolicy`):
    #: ``everywhere`` (a margin every motion keeps) or ``except_critical`` (paper 000: except where no detour
    #: exists); None for planners that cannot plan with one (a stage that gives one is then refused)
    clearance_policy: ClassVar[ClearancePolicy | None] = ClearancePolicy.EVERYWHERE
    #: the name of a setting that is an older spelling of the stage's ``clearance_threshold`` (``margin``):
    #: read as the threshold when the stage gives none, reported as deprecated, and set to the stage's
    #: threshold by :meth:`bind`, so code that reads the setting plans with the one threshold
    threshold_setting: ClassVar[str | None] = None

    def __init__(self, settings: BaseModel) -> None:
        self.settings = settings

    @classmethod
    def clearance_threshold_from(cls, settings: BaseModel) -> tuple[ClearanceThreshold | None, bool]:
        """The clearance threshold these settings ask for, and whether the user chose it (False for a default).

        safe_prm derives it from ``proficiency``; a planner with a :attr:`threshold_setting` reads that
        setting. The framework resolves the stage's threshold from this and the stage's
        ``clearance_threshold``: two explicit values that differ are refused at validation.
        """
        name = cls.threshold_setting
        value = float(getattr(settings, name, 0.0) or 0.0) if name else 0.0
        if value > 0:
            return ClearanceThreshold(value, f"settings.{name}"), name in settings.model_fields_set
        return None, False

    def bind(self, problem: PlanningProblem) -> None:
        """Called by the framework before :meth:`build`, :meth:`load_artifact` and :meth:`query`: a planner with
        a :attr:`threshold_setting` plans with the problem's threshold through it."""
        name = self.threshold_setting
        if name and problem.clearance_threshold is not None:
            self.settings = self.settings.model_copy(update={name: problem.clearance_threshold.value})

    def planning_threshold(self, problem: PlanningProblem | None) -> float:
        """The threshold (m) to plan with: the problem's, else what the settings ask for, else 0."""
        if problem is not None and problem.clearance_threshold is not None:
            return problem.clearance_threshold.value
        threshold, _ = self.clearance_threshold_from(self.settings)
        return threshold.value if threshold is not None else 0.0

    @abstractmethod
    def build(self, problem: PlanningProblem) -> Any:
        """The offline phase; returns the artifact :meth:`query` needs."""

    @abstractmethod
    def query(self, artifact: Any, start: np.ndarray, goal: np.ndarray) -> PlanResult:
        """The online phase: a path from ``start`` to ``goal`` (configurations)."""

    @classmethod
    def estimate_resources(cls, settings: BaseModel, problem: PlanningProblem) -> list[ResourceEstimate]:
        """What the stage will need, from the settings alone, before any work (:mod:`surgiplan.resources`).

        Called by ``surgiplan validate`` and ``run``; an estimate above the machine's memory refuses the
        file, naming the estimate's ``setting``. Override it when a setting scales memory (milestones,
        samples, mesh sizes, pairs); the default estimates nothing.
        """
        return []

    # ------------------------------------------------------------------ persistence
    @property
    def stores_artifacts(self) -> bool:
        return type(self).save_artifact is not Planner.save_artifact

    def save_artifact(self, artifact: Any) -> Mapping[str, Any]:
        """The artifact as named numpy arrays and JSON-able values."""
        raise NotImplementedError

    def load_artifact(self, data: Mapping[str, Any], problem: PlanningProblem) -> Any:
        """Rebuild the artifact from what :meth:`save_artifact` returned."""
        raise NotImplementedError

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def check_endpoints(space: Space, start, goal, margin: float = 0.0) -> PlanResult | None:
        """A failed :class:`PlanResult` when start or goal is not a valid configuration."""
        for status, q, what in (
            (PlanStatus.INVALID_START, start, "start"),
            (PlanStatus.INVALID_GOAL, goal, "goal"),
        ):
            q = np.asarray(q, dtype=float)
            if q.shape != (space.dimension,):
                return PlanResult.failure(
                    status, space.dimension, f"{what} has shape {q.shape}, expected ({space.dimension},)"
                )
            if not space.is_valid(q[None, :], margin)[0]:
                clearance = float(space.clearance(q[None, :])[0])
                return PlanResult.failure(
                    status, space.dimension, f"{what} is not a free configuration (clearance {clearance * 1000:.3g} mm)"
                )
        return None
