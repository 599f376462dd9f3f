"""A hostile third-party plugin package for the trust-boundary tests (not installed: the tests put it on
``sys.path`` with a ``.dist-info`` of their own, as ``pip install`` would).

* planner ``hostile``: returns each kind of bad answer (``settings.mode``) — a waypoint 5 mm inside a
  block, a straight line through blocks, wrong endpoints, a waypoint 10 m out of bounds, NaN, the
  wrong dimension, a single waypoint, not a PlanResult, an unknown status — or raises, or ``hang``s
  in tasks on the run's executor (to kill the run);
* device ``hostile_device``: reports status ``done`` (not an execute status) or raises;
* deformable model ``hostile_model``: a simulate stage with status ``ok`` or one that raises.
"""

from __future__ import annotations

import time
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict
from surgiplan import (
    DeformableModel,
    Device,
    ExecutionReport,
    Planner,
    PlanResult,
    PlanStatus,
    PluginSpec,
    PoseSample,
    PoseSource,
    SourceStopped,
    StageResult,
    hookimpl,
    run_tasks,
)

MODES = (
    "collide_waypoint",
    "through_blocks",
    "wrong_start",
    "wrong_goal",
    "out_of_bounds",
    "nan",
    "wrong_dimension",
    "single_waypoint",
    "not_a_result",
    "bad_status",
    "raises",
    "hang",
    "honest",
)


class HostileSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")
    mode: Literal[MODES] = "collide_waypoint"
    tasks: int = 4


def _sleep(seconds: float) -> dict:
    time.sleep(seconds)
    return {"slept": seconds}


class HostilePlanner(Planner):
    Settings = HostileSettings

    def build(self, problem):
        if self.settings.mode == "hang":  # long tasks on the run's executor, to be killed
            run_tasks(problem.executor, _sleep, {f"t{i}": 120.0 for i in range(self.settings.tasks)})
        return problem.space

    def query(self, space, start, goal):
        mode = self.settings.mode
        if mode == "raises":
            raise RuntimeError("the hostile planner fails on purpose")
        if mode == "not_a_result":
            return {"path": [start, goal]}
        if mode == "bad_status":
            return PlanResult("done", np.stack([start, goal]))
        path = {
            "collide_waypoint": lambda: np.stack([start, [0.040, 0.042, 0.020], goal]),  # 5 mm inside A1
            "through_blocks": lambda: np.stack([start, goal]),
            "wrong_start": lambda: np.stack([np.add(start, [0.0, 0.002, 0.0]), goal]),
            "wrong_goal": lambda: np.stack([start, np.add(goal, [0.0, 0.002, 0.0])]),
            "out_of_bounds": lambda: np.stack([start, [0.075, 0.05, 10.02], goal]),  # 10 m above the box
            "nan": lambda: np.stack([start, [np.nan, 0.05, 0.02], goal]),
            "wrong_dimension": lambda: np.stack([start, goal])[:, :2],
            "single_waypoint": lambda: start[None],
            "honest": lambda: np.stack([start, goal]),
        }[mode]()
        return PlanResult(PlanStatus.SOLVED, path, {"min_clearance_m": 0.5}, clearance_threshold=0.0)


class DeviceSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")
    mode: Literal["done", "raises", "swings", "lies", "silent", "grazes"] = "done"
    safety_margin: float = 0.0


class HostileDevice(Device):
    """Unknown status, a crash, or a motion that is not the plan: it swings 19 mm off the plan through a block,
    it reports the plan while it scraped 4.8 mm into one (and claims 5 mm of clearance), it reports no motion
    at all, or it passes inside its own safety margin."""

    Settings = DeviceSettings
    moved = False

    def run(self, trajectory):
        mode = self.settings.mode
        if mode == "raises":
            raise ValueError("the hostile device fails on purpose")
        tips = trajectory.space.tip(trajectory.path)
        if mode == "done":
            return ExecutionReport("done", executed_tip_path=tips)
        if mode == "silent":
            return ExecutionReport("completed", {"executed_min_clearance_m": 0.005})
        t = np.linspace(0.0, 2.0, 201)
        line = tips[0] + np.outer(t / 2.0, tips[-1] - tips[0])  # the plan of the tests: one straight segment
        if mode == "swings":  # joint-space-like interpolation: the middle of the motion bulges 19 mm sideways
            line[:, 1] += 0.019 * np.sin(np.pi * t / 2.0)
        elif mode == "lies":  # 4.8 mm into A1 (y 47 mm) half-way through the A gap, and says it kept 5 mm
            line[:, 1] -= np.where(np.abs(line[:, 0] - 0.040) < 0.004, 0.0078, 0.0)
        timeline = {"t": t.tolist(), "tip": line.tolist()}
        return ExecutionReport(
            "completed", {"executed_min_clearance_m": 0.005}, executed_tip_path=line, annotations={"timeline": timeline}
        )


class ModelSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")
    mode: Literal["ok", "raises"] = "ok"


class HostileModel(DeformableModel):
    Settings = ModelSettings
    rest_nodes = elements = None

    def solve(self, constraints, initial=None):
        raise NotImplementedError

    def run_stage(self, context):
        if self.settings.mode == "raises":
            raise ZeroDivisionError("the hostile model fails on purpose")
        return StageResult("simulate", context.name, "hostile_model", "ok")


@hookimpl
def surgiplan_register_planners():
    return [PluginSpec("hostile", HostilePlanner, "returns bad paths on purpose (tests)")]


@hookimpl
def surgiplan_register_devices():
    return [PluginSpec("hostile_device", HostileDevice, "reports an unknown status on purpose (tests)")]


@hookimpl
def surgiplan_register_deformable_models():
    return [PluginSpec("hostile_model", HostileModel, "reports an unknown status on purpose (tests)")]


class SourceSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")
    mode: Literal["silent", "stops", "backwards", "outside", "nan"] = "silent"


class HostileSource(PoseSource):
    """Three samples along the path, then: silence (for 30 s), SourceStopped, or a sample back in time."""

    Settings = SourceSettings

    def open(self, context):
        self.tips = context.tips

    def samples(self):
        for i in range(3):
            yield PoseSample(0.1 * i, tip=self.tips[i])
        if self.settings.mode == "silent":
            time.sleep(30)  # the stage's silence_timeout ends the attempt long before
        elif self.settings.mode == "stops":
            raise SourceStopped("the tracker lost the instrument")
        elif self.settings.mode == "outside":  # 460 mm above the box
            yield PoseSample(0.3, tip=self.tips[3] + [0.0, 0.0, 0.46])
        elif self.settings.mode == "nan":
            yield PoseSample(0.3, tip=[np.nan, 0.05, 0.02])
        else:
            yield PoseSample(0.05, tip=self.tips[3])


@hookimpl
def surgiplan_register_sources():
    return [PluginSpec("hostile_source", HostileSource, "goes silent, stops, or goes back in time (tests)")]
