"""docs/plugins.md is the plugin author's reference; these tests keep it and the code the same: every hook's
docstring is quoted verbatim, every field of every object a plugin receives or returns is described, every
status a plugin or the framework can set is named, and the exit codes it states are the command line's."""

from __future__ import annotations

import dataclasses
import inspect
import re

import pytest
from conftest import ROOT
from surgiplan import hookspecs, status
from surgiplan.deformable import Constraints, EquilibriumState
from surgiplan.devices import ExecutionReport, Trajectory
from surgiplan.guidance.source import GuideContext, PoseSample
from surgiplan.planning import PlanningProblem, PlanResult
from surgiplan.registry import PluginRegistry
from surgiplan.results import StageContext

DOC = (ROOT / "docs" / "plugins.md").read_text()


def hook_docstrings() -> dict[str, str]:
    specs = {n: f for n, f in inspect.getmembers(hookspecs, inspect.isfunction) if n.startswith("surgiplan_")}
    for info in PluginRegistry(packages={"surgiplan"}).stage_kinds.values():
        specs.update(
            (n, f) for n, f in inspect.getmembers(info.kind.hookspecs, inspect.isfunction) if n.startswith("surgiplan_")
        )
    return {name: inspect.getdoc(f) for name, f in specs.items()}


def test_every_hook_docstring_is_quoted_in_the_reference():
    docs = hook_docstrings()
    assert len(docs) == 6
    sections = re.findall(r"^### `(surgiplan_\w+)`\n\n(.*?)(?=\n### |\Z)", DOC, re.S | re.M)
    quoted = {name: text.strip() for name, text in sections}
    assert set(quoted) == set(docs)
    for name, text in docs.items():
        assert quoted[name] == text, f"docs/plugins.md's {name} differs from its docstring"


@pytest.mark.parametrize(
    "cls",
    [
        PlanningProblem,
        PlanResult,
        StageContext,
        Trajectory,
        ExecutionReport,
        GuideContext,
        PoseSample,
        Constraints,
        EquilibriumState,
    ],
)
def test_every_field_a_plugin_receives_or_returns_is_described(cls):
    missing = [f.name for f in dataclasses.fields(cls) if f"`{f.name}`" not in DOC]
    assert missing == [], f"{cls.__name__}: {missing} not in docs/plugins.md"


def test_every_status_is_named():
    values = {
        s.value
        for enum in (
            status.PlanStatus,
            status.SimulateStatus,
            status.ExecuteStatus,
            status.GuideStatus,
            status.RunStatus,
        )
        for s in enum
    }
    missing = sorted(v for v in values if f"`{v}`" not in DOC)
    assert missing == []


def test_the_exit_codes_it_states_are_the_command_lines(cli, tmp_path):
    from surgiplan.errors import ConfigError, PluginError, StageError, SurgiplanError

    assert SurgiplanError.exit_code == ConfigError.exit_code == PluginError.exit_code == 2
    assert StageError.exit_code == 1
    assert "| Ctrl-C | `interrupted` | `interrupted` | 130 |" in DOC
    (tmp_path / "bad.yaml").write_text("name: x\n")
    assert cli("validate", tmp_path / "bad.yaml")[0] == 2
