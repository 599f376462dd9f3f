"""Settings and the offline phase shared by the ``optmis`` and ``segmented_astar`` planners (paper 001 §3.1).

Both planners start from the same optMIS repository; with the same settings
in one pipeline they share its checkpoints, so it is computed once (see
:mod:`.optmis_repository`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from pydantic import Field, PositiveInt, model_validator
from surgiplan.errors import PlanningInputError, choices_hint
from surgiplan.models import StrictModel
from surgiplan.planning import PlanningProblem
from surgiplan.units import Length, PositiveLength

from .paths import PathOptions
from .repository import (
    Repository,
    SearchOptions,
    build_repository,
    checkpoint_dir,
    offline_key,
    search_space,
)
from .search_space import SearchGraph


class SmoothingSettings(StrictModel):
    """Cubic-spline smoothing of the paths (paper 001 §3.1)."""

    enabled: bool = True
    #: largest spacing of the stored path points
    resolution: PositiveLength = 0.002
    #: straight pieces are cut into equal knot intervals of at most this length
    knot_spacing: PositiveLength = 0.006
    #: the spline rounds each turn of the taut path within about this distance of it
    turn_radius: PositiveLength = 0.001
    #: knots on each side of an interval in the fallback window spline
    window: PositiveInt = 2


class OptMISSettings(StrictModel):
    """The optMIS offline planner: search space, paths and smoothing (lengths in the file's unit)."""

    #: the points of interest (names of scene points); default: every point of the scene
    points: list[str] | None = None
    #: spacing of the workspace grid of the search space
    grid_spacing: PositiveLength = 0.006
    #: spacing of the vertices seeded on the obstacles' surfaces
    surface_spacing: PositiveLength = 0.003
    #: how far beyond tip radius + margin the surface vertices, and the refined turns, sit
    surface_gap: PositiveLength = 0.0001
    #: extra edges to each vertex's nearest neighbours (besides the Delaunay edges)
    neighbours: PositiveInt = 12
    #: any-angle tautening of the Dijkstra paths (False: the search space's paths, as in the paper)
    taut: bool = True
    #: longest straight motion tautening may create (none: no limit); shorter keeps paths on shared routes
    max_jump: PositiveLength | None = None
    #: slide the turns of the taut paths along the obstacles' edges to where the paths are shortest ...
    refine: bool = True
    #: ... and pass the edges this close (beyond the margin)
    turn_gap: PositiveLength = 0.00001
    #: clearance the tip sphere keeps beyond its radius
    margin: Length = 0.0
    smoothing: SmoothingSettings = Field(default_factory=SmoothingSettings)
    #: nearest vertices tried when linking an arbitrary start or goal (a query setting: not part of
    #: the stored artifact's content key, like every setting marked exclude=True)
    link_candidates: PositiveInt = Field(default=16, exclude=True)
    seed: int = 0

    @model_validator(mode="after")
    def _check(self):
        if self.points is not None:
            if len(self.points) < 2:
                raise ValueError("give at least two points of interest")
            repeated = sorted({p for p in self.points if self.points.count(p) > 1})
            if repeated:
                raise ValueError(f"points of interest repeated: {', '.join(repeated)}")
        if self.smoothing.resolution > self.smoothing.knot_spacing:
            raise ValueError("smoothing.resolution must not exceed smoothing.knot_spacing")
        return self

    def estimate(self, scene) -> list:
        """Memory of the search space and the repository, from the scene's size and the spacings."""
        from surgiplan.resources import ResourceEstimate

        extent = np.asarray(scene.extent, float)
        grid = float(np.prod(extent / self.grid_spacing)) * 1.5  # the grid, plus the half-spacing grid near obstacles
        area = sum(float(o.to_trimesh().area) for o in scene.obstacles)
        surface = area / self.surface_spacing**2
        vertices = grid + surface
        points = len(self.points) if self.points is not None else len(scene.points)
        pairs = points * (points - 1) / 2
        per_path = float(np.linalg.norm(extent)) * 2 / self.smoothing.resolution  # a path's samples, generously
        return [
            ResourceEstimate(
                vertices * (800 + 48 * self.neighbours),
                f"a search space of about {vertices:,.0f} vertices (grid_spacing, surface_spacing)",
                "grid_spacing" if grid >= surface else "surface_spacing",
            ),
            ResourceEstimate(
                pairs * per_path * 24,
                f"{pairs:,.0f} paths between {points} points of interest at smoothing.resolution",
                "smoothing",
            ),
        ]

    def search_options(self) -> SearchOptions:
        return SearchOptions(self.grid_spacing, self.surface_spacing, self.surface_gap, self.neighbours, self.seed)

    def path_options(self) -> PathOptions:
        return PathOptions(
            taut=self.taut,
            max_jump=float(self.max_jump) if self.max_jump is not None else float("inf"),
            knot_spacing=self.smoothing.knot_spacing,
            resolution=self.smoothing.resolution,
            smoothing=self.smoothing.enabled,
            refine=self.refine,
            floor=self.turn_gap,
            turn_radius=self.smoothing.turn_radius,
            window=self.smoothing.window,
            margin=self.margin,
        )


def require_r3(space) -> None:
    if space.kind != "r3" or not hasattr(space, "tip_radius"):
        raise PlanningInputError(
            f"optMIS plans for the instrument tip, a sphere, in the r3 space; this stage's space is '{space.kind}' "
            "(use space: {kind: r3, tip_radius: ...})",
            location="space",
        )


def points_of_interest(scene, settings: OptMISSettings) -> tuple[list[str], np.ndarray]:
    """Names and positions (m) of the points of interest."""
    if settings.points is None:
        names = list(scene.points)
        if len(names) < 2:
            raise PlanningInputError(
                f"optMIS needs at least two points of interest; the scene has {len(names)} point(s) "
                "(add them under the scene's points:)",
                location="scene.points",
            )
    else:
        names = list(settings.points)
        unknown = [n for n in names if n not in scene.points]
        if unknown:
            raise PlanningInputError(
                f"no scene point named '{unknown[0]}'; {choices_hint(unknown[0], scene.points)}",
                location="settings.points",
            )
    return names, np.array([scene.points[n] for n in names], dtype=float).reshape(-1, 3)


@dataclass
class Offline:
    graph: SearchGraph
    repository: Repository
    key: str


def run_offline(problem: PlanningProblem, settings: OptMISSettings) -> Offline:
    """The search space and the all-pairs repository, on the problem's executor, resumable."""
    space = problem.space
    require_r3(space)
    names, pois = points_of_interest(problem.scene, settings)
    search, paths = settings.search_options(), settings.path_options()
    key = offline_key(space, names, pois, search, paths)
    store = checkpoint_dir(problem.workdir, key)
    started = time.perf_counter()
    graph = search_space(
        space, names, pois, search, settings.margin, store_dir=store, key=key, progress=problem.progress
    )
    graph_s = time.perf_counter() - started
    repository = build_repository(
        space, graph, names, pois, paths, executor=problem.executor, progress=problem.progress, store_dir=store
    )
    repository.stats["search_space_s"] = graph_s
    repository.stats.update(graph.stats())
    return Offline(graph, repository, key)
