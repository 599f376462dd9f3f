"""What stages receive and return: :class:`StageContext` and :class:`StageResult`.

Each entry of ``result.json`` is a :class:`StageResult` in SI units::

    {"stage": "plan", "name": "intermediate", "plugin": "safe_prm",
     "status": "solved", "path": [[x, y, z], ...], "metrics": {...}}
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .clearance import ClearanceThreshold, CriticalRegion
from .executors import Executor, InlineExecutor
from .live import LiveFeed
from .progress import NullProgress, Progress
from .scene import Scene
from .status import succeeded as status_succeeded
from .storage import to_jsonable


@dataclass
class StageContext:
    """Everything a stage plugin may use besides its settings."""

    name: str
    scene: Scene
    output_dir: Path
    #: directory of the pipeline file (relative input paths resolve against it)
    base_dir: Path
    executor: Executor = field(default_factory=InlineExecutor)
    progress: Progress = field(default_factory=NullProgress)
    #: earlier stages' results, by stage name
    previous: dict[str, StageResult] = field(default_factory=dict)
    #: where long work may checkpoint (resumable)
    workdir: Path | None = None
    #: the pipeline's length unit (for messages and figures; everything passed around is SI)
    length_unit: str = "m"
    #: where a running stage publishes what it does, for a live viewer (:mod:`surgiplan.live`)
    live: LiveFeed = field(default_factory=LiveFeed)


@dataclass
class StageResult:
    """What one stage produced, as ``result.json`` records it: its kind (``stage``), ``name``, ``plugin`` and
    ``status`` (whether that counts as success depends on the kind: :attr:`succeeded`), the ``path`` it planned or
    took (configurations, SI), its ``metrics``, a ``message`` and the ``annotations`` its plugin added."""

    stage: str
    name: str
    plugin: str
    status: str
    path: np.ndarray | None = None
    metrics: dict[str, Any] = field(default_factory=dict)
    message: str = ""
    #: files the stage wrote, relative to the output directory
    files: list[str] = field(default_factory=list)
    #: the tip trajectory (n, 3) for figures, when the path is not in R3
    tip_path: np.ndarray | None = None
    #: the space the path is in (kind), for readers of result.json
    space: str | None = None
    #: the clearance the stage's path keeps or is judged against (m), as resolved for its plan stage
    clearance_threshold: ClearanceThreshold | float | None = None
    #: the stretches of the path below that threshold where no detour exists, measured by the framework
    #: (written as ``annotations.critical_regions``)
    critical_regions: list[CriticalRegion] = field(default_factory=list)
    annotations: dict[str, Any] = field(default_factory=dict)
    #: what the framework wants a reader to know that does not change the status (shown by the summary and
    #: the report), e.g. a device that reported no executed motion
    warnings: list[str] = field(default_factory=list)
    #: the distribution and version of the plugin that ran the stage (set by the runner)
    package: str = ""
    version: str = ""

    @property
    def succeeded(self) -> bool:
        return status_succeeded(self.stage, self.status)

    def to_json(self) -> dict[str, Any]:
        """The stage's entry of ``result.json`` (JSON types only; optional keys left out when empty)."""
        entry: dict[str, Any] = {
            "stage": self.stage,
            "name": self.name,
            "plugin": self.plugin,
            "status": self.status,
            **({"package": self.package, "version": self.version} if self.package else {}),
            "path": [] if self.path is None else np.asarray(self.path).tolist(),
            "metrics": to_jsonable(self.metrics),
        }
        if self.space:
            entry["space"] = self.space
        if self.tip_path is not None and self.space not in (None, "r3"):
            entry["tip_path"] = np.asarray(self.tip_path).tolist()
        if self.message:
            entry["message"] = self.message
        if self.warnings:
            entry["warnings"] = list(self.warnings)
        if self.files:
            entry["files"] = list(self.files)
        if self.clearance_threshold is not None:
            threshold = {"value_m": float(self.clearance_threshold)}
            source = getattr(self.clearance_threshold, "source", "")
            entry["clearance_threshold"] = {**threshold, "source": source} if source else threshold
        annotations = dict(self.annotations)
        if self.critical_regions:
            annotations["critical_regions"] = [r.to_json() for r in self.critical_regions]
        if annotations:
            entry["annotations"] = to_jsonable(annotations)
        return entry
