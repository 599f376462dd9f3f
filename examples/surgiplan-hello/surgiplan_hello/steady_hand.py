"""The ``steady_hand`` pose source (an example pose-source plugin): a hand that follows the recommended path at
a constant speed with a physiological tremor.

A guide stage opens a source with a :class:`surgiplan.GuideContext` (the recommended path as dense tip
positions ``context.tips``, its space and scene, the clearance threshold and critical regions) and reads
:meth:`samples` as they arrive, one :class:`surgiplan.PoseSample` each (``t`` in seconds from the start,
and the tip position in metres, or a configuration ``q`` of the path's space). This hand moves along the
tips at ``speed`` and trembles vertically (the z axis) with ``tremor`` amplitude at ``frequency``
(physiological tremor is 8-12 Hz, a fraction of a millimetre), sampled at ``rate``; ``silent_after``
makes it stop answering (the stage then ends the attempt ``stopped`` after its ``silence_timeout``).

Because the path and the tremor are known, the deviation the stage measures has a closed form: on a
straight horizontal path it is |tremor x sin(2 pi frequency t)|, so its largest value is ``tremor`` when a
sample falls on a crest, and its RMS over whole periods is ``tremor / sqrt(2)`` (the example's test).
"""

from __future__ import annotations

import math
import time

import numpy as np
from pydantic import Field, PositiveFloat
from surgiplan import Length, PoseSample, PoseSource, PositiveLength, StrictModel


class SteadyHandSettings(StrictModel):
    speed: PositiveLength = 0.02  # m/s along the path
    tremor: Length = 0.0002  # m, amplitude of the vertical tremor
    frequency: PositiveFloat = 10.0  # Hz
    rate: PositiveFloat = 200.0  # samples per second
    #: stop sending after this many seconds (None: never), to rehearse a tracker that goes silent
    silent_after: float | None = Field(default=None, ge=0)


class SteadyHand(PoseSource):
    Settings = SteadyHandSettings

    def open(self, context) -> None:
        tips = np.asarray(context.tips, dtype=float)
        steps = np.linalg.norm(np.diff(tips, axis=0), axis=1)
        self.arc = np.concatenate([[0.0], np.cumsum(steps)])
        self.tips = tips

    def samples(self):
        s = self.settings
        duration = self.arc[-1] / s.speed
        count = math.floor(duration * s.rate) + 1
        for i in range(count):
            t = i / s.rate
            if s.silent_after is not None and t > s.silent_after:
                time.sleep(60)  # silence: the stage stops waiting after its silence_timeout
                return
            along = min(t * s.speed, self.arc[-1])
            tip = np.array([np.interp(along, self.arc, self.tips[:, k]) for k in range(3)])
            tip[2] += s.tremor * math.sin(2.0 * math.pi * s.frequency * t)
            yield PoseSample(t, tip=tip)
