"""The device interface, shaped after ros2_control's hardware components.

A device turns a planned path into motion: it maps the path through its
kinematic model to a timed joint trajectory, sends it to its drives (over a
simulated or real bus), and reports what actually happened.

Lifecycle (as ros2_control's managed nodes)::

    unconfigured --configure--> inactive --activate--> active
         ^                         |  ^                  |
         +-------cleanup-----------+  +----deactivate----+
    any --error--> error;  any --shutdown--> finalized

Commands (:meth:`Device.execute`) are accepted only when active.
"""

from __future__ import annotations

import enum
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from pydantic import BaseModel

from .clearance import ClearanceThreshold, CriticalRegion
from .errors import SurgiplanError
from .resources import ResourceEstimate

if TYPE_CHECKING:
    from .results import StageContext
    from .spaces.base import Space


class LifecycleState(enum.StrEnum):
    """Where a :class:`Device` is in its lifecycle (ros2_control's managed-node states; see the module's diagram)."""

    UNCONFIGURED = "unconfigured"
    INACTIVE = "inactive"
    ACTIVE = "active"
    FINALIZED = "finalized"
    ERROR = "error"


class LifecycleError(SurgiplanError):
    """A lifecycle transition or command that is not allowed in the current state."""

    exit_code = 1


@dataclass
class Trajectory:
    """What an execute stage hands to a device: the planned path, its space, and what the plan keeps."""

    path: np.ndarray
    space: Space
    #: the stage that planned it
    source: str = ""
    #: the clearance the plan keeps (m; :mod:`surgiplan.clearance`), None when it has none
    clearance_threshold: ClearanceThreshold | None = None
    #: where the plan passes below it because no detour exists (arc lengths along the planned tip path)
    critical_regions: list[CriticalRegion] = field(default_factory=list)


@dataclass
class ExecutionReport:
    """What the device did: an :class:`~surgiplan.status.ExecuteStatus` (``completed``, ``stopped`` with the
    reason, or ``refused`` before any motion); any other value makes the stage ``invalid_result``."""

    status: str
    metrics: dict[str, Any] = field(default_factory=dict)
    #: positions the tip actually reached (n, 3), metres
    executed_tip_path: np.ndarray | None = None
    faults: list[dict[str, Any]] = field(default_factory=list)
    message: str = ""
    #: files the device wrote (figures, logs), relative to the stage context's output directory
    files: list[str] = field(default_factory=list)
    #: the stage's annotations in result.json, e.g. ``timeline`` (see :mod:`surgiplan.outputs.report.timeline`)
    annotations: dict[str, Any] = field(default_factory=dict)
    #: what the framework re-measures (:mod:`surgiplan.verify_motion`): the executed configurations (n, d) in
    #: ``executed_space`` (a space with the device's geometry; default: the plan's), else the executed tip path
    #: as a sphere of ``tip_radius`` (m; default: the r3 plan's tip radius, else 0); ``executed_t``: their times
    executed_path: np.ndarray | None = None
    executed_space: Space | None = None
    executed_t: np.ndarray | None = None
    tip_radius: float | None = None


class Device(ABC):
    """Base class of device plugins; subclasses implement the ``on_*`` transitions and ``run``."""

    Settings: ClassVar[type[BaseModel]]

    _transitions: ClassVar[dict[str, tuple[tuple[LifecycleState, ...], LifecycleState]]] = {
        "configure": ((LifecycleState.UNCONFIGURED,), LifecycleState.INACTIVE),
        "activate": ((LifecycleState.INACTIVE,), LifecycleState.ACTIVE),
        "deactivate": ((LifecycleState.ACTIVE,), LifecycleState.INACTIVE),
        "cleanup": ((LifecycleState.INACTIVE,), LifecycleState.UNCONFIGURED),
        "shutdown": (
            (LifecycleState.UNCONFIGURED, LifecycleState.INACTIVE, LifecycleState.ACTIVE, LifecycleState.ERROR),
            LifecycleState.FINALIZED,
        ),
    }

    @classmethod
    def estimate_resources(cls, settings: BaseModel) -> list[ResourceEstimate]:
        """What a stage with these settings will need, before any work (see :mod:`surgiplan.resources`);
        override it when a setting scales memory. The default estimates nothing."""
        return []

    def __init__(self, settings: BaseModel) -> None:
        self.settings = settings
        self.state = LifecycleState.UNCONFIGURED
        self.context: StageContext | None = None
        #: files the device wrote in the output directory besides its report's (relative names), e.g. a bus
        #: trace written when it releases the bus at shutdown; the execute stage lists those that exist
        self.recordings: list[str] = []

    @property
    def safety_margin(self) -> float:
        """The clearance (m) the device keeps from obstacles: its ``safety_margin`` setting (0 without one). The
        execute stage marks the stage ``unsafe`` when the executed motion, as the framework measures it, comes
        closer (or touches)."""
        return float(getattr(self.settings, "safety_margin", 0.0) or 0.0)

    def _transition(self, name: str, action) -> None:
        allowed, target = self._transitions[name]
        if self.state not in allowed:
            raise LifecycleError(f"cannot {name} a device that is {self.state.value}")
        try:
            action()
        except Exception:
            self.state = LifecycleState.ERROR
            raise
        self.state = target

    def configure(self, context: StageContext) -> None:
        """unconfigured -> inactive: keep ``context`` (output directory, scene) and run :meth:`on_configure`.

        Raises :class:`LifecycleError` from another state; a failing ``on_configure`` leaves the device in
        ``error`` and propagates."""
        self.context = context
        self._transition("configure", lambda: self.on_configure(context))

    def activate(self) -> None:
        """inactive -> active through :meth:`on_activate`; :meth:`execute` is accepted afterwards."""
        self._transition("activate", self.on_activate)

    def deactivate(self) -> None:
        """active -> inactive through :meth:`on_deactivate`."""
        self._transition("deactivate", self.on_deactivate)

    def cleanup(self) -> None:
        """inactive -> unconfigured through :meth:`on_cleanup`."""
        self._transition("cleanup", self.on_cleanup)

    def shutdown(self) -> None:
        """Any state -> finalized through :meth:`on_shutdown`; does nothing when already finalized."""
        if self.state is not LifecycleState.FINALIZED:
            self._transition("shutdown", self.on_shutdown)

    def execute(self, trajectory: Trajectory) -> ExecutionReport:
        """Move along ``trajectory`` (:meth:`run`) and report what happened; :class:`LifecycleError` unless active."""
        if self.state is not LifecycleState.ACTIVE:
            raise LifecycleError(f"a device must be active to execute; it is {self.state.value}")
        return self.run(trajectory)

    # ------------------------------------------------------------------ for subclasses
    def on_configure(self, context: StageContext) -> None:
        """Open the bus, load the kinematic model; states become readable."""

    def on_activate(self) -> None:
        """Enable the drives; commands are accepted afterwards."""

    def on_deactivate(self) -> None:
        """Stop and disable the drives."""

    def on_cleanup(self) -> None:
        """Release what ``on_configure`` acquired."""

    def on_shutdown(self) -> None:
        """Final release of every resource."""

    @abstractmethod
    def run(self, trajectory: Trajectory) -> ExecutionReport:
        """Execute a trajectory; called only when active."""
