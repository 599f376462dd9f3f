"""The ``export`` stage kind (an example stage-kind plugin): a planned path as a timed trajectory file.

A robot controller does not take a list of waypoints; it takes positions at
times. An ``export`` stage takes the path of an earlier plan stage, times it
within per-coordinate velocity and acceleration limits, samples it at a fixed
rate, and hands it to an *exporter* plugin that writes a file a robot (or its
middleware) reads::

    - stage: export
      plugin: ros_joint_trajectory      # an exporter: joint_csv, ros_joint_trajectory, or your own
      path_from: intermediate           # default: the last plan stage
      velocity_limit: [0.05, 0.05, 0.05]        # per coordinate, SI (m/s, rad/s); one number for all
      acceleration_limit: 0.2                   # per coordinate, SI (m/s², rad/s²)
      rate: 100                                  # samples per second in the file
      file: trajectory.yaml                      # in the run's output directory

Timing: the motion stops at every waypoint (the planners' waypoints are where
the path turns), and each segment is a synchronised trapezoid: every
coordinate moves along the straight segment, and the segment takes as long as
its slowest coordinate needs with its limits (a triangle when it never reaches
its top speed). So no coordinate exceeds its velocity or acceleration limit,
and every waypoint is reached exactly at a knot.

This module is the whole stage kind: its YAML keys, its plugin kind (the
``surgiplan_register_exporters`` hook and the :class:`TrajectoryExporter`
interface), its statuses, how it runs and what the summary and the report
show. Registering it is one more hook in the package's ``__init__``; nothing
in surgiplan changes.
"""

from __future__ import annotations

import enum
import itertools
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import yaml
from pydantic import BaseModel, Field, PositiveFloat, field_validator
from surgiplan import PluginSpec, StrictModel
from surgiplan.hookspecs import hookspec
from surgiplan.kinds import PathStageModel, PathStageSpec, PluginKind, StageKind, StageRun, planned, resolve_path_from
from surgiplan.outputs.report.timeline import motion_report
from surgiplan.results import StageResult
from surgiplan.storage import write_text_atomic

# ----------------------------------------------------------------------------- the timed trajectory


@dataclass
class TimedTrajectory:
    """Positions, velocities and accelerations of every coordinate at times ``t`` (SI)."""

    t: np.ndarray  # (n,) s
    q: np.ndarray  # (n, d)
    qd: np.ndarray  # (n, d)
    qdd: np.ndarray  # (n, d)
    names: list[str]
    #: the index of the sample at each waypoint (the knots)
    knots: np.ndarray


def _unit_limits(delta: np.ndarray, vmax: np.ndarray, amax: np.ndarray) -> tuple[float, float]:
    """Along a straight segment ``q = a + u delta`` (u from 0 to 1): the largest du/dt and d²u/dt² that keep
    every moving coordinate within its limits."""
    moving = np.abs(delta) > 0
    return float(np.min(vmax[moving] / np.abs(delta[moving]))), float(np.min(amax[moving] / np.abs(delta[moving])))


def _trapezoid(speed: float, accel: float) -> tuple[float, float]:
    """The quickest rest-to-rest motion over u in [0, 1] within ``speed`` and ``accel``: (duration, top speed);
    a triangle when the top speed is never reached."""
    if speed * speed / accel >= 1.0:
        return 2.0 / math.sqrt(accel), math.sqrt(accel)
    return 1.0 / speed + speed / accel, speed


def _profile(s: np.ndarray, duration: float, peak: float, accel: float) -> tuple:
    """u, du/dt and d²u/dt² of that motion at times ``s``."""
    ramp = peak / accel
    up, down = s < ramp, s > duration - ramp
    u = np.where(
        up,
        0.5 * accel * s**2,
        np.where(down, 1.0 - 0.5 * accel * (duration - s) ** 2, 0.5 * peak * ramp + peak * (s - ramp)),
    )
    v = np.where(up, accel * s, np.where(down, accel * (duration - s), peak))
    a = np.where(up, accel, np.where(down, -accel, 0.0))
    return u, v, a


def time_path(path: np.ndarray, vmax, amax, rate: float, names: list[str]) -> TimedTrajectory:
    """Time ``path`` (waypoints joined by straight segments in coordinates) rest-to-rest within the limits,
    sampled at ``rate`` and at every waypoint."""
    path = np.asarray(path, dtype=float)
    d = path.shape[1]
    vmax = np.broadcast_to(np.asarray(vmax, dtype=float), (d,))
    amax = np.broadcast_to(np.asarray(amax, dtype=float), (d,))
    ts, qs, qds, qdds = [np.zeros(1)], [path[:1]], [np.zeros((1, d))], [np.zeros((1, d))]
    knots = [0]
    t0 = 0.0
    for a, b in itertools.pairwise(path):
        delta = b - a
        if not np.any(delta):
            continue
        duration, peak = _trapezoid(*_unit_limits(delta, vmax, amax))
        accel = _unit_limits(delta, vmax, amax)[1]
        s = np.linspace(0.0, duration, max(2, math.ceil(duration * rate) + 1))[1:]
        u, v, acc = _profile(s, duration, peak, accel)
        u[-1], v[-1] = 1.0, 0.0  # exactly at the waypoint, at rest
        ts.append(t0 + s)
        qs.append(a + u[:, None] * delta)
        qds.append(v[:, None] * delta)
        qdds.append(acc[:, None] * delta)
        knots.append(knots[-1] + len(s))
        t0 += duration
    return TimedTrajectory(
        np.concatenate(ts), np.concatenate(qs), np.concatenate(qds), np.concatenate(qdds), names, np.array(knots)
    )


# ----------------------------------------------------------------------------- the plugin kind: exporters


class Hooks:
    """The hook export stages take their plugins from."""

    @hookspec
    def surgiplan_register_exporters(self) -> list[PluginSpec]:
        """Exporter plugins (subclasses of :class:`surgiplan_hello.export.TrajectoryExporter`)."""


class TrajectoryExporter(ABC):
    """Writes a :class:`TimedTrajectory` in a file format a robot reads."""

    Settings: ClassVar[type[BaseModel]]
    #: the file name's ending when the stage does not name the file
    suffix: ClassVar[str] = ".txt"

    @classmethod
    def estimate_resources(cls, settings):
        return []

    def __init__(self, settings: BaseModel) -> None:
        self.settings = settings

    @abstractmethod
    def render(self, trajectory: TimedTrajectory) -> str:
        """The file's text."""


EXPORTER = PluginKind("exporter", "surgiplan_register_exporters", TrajectoryExporter)


class JointCsvSettings(StrictModel):
    #: digits after the point
    precision: int = Field(default=9, ge=1, le=17)


class JointCsv(TrajectoryExporter):
    """``t_s`` then each coordinate's position, velocity and acceleration, one row per sample (SI)."""

    Settings = JointCsvSettings
    suffix = ".csv"

    def render(self, trajectory: TimedTrajectory) -> str:
        p = self.settings.precision
        header = ["t_s"] + [f"{n}{suffix}" for suffix in ("", "_vel", "_acc") for n in trajectory.names]
        rows = [",".join(header)]
        table = np.column_stack([trajectory.t, trajectory.q, trajectory.qd, trajectory.qdd])
        rows += [",".join(f"{v:.{p}g}" for v in row) for row in table]
        return "\n".join(rows) + "\n"


class RosJointTrajectorySettings(StrictModel):
    #: header.frame_id of the message
    frame_id: str = "world"


class RosJointTrajectory(TrajectoryExporter):
    """A ROS 2 ``trajectory_msgs/msg/JointTrajectory`` message as YAML (what ``ros2 topic pub --once
    /joint_trajectory trajectory_msgs/msg/JointTrajectory "$(cat file)"`` and ROS 2 ``yaml`` loaders take):
    ``joint_names``, and ``points`` with ``positions``, ``velocities``, ``accelerations`` and
    ``time_from_start: {sec, nanosec}``."""

    Settings = RosJointTrajectorySettings
    suffix = ".yaml"

    def render(self, trajectory: TimedTrajectory) -> str:
        points = []
        for t, q, qd, qdd in zip(trajectory.t, trajectory.q, trajectory.qd, trajectory.qdd, strict=True):
            sec, nanosec = divmod(round(float(t) * 1e9), 1_000_000_000)
            points.append(
                {
                    "positions": [float(v) for v in q],
                    "velocities": [float(v) for v in qd],
                    "accelerations": [float(v) for v in qdd],
                    "time_from_start": {"sec": sec, "nanosec": nanosec},
                }
            )
        message = {
            "header": {"frame_id": self.settings.frame_id},
            "joint_names": list(trajectory.names),
            "points": points,
        }
        return yaml.safe_dump(message, sort_keys=False)


# ----------------------------------------------------------------------------- the stage kind


class ExportStatus(enum.StrEnum):
    WRITTEN = "written"


Limits = float | list[PositiveFloat]


class ExportStageModel(PathStageModel):
    """The keys of an export stage (SI: m/s and rad/s, m/s² and rad/s²; one number for every coordinate)."""

    velocity_limit: Limits
    acceleration_limit: Limits
    rate: PositiveFloat = 100.0
    file: str | None = Field(default=None, min_length=1)

    @field_validator("velocity_limit", "acceleration_limit")
    @classmethod
    def _positive(cls, value):
        values = value if isinstance(value, list) else [value]
        if not values or not all(math.isfinite(v) and v > 0 for v in values):
            raise ValueError(f"must be a positive number or a list of them, got {value}")
        return value

    @field_validator("file")
    @classmethod
    def _plain_name(cls, value):
        if value is not None and (Path(value).name != value or value in (".", "..")):
            raise ValueError(f"must be a file name in the run's output directory, not a path: {value!r}")
        return value


@dataclass
class ExportSpec(PathStageSpec):
    pass


def coordinate_names(space) -> list[str]:
    names = getattr(space, "coordinate_names", None)
    return list(names) if names is not None else [f"q{i}" for i in range(space.dimension)]


class ExportKind(StageKind):
    name = "export"
    description = "a planned path, timed within velocity and acceleration limits, written for a robot"
    model = ExportStageModel
    spec_type = ExportSpec
    plugin_kind = EXPORTER
    hookspecs = Hooks
    statuses = ExportStatus
    succeeded = frozenset({ExportStatus.WRITTEN.value})
    timed = True

    def check(self, spec: ExportSpec, files) -> None:
        resolve_path_from(spec, files, "whose path it exports")
        plan = next(s for s in files.earlier if s.name == spec.path_from)
        d = plan.space.dimension if getattr(plan, "space", None) is not None else None
        for key in ("velocity_limit", "acceleration_limit"):
            value = getattr(spec.keys, key)
            if isinstance(value, list) and d is not None and len(value) != d:
                raise files.error(
                    f"{key} has {len(value)} values; the {plan.space.kind} space of plan stage "
                    f"'{plan.name}' has {d} coordinates ({', '.join(coordinate_names(plan.space))})",
                    "pipeline",
                    spec.index,
                    key,
                )

    def run(self, run: StageRun) -> StageResult:
        source = planned(run, minimum=2)
        if isinstance(source, StageResult):
            return source
        plan_spec, plan = source
        spec, keys = run.spec, run.spec.keys
        space = plan_spec.space
        exporter = run.call("construction", spec.plugin.cls, spec.settings)
        names = coordinate_names(space)
        timed = time_path(np.asarray(plan.path), keys.velocity_limit, keys.acceleration_limit, keys.rate, names)
        text = run.call("render", exporter.render, timed)
        name = keys.file or f"{spec.name}{spec.plugin.cls.suffix}"
        write_text_atomic(Path(run.context.output_dir) / name, text)
        tips = space.tip(timed.q)
        return run.result(
            ExportStatus.WRITTEN.value,
            metrics={
                "duration_s": float(timed.t[-1]),
                "samples": len(timed.t),
                "waypoints": len(plan.path),
                "max_speed": np.max(np.abs(timed.qd), axis=0).tolist(),
                "max_acceleration": np.max(np.abs(timed.qdd), axis=0).tolist(),
            },
            message=f"{len(timed.t)} samples over {timed.t[-1]:.3g} s in {name}",
            files=[name],
            tip_path=tips,
            space="r3",
            annotations={"timeline": {"t": timed.t.tolist(), "tip": tips.tolist()}, "path_from": spec.path_from},
        )

    def details(self, result: StageResult, k: float, unit: str) -> list[str]:
        m = result.metrics
        return [f"{m['samples']} samples, {m['duration_s']:.3g} s"] if "samples" in m else []

    def report(self, stage, entry, inputs) -> None:
        motion_report(stage, entry, inputs)
