"""Proficiency benchmarks from expert attempts, and the proficiency gate (``docs/assessment.md``).

A task's **benchmark** is one threshold per metric, from a set of expert attempts: the expert mean plus (for a
metric where lower is better) or minus (higher is better) ``k`` standard deviations, or the ``percentile`` of
the expert attempts that an attempt must be as good as (90: as good as the worst of the best 90 % of the
experts' attempts). An attempt is **within** the benchmark when every one of its metrics is within its
threshold; a metric it has no value for is not within (the gate never passes on what was not measured). A
trainee **passes the gate** at the attempt that completes ``consecutive`` attempts in a row within the
benchmark (default 2), as proficiency-based progression curricula do.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from pydantic import Field, NonNegativeFloat, PositiveInt, field_validator

from ..models import StrictModel
from .metrics import METRIC_BY_NAME

#: the metrics a benchmark sets thresholds on unless told otherwise (those the experts' attempts have)
#: (idle time and completion are left out: experts' are nearly always 0 s and 1, so their thresholds would demand
#: exactly that, and the score and the task time already count both)
GATE_METRICS = (
    "score",
    "duration_s",
    "economy",
    "sparc",
    "corrections",
    "depth_reversals",
    "deviation_rms_m",
    "below_threshold_s",
    "contacts",
)


class BenchmarkSettings(StrictModel):
    """How a benchmark is set (``surgiplan benchmark-task`` takes these as options)."""

    method: Literal["mean_sd", "percentile"] = "mean_sd"
    #: mean_sd: the threshold is the expert mean -/+ k standard deviations (sample SD, n - 1)
    k: NonNegativeFloat = 1.0
    #: percentile: the share (%) of expert attempts within each threshold
    percentile: float = Field(default=90.0, gt=0, le=100)
    #: attempts in a row within the benchmark that pass the gate
    consecutive: PositiveInt = 2
    metrics: list[str] = Field(default_factory=lambda: list(GATE_METRICS))
    #: only each expert's last attempts (none: all)
    last: PositiveInt | None = None

    @field_validator("metrics")
    @classmethod
    def _known(cls, value: list[str]) -> list[str]:
        unknown = [m for m in value if m not in METRIC_BY_NAME]
        if unknown:
            raise ValueError(f"unknown metric(s) {', '.join(unknown)}; choose from: {', '.join(METRIC_BY_NAME)}")
        if not value:
            raise ValueError("give at least one metric")
        return value


@dataclass(frozen=True)
class Threshold:
    metric: str
    #: "lower" or "higher" is better
    better: str
    mean: float
    sd: float
    value: float
    #: the expert attempts it is made from
    n: int

    def within(self, value: float | None) -> bool:
        if value is None or not math.isfinite(value):
            return False
        return value <= self.value if self.better == "lower" else value >= self.value


@dataclass
class Benchmark:
    task: str
    method: str
    k: float | None
    percentile: float | None
    consecutive: int
    experts: list[str]
    attempts: int
    thresholds: dict[str, Threshold]
    id: int | None = None
    created: str = ""

    def describe(self) -> str:
        how = f"expert mean ± {self.k:g} SD" if self.method == "mean_sd" else f"{self.percentile:g}th percentile"
        return (
            f"{how} of {self.attempts} attempt(s) by {', '.join(self.experts)}; "
            f"{self.consecutive} in a row within every threshold pass the gate"
        )

    def check(self, values: Mapping[str, Any]) -> dict[str, bool]:
        """Each threshold's metric: within it or not."""
        return {name: t.within(_number(values.get(name))) for name, t in self.thresholds.items()}

    def within(self, values: Mapping[str, Any]) -> bool:
        return all(self.check(values).values())

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "task": self.task,
            "created": self.created,
            "method": self.method,
            "k": self.k,
            "percentile": self.percentile,
            "consecutive": self.consecutive,
            "experts": self.experts,
            "attempts": self.attempts,
            "thresholds": {
                n: {"better": t.better, "mean": t.mean, "sd": t.sd, "threshold": t.value, "n": t.n}
                for n, t in self.thresholds.items()
            },
        }


def thresholds(expert_values: Sequence[Mapping[str, Any]], settings: BenchmarkSettings) -> dict[str, Threshold]:
    """One threshold per metric of ``settings.metrics`` that at least two expert attempts have."""
    out = {}
    for name in settings.metrics:
        metric = METRIC_BY_NAME[name]
        values = np.array([v for v in (_number(e.get(name)) for e in expert_values) if v is not None], float)
        if len(values) < 2:
            continue
        mean, sd = float(values.mean()), float(values.std(ddof=1))
        lower = metric.better == "lower"
        if settings.method == "mean_sd":
            value = mean + settings.k * sd if lower else mean - settings.k * sd
        else:
            q = settings.percentile if lower else 100.0 - settings.percentile
            value = float(np.percentile(values, q))
        out[name] = Threshold(name, metric.better, mean, sd, float(value), len(values))
    return out


@dataclass
class Gate:
    """A trainee's gate on a task: which attempts were within the benchmark, and when the gate passed."""

    consecutive: int
    #: per attempt (oldest first): within every threshold
    within: list[bool] = field(default_factory=list)
    #: the 1-based attempt that completed ``consecutive`` in a row within (None: not yet)
    passed_at: int | None = None

    @property
    def passed(self) -> bool:
        return self.passed_at is not None

    @property
    def streak(self) -> int:
        """Attempts in a row within the benchmark, up to the last."""
        n = 0
        for ok in reversed(self.within):
            if not ok:
                break
            n += 1
        return n

    def describe(self) -> str:
        if self.passed:
            return f"passed at attempt #{self.passed_at} ({self.consecutive} in a row within the benchmark)"
        return f"not passed: {self.streak} of {self.consecutive} attempts in a row within the benchmark so far"

    def to_json(self) -> dict[str, Any]:
        return {
            "passed": self.passed,
            "passed_at": self.passed_at,
            "consecutive": self.consecutive,
            "streak": self.streak,
            "within": self.within,
        }


def gate(history: Sequence[Mapping[str, Any]], benchmark: Benchmark) -> Gate:
    """The gate over a trainee's attempts (oldest first, each its metric values)."""
    result = Gate(benchmark.consecutive)
    run = 0
    for i, values in enumerate(history, start=1):
        ok = benchmark.within(values)
        result.within.append(ok)
        run = run + 1 if ok else 0
        if result.passed_at is None and run >= benchmark.consecutive:
            result.passed_at = i
    return result


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None
