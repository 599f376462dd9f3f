"""Hook specifications: how a package adds planners, models, devices, spaces and pose sources.

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


@hookspec
def surgiplan_register_planners() -> list[PluginSpec]:
    """Planner plugins (subclasses of :class:`surgiplan.Planner`) this package provides.

    Used by ``stage: plan``. Return a list of :class:`PluginSpec`.
    """


@hookspec
def surgiplan_register_deformable_models() -> list[PluginSpec]:
    """Deformable-model plugins (subclasses of :class:`surgiplan.DeformableModel`).

    Used by ``stage: simulate`` and by planners that deform tissue.
    """


@hookspec
def surgiplan_register_devices() -> list[PluginSpec]:
    """Device plugins (subclasses of :class:`surgiplan.Device`). Used by ``stage: execute``."""


@hookspec
def surgiplan_register_spaces() -> list[PluginSpec]:
    """Configuration spaces (subclasses of :class:`surgiplan.Space`), chosen by ``space: {kind: name}``."""


@hookspec
def surgiplan_register_sources() -> list[PluginSpec]:
    """Pose sources (subclasses of :class:`surgiplan.PoseSource`): the instrument followed by ``stage: guide``."""


#: plugin kind -> (hook name, stage kind that uses it)
KINDS: dict[str, tuple[str, str | None]] = {
    "planner": ("surgiplan_register_planners", "plan"),
    "deformable_model": ("surgiplan_register_deformable_models", "simulate"),
    "device": ("surgiplan_register_devices", "execute"),
    "space": ("surgiplan_register_spaces", None),
    "source": ("surgiplan_register_sources", "guide"),
}
