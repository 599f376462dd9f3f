"""surgiplan: plugin-based planning for surgical training and robot-assisted surgery.

The public API for plugin authors and library users::

    from surgiplan import Planner, PlanResult, PlanStatus, PluginSpec, hookimpl, Length
    from surgiplan import load_pipeline, run_pipeline, load_scene, Scene

Every public name is imported at first use (PEP 562 ``__getattr__``): ``import surgiplan`` and the command
line's ``--help`` load no scientific library; the module that defines a name (and what it needs) loads when
the name is first read. Type checkers and the API reference see the names through the ``TYPE_CHECKING``
imports below.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .lazy import lazy_exports

if TYPE_CHECKING:
    from .deformable import Constraints, DeformableModel, EquilibriumState
    from .devices import Device, ExecutionReport, LifecycleState, Trajectory
    from .errors import (
        ConfigError,
        PlanningInputError,
        PluginError,
        SceneError,
        SurgiplanError,
    )
    from .executors import DaskExecutor, Executor, InlineExecutor, LocalExecutor, TaskStore, run_tasks
    from .guidance import GuideContext, PoseSample, PoseSource, SourceStopped
    from .hookspecs import PluginSpec, hookimpl
    from .models import StrictModel
    from .pipeline import load_pipeline, load_scene
    from .planning import Planner, PlanningProblem, PlanResult
    from .progress import NullProgress, Progress
    from .resources import ResourceEstimate
    from .results import StageContext, StageResult
    from .runner import run_pipeline
    from .scene import Scene
    from .spaces import CastGimbalSpace, R3Space, SE3Space, Space
    from .status import ExecuteStatus, GuideStatus, PlanStatus, RunStatus, SimulateStatus
    from .units import Angle, Coordinate, Length, PositiveLength, SignedLength, Vec3
    from .validation import file_length_scale, input_path

#: each public name and the submodule that defines it (imported at first use)
_LAZY = {
    "Angle": ".units",
    "CastGimbalSpace": ".spaces",
    "ConfigError": ".errors",
    "Constraints": ".deformable",
    "Coordinate": ".units",
    "DaskExecutor": ".executors",
    "DeformableModel": ".deformable",
    "Device": ".devices",
    "EquilibriumState": ".deformable",
    "ExecuteStatus": ".status",
    "ExecutionReport": ".devices",
    "Executor": ".executors",
    "GuideContext": ".guidance",
    "GuideStatus": ".status",
    "InlineExecutor": ".executors",
    "Length": ".units",
    "LifecycleState": ".devices",
    "LocalExecutor": ".executors",
    "NullProgress": ".progress",
    "PlanResult": ".planning",
    "PlanStatus": ".status",
    "Planner": ".planning",
    "PlanningInputError": ".errors",
    "PlanningProblem": ".planning",
    "PluginError": ".errors",
    "PluginSpec": ".hookspecs",
    "PoseSample": ".guidance",
    "PoseSource": ".guidance",
    "PositiveLength": ".units",
    "Progress": ".progress",
    "R3Space": ".spaces",
    "ResourceEstimate": ".resources",
    "RunStatus": ".status",
    "SE3Space": ".spaces",
    "Scene": ".scene",
    "SceneError": ".errors",
    "SignedLength": ".units",
    "SimulateStatus": ".status",
    "SourceStopped": ".guidance",
    "Space": ".spaces",
    "StageContext": ".results",
    "StageResult": ".results",
    "StrictModel": ".models",
    "SurgiplanError": ".errors",
    "TaskStore": ".executors",
    "Trajectory": ".devices",
    "Vec3": ".units",
    "file_length_scale": ".validation",
    "hookimpl": ".hookspecs",
    "input_path": ".validation",
    "load_pipeline": ".pipeline",
    "load_scene": ".pipeline",
    "run_pipeline": ".runner",
    "run_tasks": ".executors",
}


_lazy_getattr, __dir__ = lazy_exports(__name__, _LAZY)


def __getattr__(name: str):
    """Import the submodule that defines a public name at its first use and keep the name here."""
    if name == "__version__":  # reading the installed distribution's metadata costs a tenth of a second
        globals()[name] = value = _installed_version()
        return value
    return _lazy_getattr(name)


def _installed_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("surgiplan")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "0.0.0+unknown"


__all__ = [
    "Angle",
    "CastGimbalSpace",
    "ConfigError",
    "Constraints",
    "Coordinate",
    "DaskExecutor",
    "DeformableModel",
    "Device",
    "EquilibriumState",
    "ExecuteStatus",
    "ExecutionReport",
    "Executor",
    "GuideContext",
    "GuideStatus",
    "InlineExecutor",
    "Length",
    "LifecycleState",
    "LocalExecutor",
    "NullProgress",
    "PlanResult",
    "PlanStatus",
    "Planner",
    "PlanningInputError",
    "PlanningProblem",
    "PluginError",
    "PluginSpec",
    "PoseSample",
    "PoseSource",
    "PositiveLength",
    "Progress",
    "R3Space",
    "ResourceEstimate",
    "RunStatus",
    "SE3Space",
    "Scene",
    "SceneError",
    "SignedLength",
    "SimulateStatus",
    "SourceStopped",
    "Space",
    "StageContext",
    "StageResult",
    "StrictModel",
    "SurgiplanError",
    "TaskStore",
    "Trajectory",
    "Vec3",
    "file_length_scale",
    "hookimpl",
    "input_path",
    "load_pipeline",
    "load_scene",
    "run_pipeline",
    "run_tasks",
]
