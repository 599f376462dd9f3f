"""What the report shows, gathered from a run's record: ``result.json``, the files its stages list, the scene.

Everything here reads plugin outputs only as files (never by importing a
plugin): the document that becomes ``result.json``, the stages' listed files
(``.pvd``/``.vtu`` through meshio, ``<stage>-states.npz`` and stored artifacts
as surgiplan bundles, ``<stage>-execution.csv``), and the core's own
:class:`~surgiplan.pipeline.Pipeline` (scene, spaces, starts and goals) when
it is at hand. A file that is missing, unreadable, outside the output
directory or too large is skipped with a note in the report, never an error.

The result is a JSON-ready dict; numeric arrays are packed as little-endian
base64 (:func:`pack`) so a large roadmap or mesh sequence stays compact and
loads fast in the browser.

Data contract for time series (execute and guide stages): ``annotations["timeline"]
= {"t": [...], "tip": [[x, y, z], ...], "commanded"?: [[...]], "clearance"?: [...],
"deviation"?: [...], "events"?: [{"t", "kind", "message"}]}``; a guide stage's
recommended path is the path of its ``path_from`` stage. Without a timeline an
execute stage falls back to ``<stage>-execution.csv`` (columns ``t_s``,
``tip_x_m``, ``tip_y_m``, ``tip_z_m``, ...) and then to its executed path.
"""

from __future__ import annotations

import base64
import itertools
import logging
import math
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ...storage import load_bundle
from ...units import LENGTH_UNITS

log = logging.getLogger(__name__)

#: colours of successive stages (as scene.glb's)
PALETTE = ["#1f6fb4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#17becf", "#e377c2", "#7f7f7f"]

#: at most this many points are drawn per path, samples per timeline, frames per mesh sequence
MAX_PATH_POINTS = 4000
MAX_TIMELINE_SAMPLES = 6000
MAX_FRAMES = 120
#: files larger than this are not read into the report
MAX_FILE_BYTES = 512 * 1024 * 1024

TIME_KINDS = ("execute", "guide")


def pack(array, dtype: str = "f4") -> dict[str, Any]:
    """A numeric array as ``{"dtype", "shape", "b64"}`` (little-endian), for the page's ``decode``."""
    a = np.ascontiguousarray(np.asarray(array), dtype=np.dtype(dtype).newbyteorder("<"))
    return {"dtype": {"f4": "f32", "u4": "u32"}[dtype], "shape": list(a.shape), "b64": base64.b64encode(a).decode()}


def _finite_rows(a: np.ndarray) -> np.ndarray:
    return a[np.all(np.isfinite(a), axis=1)] if a.ndim == 2 else a


class Notes:
    """What could not be shown, and why (listed in the report)."""

    def __init__(self) -> None:
        self.items: list[str] = []

    def add(self, text: str) -> None:
        log.info("report: %s", text)
        self.items.append(text)


def inside(out: Path, relative: str, notes: Notes, *, what: str = "file") -> Path | None:
    """``out / relative`` if it is a regular file inside ``out`` and not too large, else None (noted)."""
    if not isinstance(relative, str) or not relative:
        return None
    try:
        root = out.resolve()
        path = (out / relative).resolve()
        path.relative_to(root)
    except (ValueError, OSError):
        notes.add(f"{what} {relative!r} is outside the output directory; not shown")
        return None
    if not path.is_file():
        notes.add(f"{what} {relative!r} is missing; not shown")
        return None
    if path.stat().st_size > MAX_FILE_BYTES:
        notes.add(f"{what} {relative!r} is larger than {MAX_FILE_BYTES // 2**20} MiB; not shown")
        return None
    return path


# ----------------------------------------------------------------------------- scene


def scene_data(scene) -> dict[str, Any]:
    """Bounds, obstacles (as triangle meshes, by name) and named points of a :class:`~surgiplan.scene.Scene`."""
    obstacles = []
    for obstacle in scene.obstacles:
        mesh = obstacle.to_trimesh()
        obstacles.append(
            {
                "name": obstacle.name,
                "kind": type(obstacle).__name__.lower(),
                "vertices": pack(np.asarray(mesh.vertices, dtype=float)),
                "faces": pack(np.asarray(mesh.faces, dtype=np.int64), "u4"),
            }
        )
    return {
        "name": getattr(scene, "name", ""),
        "bounds": [np.asarray(scene.bounds_min, float).tolist(), np.asarray(scene.bounds_max, float).tolist()],
        "obstacles": obstacles,
        "points": {k: np.asarray(v, float).tolist() for k, v in scene.points.items()},
    }


# ----------------------------------------------------------------------------- paths


def _tips_of(entry: Mapping[str, Any], spec) -> np.ndarray | None:
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
    tips = _finite_rows(tips)
    return tips if len(tips) else None


def _keep_indices(n: int, flags: np.ndarray | None, limit: int) -> np.ndarray:
    """Indices of at most about ``limit`` samples: a stride, plus both ends of every change of ``flags``."""
    stride = max(1, math.ceil(n / limit))
    keep = set(range(0, n, stride))
    keep.add(n - 1)
    if flags is not None and len(flags):
        changes = np.flatnonzero(np.diff(flags.astype(np.int8))) if len(flags) > 1 else []
        for i in changes:  # segment i differs from segment i+1: keep point i+1 (their joint) and its neighbours
            keep.update((int(i), int(i) + 1, min(int(i) + 2, n - 1)))
    return np.array(sorted(keep), dtype=np.int64)


def path_data(entry: Mapping[str, Any], spec, scene, threshold: float | None) -> dict[str, Any] | None:
    """The stage's path as drawn: tip points, clearance at each, which segments are below the threshold."""
    tips = _tips_of(entry, spec)
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
    keep = _keep_indices(len(dense_tips), low, MAX_PATH_POINTS)
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


def itertools_pairs(values: Iterable[int]) -> list[tuple[int, int]]:
    return list(itertools.pairwise(values))


# ----------------------------------------------------------------------------- roadmaps and path sets


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


# ----------------------------------------------------------------------------- tissue meshes


def _surface(cells: np.ndarray) -> np.ndarray:
    """Boundary triangles (faces of one tetrahedron only) of a tetrahedral mesh, outward-ordered; (t, 4):
    three node indices and the owning element."""
    cells = np.asarray(cells, dtype=np.int64)[:, :4]
    local = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    faces = cells[:, local].reshape(-1, 3)
    owner = np.repeat(np.arange(len(cells)), 4)
    key = np.sort(faces, axis=1)
    _, index, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    once = index[counts == 1]
    return np.column_stack([faces[once], owner[once]])


def face_owner(elements: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The element each boundary triangle belongs to (-1 where none is found)."""
    surface = _surface(elements)
    table = {tuple(sorted(f[:3])): int(f[3]) for f in surface}
    return np.array([table.get(tuple(sorted(t)), -1) for t in np.asarray(triangles, dtype=np.int64)])


def _pick(frames: int) -> np.ndarray:
    if frames <= MAX_FRAMES:
        return np.arange(frames)
    return np.unique(np.round(np.linspace(0, frames - 1, MAX_FRAMES)).astype(np.int64))


def _mesh_out(label, times, positions, triangles, stress, time_label, largest=None) -> dict[str, Any]:
    positions = np.asarray(positions, dtype=float)
    stress = None if stress is None else np.asarray(stress, dtype=float)
    out: dict[str, Any] = {
        "label": label,
        "time_label": time_label,
        "times": [float(t) for t in times],
        "triangles": pack(triangles, "u4"),
        "positions": pack(positions),  # (frames, nodes, 3)
        "frames": int(positions.shape[0]),
        "nodes": int(positions.shape[1]),
        "triangle_count": len(triangles),
    }
    if stress is not None:
        finite = stress[np.isfinite(stress)]
        out["stress"] = pack(stress)  # (frames, triangles) Pa
        # stresses span decades (the grasp against the far edge): from the 1st percentile of the positive
        # ones (at least 1e-4 of the largest) the page colours on a log scale
        positive = finite[finite > 0]
        hi = float(finite.max()) if finite.size else 1.0
        lo = max(float(np.percentile(positive, 1)), hi * 1e-4) if positive.size else 0.0
        out["stress_range"] = [lo, hi] if hi > lo else [0.0, max(hi, 1.0)]
        # the largest stress of each state over every element (the surface shows only the outer ones)
        out["max_stress"] = (
            [float(v) for v in largest]
            if largest is not None
            else [float(np.nanmax(s)) if s.size else 0.0 for s in stress]
        )
    return out


def pvd_entries(text: str) -> list[tuple[float, str]]:
    """(time, file) of each ``<DataSet timestep=... file=...>`` of a ParaView collection."""
    entries = []
    for tag in re.findall(r"<DataSet\b[^>]*>", text):
        t = re.search(r'timestep="([^"]*)"', tag)
        f = re.search(r'file="([^"]*)"', tag)
        if f:
            try:
                time = float(t.group(1)) if t else float(len(entries))
            except ValueError:
                time = float(len(entries))
            entries.append((time, f.group(1)))
    return entries


def _read_vtu(path: Path):
    import meshio

    mesh = meshio.read(path)
    cells = None
    stress = None
    for block_index, block in enumerate(mesh.cells):
        if block.type in ("tetra", "tetra10"):
            cells = np.asarray(block.data, dtype=np.int64)
            for name in ("max_principal_stress", "stress", "von_mises"):
                if name in mesh.cell_data:
                    stress = np.asarray(mesh.cell_data[name][block_index], dtype=float).reshape(len(cells), -1)[:, 0]
                    break
            break
    return np.asarray(mesh.points, dtype=float), cells, stress


def simulate_mesh(out: Path, entry: Mapping[str, Any], notes: Notes) -> dict[str, Any] | None:
    """The tissue of a simulate stage: the ``.pvd`` sequence it lists, else its ``.vtu``."""
    files = [f for f in entry.get("files", []) if isinstance(f, str)]
    sequence: list[tuple[float, Path]] = []
    pvd = next((f for f in files if f.endswith(".pvd")), None)
    if pvd is not None:
        path = inside(out, pvd, notes)
        if path is not None:
            base = path.parent
            for t, relative in pvd_entries(path.read_text(errors="replace")):
                try:  # a collection names its files relative to itself
                    within = str((base / relative).resolve().relative_to(out.resolve()))
                except ValueError:
                    notes.add(f"{pvd}: {relative!r} is outside the output directory; not shown")
                    continue
                found = inside(out, within, notes)
                if found is not None:
                    sequence.append((t, found))
    if not sequence:
        vtu = next((f for f in files if f.endswith(".vtu")), None)
        path = inside(out, vtu, notes) if vtu else None
        if path is not None:
            sequence = [(1.0, path)]
    if not sequence:
        return None
    picked = [sequence[i] for i in _pick(len(sequence))]
    positions, stresses, times, largest = [], [], [], []
    surface = None
    for t, path in picked:
        try:
            points, cells, stress = _read_vtu(path)
        except Exception as exc:
            notes.add(f"{path.name}: not readable ({type(exc).__name__}: {exc}); skipped")
            continue
        if cells is None:
            notes.add(f"{path.name}: no tetrahedra; skipped")
            continue
        if surface is None:
            surface = _surface(cells)
            count = len(points)
        if len(points) != count:
            notes.add(f"{path.name}: another mesh than the sequence's first; skipped")
            continue
        positions.append(points)
        stresses.append(None if stress is None else stress[surface[:, 3]])
        largest.append(None if stress is None else float(np.max(stress)))
        times.append(t)
    if not positions:
        return None
    stress = None if any(s is None for s in stresses) else np.stack(stresses)
    label = "fraction of the motion applied" if len(times) > 1 else "equilibrium"
    return _mesh_out(
        pvd or "tissue", times, np.stack(positions), surface[:, :3], stress, label, None if stress is None else largest
    )


def states_mesh(out: Path, relative: str, notes: Notes) -> dict[str, Any] | None:
    """The tissue along a retraction trajectory, from ``<stage>-states.npz``."""
    path = inside(out, relative, notes)
    if path is None:
        return None
    try:
        arrays, _ = load_bundle(path)
        positions = np.asarray(arrays["positions"], dtype=float)
        triangles = np.asarray(arrays["triangles"], dtype=np.int64).reshape(-1, 3)
        elements = np.asarray(arrays["elements"], dtype=np.int64)
        stress = np.asarray(arrays["stress"], dtype=float) if "stress" in arrays else None
    except (ValueError, KeyError) as exc:
        notes.add(f"{relative}: not a readable states file ({exc}); not shown")
        return None
    if positions.ndim != 3 or positions.shape[2] != 3 or not len(positions):
        notes.add(f"{relative}: positions are not (states, nodes, 3); not shown")
        return None
    picked = _pick(len(positions))
    per_triangle = None
    if stress is not None and stress.ndim == 2 and len(stress) == len(positions):
        owner = face_owner(elements, triangles)
        per_triangle = np.where(owner[None, :] >= 0, stress[picked][:, np.clip(owner, 0, None)], np.nan)
    largest = None
    if "max_stress" in arrays and len(arrays["max_stress"]) == len(positions):
        largest = np.asarray(arrays["max_stress"], dtype=float)[picked]
    elif stress is not None and stress.ndim == 2 and len(stress) == len(positions):
        largest = stress[picked].max(axis=1)
    mesh = _mesh_out(
        relative, picked.astype(float), positions[picked], triangles, per_triangle, "trajectory state", largest
    )
    if "area_points" in arrays:
        area = np.asarray(arrays["area_points"], dtype=float).reshape(-1, 3)
        visible = np.asarray(arrays.get("visible", np.zeros(len(area))), dtype=bool).ravel()
        if len(visible) == len(area):
            mesh["area"] = {"points": pack(area), "visible": pack(visible.astype(np.uint32), "u4")}
    return mesh


# ----------------------------------------------------------------------------- timelines


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


def _array(value, columns: int | None = None) -> np.ndarray | None:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    if columns is not None and (a.ndim != 2 or a.shape[1] != columns):
        return None
    return a


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
        t = _array(timeline.get("t"))
        tip = _array(timeline.get("tip"), 3)
        if t is not None and tip is not None and t.ndim == 1 and len(t) == len(tip) and len(t):
            source = "timeline"
            for key in ("commanded",):
                value = _array(timeline.get(key), 3)
                if value is not None and len(value) == len(t):
                    series[key] = value
            for key in ("clearance", "deviation"):
                value = _array(timeline.get(key))
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
        path = _array(entry.get("tip_path") or entry.get("path"), 3)
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
    keep = _keep_indices(len(t), None, MAX_TIMELINE_SAMPLES)
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
    by_name = {e.get("name"): e for e in entries}
    for index, entry in enumerate(entries):
        name = str(entry.get("name", f"stage {index}"))
        kind = str(entry.get("stage", ""))
        spec = specs.get(name)
        metrics = entry.get("metrics") if isinstance(entry.get("metrics"), Mapping) else {}
        threshold = metrics.get("clearance_threshold_m")
        threshold = float(threshold) if isinstance(threshold, int | float) else None
        stage: dict[str, Any] = {
            "name": name,
            "stage": kind,
            "plugin": entry.get("plugin", ""),
            "status": entry.get("status", ""),
            "message": entry.get("message", ""),
            "colour": PALETTE[index % len(PALETTE)],
            "metrics": _metrics_rows(metrics),
            "threshold": threshold,
            "images": [],
        }
        for f in entry.get("files", []) or []:
            if isinstance(f, str) and f.lower().endswith(".png") and inside(out, f, notes, what="figure"):
                stage["images"].append(f)
        try:
            if kind == "plan" or kind not in (*TIME_KINDS, "simulate"):
                stage["path"] = path_data(entry, spec, scene, threshold)
                regions = (entry.get("annotations") or {}).get("critical_regions") or []
                stage["critical"] = [
                    {
                        "start": float(r["start_m"]),
                        "end": float(r["end_m"]),
                        "min_clearance": r.get("min_clearance_m"),
                        "obstacles": r.get("obstacles", []),
                    }
                    for r in regions
                    if isinstance(r, Mapping) and "start_m" in r and "end_m" in r
                ]
                if spec is not None and getattr(spec, "space", None) is not None:
                    for key in ("start", "goal"):
                        q = getattr(spec, key, None)
                        if q is not None:
                            stage[key] = np.asarray(spec.space.tip(np.asarray(q, float)[None])[0], float).tolist()
                elif stage["path"] is not None:
                    tips = _tips_of(entry, spec)
                    stage["start"], stage["goal"] = tips[0].tolist(), tips[-1].tolist()
                artifact = getattr(spec, "artifact", None)
                if artifact is not None and Path(artifact).is_file():
                    stage["roadmap"] = artifact_data(Path(artifact), spec, notes)
            if kind == "simulate":
                stage["mesh"] = simulate_mesh(out, entry, notes)
            states = next(
                (f for f in entry.get("files", []) or [] if isinstance(f, str) and f.endswith("-states.npz")), None
            )
            if states is not None:
                stage["mesh"] = states_mesh(out, states, notes)
            if kind in TIME_KINDS:
                stage["timeline"] = timeline_data(out, entry, notes, scene)
                stage["path"] = path_data(entry, None, scene, None)
                source = (
                    getattr(spec, "path_from", None)
                    or entry.get("path_from")
                    or ((entry.get("annotations") or {}).get("path_from"))
                )
                reference = by_name.get(source) if isinstance(source, str) else None
                recommended = _array((entry.get("annotations") or {}).get("recommended_tips"), 3)
                if recommended is not None and len(recommended) >= 2:  # a guide stage records what it recommended
                    stage["reference"] = {"name": str(source or "recommended"), "tips": pack(recommended)}
                elif reference is not None:
                    tips = _tips_of(reference, specs.get(source))
                    if tips is not None:
                        stage["reference"] = {"name": source, "tips": pack(tips)}
        except Exception as exc:  # one stage's odd output must not cost the others their report
            notes.add(f"stage {name}: {type(exc).__name__}: {exc}; part of it is not shown")
            log.warning("report: stage %s: %s", name, exc, exc_info=log.isEnabledFor(logging.DEBUG))
        data["stages"].append(stage)
    data["notes"] = notes.items
    return data
