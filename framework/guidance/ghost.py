"""The expert ghost: an expert's recorded attempt shown beside the trainee's instrument, synchronised by progress.

A guide stage with ``ghost: {trainee: ann, attempt: best}`` takes that attempt's samples from the trainee
record. Progress is measured along each one's own recommended path, as the fraction of it covered: the same
path gives the same progress, and an expert recorded on another path (a smaller d_thresh takes a shorter way)
still keeps pace with the trainee from the start to the goal. The ghost's key is the expert's furthest fraction
so far, which never decreases; for the trainee at fraction ``f`` the ghost is where the expert was when they
first reached ``f`` (interpolated between the two samples either side), so it waits while the trainee
hesitates and goes back with a trainee going the wrong way. The attempt is chosen by ``attempt``: ``best``
(the highest score of the trainee's completed attempts at the task), ``last``, ``first``, or its number (1:
the trainee's first attempt at the task).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from pydantic import Field, PositiveInt

from ..models import StrictModel
from .record import RecordError, TraineeRecord


class GhostKeys(StrictModel):
    """``ghost:`` of a guide stage: whose recorded attempt to show beside the trainee."""

    trainee: str = Field(min_length=1)
    #: default: the task of the stage's ``trainee:`` block
    task: str | None = Field(default=None, min_length=1)
    attempt: Literal["best", "last", "first"] | PositiveInt = "best"


@dataclass
class Ghost:
    trainee: str
    task: str
    #: the attempt's id in the record and its number among the trainee's attempts at the task
    attempt_id: int
    n: int
    score: float | None
    t: np.ndarray
    tips: np.ndarray
    #: the expert's furthest fraction of their recommended path so far, per sample (non-decreasing)
    key: np.ndarray

    def at(self, fraction: float) -> np.ndarray:
        """Where the expert was when they first covered ``fraction`` of their recommended path (their first or last
        sample beyond the ends)."""
        i = int(np.searchsorted(self.key, fraction, side="left"))
        if i <= 0:
            return self.tips[0].copy()
        if i >= len(self.key):
            return self.tips[-1].copy()
        a, b = self.key[i - 1], self.key[i]
        f = (fraction - a) / (b - a) if b > a else 1.0
        return self.tips[i - 1] + f * (self.tips[i] - self.tips[i - 1])

    def describe(self) -> dict[str, Any]:
        return {
            "trainee": self.trainee,
            "task": self.task,
            "attempt": self.n,
            "id": self.attempt_id,
            "score": self.score,
        }


def choose_attempt(record: TraineeRecord, keys: GhostKeys, task: str) -> dict[str, Any]:
    """The attempt ``keys`` names (with ``n``, its number at the task); a :class:`RecordError` says why not."""
    history = record.history(keys.trainee, task)
    if not history:
        tasks = record.tasks(keys.trainee)
        raise RecordError(
            f"trainee '{keys.trainee}' has no recorded attempt at task '{task}' in {record.path}"
            + (f"; recorded tasks: {', '.join(tasks)}" if tasks else "")
        )
    if keys.attempt == "first":
        return history[0]
    if keys.attempt == "last":
        return history[-1]
    if keys.attempt == "best":
        completed = [a for a in history if a["status"] == "completed"] or history
        return max(completed, key=lambda a: (a["score"] if a["score"] is not None else -1.0, -a["n"]))
    if keys.attempt > len(history):
        raise RecordError(
            f"trainee '{keys.trainee}' has {len(history)} attempt(s) at task '{task}' in {record.path}, "
            f"no attempt {keys.attempt}"
        )
    return history[keys.attempt - 1]


def load_ghost(record: TraineeRecord, keys: GhostKeys, task: str) -> Ghost:
    """The ghost of the attempt ``keys`` names (a :class:`RecordError` says why there is none)."""
    attempt = choose_attempt(record, keys, task)
    samples = record.samples(attempt["id"])
    tips = np.asarray(samples["tip"], float)
    length = attempt["recommended_length_m"]
    if len(tips) < 2 or not (length and length > 0):
        raise RecordError(f"attempt {attempt['n']} of trainee '{keys.trainee}' at '{task}' has no samples to show")
    return Ghost(
        trainee=keys.trainee,
        task=task,
        attempt_id=int(attempt["id"]),
        n=int(attempt["n"]),
        score=attempt["score"],
        t=np.asarray(samples["t"], float),
        tips=tips,
        key=np.maximum.accumulate(np.asarray(samples["progress"], float) / length),
    )
