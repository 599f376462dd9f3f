"""What the planner derives once from its settings and the stage: model, grasps, checks, visibility.

Shared by the build (sample generation) and the query (lazy search), and
rebuilt cheaply when a stored artifact is loaded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from surgiplan.errors import PlanningInputError
from surgiplan.planning import PlanningProblem
from surgiplan.registry import default_registry

from .equilibria import deformable_model
from .geometry import CollisionModel, boundary_faces, instrument_parts
from .grasp import GraspFrame, candidate_grasps, grasp_frame
from .settings import RetractionSettings
from .visibility import Visibility


@dataclass
class Setup:
    settings: RetractionSettings
    problem: PlanningProblem
    model_class: type
    model_settings: dict
    rest: np.ndarray  # (n, 3) m
    elements: np.ndarray  # (m, 4)
    triangles: np.ndarray  # (t, 3) boundary surface
    surface_nodes: np.ndarray  # (S,) nodes of the boundary surface
    grasps: np.ndarray  # (G, 7): the stage's start, then the candidates
    frames: list[GraspFrame]
    collisions: list[CollisionModel]
    visibility: Visibility

    @classmethod
    def create(cls, settings: RetractionSettings, problem: PlanningProblem) -> Setup:
        space = problem.space
        if space.kind != "se3":
            raise PlanningInputError(
                f"the retraction planner plans gripper poses in the se3 space, not in '{space.kind}'; "
                "set space: {kind: se3, body: [...]}",
                location="space.kind",
            )
        if problem.start is None:
            raise PlanningInputError("the retraction planner needs the initial grasp as the stage's start")
        sampling = settings.sampling
        if sampling.kind == "guided" and problem.goal is None and not sampling.waypoints:
            raise PlanningInputError(
                "user-guided sampling needs the surgeon's path: give the stage a goal (the estimated final "
                "gripper position) or sampling.waypoints",
                location="settings.sampling",
            )
        info = default_registry().get("deformable_model", settings.deformable.plugin)
        model = deformable_model(info.cls, settings.deformable.settings)
        rest = np.asarray(model.rest_nodes, dtype=float)
        elements = np.asarray(model.elements)
        triangles = getattr(model, "surface_triangles", None)
        triangles = boundary_faces(elements) if triangles is None else np.asarray(triangles)
        grasps = candidate_grasps(np.asarray(problem.start, float), settings.grasps)
        frames = [
            grasp_frame(rest, settings.anchored, settings.jaws, q, "start" if k == 0 else f"grasp candidate {k}")
            for k, q in enumerate(grasps)
        ]
        collisions = [
            CollisionModel.build(
                problem.scene, space, triangles, f.grasped, settings.margin, settings.instrument_tissue_check
            )
            for f in frames
        ]
        visibility = Visibility(
            settings.visibility,
            [o.to_trimesh() for o in problem.scene.obstacles],
            [mesh.copy().apply_transform(local) for _, local, mesh in instrument_parts(space.settings.body)],
        )
        return cls(
            settings,
            problem,
            info.cls,
            settings.deformable.settings,
            rest,
            elements,
            triangles,
            np.unique(triangles),
            grasps,
            frames,
            collisions,
            visibility,
        )

    def chain_args(self, grasp: int) -> dict:
        """The arguments every equilibrium task of this grasp shares."""
        return {
            "model_class": self.model_class,
            "model_name": self.settings.deformable.plugin,
            "model_settings": self.model_settings,
            "frame": self.frames[grasp],
            "collision": self.collisions[grasp],
        }

    @property
    def model(self):
        return deformable_model(self.model_class, self.model_settings)
