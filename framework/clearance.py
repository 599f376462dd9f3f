"""The clearance threshold (paper 000's d_thresh) and the critical regions of a path: one concept, one place.

A plan stage's **clearance threshold** is the clearance (m) its path keeps from every obstacle. It has one
name in files, ``clearance_threshold:`` on a plan stage, and one in code, :class:`ClearanceThreshold`
(``PlanningProblem.clearance_threshold``, ``StageResult.clearance_threshold``). It is resolved when the
file is validated, from the stage or from what the planner's settings ask for (``safe_prm``'s
``proficiency``), and passed *into* the planner; a planner never sends one back.

How a planner keeps it is its :attr:`~surgiplan.planning.Planner.clearance_policy`:

``everywhere``
    every motion keeps it, as a margin; where none can, there is no path (OMPL, optMIS, segmented A*);
``except_critical``
    kept except in **critical regions**, the stretches where no detour exists (``safe_prm``, paper 000
    §3.3-3.4): the path passes there as well as it can.

The framework measures what the path does, whatever the planner says: :func:`critical_regions` finds the
stretches of a path below the threshold, each a :class:`CriticalRegion` (an arc-length interval along the
tip path, its length, its least clearance, the obstacles that close it). For an ``everywhere`` planner
such a stretch makes its answer invalid; for an ``except_critical`` planner they are its critical regions.
Figures, the summary, the report, guide stages and devices all read the threshold and the regions from
the plan stage's result.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import ConfigDict, Field

from .models import StrictModel


class ClearancePolicy(enum.StrEnum):
    """How a planner keeps the stage's clearance threshold."""

    EVERYWHERE = "everywhere"
    EXCEPT_CRITICAL = "except_critical"


@dataclass(frozen=True)
class ClearanceThreshold:
    """The clearance (m) a plan keeps, and where that value came from (for messages and ``result.json``).

    ``source`` is a phrase such as ``"pipeline[0].clearance_threshold"`` or ``"settings.proficiency
    'beginner'"``.
    """

    value: float
    source: str = ""

    def __post_init__(self) -> None:
        value = float(self.value)
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"a clearance threshold is a non-negative length in m, got {self.value!r}")
        object.__setattr__(self, "value", value)

    def __float__(self) -> float:
        return self.value


def threshold_value(threshold: ClearanceThreshold | float | None) -> float:
    """The threshold in m, 0 when there is none."""
    return 0.0 if threshold is None else float(threshold)


class CriticalRegion(StrictModel):
    """A stretch of a path below its clearance threshold (a critical region where no detour exists).

    ``start_m`` and ``end_m`` are arc lengths (m) along the path's tip; ``min_clearance_m`` the least
    clearance measured in it; ``obstacles`` the names of the obstacles nearest along it.
    """

    model_config = ConfigDict(frozen=True)
    start_m: float = Field(ge=0, allow_inf_nan=False)
    end_m: float = Field(ge=0, allow_inf_nan=False)
    length_m: float = Field(ge=0, allow_inf_nan=False)
    min_clearance_m: float = Field(allow_inf_nan=False)
    obstacles: tuple[str, ...] = ()

    def contains(self, arc_length: float) -> bool:
        """Whether ``arc_length`` (m along the tip path) lies in the region."""
        return self.start_m <= arc_length <= self.end_m

    @property
    def interval(self) -> tuple[float, float]:
        return (self.start_m, self.end_m)

    def to_json(self) -> dict[str, Any]:
        """The region as ``result.json`` stores it (``annotations.critical_regions``): its fields, obstacles as a
        list; :func:`regions_from_json` reads it back."""
        data = self.model_dump()
        data["obstacles"] = list(self.obstacles)
        return data


def regions_from_json(items: Iterable[Any] | None) -> list[CriticalRegion]:
    """Critical regions read back from ``result.json`` (``annotations.critical_regions``); malformed items are
    skipped (a report or a device must not fail on another program's odd file)."""
    out = []
    for item in items or []:
        if isinstance(item, CriticalRegion):
            out.append(item)
        elif isinstance(item, Mapping):
            try:
                out.append(
                    CriticalRegion.model_validate({k: item[k] for k in CriticalRegion.model_fields if k in item})
                )
            except ValueError:
                continue
    return out


def intervals(regions: Iterable[CriticalRegion]) -> list[tuple[float, float]]:
    """The regions as arc-length intervals ``[(start_m, end_m), ...]``."""
    return [r.interval for r in regions]


def default_resolution(space) -> float:
    """The spacing at which a path's clearance is measured: 1/2000 of the scene's smallest extent."""
    return float(np.min(space.scene.extent)) / 2000.0


def critical_regions(
    space, path: np.ndarray, threshold: float, resolution: float | None = None
) -> list[CriticalRegion]:
    """The stretches of ``path`` (configurations of ``space``) whose clearance is below ``threshold``, measured
    on the scene every ``resolution`` (default :func:`default_resolution`) along the space's local motions.

    Each region extends to the samples either side of its first and last sample below the threshold (the
    crossing lies between them); its obstacles are the nearest ones along it, by name.
    """
    path = np.atleast_2d(np.asarray(path, dtype=float))
    if threshold <= 0 or len(path) < 2:
        return []
    resolution = resolution or default_resolution(space)
    dense = space.densify(path, resolution)
    clearance = space.clearance(dense)
    nearest = space.nearest_obstacle(dense)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(space.tip(dense), axis=0), axis=1))])
    below = clearance < threshold
    edges = np.flatnonzero(np.diff(np.concatenate([[0], below.astype(int), [0]])))
    names = [o.name for o in space.scene.obstacles]
    regions = []
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        lo, hi = max(a - 1, 0), min(b, len(dense) - 1)
        regions.append(
            CriticalRegion(
                start_m=float(arc[lo]),
                end_m=float(arc[hi]),
                length_m=float(arc[hi] - arc[lo]),
                min_clearance_m=float(clearance[a:b].min()),
                obstacles=tuple(sorted({names[i] for i in nearest[a:b] if i >= 0})),
            )
        )
    return regions
