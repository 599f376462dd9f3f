"""retraction: optimal tissue-retraction plans and grasp selection on FEM states (paper 002).

Patil & Alterovitz, "Toward automated tissue retraction in robot-assisted
surgery": a gripper grasps a tissue flap and lifts it until an area of
interest A beneath it is visible from a camera V, avoiding obstacles and
minimising the maximum deformation energy, the maximum stress, or the
control effort. The planner

* **build** (offline): for the stage's start grasp and every candidate grasp
  (Objective 2), samples gripper configurations, solves their static
  equilibria (executor-parallel, checkpointed, resumable), relaxes each
  sample's rotation (Fig. 3), discards invalid states, measures what each
  state exposes of A, and joins the states by DISP into a roadmap;
* **query** (online): per grasp, a lazy search (Bohlin & Kavraki) for the
  optimal path from the grasp to a state exposing A, validating only the
  edges of candidate best paths by FEM along them; picks the best grasp;
  turns the path into a C¹ trajectory (cubic splines in position and
  rotation), re-simulates it densely and checks every state; writes the
  states along it and figures like the paper's Figs. 5-7.

The stage's ``goal`` is optional: when given, it is the surgeon's estimate
of the final gripper position, the end of the guide line of user-guided
sampling (Fig. 4).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from surgiplan.planning import Planner, PlanningProblem, PlanResult, PlanStatus
from surgiplan.resources import ResourceEstimate

from .generation import GraspRoadmap, generate
from .lazy import LazyPlanner
from .outputs import write_outputs
from .settings import RetractionSettings
from .setup import Setup


@dataclass
class RetractionArtifact:
    setup: Setup
    roadmaps: list[GraspRoadmap]
    build_s: float = 0.0
    notes: dict[str, Any] = field(default_factory=dict)


class RetractionPlanner(Planner):
    """The retraction planner of paper 002 (see the module docstring)."""

    Settings = RetractionSettings
    requires_goal = False
    artifact_version = 1
    #: it plans grasps through deforming tissue, not a clearance from obstacles (a stage threshold is refused)
    clearance_policy = None

    @classmethod
    def estimate_resources(cls, settings, problem):
        """The deformable model's own estimate, and the samples' states held per grasp (positions and
        stresses of every sample, and the roadmap's k neighbours each)."""
        from surgiplan.registry import default_registry

        info = default_registry().get("deformable_model", settings.deformable.plugin)
        model_settings = info.settings_model.model_validate(settings.deformable.settings)
        estimates = list(info.cls.estimate_resources(model_settings))
        box = getattr(getattr(model_settings, "mesh", None), "box", None)
        if box is not None:
            nx, ny, nz = box.divisions
            order = model_settings.mesh.order
            nodes = (order * nx + 1) * (order * ny + 1) * (order * nz + 1)
            tets = nx * ny * nz * (5 if box.pattern == "five" else 6)
            grasps = 1 + sum(e.count for e in settings.grasps.edges) + len(settings.grasps.poses)
            samples = settings.sampling.samples
            per_state = nodes * 24 + tets * 8 + settings.roadmap.k * 16
            estimates.append(
                ResourceEstimate(
                    grasps * samples * per_state * 2,
                    f"{samples:,} samples for each of {grasps} grasps ({nodes:,} nodes a state)",
                    "sampling",
                )
            )
        return estimates

    # ------------------------------------------------------------------ build
    def build(self, problem: PlanningProblem) -> RetractionArtifact:
        started = time.perf_counter()
        setup = Setup.create(self.settings, problem)
        roadmaps = generate(setup)
        return RetractionArtifact(setup, roadmaps, time.perf_counter() - started)

    def save_artifact(self, artifact: RetractionArtifact) -> dict[str, Any]:
        data: dict[str, Any] = {
            "grasps": artifact.setup.grasps,
            "start": np.asarray(artifact.setup.problem.start, float),
            "goal": [] if artifact.setup.problem.goal is None else np.asarray(artifact.setup.problem.goal).tolist(),
            "build_s": artifact.build_s,
        }
        for k, roadmap in enumerate(artifact.roadmaps):
            for name, value in roadmap.arrays().items():
                data[f"g{k}_{name}"] = np.asarray(value)
            data[f"g{k}_reason"] = list(roadmap.reason)
            data[f"g{k}_timing"] = dict(roadmap.timing)
        return data

    def load_artifact(self, data, problem: PlanningProblem) -> RetractionArtifact | None:
        goal = np.asarray(problem.goal, float).tolist() if problem.goal is not None else []
        if not np.allclose(np.asarray(data["start"], float), np.asarray(problem.start, float), atol=1e-12) or not (
            len(goal) == len(data["goal"]) and np.allclose(goal, data["goal"], atol=1e-12)
        ):
            return None  # built for another grasp or guide line: rebuild
        setup = Setup.create(self.settings, problem)
        roadmaps = []
        for k in range(len(setup.grasps)):
            relief = {
                name: np.asarray(data[f"g{k}_relief_{name}"])
                for name in ("iterations", "angle", "grasp_stress_before", "grasp_stress_after")
            }
            roadmaps.append(
                GraspRoadmap(
                    grasp=np.asarray(data[f"g{k}_grasp"], float),
                    q=np.asarray(data[f"g{k}_q"], float),
                    positions=np.asarray(data[f"g{k}_positions"], np.float32),
                    energy=np.asarray(data[f"g{k}_energy"], float),
                    max_stress=np.asarray(data[f"g{k}_max_stress"], float),
                    ok=np.asarray(data[f"g{k}_ok"], bool),
                    reason=list(data[f"g{k}_reason"]),
                    visible=np.asarray(data[f"g{k}_visible"], float),
                    edges=np.asarray(data[f"g{k}_edges"], np.int64).reshape(-1, 2),
                    disp=np.asarray(data[f"g{k}_disp"], float),
                    length=np.asarray(data[f"g{k}_length"], float),
                    relief=relief,
                    timing=dict(data[f"g{k}_timing"]),
                )
            )
        if not np.allclose(np.array([r.grasp for r in roadmaps]), setup.grasps):
            return None
        return RetractionArtifact(setup, roadmaps, float(data["build_s"]), {"loaded": True})

    # ------------------------------------------------------------------ query
    def query(self, artifact: RetractionArtifact, start, goal) -> PlanResult:
        setup = artifact.setup
        started = time.perf_counter()
        planner = LazyPlanner(setup, artifact.roadmaps)
        outcome = planner.plan()
        metrics = planner.metrics(outcome)
        metrics["planning_s"] = time.perf_counter() - started
        metrics.update(_build_metrics(artifact))
        if outcome.trajectory is None:
            return PlanResult(
                PlanStatus.NO_PATH, np.empty((0, 7)), metrics, outcome.message, annotations=outcome.annotations()
            )
        files = []
        if setup.problem.output_dir is not None:
            files = write_outputs(setup, artifact.roadmaps, outcome, metrics)
        path = outcome.trajectory.q
        if len(path) == 1:  # the grasp already exposes the area: a motion of length zero, from q0 to q0
            path = np.repeat(path, 2, axis=0)
        result = PlanResult(
            PlanStatus.SOLVED,
            path,
            metrics,
            outcome.message,
            annotations=outcome.annotations(),
            files=files,
        )
        return result


def _build_metrics(artifact: RetractionArtifact) -> dict[str, Any]:
    """Sample-generation figures of the build (Table I's left half), summed over grasps."""
    roadmaps = artifact.roadmaps
    timing: dict[str, float] = {}
    for r in roadmaps:
        for k, v in r.timing.items():
            timing[k] = timing.get(k, 0.0) + float(v)
    samples = sum(r.samples for r in roadmaps)
    valid = sum(int(r.ok[1:].sum()) for r in roadmaps)
    iterations = np.concatenate([r.relief["iterations"] for r in roadmaps])
    before = np.concatenate([r.relief["grasp_stress_before"] for r in roadmaps])
    after = np.concatenate([r.relief["grasp_stress_after"] for r in roadmaps])
    relieved = np.isfinite(before) & np.isfinite(after) & (before > 0)
    reasons: dict[str, int] = {}
    for r in roadmaps:
        for reason in r.reason[1:]:
            if reason:
                kind = reason.split(":")[0].split(" (")[0]
                reasons[kind] = reasons.get(kind, 0) + 1
    return {
        "samples": samples,
        "valid_samples": valid,
        "invalid_samples_by_reason": reasons,
        "roadmap_edges": int(sum(len(r.edges) for r in roadmaps)),
        "sample_generation_s": float(timing.get("sampling_s", 0) + timing.get("equilibria_s", 0)),
        "sample_assessment_s": float(timing.get("assess_s", 0)),
        "roadmap_s": float(timing.get("roadmap_s", 0)),
        "sample_fem_cpu_s": float(timing.get("fem_s", 0)),
        "sample_validation_cpu_s": float(timing.get("validation_s", 0)),
        "sample_collision_cpu_s": float(timing.get("collision_s", 0)),
        "sample_visibility_cpu_s": float(timing.get("visibility_s", 0)),
        "relief_mean_iterations": float(iterations.mean()) if len(iterations) else 0.0,
        "relief_median_grasp_stress_ratio": float(np.median(after[relieved] / before[relieved]))
        if relieved.any()
        else None,
        "artifact_build_s": artifact.build_s,
    }
