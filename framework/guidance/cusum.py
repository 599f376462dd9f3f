"""CUSUM learning curves: the cumulative sum of failures minus their acceptable share, as surgical training reads it.

The standard CUSUM of Williams et al. (1992) and Bolsin & Colson (2000, "The use of the Cusum technique in
the assessment of trainee competence in new procedures", Int J Qual Health Care 12(5):433-438), a sequential
probability ratio test between an acceptable failure rate ``p0`` and an unacceptable one ``p1`` with type I
and II errors ``alpha`` and ``beta``::

    P = ln(p1 / p0)          Q = ln((1 - p0) / (1 - p1))
    s = Q / (P + Q)          the step down for a success (a failure adds 1 - s)
    a = ln((1 - beta) / alpha)        b = ln((1 - alpha) / beta)
    h1 = a / (P + Q)         the upper decision line: the failure rate is unacceptable (p1)
    h0 = b / (P + Q)         the lower decision line at -h0: the rate is acceptable (p0)

    S_0 = 0,  S_n = S_{n-1} + (x_n - s),  x_n = 1 for a failed attempt, 0 for a success

A chart that falls by ``h0`` from its highest point so far says the trainee has performed at the acceptable
rate since that point (with the chosen errors); one that rises by ``h1`` from its lowest point so far, that
they fail at the unacceptable rate. These are the decision lines Bolsin & Colson draw below and above the
chart, taken from its peaks and troughs (Page's one-sided CUSUMs: max(0, T + s - x) >= h0 and
max(0, U + x - s) >= h1), so the early failures of a learning curve do not hide the later competence.
An attempt *fails* when it is not within the task's proficiency benchmark (:mod:`.benchmark`), or, without
one, when its score is below a pass score.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from pydantic import Field, model_validator

from ..models import StrictModel


class CusumSettings(StrictModel):
    """The CUSUM chart's rates and errors (``surgiplan cohort --p0 --p1 --alpha --beta``)."""

    #: acceptable failure rate
    p0: float = Field(default=0.1, gt=0, lt=1)
    #: unacceptable failure rate
    p1: float = Field(default=0.3, gt=0, lt=1)
    alpha: float = Field(default=0.1, gt=0, lt=1)
    beta: float = Field(default=0.1, gt=0, lt=1)

    @model_validator(mode="after")
    def _ordered(self):
        if not self.p1 > self.p0:
            raise ValueError(
                f"the unacceptable failure rate p1 ({self.p1:g}) must exceed the acceptable p0 ({self.p0:g})"
            )
        return self


@dataclass
class Cusum:
    s: float
    h0: float
    h1: float
    #: S_1 ... S_n
    values: list[float] = field(default_factory=list)
    #: the lines the chart is judged by after each attempt: its highest point so far - h0, lowest + h1
    acceptable_line: list[float] = field(default_factory=list)
    unacceptable_line: list[float] = field(default_factory=list)
    #: the first attempt (1-based) at which S fell by h0 from its peak (acceptable) or rose by h1 from its trough
    #: (unacceptable); None: not yet
    acceptable_at: int | None = None
    unacceptable_at: int | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "s": self.s,
            "h0": self.h0,
            "h1": self.h1,
            "values": self.values,
            "acceptable_line": self.acceptable_line,
            "unacceptable_line": self.unacceptable_line,
            "acceptable_at": self.acceptable_at,
            "unacceptable_at": self.unacceptable_at,
        }


def parameters(settings: CusumSettings) -> tuple[float, float, float]:
    """(s, h0, h1) of the settings (see the module)."""
    p0, p1 = settings.p0, settings.p1
    P, Q = math.log(p1 / p0), math.log((1 - p0) / (1 - p1))
    a = math.log((1 - settings.beta) / settings.alpha)
    b = math.log((1 - settings.alpha) / settings.beta)
    return Q / (P + Q), b / (P + Q), a / (P + Q)


def cusum(failures: Sequence[bool], settings: CusumSettings) -> Cusum:
    """The CUSUM of a sequence of attempts (True: failed), oldest first."""
    s, h0, h1 = parameters(settings)
    chart = Cusum(s, h0, h1)
    total = peak = trough = 0.0
    for n, failed in enumerate(failures, start=1):
        total += (1.0 if failed else 0.0) - s
        peak, trough = max(peak, total), min(trough, total)
        chart.values.append(total)
        chart.acceptable_line.append(peak - h0)
        chart.unacceptable_line.append(trough + h1)
        # reaching a line counts (with the default rates two failures in a row land exactly on h1)
        if chart.acceptable_at is None and total <= peak - h0 + 1e-9:
            chart.acceptable_at = n
        if chart.unacceptable_at is None and total >= trough + h1 - 1e-9:
            chart.unacceptable_at = n
    return chart
