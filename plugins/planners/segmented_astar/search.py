"""segmented_astar: online A* on the segmented pathmap of an optMIS repository (paper 001 §3.2, §5).

Build (offline): the optMIS all-pairs repository (shared with an ``optmis``
stage of the same settings, resumable), then the segmented pathmap
(:mod:`.pathmap`); the artifact holds only the pathmap, the storage the
paper is about. With ``report:``, paper 001 Table 1 for n_s = 2..5 is
written as ``table1.csv`` and ``table1.png`` (:mod:`.report`).

Query (online): A* with the Euclidean heuristic on the graph built from the
pathmap (:mod:`.graph`). Beyond the paper (which admits that its
planner fails for points not in the graph, §7):

* a start or goal that is not a point of the pathmap is linked to it by
  certified straight motions to the nearest point of each of the
  ``link_candidates`` nearest stored paths (optionally within
  ``link_radius``); when none is clear, by a short local optMIS plan in a box
  of half-size ``local_radius`` around it; when that fails too, the answer
  is ``no_path`` with the reason;
* *replanning* (paper 001 Fig. 6): :meth:`SegmentedAStar.replan` gives a
  new path from the current position to a new goal; ``replan: {goal: C,
  at: 0.6, figure: fig6.png}`` in a pipeline plans A -> B, moves 60 % of the
  way along it and replans to C, returning the travelled part and the new
  path, and draws the instance like Fig. 6 (:mod:`.figures`).

Every returned motion is certified for the tip sphere: pathmap motions were
certified when the pathmap was built, links and local plans when made.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, PositiveInt, field_validator
from surgiplan.errors import OutputError
from surgiplan.models import StrictModel
from surgiplan.planning import Planner, PlanningProblem, PlanResult, PlanStatus
from surgiplan.plugins.planners.optmis.offline import OptMISSettings, require_r3, run_offline
from surgiplan.plugins.planners.optmis.paths import PathOptions, paths_from_source
from surgiplan.plugins.planners.optmis.search_space import build_search_graph
from surgiplan.scene import meets_margin
from surgiplan.units import Length, PositiveLength, Vec3

from .graph import Attachment, OnlineGraph, certify_motions, online_graph
from .pathmap import ALIGNMENTS, SegmentedPathmap, build_pathmap
from .report import table1, write_report

log = logging.getLogger(__name__)


class ReportSettings(StrictModel):
    """Paper 001 Table 1: where to write it and for which segment sizes."""

    #: directory (relative to the current directory, like artifact files)
    dir: str
    segment_points: list[PositiveInt] = Field(default_factory=lambda: [2, 3, 4, 5])


class ReplanSettings(StrictModel):
    """Paper 001 Fig. 6: after a fraction ``at`` of the first path, a new goal."""

    #: the new goal C: a scene point's name or coordinates
    goal: str | Vec3
    at: float = Field(default=1.0, gt=0, le=1)
    #: write the instance drawn like paper 001 Fig. 6 to this PNG file (relative to the current directory)
    figure: str | None = None


class SegmentedAStarSettings(OptMISSettings):
    """The optMIS settings of the repository, plus the pathmap's and the online planner's."""

    #: n_s, points per segment (paper 001 §4.2 chooses 3)
    segment_points: PositiveInt = 3
    #: common-segment tolerance; default w_tip, the tip sphere's diameter
    tolerance: Length | None = None
    #: 'path': segments counted from each path's start (paper); 'corners': restarted at every turn
    alignment: Literal["path", "corners"] = "corners"
    #: a segment also matches one traversed the other way
    reverse: bool = True
    #: thin each path by Douglas-Peucker within this tolerance (certified chords) before segmenting it;
    #: the common-segment tolerance then defaults to w_tip - thinning, so every original point stays
    #: within w_tip of its rebuilt path (0: every point of the paths is kept, as in the paper)
    thinning: Length = 0.0
    # query settings (exclude=True: they do not change the stored pathmap, so not its content key)
    #: how far a start or goal may be linked to the pathmap by a straight motion (to the nearest point
    #: of each of the ``link_candidates`` nearest chains of the online graph); none: no limit
    link_radius: PositiveLength | None = Field(default=None, exclude=True)
    #: half-size of the box in which a local plan links a start or goal the straight links cannot
    local_radius: PositiveLength = Field(default=0.015, exclude=True)
    report: ReportSettings | None = Field(default=None, exclude=True)
    replan: ReplanSettings | None = Field(default=None, exclude=True)

    @field_validator("alignment")
    @classmethod
    def _alignment(cls, value):
        if value not in ALIGNMENTS:
            raise ValueError(f"choose one of: {', '.join(ALIGNMENTS)}")
        return value


@dataclass
class PathmapArtifact:
    pathmap: SegmentedPathmap
    graph: OnlineGraph
    space: Any
    poi_vertex: np.ndarray  # graph vertex of each point of interest (-1: in no stored path)
    table1: list[dict]


class SegmentedAStar(Planner):
    """A* on the segmented pathmap; arbitrary starts and goals; replanning."""

    @classmethod
    def estimate_resources(cls, settings, problem):
        return settings.estimate(problem.scene)

    Settings = SegmentedAStarSettings
    #: the older spelling of the stage's clearance_threshold: a margin every state and motion keeps
    threshold_setting = "margin"
    artifact_version = 1

    # ------------------------------------------------------------------ offline
    def _check_outputs(self) -> None:
        """Fail before any work when the report or figure cannot be written (not after an hour of it)."""
        from surgiplan.storage import prepare_output_dir

        targets = []
        if self.settings.report is not None:
            targets.append((Path(self.settings.report.dir), "settings.report.dir"))
        if self.settings.replan is not None and self.settings.replan.figure:
            targets.append((Path(self.settings.replan.figure).parent, "settings.replan.figure"))
        for directory, location in targets:
            try:
                prepare_output_dir(directory)
            except OutputError as exc:
                raise OutputError(exc.message.replace("output directory", "directory"), location=location) from None

    def build(self, problem: PlanningProblem) -> PathmapArtifact:
        settings = self.settings
        self._check_outputs()
        w_tip = 2.0 * getattr(problem.space, "tip_radius", 0.0)
        if settings.tolerance is None and settings.thinning > w_tip:
            from surgiplan.errors import PlanningInputError

            raise PlanningInputError(
                f"thinning ({settings.thinning * 1e3:.3g} mm) must not exceed w_tip, the tip's diameter "
                f"({w_tip * 1e3:.3g} mm): the common-segment tolerance is w_tip - thinning",
                location="settings.thinning",
            )
        offline = run_offline(problem, settings)
        started = time.perf_counter()
        with problem.progress.task("segmented pathmap", total=1) as task:
            pathmap = build_pathmap(
                offline.repository,
                problem.space,
                n_s=settings.segment_points,
                tolerance=settings.tolerance,
                alignment=settings.alignment,
                reverse=settings.reverse,
                margin=settings.margin,
                seed=settings.seed,
                thinning=settings.thinning,
            )
            task.advance(1)
        pathmap.stats["pathmap_s"] = time.perf_counter() - started
        pathmap.stats["repository"] = {
            k: v for k, v in offline.repository.summary().items() if not isinstance(v, dict | list)
        }
        rows: list[dict] = []
        if settings.report is not None:
            with problem.progress.task("paper 001 Table 1", total=1) as task:
                directory = Path(settings.report.dir)
                rows = table1(
                    offline.repository,
                    problem.space,
                    sizes=tuple(settings.report.segment_points),
                    alignment=settings.alignment,
                    reverse=settings.reverse,
                    tolerance=settings.tolerance,
                    margin=settings.margin,
                    directory=directory,
                    thinning=settings.thinning,
                )
                write_report(directory, rows, self._report_title(problem, offline.repository))
                task.advance(1)
        return self._artifact(pathmap, problem.space, rows)

    @staticmethod
    def _report_title(problem, repository) -> str:
        return (
            f"{problem.scene.name}: {repository.n_paths} paths between {len(repository.names)} points of interest, "
            f"w_tip = {2e3 * problem.space.tip_radius:.3g} mm"
        )

    @staticmethod
    def _artifact(pathmap: SegmentedPathmap, space, rows: list[dict]) -> PathmapArtifact:
        graph = online_graph(pathmap)
        graph.clearance = space.clearance(graph.points)  # for links certified by covering balls
        distance, index = graph.tree.query(pathmap.pois)
        # a point of interest that no path reaches is not in the pathmap (-1)
        index = np.where(distance <= 1e-12, index, -1)
        return PathmapArtifact(pathmap, graph, space, np.asarray(index, np.int64), rows)

    def save_artifact(self, artifact: PathmapArtifact) -> dict[str, Any]:
        return {**artifact.pathmap.to_artifact(), "table1": artifact.table1}

    def load_artifact(self, data, problem: PlanningProblem) -> PathmapArtifact:
        require_r3(problem.space)
        self._check_outputs()
        rows = list(data.get("table1", []))
        artifact = self._artifact(SegmentedPathmap.from_artifact(data), problem.space, rows)
        if self.settings.report is not None:
            directory = Path(self.settings.report.dir)
            if not rows:
                log.warning(
                    "the stored pathmap was built without report:, so it has no Table 1; delete the "
                    "artifact file to rebuild it with the report"
                )
            elif not (directory / "table1.csv").is_file():
                write_report(directory, rows)
        return artifact

    # ------------------------------------------------------------------ online
    def _attach(
        self, artifact: PathmapArtifact, ends: np.ndarray, clearance: np.ndarray, counters: dict
    ) -> list[tuple[list[Attachment], str]]:
        """Ways from each of ``ends`` into the graph: a pathmap point, certified straight links, or a local plan.

        Both ends at once: one nearest-neighbour query and one batch of certified link motions.
        """
        graph, space, settings = artifact.graph, artifact.space, self.settings
        distance, vertex = graph.tree.query(ends)
        out: list[list[Attachment]] = []
        candidates: list[np.ndarray] = []
        for q, d, v in zip(ends, distance, vertex, strict=True):
            on_map = d <= 1e-12
            if on_map and graph.is_junction[v]:
                candidates.append(np.zeros(0, np.int64))  # a point of interest or a branch point: the pathmap alone
                out.append(graph.attachments_at_vertex(int(v), q[None], 0.0))
                continue
            out.append(graph.attachments_at_vertex(int(v), q[None], 0.0) if on_map else [])
            index = self.link_candidates(artifact, q)
            candidates.append(index[np.any(graph.points[index] != q, axis=1)])  # not to itself
        owner = np.concatenate([np.full(len(c), k) for k, c in enumerate(candidates)]).astype(np.int64)
        index = np.concatenate(candidates).astype(np.int64)
        ok = np.zeros(0, dtype=bool)
        if index.size:
            slack = clearance - settings.margin
            ok = certify_motions(
                space,
                ends[owner],
                graph.points[index],
                slack[owner],
                graph.clearance[index] - settings.margin,
                settings.margin,
            )
            counters["link_checks"] += len(index)
        kinds: list[tuple[list[Attachment], str]] = []
        for k, q in enumerate(ends):
            mine = owner == k
            on_map = distance[k] <= 1e-12
            if on_map and graph.is_junction[vertex[k]]:
                kinds.append((out[k], "vertex"))
                continue
            clear = index[mine & ok]
            points = graph.points[clear]
            cost = np.linalg.norm(points - q, axis=1).tolist()
            links = np.stack([np.broadcast_to(q, points.shape), points], axis=1)  # (links, 2, 3)
            for v, link, c in zip(clear.tolist(), links, cost, strict=True):
                out[k] += graph.attachments_at_vertex(v, link, c)
            if clear.size:
                kinds.append((out[k], "straight"))
            elif out[k]:
                kinds.append((out[k], "vertex"))
            else:
                counters["local_plans"] += 1
                kinds.append((self._local_plan(artifact, q), "local"))
        return kinds

    def link_candidates(self, artifact: PathmapArtifact, q: np.ndarray) -> np.ndarray:
        """Graph vertices a straight link from q may go to, nearest first.

        The nearest point of each of the ``link_candidates`` nearest chains
        within ``link_radius``: links into different stored paths, rather than
        many into the one path that q happens to lie beside.
        """
        graph, settings = artifact.graph, self.settings
        k = min(8 * settings.link_candidates, len(graph.points))
        limit = settings.link_radius if settings.link_radius is not None else np.inf
        distance, index = graph.tree.query(q, k=k, distance_upper_bound=limit)
        index = np.atleast_1d(index)[np.isfinite(np.atleast_1d(distance))]
        owner = np.where(graph.is_junction[index], -1 - index, graph.chain_of[index])
        _, first = np.unique(owner, return_index=True)
        return index[np.sort(first)][: settings.link_candidates]

    def _local_plan(self, artifact: PathmapArtifact, q: np.ndarray) -> list[Attachment]:
        """Certified paths from q to pathmap points in a box around it (a small optMIS search space)."""
        from surgiplan.spaces.r3 import R3Space

        graph, space, settings = artifact.graph, artifact.space, self.settings
        scene = space.scene
        half = settings.local_radius
        lo = np.maximum(q - half, scene.bounds_min)
        hi = np.minimum(q + half, scene.bounds_max)
        inside = np.flatnonzero(np.all((graph.points >= lo) & (graph.points <= hi), axis=1))
        if not inside.size:
            return []
        # the nearest pathmap points in the box are enough to join the graph
        inside = inside[np.argsort(np.linalg.norm(graph.points[inside] - q, axis=1))[:64]]
        local = R3Space(scene.with_bounds(lo, hi), space.tip_radius)
        pois = np.concatenate([q[None], graph.points[inside]])
        spacing = min(settings.grid_spacing, half / 2)
        try:
            search = build_search_graph(
                local,
                pois,
                grid_spacing=spacing,
                surface_spacing=settings.surface_spacing,
                surface_gap=settings.surface_gap,
                neighbours=settings.neighbours,
                margin=settings.margin,
                seed=settings.seed,
            )
        except Exception as exc:  # a degenerate local box (too few vertices): no local plan
            log.debug("no local search space around %s: %s", q, exc)
            return []
        options = PathOptions(
            taut=True,
            smoothing=False,
            resolution=settings.smoothing.resolution,
            knot_spacing=settings.smoothing.knot_spacing,
            margin=settings.margin,
        )
        targets = np.arange(1, len(pois))
        out = paths_from_source(
            local,
            search.graph,
            search.vertices,
            search.clearance,
            int(search.poi_vertex[0]),
            search.poi_vertex[targets],
            options,
        )
        attachments = []
        reached = targets[out["reachable"]]
        for k, target in enumerate(reached):
            points = out["points"][out["path_start"][k] : out["path_start"][k + 1]]
            attachments += graph.attachments_at_vertex(int(inside[target - 1]), points, float(out["length"][k]))
        return attachments

    def query(self, artifact: PathmapArtifact, start, goal) -> PlanResult:
        start, goal = np.asarray(start, float), np.asarray(goal, float)
        result = self._plan(artifact, start, goal)
        replan = self.settings.replan
        if replan is None or not result.solved:
            return result
        new_goal = self._resolve(artifact, replan.goal)
        path = result.path
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
        where = replan.at * arc[-1]
        k = int(np.clip(np.searchsorted(arc, where, side="right") - 1, 0, max(len(path) - 2, 0)))
        t = (where - arc[k]) / max(arc[k + 1] - arc[k], 1e-15) if len(path) > 1 else 0.0
        current = path[k] + np.clip(t, 0.0, 1.0) * (path[min(k + 1, len(path) - 1)] - path[k])
        travelled = np.concatenate([path[: k + 1], current[None]])
        second = self.replan(artifact, current, new_goal)
        metrics = dict(result.metrics)
        metrics["replan"] = {
            "first_goal_m": goal.tolist(),
            "first_length_m": float(arc[-1]),
            "at": replan.at,
            "position_m": current.tolist(),
            "new_goal_m": new_goal.tolist(),
            "status": second.status.value,
            "new_length_m": second.metrics.get("path_cost_m"),
            "query_s": second.metrics.get("online_s"),
            "expanded_junctions": second.metrics.get("expanded_junctions"),
        }
        if not second.solved:
            return PlanResult.failure(
                second.status, 3, f"replanning to the new goal failed: {second.message}", **metrics
            )
        combined = np.concatenate([travelled, second.path[1:]])
        keep = np.concatenate([[True], np.any(np.diff(combined, axis=0) != 0, axis=1)])
        if replan.figure:
            from .figures import replanning_figure

            labels = {"A": start, "B": goal, "C": new_goal, "R": current}
            replanning_figure(
                Path(replan.figure),
                artifact.space.scene,
                path,
                travelled,
                second.path,
                labels,
                title=f"replanning (paper 001 Fig. 6): A to B, new goal C after {replan.at:.0%} "
                f"of the way (replanned in {second.metrics['online_s'] * 1e3:.2f} ms)",
            )
            metrics["replan"]["figure"] = replan.figure
        return PlanResult(
            PlanStatus.SOLVED,
            combined[keep],
            metrics,
            final_goal=new_goal,
            annotations={"replan": {"position_m": current.tolist(), "travelled_m": float(where)}},
        )

    def replan(self, artifact: PathmapArtifact, current, new_goal) -> PlanResult:
        """A new path from the current position (anywhere, e.g. partway along the last path) to a new goal."""
        return self._plan(artifact, np.asarray(current, float), np.asarray(new_goal, float))

    def _resolve(self, artifact: PathmapArtifact, goal) -> np.ndarray:
        if isinstance(goal, str):
            names = artifact.pathmap.names
            if goal in artifact.space.scene.points:
                return np.asarray(artifact.space.scene.points[goal], float)
            from surgiplan.errors import PlanningInputError, choices_hint

            raise PlanningInputError(
                f"no point named '{goal}'; {choices_hint(goal, names)}", location="settings.replan.goal"
            )
        return np.asarray(goal, float)

    def _plan(self, artifact: PathmapArtifact, start: np.ndarray, goal: np.ndarray) -> PlanResult:
        space, graph = artifact.space, artifact.graph
        # a point of the pathmap is a certified configuration already; anything else is checked
        ends = np.stack([start, goal])
        on_map = graph.tree.query(ends)[0] <= 1e-12
        clearance = space.clearance(ends)
        if not np.all(on_map):
            # space.is_valid for both ends from one clearance query; the messages come from check_endpoints
            valid = space.within_limits(ends) & space.in_workspace(ends) & meets_margin(clearance, self.settings.margin)
            if not np.all(valid | on_map):
                failure = self.check_endpoints(space, start, goal, self.settings.margin)
                if failure is not None:
                    return failure
        started = time.perf_counter()
        counters = {"link_checks": 0, "local_plans": 0}
        slack = clearance - self.settings.margin
        # two points off the pathmap in line of sight: no route through the graph is shorter than the
        # straight motion (the graph's answer would be it), so it is returned without linking
        in_sight = not np.any(on_map) and bool(
            certify_motions(space, start[None], goal[None], slack[:1], slack[1:], self.settings.margin)[0]
        )
        if in_sight:
            finished = time.perf_counter()
            straight = float(np.linalg.norm(goal - start))
            metrics = {
                "start_link": "direct",
                "goal_link": "direct",
                **counters,
                "w_tip_m": 2 * space.tip_radius,
                "link_s": 0.0,
                "astar_s": 0.0,
                "online_s": finished - started,
                "expanded_junctions": 0,
                "path_cost_m": straight,
            }
            return PlanResult(PlanStatus.SOLVED, np.stack([start, goal]), metrics)
        (starts, start_kind), (goals, goal_kind) = self._attach(artifact, ends, clearance, counters)
        linked = time.perf_counter()
        metrics: dict[str, Any] = {
            "start_link": start_kind,
            "goal_link": goal_kind,
            **counters,
            "w_tip_m": 2 * space.tip_radius,
            **{f"pathmap_{k}": v for k, v in artifact.pathmap.stats.items() if not isinstance(v, dict | list)},
            **graph.stats(),
        }
        within = f" within {self.settings.link_radius * 1e3:.3g} mm" if self.settings.link_radius else ""
        for attachments, what, q in ((starts, "start", start), (goals, "goal", goal)):
            if not attachments:
                metrics["link_s"] = linked - started
                return PlanResult.failure(
                    PlanStatus.NO_PATH,
                    3,
                    f"the {what} {space.scene.describe_point(q)} cannot be joined to the pathmap: no certified "
                    f"straight motion to the nearest point of any of the {self.settings.link_candidates} nearest "
                    f"stored paths{within}, and no local plan within {self.settings.local_radius * 1e3:.3g} mm "
                    "of it",
                    **metrics,
                )
        # routes that need no junction: along the one chain both ends joined, or straight from start to goal
        direct = graph.along_one_chain(starts, goals)
        if (
            np.any(on_map)
            and "vertex" not in (start_kind, goal_kind)
            and certify_motions(space, start[None], goal[None], slack[:1], slack[1:], self.settings.margin)[0]
        ):
            straight = float(np.linalg.norm(goal - start))
            if direct is None or straight < direct[0]:
                direct = (straight, np.stack([start, goal]))
        outcome = graph.astar(starts, goals, goal, direct)
        finished = time.perf_counter()
        metrics.update(
            {
                "link_s": linked - started,
                "astar_s": finished - linked,
                "online_s": finished - started,
                "expanded_junctions": outcome.expanded,
                "path_cost_m": outcome.cost if np.isfinite(outcome.cost) else None,
            }
        )
        if outcome.path is None:
            return PlanResult.failure(
                PlanStatus.NO_PATH,
                3,
                "start and goal are in parts of the pathmap that no stored path joins "
                "(e.g. a point of interest that was unreachable offline)",
                **metrics,
            )
        return PlanResult(PlanStatus.SOLVED, outcome.path, metrics)
