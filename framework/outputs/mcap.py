"""A run as an MCAP file, for Foxglove and ROS 2 tooling (``surgiplan export mcap RUN_DIR``).

Written with Foxglove's own SDK (``foxglove-sdk``) in Foxglove's well-known message schemas (protobuf), so
Foxglove shows every channel without a plugin; a JSON-schema channel carries the per-sample numbers for
its plots. Read from what the run wrote (``result.json`` and the files its stages list), never from a
plugin:

=============================  ==========================  ===================================================
topic                          schema                      what
=============================  ==========================  ===================================================
``/scene``                     ``foxglove.SceneUpdate``    the obstacles (triangle meshes) and the bounds
``/plan/<stage>``              ``foxglove.SceneUpdate``    a plan stage's path, its critical regions in red
``/<stage>/reference``         ``foxglove.SceneUpdate``    the path an execution or attempt followed
``/<stage>/tip``               ``foxglove.PoseInFrame``    the instrument's tip, every sample
``/<stage>/joints``            ``foxglove.JointStates``    measured joints (devices whose CSV has them)
``/<stage>/measures``          JSON (json schema)          clearance, deviation, progress (m), per sample
``/<stage>/events``            ``foxglove.Log``            events and faults, at their times
=============================  ==========================  ===================================================

Times: the stages follow one another on one clock from 0 (the file has no wall-clock dates): each timed
stage's samples at its own times after the previous stage's end plus one second; frame ``world``, SI.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..clearance import regions_from_json
from ..errors import OutputError, SurgiplanError
from ..storage import commit_file

FRAME = "world"
GAP_S = 1.0
MEASURES_SCHEMA = {
    "type": "object",
    "properties": {
        "t_s": {"type": "number"},
        "clearance_m": {"type": "number"},
        "deviation_m": {"type": "number"},
        "progress_m": {"type": "number"},
    },
}


def _foxglove():
    try:
        import foxglove
        import foxglove.channels as channels
        import foxglove.messages as messages
    except ImportError as exc:
        raise SurgiplanError(f"MCAP export needs Foxglove's SDK: pip install 'surgiplan[mcap]' ({exc})") from None
    return foxglove, channels, messages


@dataclass
class Series:
    """A timed stage's samples (SI)."""

    t: np.ndarray
    tip: np.ndarray
    measures: dict[str, np.ndarray] = field(default_factory=dict)
    joints: dict[str, np.ndarray] = field(default_factory=dict)
    events: list[dict[str, Any]] = field(default_factory=list)


def _csv(path: Path) -> dict[str, np.ndarray] | None:
    try:
        table = np.genfromtxt(path, delimiter=",", names=True, dtype=float)
    except (OSError, ValueError):
        return None
    if table.dtype.names is None:
        return None
    return {name: np.atleast_1d(table[name]) for name in table.dtype.names}


def stage_series(run_dir: Path, entry: Mapping[str, Any]) -> Series | None:
    """Every sample of a timed stage: its full-rate CSV (guide samples, device execution) when it wrote one,
    else the timeline annotation of result.json."""
    files = [f for f in entry.get("files", []) or [] if isinstance(f, str)]
    annotations = entry.get("annotations") or {}
    timeline = annotations.get("timeline") if isinstance(annotations, Mapping) else None
    events = list((timeline or {}).get("events") or []) + list((entry.get("metrics") or {}).get("faults") or [])
    for name in files:
        if not name.endswith(("-samples.csv", "-execution.csv")):
            continue
        table = _csv(run_dir / name)
        if table is None:
            continue
        t = table.get("t") if "t" in table else table.get("t_s")
        tip_columns = [c for c in ("x_m", "y_m", "z_m")] if "x_m" in table else ["tip_x_m", "tip_y_m", "tip_z_m"]
        if t is None or not all(c in table for c in tip_columns):
            continue
        tip = np.column_stack([table[c] for c in tip_columns])
        measures = {
            k: table[c]
            for k, c in (("clearance_m", "clearance_m"), ("deviation_m", "deviation_m"), ("progress_m", "progress_m"))
            if c in table
        }
        joints = {c.removeprefix("measured_"): table[c] for c in table if c.startswith("measured_")}
        return Series(t, tip, measures, joints, events)
    if isinstance(timeline, Mapping) and "t" in timeline and "tip" in timeline:
        t = np.asarray(timeline["t"], dtype=float)
        tip = np.asarray(timeline["tip"], dtype=float).reshape(-1, 3)
        measures = {
            f"{k}_m": np.asarray(timeline[k], dtype=float)
            for k in ("clearance", "deviation")
            if isinstance(timeline.get(k), list) and len(timeline[k]) == len(t)
        }
        return Series(t, tip, measures, {}, events)
    return None


def _scene(document: Mapping[str, Any], run_dir: Path):
    """The run's obstacles as (name, vertices, faces) and its bounds: from its pipeline file, else scene.glb."""
    from ..pipeline import load_pipeline

    try:
        scene = load_pipeline(document.get("pipeline_file", ""), output_dir=run_dir).scene
        meshes = [
            (o.name, np.asarray(m.vertices), np.asarray(m.faces)) for o in scene.obstacles for m in [o.to_trimesh()]
        ]
        return meshes, (np.asarray(scene.bounds_min), np.asarray(scene.bounds_max))
    except (SurgiplanError, OSError):
        pass
    try:
        import trimesh

        loaded = trimesh.load(run_dir / "scene.glb")
        meshes = []
        for node in loaded.graph.nodes_geometry:
            if node.startswith("obstacle:"):
                transform, name = loaded.graph[node]
                mesh = loaded.geometry[name].copy().apply_transform(transform)
                meshes.append((node.removeprefix("obstacle:"), np.asarray(mesh.vertices), np.asarray(mesh.faces)))
        return meshes, None
    except Exception:
        return [], None


def _ns(t: float) -> int:
    return round(t * 1e9)


def _stamp(m, t: float):
    sec = math.floor(t)
    return m.Timestamp(sec=int(sec), nsec=round((t - sec) * 1e9) % 1_000_000_000)


class McapExport:
    """Writes one run (or some of its stages) into an MCAP file; :meth:`counts` says what went in."""

    def __init__(self, path: Path) -> None:
        self.foxglove, self.channels, self.m = _foxglove()
        self.context = self.foxglove.Context()
        self.writer = self.foxglove.open_mcap(path, allow_overwrite=True, context=self.context)
        self._channels: dict[str, Any] = {}
        self.counts: dict[str, list[float]] = {}  # topic -> [messages, first t, last t]

    def _log(self, topic: str, kind: str, message: Any, t: float) -> None:
        channel = self._channels.get(topic)
        if channel is None:
            if kind == "json":
                schema = self.foxglove.Schema(
                    name="surgiplan.Measures", encoding="jsonschema", data=json.dumps(MEASURES_SCHEMA).encode()
                )
                channel = self.foxglove.Channel(topic, schema=schema, message_encoding="json", context=self.context)
            else:
                channel = getattr(self.channels, f"{kind}Channel")(topic, context=self.context)
            self._channels[topic] = channel
        channel.log(message, log_time=_ns(t))
        count = self.counts.setdefault(topic, [0, t, t])
        count[0] += 1
        count[2] = t

    def close(self) -> None:
        self.writer.close()

    # ------------------------------------------------------------------ messages
    def _colour(self, r, g, b, a=1.0):
        return self.m.Color(r=r, g=g, b=b, a=a)

    def _line(self, points: np.ndarray, colour, thickness: float = 0.0015):
        m = self.m
        return m.LinePrimitive(
            type=m.LinePrimitiveLineType.LineStrip,
            thickness=thickness,
            scale_invariant=False,
            points=[m.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in points],
            color=colour,
        )

    def scene(self, meshes, bounds) -> None:
        m = self.m
        entities = []
        for name, vertices, faces in meshes:
            points = [m.Point3(x=float(x), y=float(y), z=float(z)) for x, y, z in vertices]
            triangles = m.TriangleListPrimitive(
                points=points, indices=[int(i) for i in np.asarray(faces).ravel()], color=self._colour(0.6, 0.6, 0.6)
            )
            entities.append(
                m.SceneEntity(timestamp=_stamp(m, 0), frame_id=FRAME, id=f"obstacle:{name}", triangles=[triangles])
            )
        if bounds is not None:
            lo, hi = bounds
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            order = [0, 1, 3, 2, 0, 4, 5, 7, 6, 4, 5, 1, 3, 7, 6, 2]
            entities.append(
                m.SceneEntity(
                    timestamp=_stamp(m, 0),
                    frame_id=FRAME,
                    id="bounds",
                    lines=[self._line(corners[order], self._colour(0.3, 0.3, 0.3), 0.0005)],
                )
            )
        self._log("/scene", "SceneUpdate", m.SceneUpdate(entities=entities), 0.0)

    def path(self, topic: str, name: str, tips: np.ndarray, regions, t: float) -> None:
        m = self.m
        lines = [self._line(tips, self._colour(0.12, 0.44, 0.71))]
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(tips, axis=0), axis=1))])
        for region in regions:
            inside = tips[(arc >= region.start_m) & (arc <= region.end_m)]
            if len(inside) >= 2:
                lines.append(self._line(inside, self._colour(0.85, 0.1, 0.1), 0.003))
        entity = m.SceneEntity(timestamp=_stamp(m, t), frame_id=FRAME, id=name, lines=lines)
        self._log(topic, "SceneUpdate", m.SceneUpdate(entities=[entity]), t)

    def series(self, stage: str, series: Series, offset: float) -> float:
        m = self.m
        names = list(series.joints)
        for i, (t, tip) in enumerate(zip(series.t, series.tip, strict=True)):
            when = offset + float(t)
            pose = m.Pose(
                position=m.Vector3(x=float(tip[0]), y=float(tip[1]), z=float(tip[2])),
                orientation=m.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
            )
            self._log(
                f"/{stage}/tip",
                "PoseInFrame",
                m.PoseInFrame(timestamp=_stamp(m, when), frame_id=FRAME, pose=pose),
                when,
            )
            if series.measures:
                values = {"t_s": float(t), **{k: float(v[i]) for k, v in series.measures.items()}}
                self._log(f"/{stage}/measures", "json", {k: v for k, v in values.items() if math.isfinite(v)}, when)
            if names:
                joints = [m.JointState(name=n, position=float(series.joints[n][i])) for n in names]
                self._log(
                    f"/{stage}/joints", "JointStates", m.JointStates(timestamp=_stamp(m, when), joints=joints), when
                )
        for event in series.events:
            t = next(
                (event[k] for k in ("t", "start_t", "t_s", "time_s") if isinstance(event.get(k), int | float)), None
            )
            when = offset + float(t if t is not None else 0.0)
            kind = str(event.get("kind", "fault"))
            text = str(event.get("message") or event.get("detail") or event.get("cause") or kind)
            level = m.LogLevel.Error if kind in ("contact", "fault") or "fault" in event else m.LogLevel.Warning
            self._log(
                f"/{stage}/events",
                "Log",
                m.Log(timestamp=_stamp(m, when), level=level, message=f"{kind}: {text}", name=stage),
                when,
            )
        return offset + (float(series.t[-1]) if len(series.t) else 0.0)


def export_mcap(run_dir: Path, out: Path, stages: Sequence[str] | None = None) -> dict[str, list[float]]:
    """Write the run in ``run_dir`` (or the ``stages`` named) to ``out`` atomically; {topic: [messages, first
    time, last time]}."""
    run_dir = Path(run_dir)
    try:
        document = json.loads((run_dir / "result.json").read_text())
    except (OSError, ValueError) as exc:
        raise OutputError(f"{run_dir} has no readable result.json (not a finished run): {exc}") from None
    entries = [e for e in document.get("stages", []) if isinstance(e, Mapping)]
    names = [str(e.get("name")) for e in entries]
    for name in stages or []:
        if name not in names:
            from ..errors import choices_hint

            raise OutputError(f"the run has no stage named '{name}'; {choices_hint(name, names)}", location="--stage")
    by_name = dict(zip(names, entries, strict=True))
    fd, temporary = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    os.close(fd)
    os.unlink(temporary)  # the SDK creates the file itself
    export = McapExport(Path(temporary))
    try:
        meshes, bounds = _scene(document, run_dir)
        export.scene(meshes, bounds)
        clock = 0.0
        for entry in entries:
            name = str(entry.get("name"))
            if stages and name not in stages:
                continue
            tips = np.asarray(entry.get("tip_path") or entry.get("path") or [], dtype=float)
            if entry.get("stage") == "plan":
                if tips.ndim == 2 and tips.shape[1] == 3 and len(tips) >= 2:
                    export.path(
                        f"/plan/{name}",
                        name,
                        tips,
                        regions_from_json((entry.get("annotations") or {}).get("critical_regions")),
                        clock,
                    )
                continue
            series = stage_series(run_dir, entry)
            if series is None or not len(series.t):
                continue
            start = clock + GAP_S
            reference = _reference(entry, by_name)
            if reference is not None:
                export.path(f"/{name}/reference", f"{name}:reference", reference, [], start)
            clock = export.series(name, series, start - float(series.t[0]))
    except BaseException:
        export.close()
        Path(temporary).unlink(missing_ok=True)
        raise
    export.close()
    commit_file(temporary, out)  # synced, renamed into place, the directory synced (surgiplan.storage)
    return export.counts


def _reference(entry: Mapping[str, Any], by_name: Mapping[str, Mapping[str, Any]]) -> np.ndarray | None:
    annotations = entry.get("annotations") or {}
    recommended = annotations.get("recommended_tips")
    if recommended:
        return np.asarray(recommended, dtype=float).reshape(-1, 3)
    source = by_name.get(annotations.get("path_from") or entry.get("path_from"))
    if source is not None:
        tips = np.asarray(source.get("tip_path") or source.get("path") or [], dtype=float)
        if tips.ndim == 2 and tips.shape[1] == 3:
            return tips
    return None
