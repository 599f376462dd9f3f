"""Sphinx configuration of surgiplan's documentation site (``make docs``; the test suite builds it with -W).

Why Sphinx (not MkDocs): surgiplan's docstrings are written for it (``:class:`` roles, ``#:`` comments on
attributes, which autodoc reads), it is maintained for the long term, and the projects our users know (pytest,
python-can, datasette, FEniCSx) use it. The pages are Markdown (MyST); the theme is furo, which loads no web
fonts and no script from elsewhere: the site builds and reads offline.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent / "_ext"))

import surgiplan
from surgiplan_docs import known_gaps

project = "surgiplan"
author = "the surgiplan developers"
copyright = "the surgiplan developers, BSD-3-Clause"
release = surgiplan.__version__
version = ".".join(release.split(".")[:2])

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinxarg.ext",
    "surgiplan_docs",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "known-gaps.txt"]
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

# every cross-reference must resolve (warnings are errors in the test build); names from other projects are
# not linked (no intersphinx: it would download their inventories), so they are ignored here by package
nitpicky = True
nitpick_ignore_regex = [
    (r"py:.*", r"(numpy|np|scipy|pydantic|pydantic_core|pluggy|coal|trimesh|pathlib|typing|collections|enum)\b.*"),
    (r"py:.*", r"(dataclasses|concurrent|sqlite3|datetime|abc|types|io|logging|threading|asyncio|can|canopen)\b.*"),
    (r"py:.*", r"(pymavlink|dask|distributed|matplotlib|rich|meshio|pinocchio|osqp|annotated_types)\b.*"),
    (r"py:class", r"(NDArray|ndarray|Path|Any|Callable|Iterable|Iterator|Sequence|Mapping|Literal|Self)"),
    # the values of type aliases (surgiplan.units.Length = Annotated[float, BeforeValidator(_to_metres), ...])
    (r"py:.*", r"(builtins\..*|surgiplan(\.\w+)*\._\w+|'dict\[str)"),
    (r"py:class", r"(BaseModel|FieldInfo|ValidationInfo|Enum|StrEnum|IntEnum|ABC|Protocol|TypeVar)"),
]

# the debt the code had when the site came: let through, nothing new (the list only shrinks)
surgiplan_known_undocumented, _known_references = known_gaps(Path(__file__).parent / "known-gaps.txt")
nitpick_ignore = _known_references
# sphinx-argparse's domain answers no MyST "any" reference; harmless, and not ours to fix
suppress_warnings = ["myst.domains"]

autodoc_default_options = {"members": True, "undoc-members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # signatures without annotations: the docstrings say what the types mean
autodoc_preserve_defaults = True

html_theme = "furo"
html_title = f"surgiplan {release}"
html_static_path = ["_static"]
html_css_files = ["surgiplan.css"]  # the schema tables fit the page (no horizontal scroll)
html_show_sourcelink = False
html_theme_options = {"navigation_with_keys": True}
