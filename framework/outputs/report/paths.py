"""What the report draws of a path: its tip points, clearance, the stretches below the threshold, critical
regions, and the roadmap or path set of a stored artifact."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ...storage import load_bundle
from .packing import MAX_PATH_POINTS, Notes, finite_rows, itertools_pairs, keep_indices, log, pack


def tips_of(entry: Mapping[str, Any], spec) -> np.ndarray | None:
    """The stage's tip path (n, 3) in metres, or None."""
    tip_path = entry.get("tip_path")
    if tip_path:
        tips = np.asarray(tip_path, dtype=float)
    else:
        path = np.asarray(entry.get("path") or [], dtype=float)
        if path.ndim != 2 or len(path) == 0:
            return None
        space = getattr(spec, "space", None)
        if path.shape[1] == 3 and entry.get("space") in (None, "r3"):
            tips = path
        elif space is not None and path.shape[1] == space.dimension:
            try:
                tips = np.asarray(space.tip(path), dtype=float)
            except Exception as exc:  # a space that cannot map its own path: show nothing rather than fail
                log.info("report: no tip path for stage %s: %s", entry.get("name"), exc)
                return None
        else:
            return None
    if tips.ndim != 2 or tips.shape[1] != 3 or len(tips) == 0:
        return None
    tips = finite_rows(tips)
    return tips if len(tips) else None


def path_data(entry: Mapping[str, Any], spec, scene, threshold: float | None) -> dict[str, Any] | None:
    """The stage's path as drawn: tip points, clearance at each, which segments are below the threshold."""
    tips = tips_of(entry, spec)
    if tips is None:
        return None
    space = getattr(spec, "space", None)
    path = np.asarray(entry.get("path") or [], dtype=float)
    clearance = None
    dense_tips = tips
    if space is not None and path.ndim == 2 and len(path) >= 2 and path.shape[1] == space.dimension:
        try:  # as the runner measures it: the space's clearance (whole body), densified at extent / 1000
            resolution = float(np.min(space.scene.extent)) / 1000.0
            dense = space.densify(path, resolution)
            dense_tips = np.asarray(space.tip(dense), dtype=float)
            clearance = np.asarray(space.clearance(dense), dtype=float)
        except Exception as exc:
            log.info("report: clearance of stage %s not measured: %s", entry.get("name"), exc)
            dense_tips, clearance = tips, None
    if clearance is None and scene is not None:
        try:
            clearance = np.asarray(scene.clearance(dense_tips), dtype=float)
        except Exception as exc:
            log.info("report: clearance of stage %s not measured: %s", entry.get("name"), exc)
    low = None
    if clearance is not None and threshold is not None and len(dense_tips) >= 2:
        low = np.minimum(clearance[:-1], clearance[1:]) < threshold
    keep = keep_indices(len(dense_tips), low, MAX_PATH_POINTS)
    out: dict[str, Any] = {"tips": pack(dense_tips[keep])}
    if clearance is not None:
        # each kept point: the least clearance over the dense samples it stands for
        bounds = np.append(keep, len(dense_tips))
        out["clearance"] = pack([float(np.min(clearance[a : max(b, a + 1)])) for a, b in itertools_pairs(bounds)])
    if low is not None:
        segment_low = [bool(np.any(low[a:b])) for a, b in itertools_pairs(keep)]
        out["low"] = pack(np.asarray(segment_low, dtype=np.uint32), "u4")
        out["low_count"] = int(sum(segment_low))
    return out


def artifact_data(path: Path, spec, notes: Notes) -> dict[str, Any] | None:
    """A stored artifact drawn as a roadmap (``milestones`` + ``edges``) or a set of paths
    (``points`` + ``path_start``), whichever it holds; None when it holds neither."""
    try:
        arrays, _ = load_bundle(path)
    except ValueError as exc:
        notes.add(f"artifact {path.name} is not readable ({exc}); its roadmap is not shown")
        return None
    if "points" in arrays and "path_start" in arrays:
        points = np.asarray(arrays["points"], dtype=float)
        starts = np.asarray(arrays["path_start"], dtype=np.int64).ravel()
        if points.ndim != 2 or points.shape[1] != 3 or not len(starts):
            return None
        if starts[-1] != len(points):
            starts = np.append(starts, len(points))
        if np.any(np.diff(starts) < 0) or starts[0] != 0 or starts[-1] != len(points):
            notes.add(f"artifact {path.name}: path offsets do not match its points; not shown")
            return None
        return {
            "kind": "paths",
            "file": path.name,
            "points": pack(points),
            "starts": pack(starts, "u4"),
            "count": len(starts) - 1,
        }
    if "milestones" in arrays and "edges" in arrays:
        nodes = np.asarray(arrays["milestones"], dtype=float)
        edges = np.asarray(arrays["edges"], dtype=np.int64).reshape(-1, 2)
        space = getattr(spec, "space", None)
        if nodes.ndim == 2 and nodes.shape[1] != 3:
            if space is None or nodes.shape[1] != space.dimension:
                return None
            nodes = np.asarray(space.tip(nodes), dtype=float)
        if nodes.ndim != 2 or nodes.shape[1] != 3:
            return None
        if len(edges) and (edges.min() < 0 or edges.max() >= len(nodes)):
            notes.add(f"artifact {path.name}: edge indices out of range; not shown")
            return None
        out = {
            "kind": "roadmap",
            "file": path.name,
            "nodes": pack(nodes),
            "edges": pack(edges, "u4"),
            "count": len(nodes),
            "edge_count": len(edges),
        }
        safe = arrays.get("edge_safe")
        if safe is not None and len(safe) == len(edges):
            out["edge_safe"] = pack(np.asarray(safe, dtype=bool).astype(np.uint32), "u4")
        return out
    return None


def critical_data(regions) -> list[dict[str, Any]]:
    """Critical regions as the page draws them (arc-length intervals, least clearance, obstacles)."""
    return [
        {"start": r.start_m, "end": r.end_m, "min_clearance": r.min_clearance_m, "obstacles": list(r.obstacles)}
        for r in regions
    ]


def plan_report(stage: dict[str, Any], entry: Mapping[str, Any], spec, scene, notes: Notes) -> None:
    """A planned path: its tips, clearance and stretches below the threshold, critical regions, start and goal
    (the stage's own, when its spec is at hand), and the roadmap or path set of its stored artifact."""
    from ...clearance import regions_from_json

    stage["path"] = path_data(entry, spec, scene, stage.get("threshold"))
    stage["critical"] = critical_data(regions_from_json((entry.get("annotations") or {}).get("critical_regions")))
    if spec is not None and getattr(spec, "space", None) is not None:
        for key in ("start", "goal"):
            q = getattr(spec, key, None)
            if q is not None:
                stage[key] = np.asarray(spec.space.tip(np.asarray(q, float)[None])[0], float).tolist()
    elif stage["path"] is not None:
        tips = tips_of(entry, spec)
        stage["start"], stage["goal"] = tips[0].tolist(), tips[-1].tolist()
    artifact = getattr(spec, "artifact", None)
    if artifact is not None and Path(artifact).is_file():
        stage["roadmap"] = artifact_data(Path(artifact), spec, notes)
