"""Registers the built-in stage kinds, through the same entry-point group as every plugin."""

from __future__ import annotations

from ..hookspecs import hookimpl
from .execute import ExecuteKind
from .guide import GuideKind
from .plan import PlanKind
from .simulate import SimulateKind


@hookimpl
def surgiplan_register_stage_kinds():
    return [PlanKind(), SimulateKind(), ExecuteKind(), GuideKind()]
