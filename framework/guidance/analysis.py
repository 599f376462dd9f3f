"""Following a trainee against the recommended path, sample by sample.

For every pose as it arrives, :class:`Guide` measures

* **deviation**: the tip's distance to the recommended tip path (the exact
  closest point on its polyline, densified at :data:`PATH_RESOLUTION` where
  the space's local motions curve the tip);
* **progress**: the arc length (m) of that closest point along the path;
* **clearance**: of the whole instrument (the space's clearance of the
  configuration: the gimbal's whole shaft) when the sample carries one, else
  of the tip sphere, measured on the scene;
* whether the tip is **in a critical region** of the recommended path (its
  progress within a region's arc-length interval): there the path itself
  passes below d_thresh because no detour exists;

and keeps **events**, each a stretch of consecutive samples from the first
that meets its condition (``start_t``) to the last (``end_t``):

=================  ====================================================================
``contact``        clearance <= 0
``below_threshold`` clearance < d_thresh while not in a critical region
``deviation``      deviation > ``deviation_tolerance``
``wrong_way``      progress more than ``wrong_way`` behind the furthest progress so far
``stalled``        progress grew by less than ``stall_distance`` over the last
                   ``stall_time`` seconds (before the goal is reached, and not
                   while going the wrong way)
=================  ====================================================================

Each sample also gets the tip's **lateral offset** from its closest path
point along the path's two normals (a frame transported along the path without
twisting), and its **insertion depth** (distance from the gimbal's fulcrum, or
from the assessment's ``port``, to the tip) when there is one: what the skill
metrics of :mod:`.metrics` count corrections and depth reversals on.

The attempt's metrics and **score** (0-100, a weighted combination of
safety, accuracy, economy, time, idle, smoothness, corrections and depth,
times completion) are :func:`surgiplan.guidance.metrics.assess`'s; every term
is in the report, so a trainer can see why.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydantic import Field, PositiveFloat

from ..models import StrictModel
from ..scene import Scene
from ..spaces.base import Space
from ..units import LENGTH_UNITS, Length, PositiveLength
from .metrics import AssessmentSettings, AttemptSamples, assess
from .source import PoseSample

#: spacing (m) at which the recommended path is densified before the closest-point search
PATH_RESOLUTION = 2.5e-4

EVENT_KINDS = ("contact", "below_threshold", "deviation", "wrong_way", "stalled")


class GuidanceSettings(StrictModel):
    """The ``guidance:`` block of a guide stage (lengths in the pipeline's unit)."""

    #: a deviation from the recommended path above this is an event
    deviation_tolerance: PositiveLength = 0.005
    #: progress this far behind the furthest so far is going the wrong way
    wrong_way: PositiveLength = 0.005
    #: less than stall_distance of progress in stall_time seconds is a stall
    stall_time: PositiveFloat = 2.0
    stall_distance: PositiveLength = 0.001
    #: the goal is reached within this of the path's end
    goal_tolerance: PositiveLength = 0.003
    #: deprecated: the attempt is judged against the plan stage's clearance_threshold; a value here still
    #: overrides it for one release (with a warning)
    threshold: Length | None = None
    #: radius of the tip when a sample has only the tip position; default: the space's tip radius (r3), else 0
    tip_radius: Length | None = None
    #: samples per second kept in result.json's timeline (the CSV keeps all)
    timeline_rate: PositiveFloat = 50.0
    #: the attempt is stopped when no sample arrives for this long (s)
    silence_timeout: PositiveFloat = Field(default=2.0)
    #: SCHED_FIFO priority (1-99) of the stage's threads while the attempt runs (Linux; needs CAP_SYS_NICE), as a
    #: real-time control loop runs: nothing at ordinary priority (a browser rendering the live view on the same
    #: cores) can delay a sample. None: ordinary priority with the shortest slice (surgiplan.scheduling)
    realtime_priority: int | None = Field(default=None, ge=1, le=99)


@dataclass
class Measurement:
    """One sample measured against the recommended path (see the module): its time ``t`` (s), ``tip`` position
    (m), ``deviation`` from the path (m), ``progress`` along it (arc length, m), ``clearance`` (m; <= 0 is
    contact) and whether it is in a ``critical`` region."""

    t: float
    tip: np.ndarray
    deviation: float
    progress: float
    clearance: float
    critical: bool
    #: the obstacle nearest to the instrument (-1: none)
    obstacle: int
    #: seconds the analysis took (what the stage adds per sample)
    latency: float
    #: seconds from the source producing the sample to the end of its analysis (set by the stage)
    delay: float = 0.0
    #: the tip's offset from its closest path point along the path's two normals (m)
    lateral: tuple[float, float] = (0.0, 0.0)
    #: distance from the fulcrum (or port) to the tip (m); NaN when there is none
    insertion: float = math.nan
    #: the closest point of the recommended path (m)
    closest: np.ndarray | None = None
    #: where the expert ghost is at this sample's progress (m; set by the stage when it shows one)
    ghost: np.ndarray | None = None


@dataclass
class Event:
    """A stretch of consecutive samples that met one condition (``kind``: one of the module's table), from
    ``start_t`` to ``end_t`` (s) and from ``start_progress_m`` to ``end_progress_m`` along the path; ``message``
    says it for the trainee."""

    kind: str
    start_t: float
    end_t: float
    start_progress_m: float
    end_progress_m: float
    #: the worst value over the stretch: the smallest clearance, the largest deviation or lag (m), the stall (s)
    worst: float
    message: str = ""

    def to_json(self) -> dict[str, Any]:
        """The event's fields as a JSON object (how ``result.json`` and the live view carry it)."""
        return {
            "kind": self.kind,
            "start_t": self.start_t,
            "end_t": self.end_t,
            "start_progress_m": self.start_progress_m,
            "end_progress_m": self.end_progress_m,
            "worst": self.worst,
            "message": self.message,
        }


@dataclass
class _Open:
    event: Event
    last_t: float
    last_progress: float


class Guide:
    """Measures each sample against the recommended path and keeps the events (see the module)."""

    def __init__(
        self,
        space: Space,
        path: np.ndarray,
        scene: Scene,
        threshold: float | None,
        critical: list[tuple[float, float]],
        settings: GuidanceSettings,
        *,
        unit: str = "mm",
        assessment: AssessmentSettings | None = None,
        port: np.ndarray | None = None,
    ) -> None:
        self.space = space
        self.scene = scene
        self.settings = settings
        self.threshold = settings.threshold if settings.threshold is not None else (threshold or 0.0)
        self.critical = [(float(a), float(b)) for a, b in (getattr(r, "interval", r) for r in critical)]
        self.unit = unit
        self.k = 1.0 / LENGTH_UNITS.get(unit, 1e-3)
        dense = space.densify(np.asarray(path, float), PATH_RESOLUTION)
        self.tips = space.tip(dense)
        self.a = self.tips[:-1]
        self.d = self.tips[1:] - self.a
        self.seg_len_sq = np.einsum("ij,ij->i", self.d, self.d)
        seg_len = np.sqrt(self.seg_len_sq)
        self.arc = np.concatenate([[0.0], np.cumsum(seg_len)])
        self.length = float(self.arc[-1])
        self.normals = _transported_normals(self.d, seg_len)
        self.assessment = assessment if assessment is not None else AssessmentSettings()
        if port is None:
            port = getattr(space, "fulcrum", None)
        self.port = None if port is None else np.asarray(port, float).reshape(3)
        radius = settings.tip_radius
        if radius is None:
            radius = float(getattr(space, "tip_radius", 0.0) or 0.0)
        self.tip_radius = float(radius)
        self.measurements: list[Measurement] = []
        self.events: list[Event] = []
        self._open: dict[str, _Open] = {}
        self._furthest = 0.0
        self._history: deque[tuple[float, float]] = deque()
        self.reached_goal = False

    # ------------------------------------------------------------------ per sample
    def closest(self, tip: np.ndarray) -> tuple[float, float]:
        """(deviation, progress) of a tip position: the exact closest point on the recommended polyline."""
        deviation, progress, _, _ = self.nearest(tip)
        return deviation, progress

    def nearest(self, tip: np.ndarray) -> tuple[float, float, np.ndarray, tuple[float, float]]:
        """(deviation, progress, the closest point, the offset along the path's two normals there)."""
        rel = tip - self.a
        t = np.einsum("ij,ij->i", rel, self.d)
        t = np.clip(np.divide(t, self.seg_len_sq, out=np.zeros_like(t), where=self.seg_len_sq > 0), 0.0, 1.0)
        diff = rel - t[:, None] * self.d
        dist_sq = np.einsum("ij,ij->i", diff, diff)
        i = int(np.argmin(dist_sq))
        progress = float(self.arc[i] + t[i] * (self.arc[i + 1] - self.arc[i]))
        offset = diff[i]
        lateral = (float(offset @ self.normals[i, 0]), float(offset @ self.normals[i, 1]))
        return math.sqrt(float(dist_sq[i])), progress, tip - offset, lateral

    def measure(self, sample: PoseSample) -> tuple[Measurement, list[tuple[str, Event]]]:
        """Measure one sample and update the events; returns the measurement and the event changes
        (``("start", event)`` / ``("end", event)``) it caused."""
        started = time.perf_counter()
        if sample.q is not None:
            q = np.asarray(sample.q, float)[None]
            tip = self.space.tip(q)[0]
            clearance = float(self.space.clearance(q)[0])
            obstacle = int(self.space.nearest_obstacle(q)[0])
        else:
            tip = np.asarray(sample.tip, float).reshape(3)
            distance, index = self.scene.signed_distance(tip[None])
            clearance = float(distance[0]) - self.tip_radius
            obstacle = int(index[0])
        deviation, progress, closest, lateral = self.nearest(tip)
        critical = any(a <= progress <= b for a, b in self.critical)
        m = Measurement(float(sample.t), tip, deviation, progress, clearance, critical, obstacle, 0.0)
        m.lateral, m.closest = lateral, closest
        if self.port is not None:
            m.insertion = float(np.linalg.norm(tip - self.port))
        changes = self._update_events(m)
        m.latency = time.perf_counter() - started
        self.measurements.append(m)
        return m, changes

    def _conditions(self, m: Measurement) -> dict[str, float | None]:
        """Each event kind's value when its condition holds at this sample, else None."""
        s = self.settings
        out: dict[str, float | None] = dict.fromkeys(EVENT_KINDS)
        if m.clearance <= 0:
            out["contact"] = m.clearance
        if self.threshold > 0 and m.clearance < self.threshold and not m.critical:
            out["below_threshold"] = m.clearance
        if m.deviation > s.deviation_tolerance:
            out["deviation"] = m.deviation
        if m.progress < self._furthest - s.wrong_way:
            out["wrong_way"] = self._furthest - m.progress
        # progress over the last stall_time seconds
        self._history.append((m.t, m.progress))
        while len(self._history) > 1 and self._history[1][0] <= m.t - s.stall_time:
            self._history.popleft()
        t0, p0 = self._history[0]
        if (
            not self.reached_goal
            and out["wrong_way"] is None
            and m.t - t0 >= s.stall_time
            and m.progress - p0 < s.stall_distance
        ):
            out["stalled"] = m.t - t0
        return out

    def _update_events(self, m: Measurement) -> list[tuple[str, Event]]:
        values = self._conditions(m)
        self._furthest = max(self._furthest, m.progress)
        if m.progress >= self.length - self.settings.goal_tolerance and m.deviation <= self.settings.goal_tolerance:
            self.reached_goal = True
        changes = []
        for kind in EVENT_KINDS:
            value = values[kind]
            current = self._open.get(kind)
            if value is not None:
                if current is None:
                    event = Event(kind, m.t, m.t, m.progress, m.progress, value)
                    self._open[kind] = _Open(event, m.t, m.progress)
                    changes.append(("start", event))
                else:
                    current.event.end_t, current.event.end_progress_m = m.t, m.progress
                    current.event.worst = self._worse(kind, current.event.worst, value)
            elif current is not None:
                changes.append(("end", self._close(kind)))
        return changes

    @staticmethod
    def _worse(kind: str, a: float, b: float) -> float:
        return min(a, b) if kind in ("contact", "below_threshold") else max(a, b)

    def _close(self, kind: str) -> Event:
        event = self._open.pop(kind).event
        event.message = self.describe(event)
        self.events.append(event)
        return event

    def describe(self, event: Event) -> str:
        """The event in words, lengths in the guide's unit: what happened, when (s) and where along the path, e.g.
        ``off the recommended path by up to 3.2 mm (tolerance 2 mm), 1.20-2.45 s, 30-42 mm along the path``."""
        k, u = self.k, self.unit
        where = f"{event.start_progress_m * k:.4g}-{event.end_progress_m * k:.4g} {u} along the path"
        span = f"{event.start_t:.2f}-{event.end_t:.2f} s"
        text = {
            "contact": f"contact with an obstacle (clearance down to {event.worst * k:.3g} {u})",
            "below_threshold": f"closer than d_thresh {self.threshold * k:.3g} {u} outside a critical region "
            f"(down to {event.worst * k:.3g} {u})",
            "deviation": f"off the recommended path by up to {event.worst * k:.3g} {u} "
            f"(tolerance {self.settings.deviation_tolerance * k:.3g} {u})",
            "wrong_way": f"going the wrong way, up to {event.worst * k:.3g} {u} back",
            "stalled": f"stalled for {event.worst:.3g} s",
        }[event.kind]
        return f"{text}, {span}, {where}"

    # ------------------------------------------------------------------ the attempt
    def finish(self) -> list[Event]:
        """Close the events still open (the attempt ended inside them); returns all, by start time."""
        for kind in list(self._open):
            self._close(kind)
        self.events.sort(key=lambda e: (e.start_t, EVENT_KINDS.index(e.kind)))
        return self.events

    def samples(self) -> AttemptSamples:
        """The measurements as arrays (what the metrics and the record take)."""
        ms = self.measurements
        return AttemptSamples(
            t=np.array([m.t for m in ms], float),
            tip=np.array([m.tip for m in ms], float).reshape(-1, 3),
            deviation=np.array([m.deviation for m in ms], float),
            progress=np.array([m.progress for m in ms], float),
            clearance=np.array([m.clearance for m in ms], float),
            critical=np.array([m.critical for m in ms], bool),
            lateral=np.array([m.lateral for m in ms], float).reshape(-1, 2),
            insertion=np.array([m.insertion for m in ms], float) if self.port is not None else None,
        )

    @property
    def completion(self) -> float:
        if not self.measurements:
            return 0.0
        if self.reached_goal:
            return 1.0
        return min(1.0, self.measurements[-1].progress / self.length) if self.length > 0 else 0.0

    def metrics(self) -> dict[str, Any]:
        """The attempt report's numbers (SI): the skill metrics and score (``surgiplan.guidance.metrics.assess``), the
        deviation and clearance extremes, the events and the per-sample timing."""
        ms = self.measurements
        if not ms:
            return {"samples": 0}
        samples = self.samples()
        latency = np.array([m.latency for m in ms])
        delay = np.array([m.delay for m in ms])
        assessed = assess(
            samples,
            recommended_length=self.length,
            threshold=self.threshold,
            tolerance=self.settings.deviation_tolerance,
            completion=self.completion,
            settings=self.assessment,
        )
        return {
            "samples": len(ms),
            **assessed,
            "recommended_length_m": self.length,
            "deviation_max_m": float(samples.deviation.max()),
            "deviation_p95_m": float(np.percentile(samples.deviation, 95)),
            "min_clearance_m": float(samples.clearance.min()),
            "d_thresh_m": self.threshold,
            "events": {kind: sum(1 for e in self.events if e.kind == kind) for kind in EVENT_KINDS},
            "progress_m": float(ms[-1].progress),
            "reached_goal": self.reached_goal,
            "latency_median_ms": float(np.median(latency) * 1e3),
            "latency_p99_ms": float(np.percentile(latency, 99) * 1e3),
            "latency_max_ms": float(latency.max() * 1e3),
            "delay_median_ms": float(np.median(delay) * 1e3),
            "delay_p99_ms": float(np.percentile(delay, 99) * 1e3),
        }

    def timeline(self, rate: float) -> dict[str, Any]:
        """The samples, decimated to at most ``rate`` per second, and the events, for result.json."""
        keep: list[Measurement] = []
        for m in self.measurements:
            if not keep or m.t - keep[-1].t >= 1.0 / rate or m is self.measurements[-1]:
                keep.append(m)
        out = {
            "t": [m.t for m in keep],
            "tip": [m.tip.tolist() for m in keep],
            "deviation": [m.deviation for m in keep],
            "clearance": [m.clearance for m in keep],
            "progress": [m.progress for m in keep],
            "events": [{"t": e.start_t, **e.to_json()} for e in self.events],
        }
        if keep and all(m.ghost is not None for m in keep):
            out["ghost"] = [m.ghost.tolist() for m in keep]
        return out


def _transported_normals(d: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Two unit normals (n, 2, 3) of each segment of a polyline, transported from segment to segment without
    twisting (the projection of the previous normal); the first is the one closest to +z (or +x)."""
    n = len(d)
    out = np.zeros((n, 2, 3))
    tangent = np.array([1.0, 0.0, 0.0])
    normal = None
    for i in range(n):
        if length[i] > 0:
            tangent = d[i] / length[i]
        if normal is None:
            normal = np.array([0.0, 0.0, 1.0]) if abs(tangent[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        projected = normal - (normal @ tangent) * tangent
        size = np.linalg.norm(projected)
        if size < 1e-9:  # the path turned onto the normal: start again from an axis
            axis = np.array([0.0, 0.0, 1.0]) if abs(tangent[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
            projected = axis - (axis @ tangent) * tangent
            size = np.linalg.norm(projected)
        normal = projected / size
        out[i, 0] = normal
        out[i, 1] = np.cross(tangent, normal)
    return out


@dataclass
class Attempt:
    """What the ``guide`` stage hands to the report and the record."""

    guide: Guide
    status: str
    message: str = ""
    files: list[str] = field(default_factory=list)
