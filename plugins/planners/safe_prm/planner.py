"""safe_prm: the proficiency-based safe PRM with path repair (paper 000, Jain, Hong & Rozenblit 2019).

A path for a trainee should keep a clearance d_thresh from every obstacle,
larger for less proficient trainees, except where no detour exists (a
*critical region*), where it passes as well as it can. The planner builds
two roadmaps from the same milestones, R over C_free and R_safe over C_safe
(clearance >= d_thresh), answers a query with the shortest path in R and
repairs every stretch of it through the risk region that R_safe can replace
(§3, Algorithms 1-4).

Beyond the paper: every edge is certified (no corner cutting, §5's admitted
limit); a start or goal in the risk region is projected into the safe region
(§5's proposal); the repaired path is smoothed by a QP inside its certified
clearance corridor (§5: "the quality of the path is not sufficiently
smooth"); d_thresh can be derived from a trainee's recorded attempts; the
critical regions of the final path are measured and reported; the roadmap
pair is stored and reloaded.

Works in R3 (the instrument tip) and in the CAST gimbal space (the whole
shaft keeps the clearance). Settings::

    proficiency: intermediate        # a level of `levels`, a length ("5 mm"), or
                                     # {from_attempts: attempts.csv, percentile: 95}
    levels: {expert: 0, intermediate: 4 mm, beginner: 8 mm}
    milestones: 3000                 # sampled in C_free; max_milestones lets a failed query grow the roadmap
    k: 15                            # K-S strategy: at most k nearest ...
    s: 20 mm                         # ... within radius s (default: 3x the mean milestone spacing)
    seed: 1
    smoothing: {enabled: true, resolution: 1 mm, thinning: 0.2 mm}
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import (
    Field,
    PositiveFloat,
    PositiveInt,
    ValidationInfo,
    field_validator,
    model_validator,
)
from surgiplan.clearance import ClearancePolicy, ClearanceThreshold
from surgiplan.clearance import critical_regions as measured_regions
from surgiplan.models import StrictModel
from surgiplan.planning import Planner, PlanningProblem, PlanResult, PlanStatus
from surgiplan.resources import ResourceEstimate
from surgiplan.units import Length, PositiveLength
from surgiplan.validation import file_length_scale, input_path

from .proficiency import DEFAULT_LEVELS, threshold_from_attempts

if TYPE_CHECKING:
    from .roadmap import RoadmapPair


class FromAttempts(StrictModel):
    """d_thresh from recorded attempts: the ``percentile`` of the executed tips' deviations."""

    from_attempts: str
    percentile: float = Field(default=95.0, gt=0, le=100)
    # filled in from the file when the settings are validated (part of the artifact's content key)
    d_thresh: float | None = None
    attempts: int | None = None
    points: int | None = None
    deviation_median: float | None = None
    deviation_max: float | None = None

    @model_validator(mode="before")
    @classmethod
    def _user_keys_only(cls, data: Any) -> Any:
        if isinstance(data, dict):
            unknown = set(data) - {
                "from_attempts",
                "percentile",
                "d_thresh",
                "attempts",
                "points",
                "deviation_median",
                "deviation_max",
            }
            if unknown:
                raise ValueError(f"unknown key(s) {', '.join(sorted(unknown))}; give from_attempts and percentile")
        return data

    @model_validator(mode="after")
    def _read(self, info: ValidationInfo):
        path = input_path(self.from_attempts, info)
        stats = threshold_from_attempts(path, file_length_scale(info), self.percentile)
        self.from_attempts = str(path)
        self.d_thresh = stats.d_thresh
        self.attempts = stats.attempts
        self.points = stats.points
        self.deviation_median = stats.deviation_median
        self.deviation_max = stats.deviation_max
        return self


class FromRecord(StrictModel):
    """d_thresh from the trainee record: the ``percentile`` of the trainee's recorded deviations on ``task``
    (all attempts, or the ``last`` few), so the next recommended path adapts to how they actually move."""

    trainee: str = Field(min_length=1)
    task: str = Field(min_length=1)
    percentile: float = Field(default=95.0, gt=0, le=100)
    last: PositiveInt | None = None
    # filled in from the record when the settings are validated (part of the artifact's content key)
    record: str | None = None
    d_thresh: float | None = None
    attempts: int | None = None
    samples: int | None = None

    @model_validator(mode="before")
    @classmethod
    def _user_keys_only(cls, data: Any) -> Any:
        if isinstance(data, dict):
            unknown = set(data) - {"trainee", "task", "percentile", "last", "record", "d_thresh", "attempts", "samples"}
            if unknown:
                raise ValueError(f"unknown key(s) {', '.join(sorted(unknown))}; give trainee, task, percentile, last")
        return data

    @model_validator(mode="after")
    def _read(self, info: ValidationInfo):
        from surgiplan.guidance import RecordError, TraineeRecord

        path = Path((info.context or {}).get("record") or "out/trainees.sqlite")
        if not path.is_file():
            raise ValueError(f"no trainee record at {path} (a guide stage with trainee: writes one; see record:)")
        try:
            with TraineeRecord(path) as record:
                p = record.proficiency(self.trainee, self.task, self.percentile, self.last)
        except RecordError as exc:
            raise ValueError(exc.message) from None
        self.record = str(path)
        self.d_thresh = p.d_thresh
        self.attempts = p.attempts
        self.samples = p.samples
        return self


class SmoothingSettings(StrictModel):
    enabled: bool = True
    #: tip spacing of the densified path the QP smooths
    resolution: PositiveLength = 0.001
    #: weight of shortening (sum of squared steps) and of straightening (squared second differences)
    alpha: PositiveFloat = 1.0
    beta: float = Field(default=4.0, ge=0)
    #: Douglas-Peucker tolerance for the result's waypoints; 0 keeps every smoothed point
    thinning: Length = 0.0002
    #: in critical regions, move the path to the largest clearance the passage allows
    centre_critical: bool = True
    #: before the QP, replace runs of waypoints by certified straight motions (keeping their margins)
    shortcut: bool = True


class SafePRMSettings(StrictModel):
    proficiency: str | float | FromAttempts | FromRecord = "intermediate"
    levels: dict[str, Length] = Field(default_factory=lambda: dict(DEFAULT_LEVELS))
    milestones: PositiveInt = 3000
    #: Algorithm 3's loop: when a query finds no path, grow the roadmap (doubling) up to this many
    max_milestones: PositiveInt | None = None
    k: PositiveInt = 15
    s: PositiveLength | None = None
    seed: int = 0
    #: threads the roadmaps' build may use (the neighbour search's slabs, the scene's batched distances, R's and
    #: R_safe's landmarks at once; 1 keeps all of it on the calling thread); the default, two where the process
    #: may run on two CPUs, one on a real-time thread. The roadmaps are the same whatever the number
    threads: PositiveInt | None = None
    smoothing: SmoothingSettings = Field(default_factory=SmoothingSettings)

    @field_validator("proficiency", mode="before")
    @classmethod
    def _proficiency_form(cls, value: Any, info: ValidationInfo) -> Any:
        from surgiplan.units import _to_metres

        if isinstance(value, dict):
            if "trainee" in value:
                return FromRecord.model_validate(value, context=info.context)
            return FromAttempts.model_validate(value, context=info.context)
        if isinstance(value, bool):
            raise ValueError("expected a level name, a length, {from_attempts: FILE} or {trainee: NAME, task: TASK}")
        if isinstance(value, int | float):
            return _to_metres(value, info)
        if isinstance(value, str) and value[:1].isdigit():
            return _to_metres(value, info)
        return value

    @model_validator(mode="after")
    def _check(self):
        if isinstance(self.proficiency, str) and self.proficiency not in self.levels:
            from surgiplan.errors import choices_hint

            raise ValueError(
                f"unknown proficiency level '{self.proficiency}'; {choices_hint(self.proficiency, self.levels)}"
            )
        if isinstance(self.proficiency, float) and not (math.isfinite(self.proficiency) and self.proficiency >= 0):
            raise ValueError(f"proficiency must be a non-negative length, got {self.proficiency} m")
        if self.max_milestones is not None and self.max_milestones < self.milestones:
            raise ValueError("max_milestones must be at least milestones")
        return self

    @property
    def d_thresh(self) -> float:
        """The clearance threshold (m) this proficiency asks for."""
        if isinstance(self.proficiency, FromAttempts | FromRecord):
            return float(self.proficiency.d_thresh)
        if isinstance(self.proficiency, str):
            return float(self.levels[self.proficiency])
        return float(self.proficiency)

    @property
    def proficiency_label(self) -> str:
        if isinstance(self.proficiency, FromAttempts):
            return f"from attempts ({Path(self.proficiency.from_attempts).name}, p{self.proficiency.percentile:g})"
        if isinstance(self.proficiency, FromRecord):
            p = self.proficiency
            return f"trainee {p.trainee} at {p.task} ({p.attempts} attempt(s), p{p.percentile:g})"
        if isinstance(self.proficiency, str):
            return self.proficiency
        return "custom"


@dataclass
class SafePRMArtifact:
    roadmap: RoadmapPair
    problem: PlanningProblem | None = None
    grown: int = 0


def auto_radius(space, milestones: int) -> float:
    """3x the mean spacing of ``milestones`` uniform samples, in the space's metric."""
    extent = (space.high - space.low) * space.coordinate_weights
    extent = extent[np.isfinite(extent) & (extent > 0)]
    volume = float(np.prod(extent))
    return 3.0 * (volume / milestones) ** (1.0 / len(extent))


#: measured peak memory of a roadmap build, per milestone: about 500 B plus 250 B per neighbour (k); a build of
#: 32,000 milestones at k = 15 peaked at 2.8 kB per milestone, 2,000 at 4.3 kB (tracemalloc)
_BYTES_PER_MILESTONE = 500
_BYTES_PER_NEIGHBOUR = 250


class SafePRM(Planner):
    """The safe PRM of paper 000 with certified edges, projection, smoothing and critical regions."""

    Settings = SafePRMSettings
    artifact_version = 1
    #: paper 000: d_thresh is kept except in critical regions, where no detour exists
    clearance_policy = ClearancePolicy.EXCEPT_CRITICAL

    def __init__(self, settings: SafePRMSettings) -> None:
        super().__init__(settings)
        # the roadmap, query and smoothing modules (numba kernels from numba's cache, scipy, OSQP) load here, when
        # a stage constructs its planner, before the timed build and query; validating settings does not load them
        from . import query, roadmap, smoothing  # noqa: F401

    @classmethod
    def clearance_threshold_from(cls, settings):
        """d_thresh, from ``proficiency`` (a level, a length, recorded attempts or the trainee record)."""
        source = f"settings.proficiency ({settings.proficiency_label})"
        return ClearanceThreshold(settings.d_thresh, source), "proficiency" in settings.model_fields_set

    # ------------------------------------------------------------------ build
    @classmethod
    def estimate_resources(cls, settings, problem):
        n = max(settings.milestones, settings.max_milestones or 0)
        key = (
            "max_milestones"
            if settings.max_milestones and settings.max_milestones > settings.milestones
            else "milestones"
        )
        per = _BYTES_PER_MILESTONE + _BYTES_PER_NEIGHBOUR * settings.k
        return [ResourceEstimate(n * per, f"a roadmap pair of {n:,} milestones (k = {settings.k})", key)]

    def _build(self, problem: PlanningProblem, milestones: int) -> RoadmapPair:
        space = problem.space
        if space.coordinate_weights is None:
            raise ValueError(f"safe_prm plans in R3 or the CAST gimbal space, not in '{space.kind}'")
        from .roadmap import build_roadmaps

        s = self.settings.s or auto_radius(space, milestones)
        return build_roadmaps(
            space,
            milestones=milestones,
            k=self.settings.k,
            s=s,
            d_thresh=self.planning_threshold(problem),
            seed=self.settings.seed,
            progress=problem.progress,
            threads=self.settings.threads,
        )

    def build(self, problem: PlanningProblem) -> SafePRMArtifact:
        return SafePRMArtifact(self._build(problem, self.settings.milestones), problem)

    def save_artifact(self, artifact: SafePRMArtifact) -> dict[str, Any]:
        r = artifact.roadmap
        return {
            "milestones": r.milestones,
            "clearance": r.clearance,
            "safe": r.safe,
            "edges": r.edges,
            "edge_cost": r.edge_cost,
            "edge_safe": r.edge_safe,
            "d_thresh": r.d_thresh,
            "k": r.k,
            "s": r.s,
            "covered_edges": r.covered_edges,
        }

    def load_artifact(self, data, problem: PlanningProblem) -> SafePRMArtifact:
        from .roadmap import RoadmapPair

        roadmap = RoadmapPair(
            problem.space,
            np.asarray(data["milestones"], float).reshape(-1, problem.space.dimension),
            np.asarray(data["clearance"], float),
            np.asarray(data["safe"], bool),
            np.asarray(data["edges"], np.int64).reshape(-1, 2),
            np.asarray(data["edge_cost"], float),
            np.asarray(data["edge_safe"], bool),
            float(data["d_thresh"]),
            int(data["k"]),
            float(data["s"]),
            covered_edges=int(data["covered_edges"]),
            threads=self.settings.threads,
        )
        if not (
            len(roadmap.clearance) == len(roadmap.safe) == roadmap.n
            and len(roadmap.edge_cost) == len(roadmap.edge_safe) == len(roadmap.edges)
        ):
            raise ValueError("array lengths do not match")
        if len(roadmap.edges) and (roadmap.edges.min() < 0 or roadmap.edges.max() >= roadmap.n):
            raise ValueError("edge indices out of range")
        return SafePRMArtifact(roadmap, problem)

    # ------------------------------------------------------------------ query
    def query(self, artifact: SafePRMArtifact, start, goal) -> PlanResult:
        from . import query as prm_query
        from .smoothing import shortcut, smooth_in_corridor

        roadmap = artifact.roadmap
        space = roadmap.space
        d_thresh = roadmap.d_thresh
        start = np.asarray(start, dtype=float)
        goal = np.asarray(goal, dtype=float)
        failure = self.check_endpoints(space, start, goal, 0.0)
        if failure is not None:
            return failure
        started = time.perf_counter()
        outcome = prm_query.query(roadmap, start, goal)
        query_s = time.perf_counter() - started
        # Algorithm 3: sample more until a path exists (when allowed)
        limit = self.settings.max_milestones or roadmap.n
        grow_s = 0.0
        while not outcome.found and roadmap.n * 2 <= limit and artifact.problem is not None:
            started = time.perf_counter()
            roadmap = self._build(artifact.problem, roadmap.n * 2)
            grow_s += time.perf_counter() - started
            artifact.roadmap = roadmap
            artifact.grown += 1
            started = time.perf_counter()
            outcome = prm_query.query(roadmap, start, goal)
            query_s = time.perf_counter() - started
        from_settings = d_thresh == self.settings.d_thresh
        metrics: dict[str, Any] = {
            "proficiency": self.settings.proficiency_label if from_settings else "the stage's clearance_threshold",
            "d_thresh_m": d_thresh,
            **roadmap.stats,
            "k": roadmap.k,
            "s_m": roadmap.s,
            **{f"{k}": v for k, v in outcome.timings.items()},
            # the roadmap query (linking, search, repair), as bench_safe_prm.py times it; smoothing is smooth_s
            "query_s": query_s,
        }
        if artifact.grown:
            metrics["roadmap_grown"] = artifact.grown
            metrics["grow_s"] = grow_s
        if from_settings and isinstance(self.settings.proficiency, FromAttempts):
            p = self.settings.proficiency
            metrics["attempts"] = {
                "file": p.from_attempts,
                "percentile": p.percentile,
                "attempts": p.attempts,
                "points": p.points,
                "deviation_median_m": p.deviation_median,
                "deviation_max_m": p.deviation_max,
            }
        if from_settings and isinstance(self.settings.proficiency, FromRecord):
            p = self.settings.proficiency
            metrics["trainee"] = {
                "record": p.record,
                "trainee": p.trainee,
                "task": p.task,
                "percentile": p.percentile,
                "last": p.last,
                "attempts": p.attempts,
                "samples": p.samples,
            }
        if not outcome.found:
            return PlanResult.failure(PlanStatus.NO_PATH, space.dimension, outcome.message, **metrics)

        path = outcome.path
        metrics["repaired"] = outcome.repaired
        metrics["search_settled"] = outcome.settled
        metrics["roadmap_waypoints"] = len(path)
        started = time.perf_counter()
        if self.settings.smoothing.enabled:
            smoothing = self.settings.smoothing
            kinds = outcome.kinds
            if smoothing.shortcut:
                margins = self._segment_margins(space, path, np.array([k != prm_query.SAFE for k in kinds]), d_thresh)
                path, margins = shortcut(space, path, margins)
                kinds = [prm_query.SAFE if m >= d_thresh else prm_query.RISK for m in margins]
                metrics["shortcut_waypoints"] = len(path)
            dense, risky = _densify(space, path, kinds, smoothing.resolution)
            if smoothing.centre_critical and d_thresh > 0 and np.any(risky):
                dense = self._centre_critical(space, dense, risky, smoothing.resolution, d_thresh)
            margins = self._segment_margins(space, dense, risky, d_thresh)
            smoothed = smooth_in_corridor(
                space,
                dense,
                margins,
                resolution=smoothing.resolution,
                alpha=smoothing.alpha,
                beta=smoothing.beta,
                thinning=smoothing.thinning or None,
            )
            metrics["smoothed"] = smoothed.smoothed
            metrics["smoothing_rounds"] = smoothed.rounds
            if smoothed.message:
                metrics["smoothing_note"] = smoothed.message
            path = smoothed.path
        metrics["smooth_s"] = time.perf_counter() - started
        regions = critical_regions(space, path, d_thresh)
        metrics["critical_regions"] = regions
        message = ""
        if regions:
            message = (
                f"{len(regions)} critical region(s) below the {space.scene.describe_length(d_thresh)} threshold, "
                "where no safe detour exists"
            )
        detours = self._avoided_passages(space, outcome.detours, d_thresh)
        metrics["detours"] = len(detours)
        return PlanResult(PlanStatus.SOLVED, path, metrics, message, annotations={"detours": detours})

    @staticmethod
    def _avoided_passages(space, stretches: list[np.ndarray], d_thresh: float) -> list[dict]:
        """The passages a repair avoided: where the replaced stretch of R's path came closer than d_thresh
        (each contiguous run of it, as tip positions), as paper 000 Fig. 4 circles them with dashed ovals."""
        out = []
        resolution = float(np.min(space.scene.extent)) / 400.0
        for stretch in stretches:
            if len(stretch) < 2:
                continue
            dense = space.densify(stretch, resolution)
            low = space.clearance(dense) < d_thresh
            edges = np.flatnonzero(np.diff(np.concatenate([[0], low.astype(int), [0]])))
            for a, b in zip(edges[::2], edges[1::2], strict=True):
                out.append({"tips_m": space.tip(dense[a:b]).tolist()})
        return out

    @staticmethod
    def _centre_critical(space, dense: np.ndarray, risky: np.ndarray, resolution: float, d_thresh: float) -> np.ndarray:
        """Raise the clearance inside critical stretches (as much as the passage allows, up to d_thresh)."""
        from .smoothing import raise_clearance

        movable = np.zeros(len(dense), dtype=bool)
        movable[1:-1] = risky[:-1] & risky[1:]  # interior points of critical stretches
        raised = raise_clearance(space, dense, movable, step=resolution, target=d_thresh)
        # keep each stretch's raise only if its motions are no tighter than before
        out = dense.copy()
        for a, b in _stretches(risky):
            before = space.segment_clearance(dense[a:b], dense[a + 1 : b + 1]).min()
            after = space.segment_clearance(raised[a:b], raised[a + 1 : b + 1]).min()
            if after > before:
                out[a : b + 1] = raised[a : b + 1]
        return out

    @staticmethod
    def _segment_margins(space, path: np.ndarray, risky: np.ndarray, d_thresh: float) -> np.ndarray:
        """d_thresh on safe motions; on a critical stretch, the clearance the path keeps there."""
        margins = np.full(len(risky), d_thresh)
        if np.any(risky):
            clearance = space.segment_clearance(path[:-1][risky], path[1:][risky])
            floor = np.full(len(risky), np.nan)
            floor[risky] = clearance
            # one floor per contiguous critical stretch: its minimum, less 1 um so that the
            # smoother's round-off cannot make an exact bottleneck fail its own re-verification
            for a, b in _stretches(risky):
                margins[a:b] = max(0.0, float(np.min(floor[a:b])) - 1e-6)
        return margins


def _stretches(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index ranges of the runs of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], np.asarray(mask, int), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _densify(space, path: np.ndarray, kinds: list[str], resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """The path densified to ``resolution``, and per dense motion whether it is on a risk/link edge."""
    from . import query as prm_query

    pieces = [path[:1]]
    risky = []
    for i, kind in enumerate(kinds):
        dense = space.densify(path[i : i + 2], resolution)[1:]
        pieces.append(dense)
        risky.append(np.full(len(dense), kind != prm_query.SAFE))
    return np.concatenate(pieces), np.concatenate(risky) if risky else np.zeros(0, dtype=bool)


def critical_regions(space, path: np.ndarray, d_thresh: float, resolution: float | None = None) -> list[dict]:
    """The stretches of ``path`` below ``d_thresh`` (:func:`surgiplan.clearance.critical_regions`, the framework's
    own measure), as the JSON records of ``metrics.critical_regions``: ``start_m``/``end_m`` along the tip path,
    ``length_m``, ``min_clearance_m`` and the nearest ``obstacles``."""
    return [r.to_json() for r in measured_regions(space, path, d_thresh, resolution)]
