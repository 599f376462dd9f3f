"""The one-screen summary table printed at the end of ``surgiplan run``."""

from __future__ import annotations

from collections.abc import Sequence

from rich.console import Console
from rich.table import Table

from ..results import StageResult


def _length(value, k: float) -> str:
    return "—" if value is None else f"{value * k:.4g}"


def _seconds(value) -> str:
    return "—" if value is None else f"{value:.3g}"


def summary_table(name: str, results: Sequence[StageResult], *, unit: str, unit_scale: float, output_dir: str) -> Table:
    k = 1.0 / unit_scale
    table = Table(
        title=f"surgiplan run: {name}",
        caption=f"lengths in {unit}, times in s; results in {output_dir}/result.json",
        title_justify="left",
        caption_justify="left",
    )
    table.add_column("stage", overflow="fold")
    table.add_column("plugin")
    table.add_column("status")
    table.add_column("length", justify="right")
    table.add_column("min clear.", justify="right")
    table.add_column("< thresh.", justify="right")
    table.add_column("build", justify="right")
    table.add_column("run", justify="right")
    for r in results:
        m = r.metrics
        style = "green" if r.succeeded else ("yellow" if r.status == "skipped" else "red")
        clearance = m.get("min_clearance_m", m.get("executed_min_clearance_m"))
        table.add_row(
            r.name,
            r.plugin,
            f"[{style}]{r.status}[/{style}]",
            _length(m.get("length_m"), k),
            _length(clearance, k),
            _length(m.get("length_below_threshold_m"), k),
            _seconds(m.get("build_s")),
            _seconds(m.get("query_s", m.get("run_s"))),
        )
    return table


def print_summary(console: Console, *args, **kwargs) -> None:
    console.print(summary_table(*args, **kwargs))
