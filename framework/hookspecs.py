"""Hook specifications: how a package adds stage kinds, spaces, and the plugins stages run.

The core declares two hooks here: ``surgiplan_register_stage_kinds`` (what a
``stage:`` can be, :mod:`surgiplan.kinds`) and ``surgiplan_register_spaces``.
Each stage kind declares the hook of the plugins it runs
(``surgiplan_register_planners`` for ``plan`` stages, ...,
:mod:`surgiplan.stages`), and the registry adds it when the kind registers,
so a third-party stage kind brings its own plugin hook.

A plugin is a module (or object) named by an entry point in the
``surgiplan`` group. It implements one or more of these hooks, marked with
:data:`hookimpl`, each returning a list of :class:`PluginSpec` records::

    # my_package/__init__.py
    from surgiplan import PluginSpec, hookimpl

    @hookimpl
    def surgiplan_register_planners():
        return [PluginSpec("straight_line", StraightLinePlanner, "connect start and goal if clear")]

    # pyproject.toml
    [project.entry-points.surgiplan]
    my_package = "my_package"

surgiplan's own plugins register through the very same entry points.
Set ``SURGIPLAN_TRACE_HOOKS=1`` to print every hook call.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import pluggy
from pydantic import BaseModel

#: the project name: entry-point group and pluggy project
NAME = "surgiplan"

hookspec = pluggy.HookspecMarker(NAME)
#: marker for hook implementations in plugins
hookimpl = pluggy.HookimplMarker(NAME)


@dataclass(frozen=True)
class PluginSpec:
    """One registered plugin.

    ``name``: what pipeline files use (``plugin: name`` or ``space: {kind: name}``);
    ``cls``: the class; it must have a ``Settings`` pydantic model (``extra="forbid"``);
    ``description``: one line for ``surgiplan plugins``;
    ``unavailable``: if set, why the plugin cannot be used here (e.g. a missing
    optional dependency, with the command that installs it); the plugin is
    listed, and a pipeline asking for it gets this reason.
    """

    name: str
    cls: type[Any]
    description: str = ""
    unavailable: str = ""


@dataclass(frozen=True)
class PluginInfo:
    """A plugin as the registry knows it: what it is and where it came from."""

    name: str
    kind: str
    cls: type[Any] | None
    description: str
    package: str
    version: str
    entry_point: str
    unavailable: str = ""

    @property
    def settings_model(self) -> type[BaseModel]:
        return self.cls.Settings


@hookspec
def surgiplan_register_stage_kinds() -> list[Any]:
    """Stage kinds (instances of subclasses of :class:`surgiplan.kinds.StageKind`) this package provides.

    A stage kind is what a pipeline's ``stage:`` names: its YAML keys, the plugins it runs (and their hook),
    its statuses, how it runs, and what the summary and the report show of it.
    """


@hookspec
def surgiplan_register_spaces() -> list[PluginSpec]:
    """Configuration spaces (subclasses of :class:`~surgiplan.spaces.Space`), chosen by ``space: {kind: name}``."""
