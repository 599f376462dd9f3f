"""What the report shows, gathered from a run's record: ``result.json``, the files its stages list, the scene.

Everything here reads plugin outputs only as files (never by importing a
plugin): the document that becomes ``result.json``, the stages' listed files
(``.pvd``/``.vtu`` through meshio, ``<stage>-states.npz`` and stored artifacts
as surgiplan bundles, ``<stage>-execution.csv``), and the core's own
:class:`~surgiplan.pipeline.Pipeline` (scene, spaces, starts and goals) when
it is at hand. A file that is missing, unreadable, outside the output
directory or too large is skipped with a note in the report, never an error.

The result is a JSON-ready dict; numeric arrays are packed as little-endian
base64 (``pack``) so a large roadmap or mesh sequence stays compact and
loads fast in the browser.

What each stage contributes is its kind's (:meth:`surgiplan.kinds.StageKind.report`,
with the helpers of ``paths``, ``meshes`` and :mod:`.timeline`); a stage of a
kind that is not installed (a run recorded elsewhere) is drawn as a path, with its
timeline when it has one. The data contract of time series is in :mod:`.timeline`.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ...kinds import ReportInput
from ...registry import default_registry
from ...units import LENGTH_UNITS
from ..merged import drawn_meshes
from .meshes import states_mesh
from .packing import Notes, inside, pack
from .paths import plan_report
from .timeline import motion_report

log = logging.getLogger(__name__)

#: colours of successive stages (as scene.glb's)
PALETTE = ["#1f6fb4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#17becf", "#e377c2", "#7f7f7f"]


def scene_data(scene) -> dict[str, Any]:
    """Bounds, obstacles (as triangle meshes, by name) and named points of a :class:`~surgiplan.scene.Scene`."""
    obstacles = []
    for drawn in drawn_meshes(scene.obstacles):  # one an obstacle, or one merged mesh a group of many
        obstacles.append(
            {
                "name": drawn.name,
                "kind": drawn.kind,
                "count": drawn.count,
                "vertices": pack(np.asarray(drawn.vertices, dtype=float)),
                "faces": pack(np.asarray(drawn.faces, dtype=np.int64), "u4"),
            }
        )
    return {
        "name": getattr(scene, "name", ""),
        "bounds": [np.asarray(scene.bounds_min, float).tolist(), np.asarray(scene.bounds_max, float).tolist()],
        "obstacles": obstacles,
        "points": {k: np.asarray(v, float).tolist() for k, v in scene.points.items()},
    }


# ----------------------------------------------------------------------------- the whole report


def _metrics_rows(metrics: Mapping[str, Any]) -> list[list[Any]]:
    """Metrics as (name, value) rows; long lists and nested tables are summarised."""
    rows = []
    for key, value in metrics.items():
        if isinstance(value, list) and len(value) > 12:
            numbers = [v for v in value if isinstance(v, int | float) and not isinstance(v, bool)]
            if len(numbers) == len(value):
                value = {"count": len(value), "min": min(numbers), "max": max(numbers), "last": numbers[-1]}
            else:
                value = f"{len(value)} entries"
        rows.append([key, value])
    return rows


def report_data(out: Path, document: Mapping[str, Any], pipeline=None) -> dict[str, Any]:
    """Everything the page draws, from the run's ``document`` (result.json) and, when given, its pipeline."""
    out = Path(out)
    notes = Notes()
    unit = str(document.get("length_unit", "m"))
    specs = {s.name: s for s in pipeline.stages} if pipeline is not None else {}
    scene = pipeline.scene if pipeline is not None else None
    data: dict[str, Any] = {
        "run": {
            "name": document.get("name", ""),
            "status": document.get("status", ""),
            "pipeline_file": document.get("pipeline_file", ""),
            "surgiplan_version": document.get("surgiplan_version", ""),
            "length_unit": unit,
            "unit_scale": LENGTH_UNITS.get(unit, 1.0),
            "not_run": list(document.get("not_run", [])),
            "files": list(document.get("files", [])),
        },
        "scene": scene_data(scene) if scene is not None else None,
        "stages": [],
    }
    if scene is None:
        notes.add("the pipeline could not be loaded: obstacles are not shown")
    entries = [e for e in document.get("stages", []) if isinstance(e, Mapping)]
    registry = pipeline.registry if pipeline is not None else default_registry()
    kinds = registry.kinds_of({str(e.get("stage", "")) for e in entries})
    inputs = ReportInput(out, {e.get("name"): e for e in entries}, specs, scene, notes)
    for index, entry in enumerate(entries):
        name = str(entry.get("name", f"stage {index}"))
        kind = str(entry.get("stage", ""))
        metrics = entry.get("metrics") if isinstance(entry.get("metrics"), Mapping) else {}
        threshold = (entry.get("clearance_threshold") or {}).get("value_m", metrics.get("clearance_threshold_m"))
        threshold = float(threshold) if isinstance(threshold, int | float) else None
        stage: dict[str, Any] = {
            "name": name,
            "stage": kind,
            "plugin": entry.get("plugin", ""),
            "status": entry.get("status", ""),
            "message": entry.get("message", ""),
            "warnings": [str(w) for w in entry.get("warnings", []) or []],
            "colour": PALETTE[index % len(PALETTE)],
            "metrics": _metrics_rows(metrics),
            "threshold": threshold,
            "images": [],
        }
        for f in entry.get("files", []) or []:
            if isinstance(f, str) and f.lower().endswith(".png") and inside(out, f, notes, what="figure"):
                stage["images"].append(f)
        try:
            stage_kind = kinds.get(kind)
            if stage_kind is not None:
                stage_kind.report(stage, entry, inputs)
            elif isinstance((entry.get("annotations") or {}).get("timeline"), Mapping):
                motion_report(stage, entry, inputs)
            else:
                plan_report(stage, entry, specs.get(name), scene, notes)
            states = next(
                (f for f in entry.get("files", []) or [] if isinstance(f, str) and f.endswith("-states.npz")), None
            )
            if states is not None:  # a plan through deforming tissue (the retraction planner)
                stage["mesh"] = states_mesh(out, states, notes)
        except Exception as exc:  # one stage's odd output must not cost the others their report
            notes.add(f"stage {name}: {type(exc).__name__}: {exc}; part of it is not shown")
            log.warning("report: stage %s: %s", name, exc, exc_info=log.isEnabledFor(logging.DEBUG))
        data["stages"].append(stage)
    data["notes"] = notes.items
    return data
