"""surgiplan: plugin-based planning for surgical training and robot-assisted surgery.

The public API for plugin authors and library users::

    from surgiplan import Planner, PlanResult, PlanStatus, PluginSpec, hookimpl, Length
    from surgiplan import load_pipeline, run_pipeline, load_scene, Scene
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("surgiplan")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

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
