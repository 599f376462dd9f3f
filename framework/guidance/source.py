"""Pose sources: where a ``guide`` stage gets the instrument's pose, sample by sample.

A source plugin (hook ``surgiplan_register_sources``) subclasses
:class:`PoseSource`. The ``guide`` stage opens it with a :class:`GuideContext`
(the recommended path, its space and scene, the stage context), then reads
:meth:`PoseSource.samples` as they arrive and analyses each at once
(:mod:`surgiplan.guidance.analysis`); it closes the source however the
attempt ends.

A sample carries the instrument's configuration ``q`` in the recommended
path's space when the source knows the whole instrument (the gimbal's
joints: then the whole shaft's clearance is measured), or only the tip
position ``tip`` (a recorded tip trajectory: then the tip's clearance). A
source that stops sending raises :class:`SourceStopped` with the reason; the
stage then ends ``stopped``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from pydantic import BaseModel

from ..clearance import CriticalRegion
from ..errors import SurgiplanError
from ..resources import ResourceEstimate

if TYPE_CHECKING:
    from ..results import StageContext
    from ..scene import Scene
    from ..spaces.base import Space


class SourceStopped(SurgiplanError):
    """The source stopped sending (a lost bus, a silent tracker, an attempt abandoned); the message says why.

    Raised by a source's ``samples()``; the guide stage ends ``stopped`` with the reason."""

    exit_code = 1


@dataclass
class PoseSample:
    """One instrument pose: ``t`` seconds since the attempt started, and ``q`` (a configuration of the
    recommended path's space) or ``tip`` (m)."""

    t: float
    q: np.ndarray | None = None
    tip: np.ndarray | None = None


@dataclass
class GuideContext:
    """What a source gets when the attempt starts."""

    stage: StageContext
    #: the recommended path (configurations of ``space``) and its dense tip positions (m)
    path: np.ndarray
    tips: np.ndarray
    space: Space
    scene: Scene
    #: the clearance threshold d_thresh of the recommended path (m), if it has one
    threshold: float | None
    #: arc-length intervals (m) of the recommended path's critical regions
    critical: list[tuple[float, float]] = field(default_factory=list)
    #: the stage stops the attempt when no sample arrives for this long (s)
    silence_timeout: float = 2.0
    #: the recommended path's critical regions (:class:`~surgiplan.clearance.CriticalRegion`: where it passes
    #: below ``threshold`` because no detour exists), as the plan stage measured them
    critical_regions: list[CriticalRegion] = field(default_factory=list)
    #: whose attempt it is, at which task, and the trainee record it goes to (None: not recorded)
    trainee: str | None = None
    task: str | None = None
    record: Path | None = None


class PoseSource(ABC):
    """Base class of source plugins: a stream of instrument poses for a ``guide`` stage."""

    Settings: ClassVar[type[BaseModel]]

    @classmethod
    def estimate_resources(cls, settings: BaseModel) -> list[ResourceEstimate]:
        """What the source will need, before any work (:mod:`surgiplan.resources`)."""
        return []

    def __init__(self, settings: BaseModel) -> None:
        self.settings = settings
        #: files the source wrote in the output directory (relative names), e.g. a bus trace; the guide stage
        #: lists those that exist once the source is closed
        self.recordings: list[str] = []
        #: how the source assisted the trainee (a haptic device's mode and assistance level), set by the time it
        #: is closed; the guide stage keeps it in the attempt's metrics and record (None: no assistance)
        self.assistance: dict | None = None

    @classmethod
    def check_plan(cls, settings: BaseModel, plan) -> tuple[str, tuple[str, ...]] | None:
        """At validation: why these settings cannot follow the plan stage ``plan`` (its spec), and the settings
        keys at fault; None: they can."""
        return None

    def open(self, context: GuideContext) -> None:
        """Start: connect to the instrument, load the file, start the trainee model."""

    @abstractmethod
    def samples(self) -> Iterator[PoseSample]:
        """The poses, in time order, as they arrive; ends when the attempt ends.

        Raises :class:`SourceStopped` when the source stops sending.
        """

    def close(self) -> None:
        """Release what :meth:`open` acquired (called however the attempt ended)."""
