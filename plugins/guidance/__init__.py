"""Pose sources for the ``guide`` stage (trainee guidance, paper 000's training loop).

* ``recorded_attempt`` (:mod:`.recorded`): replays a recorded attempt from a
  CSV file (time and tip position, or the CAST gimbal's joints), in real time
  or as fast as it can;
* ``synthetic_trainee`` (:mod:`.synthetic`): a seeded synthetic trainee that
  follows the recommended path with proficiency-dependent deviation,
  hesitation and speed (:mod:`surgiplan.guidance.trainee`).

The CAST gimbal itself is a source too, in observe mode: registered by
:mod:`surgiplan.plugins.devices.cast_gimbal`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from surgiplan.hookspecs import PluginSpec, hookimpl
from surgiplan.lazy import lazy_exports

if TYPE_CHECKING:
    from .recorded import RecordedAttempt, RecordedAttemptSettings
    from .synthetic import SyntheticTrainee

__getattr__, __dir__ = lazy_exports(
    __name__,
    {"RecordedAttempt": ".recorded", "RecordedAttemptSettings": ".recorded", "SyntheticTrainee": ".synthetic"},
)

__all__ = ["RecordedAttempt", "RecordedAttemptSettings", "SyntheticTrainee"]


@hookimpl
def surgiplan_register_sources():
    return [
        PluginSpec(
            "recorded_attempt",
            "surgiplan.plugins.guidance.recorded:RecordedAttempt",
            "replays a recorded attempt: time and tip position or gimbal joints",
        ),
        PluginSpec(
            "synthetic_trainee",
            "surgiplan.plugins.guidance.synthetic:SyntheticTrainee",
            "a seeded synthetic trainee following the recommended path (expert, intermediate, beginner)",
        ),
    ]
