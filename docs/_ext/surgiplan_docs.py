"""Sphinx extension of surgiplan's documentation: the pages generated from the code, at build time.

- ``surgiplan-schema``: the keys of a pipeline file, of each stage kind and of every registered plugin's
  ``Settings``, read from the pydantic models (:mod:`schema_fields`), so the page cannot drift from the code.
- ``surgiplan-exports``: what ``from surgiplan import ...`` offers, each name linked to where it is documented.
- every public name autodoc documents must have a docstring: an empty one is a warning, and the build runs
  with warnings as errors (``-W``).
"""

from __future__ import annotations

import importlib
import inspect
import re

from docutils import nodes
from docutils.statemachine import StringList
from schema_fields import model_summary, rows
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles

logger = logging.getLogger(__name__)

#: the plugin kinds in the order the schema page lists them, with where their settings go in a pipeline
PLUGIN_KINDS = {
    "planner": "a ``plan`` stage: ``plugin: NAME`` and ``settings:``",
    "space": "a ``plan`` stage's ``space: {kind: NAME, ...}``",
    "deformable_model": "a ``simulate`` stage (and the retraction planner's ``model:``): ``plugin: NAME``, "
    "``settings:``",
    "device": "an ``execute`` stage: ``plugin: NAME`` and ``settings:``",
    "source": "a ``guide`` stage: ``plugin: NAME`` and ``settings:``",
}
_ESCAPE = re.compile(r"([\\`*|_])")


def escape(text: str) -> str:
    """Plain text safe inside reST: no stray emphasis, literals, substitutions or references."""
    return _ESCAPE.sub(r"\\\1", text)


def _literal(text: str) -> str:
    return f"``{text}``" if text else ""


def table(model, prefix: str = "") -> list[str]:
    """A ``list-table`` of every key of ``model`` (nested keys flattened)."""
    lines = [".. list-table::", "   :header-rows: 1", "   :width: 100%", "   :widths: 26 18 12 10 34"]
    lines += ["   :class: schema-table", ""]
    lines += ["   * - key", "     - type", "     - default", "     - unit", "     - description"]
    for row in rows(model, prefix):
        lines += [f"   * - {_literal(row.key)}", f"     - {escape(row.type)}", f"     - {_literal(row.default)}"]
        lines += [f"     - {_literal(row.unit)}", f"     - {escape(row.description)}"]
    return [*lines, ""]


def _heading(text: str, char: str) -> list[str]:
    return [text, char * max(len(text), 4), ""]


def schema_lines() -> list[str]:
    """The schema page's body, as reST."""
    from surgiplan.config import PipelineModel
    from surgiplan.registry import default_registry

    registry = default_registry()
    out = [*_heading("Pipeline file", "-"), ".. _schema-pipeline:", ""]
    out += [escape(model_summary(PipelineModel) or "The top-level keys of a pipeline file."), ""]
    out += table(PipelineModel)
    out += [*_heading("Stage kinds", "-")]
    out += ["Each entry of ``pipeline:`` is validated against its kind's keys; ``settings:`` holds its plugin's.", ""]
    for name, info in sorted(registry.stage_kinds.items()):
        if info.package != "surgiplan":
            continue
        out += [f".. _schema-stage-{name}:", "", *_heading(f"stage: {name}", "~")]
        out += [escape(info.kind.description), ""] if info.kind.description else []
        out += table(info.kind.model)
    for kind, where in PLUGIN_KINDS.items():
        plugins = sorted(
            (p for (k, _), p in registry.plugins.items() if k == kind and p.package == "surgiplan"),
            key=lambda p: p.name,
        )
        out += [*_heading(f"{kind.replace('_', ' ')} plugins", "-"), f"Their settings go in {where}.", ""]
        for plugin in plugins:
            out += [f".. _schema-{kind}-{plugin.name}:", "", *_heading(f"{kind}: {plugin.name}", "~")]
            out += [escape(plugin.description), ""] if plugin.description else []
            if plugin.unavailable:
                out += [f"Not installed here: {escape(plugin.unavailable)}", ""]
            if plugin.cls is not None:
                model = plugin.cls.Settings
                summary = model_summary(model)
                name = f"``{model.__module__}.{model.__qualname__}``"
                out += [name + (f": {escape(summary)}" if summary else ""), ""]
                out += table(model) if model.model_fields else ["No settings.", ""]
    return out


class SchemaDirective(SphinxDirective):
    """``.. surgiplan-schema::`` the keys of pipeline files, stage kinds and plugins."""

    def run(self) -> list[nodes.Node]:
        container = nodes.section()
        container.document = self.state.document
        nested_parse_with_titles(self.state, StringList(schema_lines(), source="surgiplan-schema"), container)
        return container.children


class ExportsDirective(SphinxDirective):
    """``.. surgiplan-exports::`` each name of ``surgiplan.__all__``, linked to the module that documents it."""

    def run(self) -> list[nodes.Node]:
        import surgiplan

        lines = [".. list-table::", "   :header-rows: 1", "   :widths: 30 70", "", "   * - name", "     - summary"]
        for name in sorted(surgiplan.__all__, key=str.lower):
            obj = getattr(surgiplan, name)
            if inspect.isclass(obj) or inspect.isfunction(obj):
                target = f"{obj.__module__}.{obj.__qualname__}"
            else:  # a type alias or an instance (hookimpl): documented as the data of the module that defines it
                target = f"{_data_module(name, obj)}.{name}"
            role = "class" if inspect.isclass(obj) else "func" if callable(obj) and inspect.isfunction(obj) else "obj"
            doc = inspect.getdoc(obj) if inspect.isclass(obj) or inspect.isfunction(obj) else ""
            summary = (doc or "").split("\n\n")[0].replace("\n", " ")
            lines += [f"   * - :{role}:`~{target}`", f"     - {escape(summary)}" if summary else "     -"]
        container = nodes.container()
        self.state.nested_parse(StringList(lines, source="surgiplan-exports"), self.content_offset, container)
        return container.children


def _data_module(name: str, obj) -> str:
    for module in ("surgiplan.units", "surgiplan.hookspecs", "surgiplan.models", "surgiplan.status"):
        if vars(importlib.import_module(module)).get(name) is obj:
            return module
    raise ValueError(f"surgiplan.{name}: no API page documents it; add its module to surgiplan-exports")


def _skip_foreign(app, what, name, obj, skip, options):
    """A module page documents what the module defines: not the names it imports (typing's, another module's)."""
    if what == "module" and (inspect.isclass(obj) or inspect.isfunction(obj)):
        home = getattr(obj, "__module__", "") or ""
        page = app.env.temp_data.get("autodoc:module") or app.env.ref_context.get("py:module") or ""
        if page and home != page and not home.startswith(page + "."):
            return True
    return None


def known_gaps(path) -> tuple[set[str], list[tuple[str, str]]]:
    """The documentation debt recorded in ``known-gaps.txt``: undocumented names and unresolved references
    that the code had when the site was introduced. The build lets these through and nothing new; the list
    only shrinks."""
    undocumented, references = set(), []
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        kind, target = line.split(None, 1)
        if kind == "undocumented":
            undocumented.add(target)
        else:
            references.append((kind, target))
    return undocumented, references


def _require_docstring(app, what, name, obj, options, lines) -> None:
    """Warn (an error under -W) when a public class, function, method or module has no docstring."""
    if what not in ("module", "class", "exception", "function", "method"):
        return
    if any(part.startswith("_") for part in name.split(".")):
        return
    if name in app.config.surgiplan_known_undocumented:
        return
    if not any(line.strip() for line in lines):
        logger.warning("undocumented public name %s (%s): give it a docstring", name, what, type="surgiplan")


def setup(app):
    app.add_directive("surgiplan-schema", SchemaDirective)
    app.add_directive("surgiplan-exports", ExportsDirective)
    app.add_config_value("surgiplan_known_undocumented", set(), "env")
    app.connect("autodoc-process-docstring", _require_docstring)
    app.connect("autodoc-skip-member", _skip_foreign)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
