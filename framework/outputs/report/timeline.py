"""What the report draws of a motion over time (execute and guide stages).

Data contract: ``annotations["timeline"] = {"t": [...], "tip": [[x, y, z], ...], "commanded"?: [[...]],
"clearance"?: [...], "deviation"?: [...], "events"?: [{"t", "kind", "message"}]}`` (SI). Without a timeline an
execute stage falls back to ``<stage>-execution.csv`` (columns ``t_s``, ``tip_x_m``, ``tip_y_m``,
``tip_z_m``, ...) and then to its executed path.

Zones a device keeps the motion in or out of (a vehicle's geofence): ``annotations["zones"] = [{"name",
"inclusion": bool, "outline": [[x, y], ...], "z": [bottom, top]}]`` (m, scene frame), drawn as prisms.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .packing import MAX_TIMELINE_SAMPLES, Notes, as_array, inside, keep_indices, log, pack
from .paths import path_data, tips_of


def _event(item: Mapping[str, Any], default_kind: str = "event") -> dict[str, Any] | None:
    if not isinstance(item, Mapping):
        return None
    t = next((item[k] for k in ("t", "t_s", "time_s", "vehicle_time_s", "time") if k in item), None)
    try:
        t = float(t) if t is not None else None
    except (TypeError, ValueError):
        t = None
    message = next((str(item[k]) for k in ("message", "detail", "action", "cause") if k in item), "")
    extra = ", ".join(f"{k} {item[k]}" for k in ("node", "joint", "mode") if k in item)
    return {"t": t, "kind": str(item.get("kind", default_kind)), "message": ", ".join(p for p in (extra, message) if p)}


def timeline_data(out: Path, entry: Mapping[str, Any], notes: Notes, scene=None) -> dict[str, Any] | None:
    """The stage's motion over time: its ``timeline`` annotation, else its execution CSV, else its path.

    Without a recorded clearance, the tip's clearance is measured on ``scene`` (when given)."""
    annotations = entry.get("annotations") or {}
    timeline = annotations.get("timeline") if isinstance(annotations, Mapping) else None
    source = None
    t = tip = None
    series: dict[str, np.ndarray] = {}
    events: list[dict[str, Any]] = []
    if isinstance(timeline, Mapping):
        t = as_array(timeline.get("t"))
        tip = as_array(timeline.get("tip"), 3)
        if t is not None and tip is not None and t.ndim == 1 and len(t) == len(tip) and len(t):
            source = "timeline"
            for key in ("commanded",):
                value = as_array(timeline.get(key), 3)
                if value is not None and len(value) == len(t):
                    series[key] = value
            for key in ("clearance", "deviation"):
                value = as_array(timeline.get(key))
                if value is not None and value.ndim == 1 and len(value) == len(t):
                    series[key] = value
            events += [e for e in map(_event, timeline.get("events") or []) if e]
        else:
            notes.add(f"stage {entry.get('name')}: its timeline annotation is malformed (t and tip); not used")
            t = tip = None
    if source is None:
        csv = next((f for f in entry.get("files", []) if isinstance(f, str) and f.endswith("-execution.csv")), None)
        path = inside(out, csv, notes) if csv else None
        if path is not None:
            try:
                table = np.genfromtxt(path, delimiter=",", names=True)
                t = np.asarray(table["t_s"], dtype=float).ravel()
                tip = np.column_stack([np.asarray(table[f"tip_{a}_m"], dtype=float).ravel() for a in "xyz"])
                source = csv
            except Exception as exc:
                notes.add(f"{csv}: no t_s and tip_x_m/tip_y_m/tip_z_m columns ({exc}); not used")
                t = tip = None
    if source is None:
        path = as_array(entry.get("tip_path") or entry.get("path"), 3)
        if path is None or not len(path):
            return None
        source = "path"
        tip = path
        t = np.arange(len(path), dtype=float)
    metrics = entry.get("metrics") or {}
    faults = metrics.get("faults") if isinstance(metrics, Mapping) else None
    if isinstance(faults, list):
        events += [e for e in (_event(f, "fault") for f in faults) if e]
    ok = np.isfinite(t) & np.all(np.isfinite(tip), axis=1)
    t, tip = t[ok], tip[ok]
    series = {k: v[ok] for k, v in series.items()}
    if not len(t):
        return None
    keep = keep_indices(len(t), None, MAX_TIMELINE_SAMPLES)
    if "clearance" not in series and scene is not None:
        try:  # the tip point's own clearance, measured on the scene
            series["clearance"] = np.full(len(t), np.nan)
            series["clearance"][keep] = np.asarray(scene.clearance(tip[keep]), dtype=float)
        except Exception as exc:
            series.pop("clearance", None)
            log.info("report: clearance of stage %s not measured: %s", entry.get("name"), exc)
    data: dict[str, Any] = {
        "source": source,
        "time_unit": "sample" if source == "path" else "s",
        "t": pack(t[keep]),
        "tip": pack(tip[keep]),
        "samples": len(t),
        "events": sorted(events, key=lambda e: (e["t"] is None, e["t"] or 0.0)),
    }
    for key, value in series.items():
        data[key] = pack(value[keep])
    return data


def zones_data(annotations: Mapping[str, Any], notes: Notes, name: str) -> list[dict[str, Any]]:
    """The ``zones`` annotation, checked (a malformed zone is skipped with a note)."""
    zones = annotations.get("zones") if isinstance(annotations, Mapping) else None
    out = []
    for k, zone in enumerate(zones if isinstance(zones, list) else []):
        outline = as_array(zone.get("outline"), 2) if isinstance(zone, Mapping) else None
        z = as_array(zone.get("z")) if isinstance(zone, Mapping) else None
        if outline is None or len(outline) < 3 or z is None or z.shape != (2,) or not np.all(np.isfinite(z)):
            notes.add(f"stage {name}: zone {k} of its zones annotation is malformed (outline, z); not drawn")
            continue
        out.append(
            {
                "name": str(zone.get("name", "")),
                "inclusion": bool(zone.get("inclusion", False)),
                "outline": pack(outline),
                "z": [float(z[0]), float(z[1])],
            }
        )
    return out


def motion_report(stage: dict[str, Any], entry: Mapping[str, Any], inputs) -> None:
    """A motion over time (execute and guide stages): the timeline, the path followed, and the reference it is
    drawn against: the recommended path a guide stage recorded, else its ``path_from`` stage's path."""
    stage["timeline"] = timeline_data(inputs.out, entry, inputs.notes, inputs.scene)
    stage["path"] = path_data(entry, None, inputs.scene, None)
    spec = inputs.specs.get(stage["name"])
    annotations = entry.get("annotations") or {}
    stage["zones"] = zones_data(annotations, inputs.notes, stage["name"])
    source = getattr(spec, "path_from", None) or entry.get("path_from") or annotations.get("path_from")
    reference = inputs.entries.get(source) if isinstance(source, str) else None
    recommended = as_array(annotations.get("recommended_tips"), 3)
    if recommended is not None and len(recommended) >= 2:  # a guide stage records what it recommended
        stage["reference"] = {"name": str(source or "recommended"), "tips": pack(recommended)}
    elif reference is not None:
        tips = tips_of(reference, inputs.specs.get(source))
        if tips is not None:
            stage["reference"] = {"name": source, "tips": pack(tips)}
