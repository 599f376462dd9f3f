"""The CAST gimbal as a guide stage's source, for tests/test_guide_observe.py (observe mode) and
tests/test_guide_assist.py (assist mode): one pipeline builder, one way of opening the source as the guide
stage opens it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pipeline_support import block_world_pipeline, safe_prm_stage
from surgiplan.guidance import Guide, GuideContext
from surgiplan.results import StageContext

#: the gimbal's fulcrum, as configs/gimbal_in_the_loop.yaml places it
FULCRUM = {"xyz": [150, 50, 130], "rpy": [0, "90 deg", 0]}


def gimbal_guide_pipeline(
    tmp_path: Path, name: str, guide_settings: dict[str, Any], trainee=None, artifact: Path | None = None
) -> Path:
    """Write ``<name>.yaml`` in ``tmp_path``: a safe PRM plan for the gimbal (1000 milestones, from [60, 50, 20]
    to ``target`` in block_world; stored as ``artifact`` when given), then a ``cast_gimbal`` guide stage with
    ``guide_settings`` (for ``trainee`` when given) into ``tmp_path/record.sqlite``; returns the file."""
    space = {"kind": "cast_gimbal", "fulcrum": FULCRUM}
    plan = safe_prm_stage("recommended", 1000, start=[60, 50, 20], artifact=artifact, space=space)
    guide = {
        "stage": "guide",
        "name": "attempt",
        "plugin": "cast_gimbal",
        "path_from": "recommended",
        "settings": guide_settings,
        **({"trainee": trainee} if trainee else {}),
    }
    record = str(tmp_path / "record.sqlite")
    return block_world_pipeline(tmp_path / f"{name}.yaml", name, [plan, guide], tmp_path / "out", record=record)


def open_source(tmp: Path, plan, space, spec, threshold, critical=()):
    """The guide stage ``spec``'s source, opened as the stage opens it (its Guide along ``plan``'s path, output
    in ``tmp/out``); returns it (the caller closes it)."""
    guide = Guide(space, plan.path, space.scene, threshold, list(critical), spec.guidance)
    context = StageContext("attempt", space.scene, tmp / "out", tmp)
    (tmp / "out").mkdir(exist_ok=True)
    source = spec.plugin.cls(spec.settings)
    source.open(GuideContext(context, plan.path, guide.tips, space, space.scene, guide.threshold, list(critical)))
    return source
