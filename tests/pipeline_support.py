"""Pipelines several tests (and the crash walk) build: one builder each, so a change of a plugin's settings is
made in one place.

- :func:`safe_prm_stage`: a safe PRM ``plan`` stage to ``target`` of block_world;
- :func:`recommended_stage`: the recommended path (that stage, ``recommended``, from ``entry``);
- :func:`guide_stages`: that and a synthetic trainee's attempt at it;
- :func:`block_world_pipeline`: stages in a pipeline document on block_world, written as a file;
- :func:`point_robot_pipeline`: a safe PRM plan (4 mm threshold, red stretches where no detour exists) and the
  ``point_robot`` executing it, on block_world;
- :func:`retraction_pipeline`: the retraction planner (paper 002) on a flap anchored along x = 0 with a bar
  above it, as a whole pipeline document."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

BLOCK_WORLD = Path(__file__).resolve().parent.parent / "configs" / "scenes" / "block_world.yaml"


def safe_prm_stage(
    name: str,
    milestones: int,
    proficiency: str | None = "beginner",
    *,
    seed: int = 1,
    start: str | list[float] = "entry",
    k: int | None = None,
    artifact: Path | None = None,
    **keys: Any,
) -> dict[str, Any]:
    """A ``plan`` stage ``name``: safe PRM with ``milestones`` (``proficiency``: the planner's default when
    None; ``k`` when given) from ``start`` to ``target``, stored as ``artifact`` when given; ``keys``: more of
    the stage's keys (``space``, ``clearance_threshold``)."""
    settings = {
        **({"proficiency": proficiency} if proficiency else {}),
        "milestones": milestones,
        **({"k": k} if k else {}),
        "seed": seed,
    }
    return {
        "stage": "plan",
        "name": name,
        "plugin": "safe_prm",
        "settings": settings,
        "start": start,
        "goal": "target",
        **({"artifact": str(artifact)} if artifact else {}),
        **keys,
    }


def recommended_stage(
    proficiency: str = "beginner", milestones: int = 300, k: int | None = None, artifact: Path | None = None
) -> dict[str, Any]:
    """A ``plan`` stage ``recommended``: safe PRM (seed 1) from ``entry`` to ``target``, stored as ``artifact``
    when given."""
    return safe_prm_stage("recommended", milestones, proficiency, k=k, artifact=artifact)


def block_world_pipeline(path: Path, name: str, stages: list[dict[str, Any]], out: Path, **extra) -> Path:
    """Write the pipeline ``name`` of ``stages`` on block_world (mm) to ``path``, output in ``out`` without
    figures or glTF; ``extra``: more top-level keys (``record``), or ``output`` in place of that one. Returns
    ``path``."""
    data = {
        "name": name,
        "length_unit": "mm",
        "scene": str(BLOCK_WORLD),
        "pipeline": stages,
        "output": {"dir": str(out), "figures": False, "gltf": False},
    }
    data.update(extra)
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def point_robot_pipeline(path: Path, name: str, out: Path, robot: dict[str, Any], **extra) -> Path:
    """Write :func:`block_world_pipeline` ``name``: a safe PRM ``plan`` (800 milestones, seed 2, a 0.5 mm tip,
    the 4 mm threshold kept except where no detour exists, so the path has red stretches) and an ``execute``
    stage ``robot`` (the ``point_robot`` device with settings ``robot``) following it. Returns ``path``."""
    plan = safe_prm_stage("plan", 800, None, seed=2, space={"kind": "r3", "tip_radius": 0.5}, clearance_threshold=4)
    execute = {"stage": "execute", "name": "robot", "plugin": "point_robot", "path_from": "plan", "settings": robot}
    return block_world_pipeline(path, name, [plan, execute], out, **extra)


def guide_stages(seed: int, trainee: str | None = None, milestones: int = 300) -> list[dict[str, Any]]:
    """:func:`recommended_stage` (beginner) and a ``guide`` stage (``attempt``: a beginner synthetic trainee
    following it, ``seed``, no pacing) for ``trainee`` when given."""
    return [
        recommended_stage("beginner", milestones),
        {
            "stage": "guide",
            "name": "attempt",
            "plugin": "synthetic_trainee",
            "path_from": "recommended",
            "settings": {"level": "beginner", "seed": seed, "pace": 0},
            **({"trainee": {"name": trainee, "task": "block-world"}} if trainee else {}),
        },
    ]


def retraction_flap(divisions: tuple[int, int, int]) -> dict[str, Any]:
    """The ``stvk`` settings of a 50 x 50 x 2.5 mm flap of ``divisions`` cells on a base plane."""
    return {
        "mesh": {"box": {"size": [50, 50, 2.5], "divisions": list(divisions), "pattern": "five"}},
        "material": {"youngs_modulus": 1.0e6, "poisson_ratio": 0.45, "density": 1000},
        "base_plane": {},
    }


def retraction_pipeline(
    name: str,
    divisions: tuple[int, int, int],
    samples: int,
    chunk: int,
    grasps: dict[str, Any] | None = None,
    artifact: str | None = None,
) -> dict[str, Any]:
    """A pipeline document of one retraction stage (``page``): the flap (:func:`retraction_flap`) anchored along
    x = 0, grasped on its free edge (``grasps``: the planner's default when None), a bar above it, the area of
    interest beneath the free edge; ``samples`` uniform samples per grasp in chunks of ``chunk``."""
    stage = {
        "stage": "plan",
        "name": "page",
        "plugin": "retraction",
        "space": {
            "kind": "se3",
            "body": [
                {"name": "jaws", "box": {"size": [7, 7, 4]}},
                {"name": "shaft", "capsule": {"a": [0, 0, 2], "b": [0, 0, 30], "radius": 1.5}},
            ],
            "rotation_weight": 20,
        },
        "start": {"xyz": [50, 25, 1.25]},
        "settings": {
            "deformable": {"plugin": "stvk", "settings": retraction_flap(divisions)},
            "anchored": [{"min": [0, 0, 0], "max": [0, 50, 2.5]}],
            "jaws": {"size": [7, 7, 4]},
            "grasps": grasps or {},
            "sampling": {
                "kind": "uniform",
                "samples": samples,
                "region": {"min": [28, 12, 3], "max": [52, 38, 32]},
                "max_rotation": "30 deg",
                "chunk": chunk,
            },
            "relief": {"max_iterations": 1},
            "visibility": {
                "camera": [40, 25, 150],
                "area": [[38, 20], [46, 20], [46, 30], [38, 30]],
                "resolution": 2,
            },
            "roadmap": {"k": 8, "step": 4},
            "smoothing": {"step": 4},
            "metric": "max_energy",
        },
        **({"artifact": artifact} if artifact else {}),
    }
    return {
        "name": name,
        "length_unit": "mm",
        "scene": {
            "bounds": {"min": [-10, -10, -5], "max": [80, 60, 60]},
            "obstacles": [{"name": "bar", "box": {"min": [8, -5, 20], "max": [18, 55, 24]}}],
        },
        "pipeline": [stage],
        "executor": {"kind": "local", "workers": 1},
    }
