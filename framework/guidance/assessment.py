"""An attempt into the record, and where a trainee stands against the task's proficiency benchmark.

:func:`record_attempt` is what the guide stage calls when an attempt ends; :func:`standing` is what the stage,
``surgiplan trainee`` and ``surgiplan cohort`` show: each metric of the last attempt against its threshold,
and the gate (:mod:`.benchmark`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .analysis import Event, Guide
from .benchmark import Benchmark, gate
from .record import TraineeRecord


def standing(benchmark: Benchmark | None, history: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """The gate over ``history`` (:meth:`TraineeRecord.history`) and each metric of its last attempt against
    its threshold; None without a benchmark."""
    if benchmark is None:
        return None
    result = gate([h["metrics"] for h in history], benchmark)
    last = history[-1]["metrics"] if history else {}
    return {
        "benchmark": benchmark.id,
        "benchmark_rule": benchmark.describe(),
        **result.to_json(),
        "status": result.describe(),
        "last": {
            name: {
                "value": last.get(name),
                "threshold": t.value,
                "better": t.better,
                "within": ok,
            }
            for (name, t), ok in zip(benchmark.thresholds.items(), benchmark.check(last).values(), strict=True)
        },
    }


def record_attempt(
    path: Path,
    trainee,
    guide: Guide,
    metrics: dict[str, Any],
    events: Sequence[Event],
    *,
    status: str,
    pipeline: str = "",
    stage: str = "",
    source: str = "",
    output_dir: str = "",
    assistance: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Store the attempt (``trainee``: its name, task and level; ``assistance``: how a haptic source assisted, kept
    in the attempt's assessment JSON) and return where it went and the trainee's standing at the task's gate (None
    without a benchmark)."""
    with TraineeRecord(path) as record:
        attempt_id = record.add_attempt(
            trainee.name,
            trainee.task,
            metrics,
            [e.to_json() for e in events],
            guide.samples(),
            status=status,
            level=trainee.level,
            assessment={
                "schema": 2,
                **guide.assessment.model_dump(mode="json"),
                **({"assistance": assistance} if assistance is not None else {}),
            },
            pipeline=pipeline,
            stage=stage,
            source=source,
            output_dir=output_dir,
        )
        result = standing(record.benchmark(trainee.task), record.history(trainee.name, trainee.task))
    return {
        "path": str(path),
        "attempt": attempt_id,
        "trainee": trainee.name,
        "task": trainee.task,
        "gate": result,
    }
