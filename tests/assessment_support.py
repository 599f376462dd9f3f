"""Pipelines for the assessment tests: experts' attempts recorded, then a trainee's attempt with an expert ghost."""

from __future__ import annotations

import json
from pathlib import Path

import yaml
from conftest import CONFIGS


def guide_stage(name, level, seed, trainee, **extra):
    return {
        "stage": "guide",
        "name": name,
        "plugin": "synthetic_trainee",
        "path_from": "recommended",
        "settings": {"level": level, "seed": seed, "pace": 0},
        "trainee": trainee,
        **extra,
    }


def pipeline(tmp: Path, name: str, proficiency: str, stages: list[dict]) -> Path:
    data = {
        "name": name,
        "length_unit": "mm",
        "scene": str(CONFIGS / "scenes" / "block_world.yaml"),
        "record": str(tmp / "record.sqlite"),
        "pipeline": [
            {
                "stage": "plan",
                "name": "recommended",
                "plugin": "safe_prm",
                "settings": {"proficiency": proficiency, "milestones": 600, "seed": 1},
                "start": "entry",
                "goal": "target",
            },
            *stages,
        ],
        "output": {"dir": str(tmp / name), "gltf": False},
    }
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def run(path: Path) -> dict:
    """Run the pipeline as `surgiplan run --quiet` does (in this process); its result.json."""
    from surgiplan.cli import main

    assert main(["run", str(path), "--quiet"]) == 0
    return json.loads((Path(yaml.safe_load(path.read_text())["output"]["dir"]) / "result.json").read_text())


def ghost_run(tmp: Path) -> tuple[Path, dict]:
    """Three expert attempts (ann twice, ben once) on the expert's path, the task's benchmark from them, then a
    beginner's attempt (eve) on the beginner's path with ann's best attempt as the ghost; returns the record and
    the beginner run's result.json."""
    experts = [
        guide_stage("ann1", "expert", 1, {"name": "ann", "task": "bw", "level": "expert"}),
        guide_stage("ann2", "expert", 2, {"name": "ann", "task": "bw", "level": "expert"}),
        guide_stage("ben1", "expert", 3, {"name": "ben", "task": "bw", "level": "expert"}),
    ]
    run(pipeline(tmp, "experts", "expert", experts))
    from surgiplan.cli import main

    assert main(["benchmark-task", "bw", "--record", str(tmp / "record.sqlite"), "--metrics", "score,duration_s"]) == 0
    stage = guide_stage(
        "attempt", "beginner", 7, {"name": "eve", "task": "bw", "level": "beginner"}, ghost={"trainee": "ann"}
    )
    return tmp / "record.sqlite", run(pipeline(tmp, "beginner", "beginner", [stage]))
