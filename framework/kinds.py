"""Stage kinds as plugins: what a ``stage:`` entry of a pipeline can be, and the plugin kinds stages run.

A **stage kind** is a :class:`StageKind` subclass, registered (an instance of it) through the
``surgiplan_register_stage_kinds`` hook, the same entry points as any plugin. The built-in ``plan``,
``simulate``, ``execute`` and ``guide`` kinds (:mod:`surgiplan.stages`) register exactly like a third
party's. A kind is one record that says everything the core needs about it:

* its YAML keys (:attr:`StageKind.model`, a :class:`StageModel` subclass) and the :class:`StageSpec` it
  resolves them into (:meth:`StageKind.resolve` when the plugin is known, :meth:`StageKind.check` once the
  scene and the earlier stages are);
* the plugins it runs (:attr:`StageKind.plugin_kind`, a :class:`PluginKind`: the hook that registers them
  and the interface they subclass), with the hook's specification (:attr:`StageKind.hookspecs`);
* the statuses its plugins may return and the ones that count as success;
* how it runs (:meth:`StageKind.run`, given a :class:`StageRun`), what the summary table says about it
  (:meth:`StageKind.details`) and what the report draws (:meth:`StageKind.report`).

The pipeline loader, the runner, the summary and the report loop over the registered kinds; adding a
kind touches only its own module.
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, Field

from .errors import ConfigError, StageError, SurgiplanError, choices_hint
from .hookspecs import PluginInfo
from .models import StrictModel
from .resources import ResourceEstimate
from .results import StageContext, StageResult
from .scene import Scene
from .status import RunStatus, declare_statuses
from .yamlio import LineMap, format_path, line_of

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- plugin kinds


@dataclass(frozen=True)
class PluginKind:
    """A kind of plugin: its name (``planner``), the hook that registers its plugins and the interface
    every one of them subclasses."""

    name: str
    hook: str
    interface: type

    @property
    def label(self) -> str:
        return self.name.replace("_", " ")


# ----------------------------------------------------------------------------- what a stage is, in a file


class StageModel(StrictModel):
    """The keys every stage has; a kind's :attr:`StageKind.model` adds its own."""

    stage: str = Field(min_length=1)
    plugin: str | None = Field(default=None, min_length=1)
    name: str | None = Field(default=None, min_length=1)
    settings: dict[str, Any] = Field(default_factory=dict)


@dataclass
class StageSpec:
    """A validated stage, ready to run. A kind with keys of its own subclasses it (:attr:`StageKind.spec_type`)."""

    index: int
    kind: str
    name: str
    plugin: PluginInfo | None
    settings: BaseModel | None
    location: str
    scene: Scene
    #: the stage's entry as validated (the kind's :attr:`~StageKind.model`)
    keys: StageModel | None = field(default=None, repr=False)


@dataclass
class FileContext:
    """What resolving a stage's keys may use: its file (for messages with lines), the validation context,
    the registry (spaces and other plugins by name), the scene (None when it has errors of its own), the
    earlier stages, and where warnings go (deprecated spellings: reported, not refused)."""

    file: Path
    lines: LineMap
    validation: dict[str, Any]
    registry: Any
    scene: Scene | None
    earlier: list[StageSpec] = field(default_factory=list)
    warnings: list[ConfigError] = field(default_factory=list)

    def error(self, message: str, *path: Any, error: type[SurgiplanError] = ConfigError) -> SurgiplanError:
        """An error at ``path`` (YAML keys from the file's root) with its line."""
        return error(message, file=self.file, location=format_path(path), line=line_of(self.lines, path))

    def warn(self, message: str, *path: Any) -> None:
        """A warning at ``path``: ``surgiplan validate`` and ``run`` print it with the file and line."""
        self.warnings.append(
            ConfigError(message, file=self.file, location=format_path(path), line=line_of(self.lines, path))
        )


# ----------------------------------------------------------------------------- a run


@dataclass
class RunState:
    """What a run knows as it goes: the stages so far, and what kinds keep across stages."""

    pipeline_name: str
    output_dir: Path
    #: the trainee record guide stages write to (relative to the current directory)
    record: Path
    length_unit: str
    unit_scale: float
    figures: bool = True
    #: earlier stages, by name
    results: dict[str, StageResult] = field(default_factory=dict)
    specs: dict[str, StageSpec] = field(default_factory=dict)
    #: anything a kind keeps across its stages (the plan kind's views for overview.png), by kind name
    kept: dict[str, Any] = field(default_factory=dict)


@dataclass
class StageRun:
    """What :meth:`StageKind.run` gets: its stage, the context its plugin gets, and the run so far."""

    spec: StageSpec
    context: StageContext
    state: RunState

    def call(self, what: str, fn, *args, **kwargs):
        """Call into the stage's plugin; a crash becomes a :class:`~surgiplan.errors.StageError` naming the stage,
        the plugin and its package (a :class:`~surgiplan.errors.SurgiplanError` it raises keeps its message, located
        at the stage)."""
        spec = self.spec
        try:
            return fn(*args, **kwargs)
        except SurgiplanError as exc:
            if exc.location is None:  # say which stage it came from (e.g. a device's bus error)
                exc.location = f"{spec.location} ({spec.kind} stage '{spec.name}')"
            raise
        except Exception as exc:
            raise StageError(
                f"plugin '{spec.plugin.name}' ({spec.plugin.package} {spec.plugin.version}) failed in {what} of "
                f"{spec.kind} stage '{spec.name}': {type(exc).__name__}: {exc}",
                location=spec.location,
            ) from exc

    def recordings(self, plugin: Any, warnings: list[str]) -> list[str]:
        """The files a plugin says it wrote besides its result (its ``recordings``: names relative to the output
        directory), checked: a name that is not a plain relative name, or a file that does not exist, is left out
        with a warning in ``warnings``."""
        names = getattr(plugin, "recordings", None) or []
        if not isinstance(names, list | tuple):
            warnings.append(f"plugin '{self.spec.plugin.name}' gave recordings as a {type(names).__name__}")
            return []
        out = Path(self.context.output_dir)
        kept = []
        for name in names:
            ok = isinstance(name, str) and name and not Path(name).is_absolute() and ".." not in Path(name).parts
            if not ok or not (out / name).is_file():
                warnings.append(f"plugin '{self.spec.plugin.name}' listed a recording that is not a file: {name!r}")
            elif name not in kept:
                kept.append(name)
        return kept

    def result(self, status: str, **fields: Any) -> StageResult:
        """A :class:`~surgiplan.results.StageResult` of this stage."""
        spec = self.spec
        return StageResult(spec.kind, spec.name, spec.plugin.name if spec.plugin else "", str(status), **fields)

    def invalid(self, problem: str) -> StageResult:
        """The stage a refused plugin answer becomes: ``invalid_result``, naming the plugin and its package."""
        spec = self.spec
        return self.result(
            RunStatus.INVALID_RESULT.value,
            message=f"{spec.kind} plugin '{spec.plugin.name}' ({spec.plugin.package} {spec.plugin.version}) "
            f"returned an invalid result: {problem}",
        )

    def skipped(self, message: str) -> StageResult:
        """The stage's result as ``skipped``, ``message`` saying why (e.g. the stage it needs did not succeed)."""
        return self.result(RunStatus.SKIPPED.value, message=message)


# ----------------------------------------------------------------------------- the record of a kind


@dataclass
class ReportInput:
    """What :meth:`StageKind.report` may read: the run's output directory and record, the pipeline's stages
    (when the run is at hand; ``specs`` is empty for a report rebuilt from ``result.json``) and its scene."""

    out: Path
    entries: Mapping[str, Mapping[str, Any]]
    specs: Mapping[str, StageSpec]
    scene: Scene | None
    #: what could not be shown, and why (``notes.add(text)``; listed in the report)
    notes: Any


class StageKind:
    """Base of stage kinds. Subclasses set the class attributes and implement :meth:`run`."""

    #: what ``stage:`` says
    name: ClassVar[str]
    #: one line for ``surgiplan plugins``
    description: ClassVar[str] = ""
    #: the stage's YAML keys
    model: ClassVar[type[StageModel]] = StageModel
    #: what :meth:`resolve` fills
    spec_type: ClassVar[type[StageSpec]] = StageSpec
    #: the plugins ``plugin:`` names (None: the kind has no plugins, and ``plugin:`` is refused)
    plugin_kind: ClassVar[PluginKind | None] = None
    #: the hook specification of :attr:`plugin_kind` (a class or module with a ``@hookspec`` function), added
    #: to the plugin manager when the kind registers
    hookspecs: ClassVar[Any] = None
    #: what its plugins (or its run) may return, and which of those count as success
    statuses: ClassVar[type[enum.Enum] | None] = None
    succeeded: ClassVar[frozenset[str]] = frozenset()
    #: the report draws the stage's motion over time (execute and guide stages)
    timed: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if isinstance(cls.__dict__.get("name"), str):  # a concrete kind: its success statuses, for StageResult
            declare_statuses(cls.name, cls.succeeded, replace=False)

    # ------------------------------------------------------------------ validation
    def plugin_statuses(self) -> frozenset[str]:
        """The values of :attr:`statuses`: what the kind's stages may report besides the framework's own
        (:class:`~surgiplan.status.RunStatus`); the runner makes any other status ``invalid_result``."""
        return frozenset(s.value for s in self.statuses) if self.statuses is not None else frozenset()

    def resolve(self, spec: StageSpec, files: FileContext) -> None:
        """Pass 2: fill ``spec`` from its keys (``spec.keys``), once its plugin and settings are validated.
        Raise :class:`~surgiplan.errors.ConfigError` (or ``ConfigErrors``) naming the key."""

    def check(self, spec: StageSpec, files: FileContext) -> None:
        """Pass 3, with the scene built and the earlier stages resolved (``files.earlier``): what needs them
        (starts and goals inside the bounds and free, the plan stage a path comes from)."""

    def estimate_resources(self, spec: StageSpec) -> list[ResourceEstimate]:
        """Pass 4: what the stage will need, before any work; by default its plugin's estimate."""
        if spec.plugin is None:
            return []
        return list(spec.plugin.cls.estimate_resources(spec.settings) or [])

    # ------------------------------------------------------------------ running
    def run(self, run: StageRun) -> StageResult:
        """Run one stage of the kind and return its :class:`~surgiplan.results.StageResult` (made by
        :meth:`StageRun.result`; plugin calls go through :meth:`StageRun.call`, which names the stage when they fail).
        Subclasses implement it; the runner checks what it returns."""
        raise NotImplementedError

    def finish(self, state: RunState) -> list[str]:
        """After every stage ran: files the kind writes about the whole run (relative to the output directory)."""
        return []

    def markers(self, spec: StageSpec, result: StageResult) -> list[tuple[str, np.ndarray]]:
        """Labelled points (m) the run's scene.glb shows for this stage (a plan stage's start and goal)."""
        return []

    # ------------------------------------------------------------------ presenting
    def details(self, result: StageResult, k: float, unit: str) -> list[str]:
        """What matters about a stage in the summary table (plain text, lengths times ``k`` in ``unit``)."""
        return []

    def report(self, stage: dict[str, Any], entry: Mapping[str, Any], inputs: ReportInput) -> None:
        """Add what the report draws for this stage to ``stage`` (see :mod:`surgiplan.outputs.report.data`):
        ``path``, ``critical``, ``start``/``goal``, ``roadmap``, ``mesh``, ``timeline``, ``reference``."""


# ----------------------------------------------------------------------------- stages that take a planned path


class PathStageModel(StageModel):
    """The keys of a stage that works on an earlier plan stage's path (execute, guide, a third party's export)."""

    #: the plan stage whose path the stage takes; default: the last plan stage before it
    path_from: str | None = Field(default=None, min_length=1)


@dataclass
class PathStageSpec(StageSpec):
    """A resolved stage that takes a plan stage's path: ``path_from`` names that stage (see
    :func:`resolve_path_from`)."""

    path_from: str | None = None


def resolve_path_from(spec: PathStageSpec, files: FileContext, purpose: str) -> None:
    """Set ``spec.path_from`` to the plan stage it names, or the last plan stage before it; ``purpose`` ends
    the message when there is none ("whose path it executes")."""
    earlier = [s for s in files.earlier if s.index < spec.index and s.kind == "plan"]
    named = spec.keys.path_from if spec.keys is not None else spec.path_from
    if named is None:
        if not earlier:
            article = "an" if spec.kind[:1] in "aeiou" else "a"
            raise files.error(
                f"{article} {spec.kind} stage needs an earlier plan stage {purpose}", "pipeline", spec.index
            )
        spec.path_from = earlier[-1].name
    elif named not in {s.name for s in earlier}:
        raise files.error(
            f"no earlier plan stage named '{named}'; {choices_hint(named, [s.name for s in earlier])}",
            "pipeline",
            spec.index,
            "path_from",
        )
    else:
        spec.path_from = named


def planned(run: StageRun, minimum: int = 1) -> tuple[StageSpec, StageResult] | StageResult:
    """The plan stage ``run.spec.path_from`` and its result; or, when it has no path (of at least ``minimum``
    waypoints), the ``skipped`` result this stage ends with."""
    name = run.spec.path_from
    spec, result = run.state.specs[name], run.state.results[name]
    if not result.succeeded or result.path is None or len(result.path) < minimum:
        return run.skipped(f"plan stage '{result.name}' ended '{result.status}' without a path")
    return spec, result
