"""The plugin registry: a small typed facade over pluggy's PluginManager.

It finds plugins through the ``surgiplan`` entry-point group (ours included),
calls each plugin's registration hooks one plugin at a time (so an error
names the plugin and its package), and answers ``get(kind, name)``.

Environment variables:

``SURGIPLAN_STRICT_PLUGINS=1``
    a plugin that fails to import or register raises instead of being logged
    and skipped (for plugin authors).
``SURGIPLAN_DISABLE_PLUGINS=a,b``
    skip entry points, or individual plugins, with these names.
``SURGIPLAN_PLUGIN_PACKAGES=surgiplan,my-pkg``
    load entry points from these distributions only (the test suite uses it
    so that whatever else is installed cannot leak into it).
``SURGIPLAN_TRACE_HOOKS=1``
    print every hook call to stderr.
"""

from __future__ import annotations

import importlib.metadata as metadata
import logging
import os
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import pluggy
from pydantic import BaseModel

from . import hookspecs
from .errors import PluginError, choices_hint
from .hookspecs import KINDS, NAME, PluginSpec

log = logging.getLogger(__name__)


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


@dataclass
class LoadFailure:
    entry_point: str
    package: str
    error: str


def _env_list(name: str) -> set[str]:
    return {part.strip() for part in os.environ.get(name, "").split(",") if part.strip()}


def _dist_name(ep: metadata.EntryPoint) -> tuple[str, str]:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return "unknown", ""
    return dist.metadata["Name"] or dist.name, dist.version or ""


@dataclass
class PluginRegistry:
    """Plugins found through entry points, by kind and name.

    ``entry_points``: the entry points to consider (default: the installed
    ones in the ``surgiplan`` group); ``strict``, ``disabled`` and
    ``packages`` default to the environment variables above.
    """

    entry_points: Iterable[metadata.EntryPoint] | None = None
    strict: bool | None = None
    disabled: set[str] | None = None
    packages: set[str] | None = None

    plugins: dict[tuple[str, str], PluginInfo] = field(default_factory=dict, init=False)
    failures: list[LoadFailure] = field(default_factory=list, init=False)
    skipped: list[str] = field(default_factory=list, init=False)

    def __post_init__(self) -> None:
        if self.strict is None:
            self.strict = os.environ.get("SURGIPLAN_STRICT_PLUGINS", "") not in ("", "0")
        if self.disabled is None:
            self.disabled = _env_list("SURGIPLAN_DISABLE_PLUGINS")
        if self.packages is None:
            self.packages = _env_list("SURGIPLAN_PLUGIN_PACKAGES") or None
        self._trace = os.environ.get("SURGIPLAN_TRACE_HOOKS", "") not in ("", "0")
        self._load()

    # ------------------------------------------------------------------ loading
    def _discover(self) -> list[metadata.EntryPoint]:
        found = metadata.entry_points(group=NAME) if self.entry_points is None else self.entry_points
        unique: dict[tuple[str, str, str], metadata.EntryPoint] = {}
        for ep in found:
            unique.setdefault((_dist_name(ep)[0], ep.name, ep.value), ep)
        return sorted(unique.values(), key=lambda ep: (_dist_name(ep)[0] != NAME, ep.name))

    def _fail(self, entry_point: str, package: str, message: str) -> None:
        if self.strict:
            raise PluginError(message + " (SURGIPLAN_STRICT_PLUGINS is set)")
        log.warning("%s; skipping it", message)
        self.failures.append(LoadFailure(entry_point, package, message))

    def _load(self) -> None:
        manager = pluggy.PluginManager(NAME)
        manager.add_hookspecs(hookspecs)
        owners: dict[str, tuple[str, str, str]] = {}
        for ep in self._discover():
            package, version = _dist_name(ep)
            if self.packages is not None and package not in self.packages:
                continue
            if ep.name in self.disabled:
                self.skipped.append(f"{ep.name} ({package})")
                continue
            try:
                obj = ep.load()
            except Exception as exc:  # any error inside third-party import code
                self._fail(
                    ep.name,
                    package,
                    f"plugin entry point '{ep.name}' from package '{package}' "
                    f"failed to import: {type(exc).__name__}: {exc}",
                )
                continue
            plugin_name = f"{package}:{ep.name}"
            if manager.is_registered(obj) or manager.has_plugin(plugin_name):
                continue
            try:
                manager.register(obj, name=plugin_name)
                manager.check_pending()
            except (pluggy.PluginValidationError, ValueError) as exc:
                if manager.has_plugin(plugin_name):
                    manager.unregister(name=plugin_name)
                self._fail(
                    ep.name,
                    package,
                    f"plugin entry point '{ep.name}' from package '{package}' is not a valid surgiplan plugin: {exc}",
                )
                continue
            owners[plugin_name] = (package, version, ep.name)

        for kind, (hook_name, _) in KINDS.items():
            caller = getattr(manager.hook, hook_name)
            for impl in caller.get_hookimpls():  # registration order
                package, version, ep_name = owners[impl.plugin_name]
                try:
                    specs = impl.function()
                    if self._trace:
                        print(
                            f"surgiplan hook: {impl.plugin_name}.{hook_name}() -> {[s.name for s in specs or []]}",
                            file=sys.stderr,
                        )
                    self._add(kind, specs or [], package, version, ep_name)
                except PluginError:
                    raise
                except Exception as exc:
                    self._fail(
                        ep_name,
                        package,
                        f"plugin entry point '{ep_name}' from package '{package}' "
                        f"failed in {hook_name}: {type(exc).__name__}: {exc}",
                    )

    def _add(self, kind: str, specs: Iterable[PluginSpec], package: str, version: str, ep_name: str) -> None:
        for spec in specs:
            if not isinstance(spec, PluginSpec):
                self._fail(
                    ep_name,
                    package,
                    f"plugin entry point '{ep_name}' from package '{package}': its {kind} hook must return "
                    f"PluginSpec records, got {type(spec).__name__}",
                )
                continue
            if spec.name in self.disabled:
                self.skipped.append(f"{spec.name} ({package})")
                continue
            if not spec.unavailable:
                problem = plugin_class_problem(kind, spec.cls)
                if problem:
                    self._fail(
                        ep_name,
                        package,
                        f"{kind.replace('_', ' ')} '{spec.name}' from package '{package}' (entry point "
                        f"'{ep_name}') is refused: {problem}",
                    )
                    continue
            key = (kind, spec.name)
            if key in self.plugins:
                other = self.plugins[key]
                raise PluginError(
                    f"two plugins are both named '{spec.name}' ({kind}): one from package "
                    f"'{other.package}' (entry point '{other.entry_point}'), one from package "
                    f"'{package}' (entry point '{ep_name}'); uninstall one, or disable one with "
                    f"SURGIPLAN_DISABLE_PLUGINS={ep_name}"
                )
            self.plugins[key] = PluginInfo(
                spec.name, kind, spec.cls, spec.description, package, version, ep_name, spec.unavailable
            )

    # ------------------------------------------------------------------ lookup
    def names(self, kind: str) -> list[str]:
        return sorted(name for (k, name), info in self.plugins.items() if k == kind and not info.unavailable)

    def all(self) -> list[PluginInfo]:
        return sorted(self.plugins.values(), key=lambda p: (p.kind, p.name))

    def get(self, kind: str, name: str, *, location: str | None = None) -> PluginInfo:
        """The plugin ``name`` of ``kind``; a :class:`PluginError` that lists the choices otherwise."""
        info = self.plugins.get((kind, name))
        label = kind.replace("_", " ")
        if info is not None and info.unavailable:
            raise PluginError(f"{label} '{name}' is not available: {info.unavailable}", location=location)
        if info is not None:
            return info
        message = f"unknown {label} '{name}'"
        elsewhere = [k for (k, n) in self.plugins if n == name]
        if elsewhere:
            message += f" ('{name}' is a {elsewhere[0].replace('_', ' ')})"
        if any(name in entry for entry in self.skipped):
            message += " (it is disabled by SURGIPLAN_DISABLE_PLUGINS)"
        message += f"; {choices_hint(name, self.names(kind))}"
        if self.failures:
            broken = ", ".join(f"'{f.entry_point}' ({f.package})" for f in self.failures)
            message += f". Note: plugin entry points that failed to load: {broken}"
        raise PluginError(message, location=location)


def _interfaces() -> dict[str, type]:
    from .deformable import DeformableModel
    from .devices import Device
    from .planning import Planner
    from .spaces.base import Space

    return {"planner": Planner, "deformable_model": DeformableModel, "device": Device, "space": Space}


def plugin_class_problem(kind: str, cls: Any) -> str:
    """Why ``cls`` cannot be a plugin of ``kind`` (empty if it can).

    It must subclass the interface of its kind (:class:`~surgiplan.Planner`, ...) and declare a pydantic
    ``Settings`` model that forbids unknown keys (``extra="forbid"``) at every level, so that a misspelt
    setting is an error naming it rather than silently ignored.
    """
    interface = _interfaces()[kind]
    if not (isinstance(cls, type) and issubclass(cls, interface)):
        what = cls.__name__ if isinstance(cls, type) else type(cls).__name__
        return f"{what} is not a subclass of surgiplan.{interface.__name__}"
    settings = getattr(cls, "Settings", None)
    if not (isinstance(settings, type) and issubclass(settings, BaseModel)):
        return f"{cls.__name__} has no pydantic Settings model"
    permissive = permissive_models(settings)
    if permissive:
        return (
            f"its settings model {', '.join(permissive)} accepts unknown keys; declare "
            'model_config = ConfigDict(extra="forbid") so a misspelt setting is an error'
        )
    return ""


def permissive_models(model: type[BaseModel], label: str | None = None, seen: set | None = None) -> list[str]:
    """The settings models (by field path) inside ``model`` that do not forbid extra keys."""
    import typing

    seen = set() if seen is None else seen
    if model in seen:
        return []
    seen.add(model)
    label = label or model.__name__
    found = [] if model.model_config.get("extra") == "forbid" else [label]
    for name, info in model.model_fields.items():
        stack = [info.annotation]
        while stack:
            item = stack.pop()
            if isinstance(item, type) and issubclass(item, BaseModel):
                found += permissive_models(item, f"{label}.{name}", seen)
            else:
                stack.extend(typing.get_args(item))
    return found


_default: PluginRegistry | None = None


def default_registry() -> PluginRegistry:
    """The registry of installed plugins, loaded once per process."""
    global _default
    if _default is None:
        _default = PluginRegistry()
    return _default


def reset_default_registry() -> None:
    """Forget the cached registry (tests, or after installing a plugin at run time)."""
    global _default
    _default = None
