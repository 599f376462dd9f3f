"""Trainee guidance: follow an instrument live against the recommended path, score the attempt, keep a record.

Paper 000's recommended path keeps a clearance matched to the trainee's
proficiency; a trainer watches the instrument against it. This package is
that loop:

* ``source`` — :class:`PoseSource`, the plugin interface of pose sources
  (hook ``surgiplan_register_sources``), and :class:`PoseSample`;
* ``analysis`` — :class:`Guide`: per sample deviation, progress, clearance,
  critical regions, lateral offset, insertion and events;
* ``stage`` — the ``guide`` stage;
* ``report`` — the attempt's figure and samples CSV;
* ``record`` — :class:`TraineeRecord`, the SQLite record of attempts per
  trainee and task, and proficiency from it;
* ``trainee`` — a synthetic trainee (seeded, documented parameters);
* the skill assessment (``docs/assessment.md``): ``metrics`` (the metrics
  and the score), ``benchmark`` (a task's thresholds and the proficiency
  gate), ``cusum``, ``validity`` (construct validity), ``cohort``
  and ``assessment_figures`` (learning curves), ``ghost`` (the expert
  ghost), ``assessment`` (an attempt into the record, a trainee's
  standing), ``schema`` (the record's schema and migrations).
"""

from __future__ import annotations

from .analysis import EVENT_KINDS, Event, GuidanceSettings, Guide, Measurement
from .metrics import METRICS, AssessmentSettings
from .record import Proficiency, RecordError, TraineeRecord
from .source import GuideContext, PoseSample, PoseSource, SourceStopped
from .trainee import LEVELS, TraineeModel, synthetic_attempt

__all__ = [
    "EVENT_KINDS",
    "LEVELS",
    "METRICS",
    "AssessmentSettings",
    "Event",
    "GuidanceSettings",
    "Guide",
    "GuideContext",
    "Measurement",
    "PoseSample",
    "PoseSource",
    "Proficiency",
    "RecordError",
    "SourceStopped",
    "TraineeModel",
    "TraineeRecord",
    "synthetic_attempt",
]
