"""optmis: the optMIS offline planner (paper 001 §3.1; Napalkova et al. 2014).

Build (offline): a Delaunay search space of the free space for the tip
sphere (:mod:`.search_space`), then every pair of points of interest joined
by a shortest path (one Dijkstra call per source), tautened and smoothed by
certified cubic splines (:mod:`.paths`, :mod:`surgiplan.paths.splines`), on the
pipeline's executor, resumable (:mod:`.repository`). The artifact
(``artifact:``) holds the search space and the repository.

Query (online): a start and goal that are points of interest get their
stored path; any other start or goal is linked to the search space by
certified straight motions and searched there (the paper's offline-only
planner, which took 67.6 s per query, §6). Unreachable pairs answer
``no_path`` and are listed in the metrics.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field
from scipy.sparse import coo_matrix
from surgiplan.errors import OutputError
from surgiplan.paths import certify_edges
from surgiplan.planning import Planner, PlanningProblem, PlanResult, PlanStatus

from .offline import OptMISSettings, run_offline
from .paths import paths_from_source
from .repository import Repository
from .search_space import SearchGraph


@dataclass
class OptMISArtifact:
    graph: SearchGraph
    repository: Repository
    space: Any


def link_vertices(space, graph: SearchGraph, q: np.ndarray, margin: float, candidates: int) -> tuple[np.ndarray, float]:
    """Search-space vertices reachable from q by a certified straight motion (nearest ``candidates``, then 8x)."""
    clearance = float(space.clearance(q[None])[0])
    for k in (candidates, 8 * candidates):
        k = min(k, graph.n)
        _, index = graph.tree.query(q, k=k)
        index = np.atleast_1d(index)
        ok, _ = certify_edges(
            space,
            np.repeat(q[None], len(index), 0),
            graph.vertices[index],
            np.full(len(index), clearance - margin),
            graph.clearance[index] - margin,
            margin,
        )
        if np.any(ok):
            return index[ok], clearance
        if k == graph.n:
            break
    return np.zeros(0, dtype=np.int64), clearance


def search_between(space, graph: SearchGraph, start: np.ndarray, goal: np.ndarray, settings: OptMISSettings) -> dict:
    """An optMIS path between arbitrary points: linked into the search space, Dijkstra, tautened, smoothed."""
    n = graph.n
    links = []
    for q, what in ((start, "start"), (goal, "goal")):
        index, _ = link_vertices(space, graph, q, settings.margin, settings.link_candidates)
        if not index.size:
            return {
                "message": f"the {what} {space.scene.describe_point(q)} cannot be linked to the search space: "
                f"no certified straight motion to any of its {8 * settings.link_candidates} "
                "nearest vertices"
            }
        links.append(index)
    vertices = np.concatenate([graph.vertices, start[None], goal[None]])
    clearance = np.concatenate([graph.clearance, space.clearance(np.stack([start, goal]))])
    base = graph.graph.tocoo()
    rows = [base.row, np.full(len(links[0]), n), links[0], np.full(len(links[1]), n + 1), links[1]]
    cols = [base.col, links[0], np.full(len(links[0]), n), links[1], np.full(len(links[1]), n + 1)]
    lengths = [
        base.data,
        np.linalg.norm(graph.vertices[links[0]] - start, axis=1),
        np.linalg.norm(graph.vertices[links[0]] - start, axis=1),
        np.linalg.norm(graph.vertices[links[1]] - goal, axis=1),
        np.linalg.norm(graph.vertices[links[1]] - goal, axis=1),
    ]
    augmented = coo_matrix(
        (np.maximum(np.concatenate(lengths), 1e-15), (np.concatenate(rows), np.concatenate(cols))), (n + 2, n + 2)
    ).tocsr()
    out = paths_from_source(space, augmented, vertices, clearance, n, np.array([n + 1]), settings.path_options())
    if not len(out["targets"]):
        return {
            "message": f"start {space.scene.describe_point(start)} and goal {space.scene.describe_point(goal)} "
            "are not connected in the search space"
        }
    return out


class OptMISPlanSettings(OptMISSettings):
    """The optMIS settings of the repository, plus where to draw it."""

    #: write the whole repository (every path faintly, the query's and a few others highlighted, and a
    #: top view of how many paths pass each 1 mm cell) to this PNG file, relative to the current
    #: directory; a query setting: it does not change the stored repository's content key
    figure: str | None = Field(default=None, exclude=True)


class OptMIS(Planner):
    """optMIS: all-pairs optimal paths between points of interest, stored; certified smooth paths."""

    @classmethod
    def estimate_resources(cls, settings, problem):
        return settings.estimate(problem.scene)

    Settings = OptMISPlanSettings
    #: the older spelling of the stage's clearance_threshold: a margin every state and motion keeps
    threshold_setting = "margin"
    artifact_version = 1

    def _check_outputs(self) -> None:
        """Fail before the offline work when the figure cannot be written."""
        from surgiplan.storage import prepare_output_dir

        if getattr(self.settings, "figure", None):  # OptMISSettings alone (no figure) is accepted too
            try:
                prepare_output_dir(Path(self.settings.figure).parent)
            except OutputError as exc:
                raise OutputError(
                    exc.message.replace("output directory", "directory"), location="settings.figure"
                ) from None

    def build(self, problem: PlanningProblem) -> OptMISArtifact:
        self._check_outputs()
        offline = run_offline(problem, self.settings)
        return OptMISArtifact(offline.graph, offline.repository, problem.space)

    def save_artifact(self, artifact: OptMISArtifact) -> dict[str, Any]:
        g = artifact.graph
        return {
            "vertices": g.vertices,
            "clearance": g.clearance,
            "edges": g.edges,
            "poi_vertex": g.poi_vertex,
            "margin": g.margin,
            **artifact.repository.to_arrays(),
        }

    def load_artifact(self, data, problem: PlanningProblem) -> OptMISArtifact:
        self._check_outputs()
        graph = SearchGraph(
            np.asarray(data["vertices"], float).reshape(-1, 3),
            np.asarray(data["clearance"], float),
            np.asarray(data["edges"], np.int64).reshape(-1, 2).astype(np.int32),
            np.asarray(data["poi_vertex"], np.int64),
            float(data["margin"]),
        )
        if len(graph.clearance) != graph.n or (len(graph.edges) and graph.edges.max() >= graph.n):
            raise ValueError("search space arrays do not match")
        return OptMISArtifact(graph, Repository.from_arrays(data), problem.space)

    def query(self, artifact: OptMISArtifact, start, goal) -> PlanResult:
        space = artifact.space
        start, goal = np.asarray(start, float), np.asarray(goal, float)
        failure = self.check_endpoints(space, start, goal, self.settings.margin)
        if failure is not None:
            return failure
        repository = artifact.repository
        metrics: dict[str, Any] = {"w_tip_m": 2 * space.tip_radius, **repository.summary()}
        i, j = _poi_index(repository.pois, start), _poi_index(repository.pois, goal)
        started = time.perf_counter()
        if i >= 0 and j >= 0:
            path = repository.between(i, j)
            metrics["source"] = "repository"
            if path is None:
                return PlanResult.failure(
                    PlanStatus.NO_PATH,
                    3,
                    f"points of interest '{repository.names[i]}' and '{repository.names[j]}' are not connected: "
                    "the pair is listed as unreachable in the repository",
                    **metrics,
                )
            if i != j:
                k = repository.index(i, j)
                metrics.update(
                    {
                        "graph_length_m": float(repository.graph_length[k]),
                        "taut_length_m": float(repository.taut_length[k]),
                        "smoothing_intervals": dict(
                            zip(("spline", "window_spline", "chord"), repository.kinds[k].tolist(), strict=True)
                        ),
                    }
                )
        else:
            out = search_between(space, artifact.graph, start, goal, self.settings)
            metrics["source"] = "search"
            if "points" not in out:
                return PlanResult.failure(PlanStatus.NO_PATH, 3, out["message"], **metrics)
            path = out["points"]
            metrics.update(
                {
                    "graph_length_m": float(out["graph_length"][0]),
                    "taut_length_m": float(out["taut_length"][0]),
                    "smoothing_intervals": dict(
                        zip(("spline", "window_spline", "chord"), out["kinds"][0].tolist(), strict=True)
                    ),
                }
            )
        metrics["lookup_s"] = time.perf_counter() - started
        result = PlanResult(PlanStatus.SOLVED, path, metrics)
        if getattr(self.settings, "figure", None):
            self._draw(artifact, i, j, result)
        return result

    def _draw(self, artifact: OptMISArtifact, i: int, j: int, result: PlanResult) -> None:
        """The repository figure: the query's stored path (if any), the longest path and three spread-out others."""
        from .figures import repository_figure

        repository = artifact.repository
        highlight: list[int] = []
        if i >= 0 and j >= 0 and i != j and repository.index(i, j) >= 0:
            highlight.append(int(repository.index(i, j)))
        if repository.n_paths:
            order = np.argsort(repository.length)
            highlight += [int(order[-1]), *(int(order[int(q * (len(order) - 1))]) for q in (0.25, 0.5, 0.75))]
        highlight = list(dict.fromkeys(highlight))
        figure = Path(self.settings.figure)
        w_tip = 2e3 * artifact.space.tip_radius
        repository_figure(
            figure,
            artifact.space.scene,
            repository,
            highlight,
            title=f"optMIS repository: {repository.n_paths:,} paths between {len(repository.names)} points of "
            f"interest, w_tip = {w_tip:.3g} mm",
        )
        result.metrics["figure"] = str(figure)


def _poi_index(pois: np.ndarray, q: np.ndarray, tolerance: float = 1e-9) -> int:
    """Index of the point of interest at q (within ``tolerance`` m), else -1."""
    if not len(pois):
        return -1
    d = np.linalg.norm(pois - q, axis=1)
    k = int(np.argmin(d))
    return k if d[k] <= tolerance else -1
