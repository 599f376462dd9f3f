"""The one-screen summary table printed at the end of ``surgiplan run``.

One row per stage: its status, the path's length and clearance against the
threshold (plan and execute stages), and a *details* column with what
matters for its kind: a plan stage's message (its critical regions), a
simulate stage's energy, largest stress and displacement, an execute
stage's tracking error and faults, or why a stage did not succeed.
"""

from __future__ import annotations

from collections.abc import Sequence

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from ..results import StageResult


def _length(value, k: float) -> str:
    return "—" if value is None else f"{value * k:.4g}"


def _seconds(value) -> str:
    if value is None:
        return "—"
    return f"{value:.2g}" if value < 1 else f"{value:.3g}"


def _si(value: float, unit: str) -> str:
    """1.889e6 Pa -> '1.89 MPa'."""
    for factor, prefix in ((1e9, "G"), (1e6, "M"), (1e3, "k"), (1.0, ""), (1e-3, "m"), (1e-6, "µ")):
        if abs(value) >= factor:
            return f"{value / factor:.3g} {prefix}{unit}"
    return f"{value:.3g} {unit}"


def details(result: StageResult, k: float, unit: str) -> str:
    """What matters about a stage in one line (plain text)."""
    m = result.metrics
    parts: list[str] = []
    if result.stage == "simulate" and result.succeeded:
        if "energy_J" in m:
            parts.append(f"energy {_si(m['energy_J'], 'J')}")
        if "max_stress_Pa" in m:
            parts.append(f"max stress {_si(m['max_stress_Pa'], 'Pa')}")
        if "max_displacement_m" in m:
            parts.append(f"max displacement {m['max_displacement_m'] * k:.3g} {unit}")
        for key, label in (("tip_deflection_error", "tip deflection vs elastica"), ("sag_error_m", "sag error")):
            if key in m:
                parts.append(f"{label} {m[key]:.3g}")
    elif result.stage == "execute" and result.status in ("completed", "stopped"):
        if "tracking_error_max_m" in m:
            rms = m.get("tracking_error_rms_m")
            text = f"tracking max {m['tracking_error_max_m'] * k:.3g} {unit}"
            parts.append(text + (f", rms {rms * k:.3g} {unit}" if rms is not None else ""))
        faults = m.get("faults") or []
        if faults:
            first = faults[0]
            what = first.get("kind") or first.get("cause") or "fault" if isinstance(first, dict) else str(first)
            parts.append(f"{len(faults)} fault{'s' if len(faults) != 1 else ''} ({what})")
        else:
            parts.append("no faults")
    elif result.stage == "guide" and "score" in m:
        parts.append(f"score {m['score']:.0f}")
        parts.append(f"deviation rms {m['deviation_rms_m'] * k:.3g} {unit}, max {m['deviation_max_m'] * k:.3g} {unit}")
        events = m.get("events") or {}
        listed = ", ".join(f"{n} {kind.replace('_', ' ')}" for kind, n in events.items() if n)
        parts.append(f"events: {listed or 'none'}")
        parts.append(f"{m.get('duration_s', 0):.3g} s")
    if result.message:
        parts.append(result.message)
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
    for r in results:
        m = r.metrics
        style = "green" if r.succeeded else ("yellow" if r.status in ("skipped", "not_run") else "red")
        clearance = m.get("min_clearance_m", m.get("executed_min_clearance_m"))
        threshold = r.clearance_threshold if r.clearance_threshold is not None else m.get("clearance_threshold_m")
        table.add_row(
            r.name,
            r.plugin,
            f"[{style}]{r.status}[/{style}]",
            _length(m.get("length_m", m.get("path_length_m")), k),
            _length(clearance, k),
            _length(threshold, k),
            _length(m.get("length_below_threshold_m", m.get("below_threshold_m")), k),
            escape(details(r, k, unit)),
            _seconds(m.get("build_s")),
            _seconds(m.get("query_s", m.get("run_s"))),
        )
    return table


def print_summary(console: Console, *args, **kwargs) -> None:
    console.print(summary_table(*args, **kwargs))
