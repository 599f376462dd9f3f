"""The ``point_robot`` device (an example device plugin): a simulated 3-axis gantry.

It moves its tool (a sphere of ``tool_radius``) along the planned tip path at
``speed``; each axis follows its command with a first-order lag of time
constant ``lag`` (the closed form of its steady tracking error on a straight
stretch is ``speed * lag``). Before any motion it refuses, with status
``refused``, a path whose tool would come closer than ``safety_margin`` to
an obstacle anywhere along it (exact capsule clearances), whatever planner
produced it. It reports the executed tip path, the tracking error and the
executed clearance re-measured on the scene.

With ``realtime: true`` the motion takes as long as it would on the gantry
(each sample waits for its time), and each sample is published on the
stage's live feed (``context.live``: ``surgiplan run --live`` and
``surgiplan view --live``) as it happens. The samples are also returned as
the stage's ``timeline`` annotation (time, executed and commanded tip,
clearance, deviation from the command, events), which ``report.html`` plays
back with a time slider.

A device implements the lifecycle transitions it needs (``on_configure``,
``on_activate``, ...; all optional) and ``run``.
"""

from __future__ import annotations

import time

import numpy as np
from pydantic import PositiveFloat
from surgiplan import Device, ExecuteStatus, ExecutionReport, Length, PositiveLength
from surgiplan.models import StrictModel


class PointRobotSettings(StrictModel):
    speed: PositiveLength = 0.02  # m/s
    lag: PositiveFloat = 0.05  # s
    rate: PositiveFloat = 200.0  # Hz
    tool_radius: Length = 0.0
    safety_margin: Length = 0.0
    realtime: bool = False  # take as long as the motion does, publishing each sample as it happens


class PointRobot(Device):
    Settings = PointRobotSettings

    def on_configure(self, context) -> None:
        self.scene = context.scene
        self.live = context.live
        self.stage = context.name

    def run(self, trajectory) -> ExecutionReport:
        s = self.settings
        tips = trajectory.space.tip(trajectory.path)
        clearance = self.scene.motion_clearance(tips[:-1], tips[1:], s.tool_radius)
        worst = int(np.argmin(clearance))
        if clearance[worst] < s.safety_margin:
            return ExecutionReport(
                ExecuteStatus.REFUSED,
                {"planned_min_clearance_m": float(clearance[worst])},
                message=f"refused before any motion: segment {worst} of the path comes within "
                f"{clearance[worst] * 1000:.3g} mm of an obstacle; the safety margin is "
                f"{s.safety_margin * 1000:.3g} mm",
            )
        # the command: the tip path at constant speed, sampled at the control rate
        steps = np.linalg.norm(np.diff(tips, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(steps)])
        duration = arc[-1] / s.speed
        t = np.arange(0.0, duration + 5 * s.lag, 1.0 / s.rate)
        along = np.clip(t * s.speed, 0.0, arc[-1])
        command = np.column_stack([np.interp(along, arc, tips[:, k]) for k in range(3)])
        # each axis: x' = (command - x) / lag, integrated exactly for a command held over each period
        decay = np.exp(-1.0 / (s.rate * s.lag))
        executed = np.empty_like(command)
        executed[0] = command[0]
        for i in range(1, len(command)):
            executed[i] = command[i - 1] + (executed[i - 1] - command[i - 1]) * decay
        error = np.linalg.norm(executed - command, axis=1)
        flown = self.scene.motion_clearance(executed[:-1], executed[1:], s.tool_radius)
        at = self.scene.clearance(executed, s.tool_radius)
        closest = int(np.argmin(at))
        events = [
            {"t": 0.0, "kind": "start", "message": f"{len(t)} samples at {s.rate:g} Hz"},
            {"t": float(t[closest]), "kind": "closest_approach", "message": f"{at[closest] * 1000:.3g} mm"},
            {"t": float(duration), "kind": "command_end", "message": "the command reached the goal"},
        ]
        events.sort(key=lambda e: e["t"])
        late = self._play(trajectory, tips, t, command, executed, at, error, events)
        metrics = {
            "duration_s": float(t[-1]),
            "tracking_error_max_m": float(error.max()),
            "tracking_error_rms_m": float(np.sqrt(np.mean(error**2))),
            "executed_min_clearance_m": float(flown.min()),
            "planned_min_clearance_m": float(clearance.min()),
            "samples": len(t),
        }
        if s.realtime:
            metrics["realtime_late_max_s"] = float(late.max(initial=0.0))  # how far behind its time a sample was
            metrics["realtime_late_samples"] = int(np.count_nonzero(late > 1.0 / s.rate))
        timeline = {
            "t": t,
            "tip": executed,
            "commanded": command,
            "clearance": at,
            "deviation": error,
            "events": events,
        }
        return ExecutionReport(
            ExecuteStatus.COMPLETED, metrics, executed_tip_path=executed, annotations={"timeline": timeline}
        )

    def _play(self, trajectory, tips, t, command, executed, clearance, error, events) -> np.ndarray:
        """Publish the motion on the live feed (at the pace of its clock when ``realtime``); the lateness
        of each sample (s)."""
        live, realtime = self.live, self.settings.realtime
        late = np.zeros(len(t))
        if not (live.active or realtime):
            return late
        if live.active:
            stage = {"name": self.stage, "kind": "execute", "plugin": "point_robot", "path_from": trajectory.source}
            live.publish("stage", {**stage, "recommended": tips.tolist()})
        pending = list(events)
        start = time.perf_counter()
        for i in range(len(t)):
            if realtime:
                wait = start + t[i] - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
                late[i] = max(0.0, -wait)
            if live.active:
                sample = {"t": float(t[i]), "tip": executed[i].tolist(), "commanded": command[i].tolist()}
                live.publish("tip", {**sample, "clearance": float(clearance[i]), "deviation": float(error[i])})
                while pending and pending[0]["t"] <= t[i]:
                    live.publish("event", pending.pop(0))
        if live.active:
            live.publish("status", {"status": "completed"})
        return late
