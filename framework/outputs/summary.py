"""The one-screen summary table printed at the end of ``surgiplan run``.

One row per stage: its status, the path's length and clearance against the
threshold (plan and execute stages), and a *details* column with what
matters for its kind (:meth:`surgiplan.kinds.StageKind.details`: a
simulate stage's energy, largest stress and displacement, an execute
stage's tracking error and faults, ...), then its message (a plan stage's
critical regions, or why a stage did not succeed).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from ..clearance import threshold_value
from ..kinds import StageKind
from ..registry import default_registry
from ..results import StageResult


def _length(value, k: float) -> str:
    return "—" if value is None else f"{value * k:.4g}"


def _seconds(value) -> str:
    if value is None:
        return "—"
    return f"{value:.2g}" if value < 1 else f"{value:.3g}"


def si(value: float, unit: str) -> str:
    """1.889e6 Pa -> '1.89 MPa'."""
    for factor, prefix in ((1e9, "G"), (1e6, "M"), (1e3, "k"), (1.0, ""), (1e-3, "m"), (1e-6, "µ")):
        if abs(value) >= factor:
            return f"{value / factor:.3g} {prefix}{unit}"
    return f"{value:.3g} {unit}"


def details(result: StageResult, k: float, unit: str, kinds: Mapping[str, StageKind] | None = None) -> str:
    """What matters about a stage in one line (plain text): what its kind says of it, then its message."""
    kinds = default_registry().kinds_of({result.stage}) if kinds is None else kinds
    kind = kinds.get(result.stage)
    parts = list(kind.details(result, k, unit)) if kind is not None else []
    if result.message:
        parts.append(result.message)
    parts += [f"warning: {w}" for w in result.warnings]
    return "; ".join(parts)


def summary_table(name: str, results: Sequence[StageResult], *, unit: str, unit_scale: float, output_dir: str) -> Table:
    k = 1.0 / unit_scale
    table = Table(
        title=f"surgiplan run: {name}",
        caption=f"lengths in {unit}, times in s; results in {output_dir}/result.json",
        title_justify="left",
        caption_justify="left",
    )
    table.add_column("stage", no_wrap=True)
    table.add_column("plugin")
    table.add_column("status")
    table.add_column("length", justify="right")
    table.add_column("min clear.", justify="right")
    table.add_column("threshold", justify="right")
    table.add_column("< thresh.", justify="right")
    table.add_column("details", overflow="fold", ratio=1, min_width=36)
    table.add_column("build", justify="right")
    table.add_column("run", justify="right")
    kinds = default_registry().kinds_of({r.stage for r in results})
    for r in results:
        m = r.metrics
        style = "green" if r.succeeded else ("yellow" if r.status in ("skipped", "not_run") else "red")
        clearance = m.get("min_clearance_m", m.get("executed_min_clearance_m"))
        threshold = threshold_value(r.clearance_threshold) if r.clearance_threshold is not None else None
        threshold = threshold if threshold is not None else m.get("clearance_threshold_m")
        table.add_row(
            r.name,
            r.plugin,
            f"[{style}]{r.status}[/{style}]",
            _length(m.get("length_m", m.get("path_length_m")), k),
            _length(clearance, k),
            _length(threshold, k),
            _length(m.get("length_below_threshold_m", m.get("below_threshold_m")), k),
            escape(details(r, k, unit, kinds)),
            _seconds(m.get("build_s")),
            _seconds(m.get("query_s", m.get("run_s"))),
        )
    return table


def print_summary(console: Console, *args, **kwargs) -> None:
    console.print(summary_table(*args, **kwargs))
