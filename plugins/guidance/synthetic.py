"""``synthetic_trainee``: a seeded synthetic trainee following the recommended path.

The model and its documented parameters are :mod:`surgiplan.guidance.trainee`
(``level: expert | intermediate | beginner``, ``speed``, ``deviation``,
``hesitation_rate``, ``hesitation``, ``seed``, ...). ``pace`` paces the samples
on the wall clock (1: real time, 0: as fast as the stage takes them). In the
``cast_gimbal`` space the tip positions become gimbal configurations (roll 0)
through the space's inverse kinematics, so the whole shaft's clearance is
measured.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field
from surgiplan.errors import PlanningInputError
from surgiplan.guidance import PoseSample, PoseSource, SourceStopped, TraineeModel, synthetic_attempt

from .pacing import Pacer


class SyntheticTraineeSettings(TraineeModel):
    #: 1: samples on the wall clock in real time; 0: as fast as the stage takes them
    pace: float = Field(default=1.0, ge=0.0)


class SyntheticTrainee(PoseSource):
    Settings = SyntheticTraineeSettings

    def open(self, context) -> None:
        self.context = context
        scene = context.scene
        self.times, self.tips = synthetic_attempt(context.tips, self.settings, (scene.bounds_min, scene.bounds_max))

    def samples(self):
        space = self.context.space
        pacer = Pacer(self.settings.pace)
        gimbal = space.kind == "cast_gimbal"
        for t, tip in zip(self.times, self.tips, strict=True):
            pacer.wait(float(t))
            if gimbal:
                try:
                    q = np.asarray(space.configuration(tip, what="trainee tip"), float)
                except PlanningInputError as exc:
                    raise SourceStopped(f"the synthetic trainee's tip left the gimbal's reach: {exc}") from None
                yield PoseSample(float(t), q=q)
            elif space.dimension == 3:
                yield PoseSample(float(t), q=np.asarray(tip, float))
            else:
                yield PoseSample(float(t), tip=np.asarray(tip, float))
