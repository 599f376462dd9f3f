"""The plugin registry: a small typed facade over pluggy's PluginManager.

It finds plugins through the ``surgiplan`` entry-point group (ours included),
first collects the **stage kinds** they register (:mod:`surgiplan.kinds`: the
built-in plan, simulate, execute and guide, and any third party's), adds the
hook each kind declares for its plugins, then calls each plugin's
registration hooks one plugin at a time (so an error names the plugin and its
package), and answers ``get(kind, name)`` and ``stage_kind(name)``.

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

import email.parser
import functools
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
from .hookspecs import NAME, PluginInfo, PluginSpec
from .kinds import PluginKind, StageKind
from .spaces.base import Space
from .status import declare_statuses

log = logging.getLogger(__name__)

__all__ = ["LoadFailure", "PluginInfo", "PluginRegistry", "StageKindInfo", "default_registry", "plugin_class_problem"]

#: the plugin kind the core itself declares (spaces serve every stage kind that plans)
SPACE = PluginKind("space", "surgiplan_register_spaces", Space)


@dataclass(frozen=True)
class StageKindInfo:
    """A registered stage kind and where it came from."""

    kind: StageKind
    package: str
    version: str
    entry_point: str

    @property
    def name(self) -> str:
        return self.kind.name


@dataclass
class LoadFailure:
    """A plugin that could not be loaded and was skipped (``surgiplan plugins`` lists them): its entry point, its
    distribution (``package``) and the reason (``error``)."""

    entry_point: str
    package: str
    error: str


def _env_list(name: str) -> set[str]:
    return {part.strip() for part in os.environ.get(name, "").split(",") if part.strip()}


def _dist_name(ep: metadata.EntryPoint) -> tuple[str, str]:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return "unknown", ""
    # the metadata's headers only: dist.metadata parses the whole file, long description included (surgiplan's
    # README), and dist.name and dist.version each parse it again; that was most of `surgiplan plugins`' time
    text = dist.read_text("METADATA") or dist.read_text("PKG-INFO")
    if text is None:
        return dist.metadata["Name"] or dist.name, dist.version or ""
    headers = email.parser.HeaderParser().parsestr(text.split("\n\n", 1)[0])
    return headers["Name"] or dist.name, headers["Version"] or ""


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
    stage_kinds: dict[str, StageKindInfo] = field(default_factory=dict, init=False)
    plugin_kinds: dict[str, PluginKind] = field(default_factory=dict, init=False)
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
    def _discover(self) -> list[tuple[metadata.EntryPoint, str, str]]:
        """The entry points to load, surgiplan's first, each with its distribution's name and version (read once
        per entry point: each read parses the distribution's METADATA headers)."""
        found = metadata.entry_points(group=NAME) if self.entry_points is None else self.entry_points
        unique: dict[tuple[str, str, str], tuple[metadata.EntryPoint, str, str]] = {}
        for ep in found:
            package, version = _dist_name(ep)
            unique.setdefault((package, ep.name, ep.value), (ep, package, version))
        return sorted(unique.values(), key=lambda named: (named[1] != NAME, named[0].name))

    def _fail(self, entry_point: str, package: str, message: str) -> None:
        if self.strict:
            raise PluginError(message + " (SURGIPLAN_STRICT_PLUGINS is set)")
        log.warning("%s; skipping it", message)
        self.failures.append(LoadFailure(entry_point, package, message))

    def _load(self) -> None:
        manager = pluggy.PluginManager(NAME)
        manager.add_hookspecs(hookspecs)
        owners: dict[str, tuple[str, str, str]] = {}
        for ep, package, version in self._discover():
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
                manager.register(obj, name=plugin_name)  # hooks of stage kinds not yet known are checked below
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

        self._load_stage_kinds(manager, owners)
        self.plugin_kinds.setdefault(SPACE.name, SPACE)  # after the stages' kinds: names are looked up in this order
        self._refuse_unknown_hooks(manager, owners)
        for kind in self.plugin_kinds.values():
            caller = getattr(manager.hook, kind.hook)
            for impl in caller.get_hookimpls():  # registration order
                package, version, ep_name = owners[impl.plugin_name]
                try:
                    specs = impl.function()
                    if self._trace:
                        print(
                            f"surgiplan hook: {impl.plugin_name}.{kind.hook}() -> {[s.name for s in specs or []]}",
                            file=sys.stderr,
                        )
                    self._add(kind.name, specs or [], package, version, ep_name)
                except PluginError:
                    raise
                except Exception as exc:
                    self._fail(
                        ep_name,
                        package,
                        f"plugin entry point '{ep_name}' from package '{package}' "
                        f"failed in {kind.hook}: {type(exc).__name__}: {exc}",
                    )

    def _load_stage_kinds(self, manager: pluggy.PluginManager, owners: dict[str, tuple[str, str, str]]) -> None:
        """Collect the stage kinds, and add the hook each declares for its plugins."""
        for impl in manager.hook.surgiplan_register_stage_kinds.get_hookimpls():
            package, version, ep_name = owners[impl.plugin_name]
            where = f"plugin entry point '{ep_name}' from package '{package}'"
            try:
                kinds = list(impl.function() or [])
            except Exception as exc:
                self._fail(ep_name, package, f"{where} failed in surgiplan_register_stage_kinds: {exc}")
                continue
            if self._trace:
                names = [getattr(k, "name", k) for k in kinds]
                hook = f"{impl.plugin_name}.surgiplan_register_stage_kinds()"
                print(f"surgiplan hook: {hook} -> {names}", file=sys.stderr)
            for kind in kinds:
                problem = self._stage_kind_problem(kind, manager)
                if problem:
                    label = getattr(kind, "name", kind)
                    self._fail(ep_name, package, f"{where}: stage kind {label!r} is refused: {problem}")
                    continue
                if kind.name in self.disabled:
                    self.skipped.append(f"{kind.name} ({package})")
                    continue
                self.stage_kinds[kind.name] = StageKindInfo(kind, package, version, ep_name)
                declare_statuses(kind.name, kind.succeeded)  # what StageResult.succeeded reads
                if kind.plugin_kind is not None:
                    self.plugin_kinds[kind.plugin_kind.name] = kind.plugin_kind

    def _stage_kind_problem(self, kind: Any, manager: pluggy.PluginManager) -> str:
        """Why ``kind`` cannot be registered ('' if it can); adds its plugin hook to ``manager`` when it can."""
        if not isinstance(kind, StageKind):
            return f"it is a {type(kind).__name__}, not an instance of a surgiplan.kinds.StageKind subclass"
        name = getattr(kind, "name", None)
        if not isinstance(name, str) or not name.isidentifier():
            return f"its name {name!r} is not an identifier"
        if name in self.stage_kinds:
            other = self.stage_kinds[name]
            return f"stage kind '{name}' is already registered by package '{other.package}'"
        if not (isinstance(kind.model, type) and issubclass(kind.model, BaseModel)):
            return "its model is not a pydantic model (a subclass of surgiplan.kinds.StageModel)"
        permissive = permissive_models(kind.model)
        if permissive:
            return f"its model {', '.join(permissive)} accepts unknown keys; declare extra='forbid'"
        plugin_kind = kind.plugin_kind
        if plugin_kind is None:
            return ""
        known = self.plugin_kinds.get(plugin_kind.name)
        if known is not None and known != plugin_kind:
            return f"its plugin kind '{plugin_kind.name}' differs from the one already declared ({known.hook})"
        if not _declared(manager, plugin_kind.hook):
            if kind.hookspecs is None:
                return f"it declares plugin kind '{plugin_kind.name}' but no hookspecs with {plugin_kind.hook}"
            try:
                manager.add_hookspecs(kind.hookspecs)
            except (pluggy.PluginValidationError, ValueError) as exc:
                return f"its hook {plugin_kind.hook} does not match what plugins implement: {exc}"
            if not _declared(manager, plugin_kind.hook):
                return f"its hookspecs do not declare {plugin_kind.hook}"
        return ""

    def _refuse_unknown_hooks(self, manager: pluggy.PluginManager, owners: dict[str, tuple[str, str, str]]) -> None:
        """A plugin implementing a hook nobody declares (a misspelt hook, a stage kind not installed) is refused."""
        for plugin_name, plugin in list(manager.list_name_plugin()):
            unknown = sorted(caller.name for caller in (manager.get_hookcallers(plugin) or []) if not caller.has_spec())
            if unknown:
                package, _, ep_name = owners[plugin_name]
                manager.unregister(name=plugin_name)
                self._fail(
                    ep_name,
                    package,
                    f"plugin entry point '{ep_name}' from package '{package}' is not a valid surgiplan plugin: it "
                    f"implements {', '.join(unknown)}, which no installed stage kind declares",
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
            if not spec.unavailable and not isinstance(spec.cls, str):  # a "module:Class" is checked at first use
                problem = plugin_class_problem(self.plugin_kinds[kind], spec.cls)
                if problem:
                    self._fail(
                        ep_name,
                        package,
                        f"{kind.replace('_', ' ')} '{spec.name}' from package '{package}' (entry point "
                        f"'{ep_name}') is refused: {problem}",
                    )
                    continue
            key = (kind, spec.name)
            if key in self.plugins:  # the first registration keeps the name; only this one is refused
                other = self.plugins[key]
                self._fail(
                    ep_name,
                    package,
                    f"{kind.replace('_', ' ')} '{spec.name}' from package '{package}' (entry point '{ep_name}') is "
                    f"refused: two plugins are both named '{spec.name}', and package '{other.package}' (entry point "
                    f"'{other.entry_point}') registered it first; rename one, uninstall one, or disable one with "
                    f"SURGIPLAN_DISABLE_PLUGINS={ep_name}",
                )
                continue
            self.plugins[key] = PluginInfo(
                spec.name,
                kind,
                spec.cls,
                spec.description,
                package,
                version,
                ep_name,
                spec.unavailable,
                check=functools.partial(plugin_class_problem, self.plugin_kinds[kind]),
            )

    # ------------------------------------------------------------------ lookup
    def names(self, kind: str) -> list[str]:
        """The names of the usable (installed and available) plugins of ``kind`` (``planner``, ``device``, ...),
        sorted."""
        return sorted(name for (k, name), info in self.plugins.items() if k == kind and not info.unavailable)

    def all(self) -> list[PluginInfo]:
        """Every registered plugin, unavailable ones included, by kind then name."""
        return sorted(self.plugins.values(), key=lambda p: (p.kind, p.name))

    def stage_kind(self, name: str, *, location: str | None = None) -> StageKind:
        """The stage kind ``name``; a :class:`~surgiplan.errors.PluginError` that lists the choices otherwise."""
        info = self.stage_kinds.get(name)
        if info is not None:
            return info.kind
        message = f"unknown stage kind '{name}'"
        if any(name in entry for entry in self.skipped):
            message += " (it is disabled by SURGIPLAN_DISABLE_PLUGINS)"
        raise PluginError(f"{message}; {choices_hint(name, self.stage_kinds)}", location=location)

    def kinds_of(self, names) -> dict[str, StageKind]:
        """The registered stage kinds among ``names`` (a report of a run made with a kind since uninstalled
        shows that stage plainly)."""
        return {n: self.stage_kinds[n].kind for n in names if n in self.stage_kinds}

    def get(self, kind: str, name: str, *, location: str | None = None) -> PluginInfo:
        """The plugin ``name`` of ``kind``; a :class:`~surgiplan.errors.PluginError` that lists the choices
        otherwise."""
        info = self.plugins.get((kind, name))
        label = kind.replace("_", " ")
        if info is not None and info.unavailable:
            raise PluginError(f"{label} '{name}' is not available: {info.unavailable}", location=location)
        if info is not None:
            try:
                info.cls  # noqa: B018 - a class named by "module:Class" is imported (and checked) here
            except PluginError as exc:
                exc.location = exc.location or location
                raise
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


def _declared(manager: pluggy.PluginManager, hook: str) -> bool:
    caller = getattr(manager.hook, hook, None)
    return caller is not None and caller.has_spec()


def plugin_class_problem(kind: PluginKind, cls: Any) -> str:
    """Why ``cls`` cannot be a plugin of ``kind`` (empty if it can).

    It must subclass the interface of its kind (:class:`~surgiplan.planning.Planner`, ...) and declare a pydantic
    ``Settings`` model that forbids unknown keys (``extra="forbid"``) at every level, so that a misspelt
    setting is an error naming it rather than silently ignored.
    """
    interface = kind.interface
    if not (isinstance(cls, type) and issubclass(cls, interface)):
        what = cls.__name__ if isinstance(cls, type) else type(cls).__name__
        return f"{what} is not a subclass of surgiplan.{interface.__name__}"
    settings = getattr(cls, "Settings", None)
    if not (isinstance(settings, type) and issubclass(settings, BaseModel)):
        return f"{cls.__name__} has no pydantic Settings model"
    permissive = permissive_models(settings)
    if permissive:
        return (
            f"its settings model {', '.join(permissive)} accepts unknown keys; "
            "subclass surgiplan.StrictModel (extra='forbid') so a misspelt setting is an error"
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
