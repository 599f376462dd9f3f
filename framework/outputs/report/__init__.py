"""``report.html``: an interactive 3D report of a run that opens from the file system, and the live view.

:func:`write_run_report` is what the runner calls, right before it writes
``result.json``: it writes ``report.html`` atomically beside it (the run's
obstacles, every stage's path with its below-threshold stretches and
critical regions, starts and goals, stored roadmaps, metrics and figures,
tissue meshes coloured by stress and motions over time with a slider) and
lists it in the document's ``files``. It never costs the run its record: a
failure (or Ctrl-C) while writing the report is a warning, and
``result.json`` is written all the same.

The page is one file: three.js (vendored, see ``static/VENDOR.md``), the
viewer script and the data are inlined; figures are the PNGs beside it.
Nothing is fetched from anywhere (its Content-Security-Policy forbids it).
``surgiplan view OUT_DIR`` serves it on 127.0.0.1 (:mod:`.server`); the same
viewer, fed over a websocket, is ``surgiplan view --live``.
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from ...storage import write_text_atomic
from .data import report_data, scene_data

log = logging.getLogger(__name__)

__all__ = ["REPORT", "page", "report_data", "scene_data", "write_report", "write_run_report"]

#: the report's file name in a run's output directory
REPORT = "report.html"


def _static(name: str) -> str:
    return resources.files(__package__).joinpath("static", name).read_text(encoding="utf-8")


def _inline_json(value: Any) -> str:
    """JSON that cannot end the <script> element it sits in."""
    return json.dumps(value, separators=(",", ":"), allow_nan=False).replace("</", "<\\/").replace("<!--", "<\\!--")


def page(data: Mapping[str, Any], title: str) -> str:
    """The whole HTML page for ``data`` (a report's, or a live view's with ``"live": true``)."""
    html = _static("template.html")
    parts = {
        "__TITLE__": title.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;"),
        "/*__CSS__*/": _static("report.css"),
        "__DATA__": _inline_json(data),
        "/*__THREE__*/": _static("three.iife.min.js"),
        "/*__APP__*/": _static("report.js"),
    }
    # one pass over the template only: a value (the data, a stage's message) never has a marker replaced
    return re.sub("|".join(re.escape(k) for k in parts), lambda m: parts[m.group(0)], html)


def _clean(value: Any) -> Any:
    """NaN and infinities (which JSON has not) as null."""
    if isinstance(value, float):
        return value if value == value and abs(value) != float("inf") else None
    if isinstance(value, Mapping):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    return value


def write_report(out: str | Path, document: Mapping[str, Any], pipeline=None) -> Path:
    """Write ``report.html`` for the run recorded in ``document`` (result.json's content) into ``out``."""
    out = Path(out)
    data = _clean(report_data(out, document, pipeline))
    name = document.get("name") or out.name
    path = out / REPORT
    write_text_atomic(path, page(data, f"{name} · surgiplan report"))
    return path


def write_run_report(out: Path, document: dict[str, Any], pipeline) -> None:
    """The runner's call, right before result.json: write ``report.html`` and list it in ``document["files"]``.

    Never raises: the run's record matters more than its report.
    """
    files = list(document.get("files", []))
    document["files"] = sorted({*files, REPORT})
    try:
        write_report(out, document, pipeline)
    except Exception as exc:
        log.warning("could not write %s: %s: %s", out / REPORT, type(exc).__name__, exc)
        document["files"] = files
    except KeyboardInterrupt:
        log.warning("interrupted while writing %s: the report is not written, the run's record is", out / REPORT)
        document["files"] = files
