"""Construct validity: do the metrics separate trainees of adjacent levels?

For each metric and each pair of adjacent levels (most experienced first: expert vs intermediate, intermediate
vs beginner), the two-sided Mann-Whitney U test's p-value (scipy) and the AUC: the probability that an attempt
of the more experienced level is *better* on the metric than one of the less experienced (ties count half;
0.5 is no separation, 1 a perfect one). The same analysis runs on synthetic cohorts
(``benchmarks/bench_assessment.py``) and on a lab's own record (``surgiplan validity --task TASK``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any

import numpy as np

from .metrics import METRIC_BY_NAME, METRICS
from .record import RecordError, TraineeRecord


@dataclass
class Separation:
    metric: str
    better: str
    #: the more and the less experienced level
    higher: str
    lower: str
    n_higher: int
    n_lower: int
    median_higher: float | None
    median_lower: float | None
    auc: float | None
    p: float | None

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)


def separation(metric: str, higher: tuple[str, Sequence[float]], lower: tuple[str, Sequence[float]]) -> Separation:
    """How well ``metric`` separates the values of the more experienced level from the less experienced one's."""
    from scipy.stats import mannwhitneyu

    better = METRIC_BY_NAME[metric].better
    a = np.asarray([v for v in higher[1] if v is not None and math.isfinite(v)], float)
    b = np.asarray([v for v in lower[1] if v is not None and math.isfinite(v)], float)
    out = Separation(metric, better, higher[0], lower[0], len(a), len(b), None, None, None, None)
    if len(a):
        out.median_higher = float(np.median(a))
    if len(b):
        out.median_lower = float(np.median(b))
    if len(a) < 2 or len(b) < 2:
        return out
    test = mannwhitneyu(a, b, alternative="two-sided")
    greater = float(test.statistic) / (len(a) * len(b))  # P(a > b) + P(a == b) / 2
    out.auc = greater if better == "higher" else 1.0 - greater
    out.p = float(test.pvalue) if math.isfinite(test.pvalue) else 1.0
    return out


@dataclass
class Validity:
    task: str
    #: most experienced first
    levels: list[str]
    trainees: dict[str, list[str]]
    attempts: dict[str, int]
    rows: list[Separation] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {
            "task": self.task,
            "levels": self.levels,
            "trainees": self.trainees,
            "attempts": self.attempts,
            "separations": [r.to_json() for r in self.rows],
        }


def validity(
    groups: Mapping[str, Sequence[Mapping[str, Any]]],
    levels: Sequence[str],
    *,
    task: str = "",
    trainees: Mapping[str, list[str]] | None = None,
    metrics: Sequence[str] | None = None,
) -> Validity:
    """Every metric's separation of each pair of adjacent ``levels`` (most experienced first); ``groups`` are
    each level's attempts, each its metric values."""
    names = list(metrics) if metrics is not None else [m.name for m in METRICS]
    result = Validity(
        task, list(levels), {k: list(v) for k, v in (trainees or {}).items()}, {k: len(groups[k]) for k in levels}
    )
    for name in names:
        for high, low in pairwise(levels):
            result.rows.append(
                separation(
                    name,
                    (high, [a.get(name) for a in groups[high]]),
                    (low, [a.get(name) for a in groups[low]]),
                )
            )
    return result


def groups_from_record(
    record: TraineeRecord, task: str, levels: Mapping[str, Sequence[str]] | None, order: Sequence[str]
) -> tuple[dict[str, list[dict[str, float]]], dict[str, list[str]]]:
    """Each level's attempts at ``task`` (their metrics): the trainees ``levels`` names for it, or else those
    whose recorded level it is. A :class:`RecordError` names a level without trainees or attempts."""
    recorded = record.levels()
    at_task = set(record.trainees(task))
    if not at_task:
        tasks = record.all_tasks()
        raise RecordError(
            f"no attempt at task '{task}' in {record.path}" + (f"; recorded tasks: {', '.join(tasks)}" if tasks else "")
        )
    groups: dict[str, list[dict[str, float]]] = {}
    members: dict[str, list[str]] = {}
    for level in order:
        names = list(levels[level]) if levels and level in levels else [n for n, lv in recorded.items() if lv == level]
        missing = [n for n in names if n not in recorded]
        if missing:
            raise RecordError(f"no trainee {', '.join(repr(n) for n in missing)} in the record {record.path}")
        names = [n for n in names if n in at_task]
        if not names:
            known = sorted({lv for lv in recorded.values() if lv})
            raise RecordError(
                f"no trainee of level '{level}' has an attempt at task '{task}' in {record.path} "
                f"(recorded levels: {', '.join(known) or 'none'}; give the trainees with --group {level}=NAME,...)"
            )
        members[level] = names
        groups[level] = [h["metrics"] for n in names for h in record.history(n, task)]
    return groups, members
