"""A cohort at a task: every trainee's learning curve, gate and CUSUM, from the record (``surgiplan cohort``).

Per trainee: attempts, last score, the attempt at which the gate passed (:mod:`.benchmark`) and the CUSUM of
their failures (:mod:`.cusum`; a failure is an attempt outside the benchmark, or without one, below
``pass_score``). Per attempt, for statistics tools: every metric, whether it was within the benchmark and the
CUSUM after it (:func:`write_csv`, and the JSON of ``--json``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .benchmark import Benchmark, gate
from .cusum import Cusum, CusumSettings, cusum
from .metrics import METRICS
from .record import RecordError, TraineeRecord


@dataclass
class TraineeCurve:
    name: str
    level: str | None
    #: the attempts (:meth:`TraineeRecord.history`)
    attempts: list[dict[str, Any]]
    #: per attempt: failed (outside the benchmark, or below the pass score); None: no rule to judge by
    failed: list[bool] | None
    passed_at: int | None
    streak: int
    cusum: Cusum | None

    @property
    def last_score(self) -> float | None:
        return self.attempts[-1]["score"] if self.attempts else None

    def summary(self) -> dict[str, Any]:
        return {
            "trainee": self.name,
            "level": self.level,
            "attempts": len(self.attempts),
            "last_score": self.last_score,
            "gate_passed_at": self.passed_at,
            "streak": self.streak,
            "cusum": self.cusum.to_json() if self.cusum else None,
        }


@dataclass
class Cohort:
    task: str
    benchmark: Benchmark | None
    pass_score: float | None
    settings: CusumSettings
    trainees: list[TraineeCurve] = field(default_factory=list)

    def rows(self) -> list[dict[str, Any]]:
        """One row per attempt (trainee, level, n, started, status, every metric, within, cusum)."""
        out = []
        for curve in self.trainees:
            for i, attempt in enumerate(curve.attempts):
                row: dict[str, Any] = {
                    "trainee": curve.name,
                    "level": curve.level,
                    "attempt": attempt["n"],
                    "started": attempt["started"],
                    "status": attempt["status"],
                }
                row.update({m.name: attempt["metrics"].get(m.name) for m in METRICS})
                row["failed"] = curve.failed[i] if curve.failed is not None else None
                row["cusum"] = curve.cusum.values[i] if curve.cusum else None
                out.append(row)
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "task": self.task,
            "benchmark": self.benchmark.to_json() if self.benchmark else None,
            "pass_score": self.pass_score,
            "cusum_settings": self.settings.model_dump(),
            "trainees": [c.summary() for c in self.trainees],
            "attempts": self.rows(),
        }


def cohort(
    record: TraineeRecord,
    task: str,
    settings: CusumSettings | None = None,
    *,
    pass_score: float | None = None,
    trainees: list[str] | None = None,
) -> Cohort:
    """The cohort at ``task`` (every trainee with an attempt at it, or ``trainees``)."""
    settings = settings or CusumSettings()
    names = trainees or record.trainees(task)
    if not names:
        tasks = record.all_tasks()
        raise RecordError(
            f"no attempt at task '{task}' in {record.path}" + (f"; recorded tasks: {', '.join(tasks)}" if tasks else "")
        )
    benchmark = record.benchmark(task)
    levels = record.levels()
    result = Cohort(task, benchmark, pass_score, settings)
    for name in names:
        history = record.history(name, task)
        if not history:
            raise RecordError(f"trainee '{name}' has no attempt at task '{task}' in {record.path}")
        failed = None
        passed_at, streak = None, 0
        if benchmark is not None:
            g = gate([h["metrics"] for h in history], benchmark)
            failed = [not ok for ok in g.within]
            passed_at, streak = g.passed_at, g.streak
        elif pass_score is not None:
            failed = [not (h["score"] is not None and h["score"] >= pass_score) for h in history]
        chart = cusum(failed, settings) if failed is not None else None
        result.trainees.append(TraineeCurve(name, levels.get(name), history, failed, passed_at, streak, chart))
    return result


def write_csv(path: Path, result: Cohort) -> None:
    """Every attempt of the cohort, one row each (written atomically, mode 0600: it names trainees)."""
    from .export import write_rows_csv

    write_rows_csv(path, result.rows())
