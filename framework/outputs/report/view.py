"""What ``surgiplan view OUT_DIR`` checks before serving: a finished run's directory, its report written."""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from pathlib import Path

from ...errors import OutputError, SurgiplanError
from . import REPORT, write_report

log = logging.getLogger(__name__)


def ensure_report(out: Path, announce: Callable[[str], None] = print) -> Path:
    """``out/report.html``, written from ``result.json`` first when the run predates reports.

    Raises :class:`~surgiplan.errors.OutputError` (exit status 2, no traceback) when ``out`` is not a
    finished run's output directory, saying what it is instead.
    """
    out = Path(out)
    if not out.exists():
        raise OutputError(f"{out}: no such directory; give a run's output directory (the one with result.json)")
    if not out.is_dir():
        raise OutputError(f"{out} is a file; give a run's output directory (the one with result.json)")
    record = out / "result.json"
    if not record.is_file():
        if (out / ".in-progress.json").exists():
            raise OutputError(
                f"{out} has no result.json: a run is still writing there (or was killed before it finished); "
                "view it when the run has ended"
            )
        raise OutputError(f"{out} has no result.json: not a surgiplan run's output directory")
    try:
        document = json.loads(record.read_text())
        if not isinstance(document, dict) or not isinstance(document.get("stages"), list):
            raise ValueError("no list of stages")
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise OutputError(f"{record} is not a readable surgiplan record ({exc})") from None
    report = out / REPORT
    if report.is_file():
        return report
    pipeline = None
    try:  # the scene and the stages' spaces come from the pipeline file; without it, no obstacles
        from ...pipeline import load_pipeline

        pipeline = load_pipeline(document.get("pipeline_file", ""), output_dir=out)
    except (SurgiplanError, OSError, TypeError, ValueError) as exc:
        log.warning("the pipeline file of %s cannot be loaded (%s): the report has no obstacles", out, exc)
    write_report(out, document, pipeline)
    announce(f"wrote {report} (the run predates reports)")
    return report
