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

import functools
import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import pluggy
from pydantic import BaseModel

from .errors import PluginError

#: the project name: entry-point group and pluggy project
NAME = "surgiplan"

hookspec = pluggy.HookspecMarker(NAME)
#: marker for hook implementations in plugins
hookimpl = pluggy.HookimplMarker(NAME)


@dataclass(frozen=True)
class PluginSpec:
    """One registered plugin.

    ``name``: what pipeline files use (``plugin: name`` or ``space: {kind: name}``);
    ``cls``: the class; it must have a ``Settings`` pydantic model (``extra="forbid"``); or where it is,
    ``"package.module:Class"``, imported when the plugin is first used (so that listing the plugins, or
    checking a pipeline that does not use this one, does not import what its class needs);
    ``description``: one line for ``surgiplan plugins``;
    ``unavailable``: if set, why the plugin cannot be used here (e.g. a missing
    optional dependency, with the command that installs it); the plugin is
    listed, and a pipeline asking for it gets this reason.
    """

    name: str
    cls: type[Any] | str
    description: str = ""
    unavailable: str = ""


@dataclass(frozen=True, init=False)
class PluginInfo:
    """A plugin as the registry knows it: what it is and where it came from.

    ``target`` is the class its :class:`PluginSpec` gave, or the ``"module:Class"`` reference to it; :attr:`cls`
    is the class, imported at its first use and then checked by ``check`` (the registry's test of a plugin
    class: an interface subclass with a strict ``Settings`` model). ``cls=`` is accepted for ``target=`` when
    constructing one (``dataclasses.replace(info, cls=Other)``), as before classes could be named by reference.
    """

    name: str
    kind: str
    target: type[Any] | str | None
    description: str
    package: str
    version: str
    entry_point: str
    unavailable: str = ""
    check: Callable[[Any], str] | None = field(default=None, repr=False, compare=False)

    def __init__(
        self,
        name: str,
        kind: str,
        target: type[Any] | str | None = None,
        description: str = "",
        package: str = "",
        version: str = "",
        entry_point: str = "",
        unavailable: str = "",
        check: Callable[[Any], str] | None = None,
        *,
        cls: type[Any] | None = None,
    ) -> None:
        fields = {
            "name": name,
            "kind": kind,
            "target": cls if cls is not None else target,
            "description": description,
            "package": package,
            "version": version,
            "entry_point": entry_point,
            "unavailable": unavailable,
            "check": check,
        }
        for key, value in fields.items():  # frozen: set once, here
            object.__setattr__(self, key, value)

    @functools.cached_property
    def cls(self) -> type[Any] | None:
        """The plugin's class (imported now if its spec named it by ``"module:Class"``)."""
        if not isinstance(self.target, str):
            return self.target
        label = f"{self.kind.replace('_', ' ')} '{self.name}' from package '{self.package}'"
        found = import_reference(self.target, label)
        problem = self.check(found) if self.check is not None else ""
        if problem:
            raise PluginError(f"{label} (entry point '{self.entry_point}') is refused: {problem}")
        return found

    @property
    def settings_model(self) -> type[BaseModel]:
        """The plugin's settings model (its class's ``Settings``)."""
        return self.cls.Settings


def import_reference(reference: str, label: str) -> Any:
    """The object a ``"package.module:name"`` reference names, imported now; a
    :class:`~surgiplan.errors.PluginError` saying which plugin (``label``) and what failed otherwise."""
    module_name, _, attribute = reference.partition(":")
    if not module_name or not attribute:
        raise PluginError(f"{label}: its class reference {reference!r} is not of the form 'package.module:Class'")
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # any error inside the plugin's own import code
        raise PluginError(f"{label}: importing {module_name} failed: {type(exc).__name__}: {exc}") from exc
    try:
        return functools.reduce(getattr, attribute.split("."), module)
    except AttributeError:
        raise PluginError(f"{label}: {module_name} has no {attribute!r} (its class reference {reference!r})") from None


@hookspec
def surgiplan_register_stage_kinds() -> list[Any]:
    """Stage kinds (instances of subclasses of :class:`surgiplan.kinds.StageKind`) this package provides.

    A stage kind is what a pipeline's ``stage:`` names: its YAML keys, the plugins it runs (and their hook),
    its statuses, how it runs, and what the summary and the report show of it.
    """


@hookspec
def surgiplan_register_spaces() -> list[PluginSpec]:
    """Configuration spaces (subclasses of :class:`~surgiplan.spaces.Space`), chosen by ``space: {kind: name}``."""
