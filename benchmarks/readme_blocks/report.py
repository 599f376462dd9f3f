"""The report block: writing and loading report.html, and the live view (``bench_report.py``)."""

from __future__ import annotations

from pathlib import Path

from .formatting import load, section, span, table


def render_report(results: Path) -> str:
    data = load(results, "report")
    rows = {r["result"]: r for r in data["rows"]}
    roadmap = next(r for r in data["rows"] if "roadmap_edges" in r.get("drawn", {}))
    repository = next(r for r in data["rows"] if "stored_paths" in r.get("drawn", {}))
    mesh = next(r for r in data["rows"] if "meshes" in r.get("drawn", {}))
    live, loads = rows["live view"], rows["load average"]

    def row(label: str, r: dict) -> list[str]:
        step = "—" if r["slider_step_ms"] is None else f"{r['slider_step_ms']:.0f} ms"
        return [label, f"{r['report_MB']:.1f} MB", f"{r['write_s']:.2f} s", f"{r['load_s']:.2f} s", step]

    loads_n = len(roadmap["load_s_runs"])
    body = table(
        ["result", "report.html", "written in", "loads in (first frame, all drawn)", "slider step"],
        [
            row(f"{roadmap['result']} ({roadmap['drawn']['roadmap_edges']:,} edges)", roadmap),
            row(f"the {repository['drawn']['stored_paths']:,}-path optMIS repository (hand-eye)", repository),
            row(f"the flap: {mesh['result']}", mesh),
        ],
    )
    alone, fed, watched = live["stage_alone"], live["stage_fed_no_page"], live["stage_watched"]
    redraws = [r["redraws_per_s"] for r in live["runs"]]
    head = (
        f"Measured by `benchmarks/bench_report.py` (headless chromium without a GPU, on SwiftShader; 2 shared "
        f"cores, load average {loads['before'][0]:.1f} before and {loads['after'][0]:.1f} after (1 min); medians "
        f"of {loads_n} loads after a warm-up, `benchmarks/results/report.json`):"
    )
    period_late = watched["late_samples"]
    tail = (
        f"Live (a `point_robot` at 200 Hz, `realtime: true`, {alone['samples']:,} samples): "
        f"{live['samples_per_s']:.0f} samples a second reach the page, which redraws {live['redraws_per_s']:.0f} "
        f"times a second with a new one (medians of {len(live['runs'])} runs; {span(redraws, lambda v: f'{v:.0f}')}). "
        f"Fed to the viewer with no page watching, the stage's worst lateness behind its clock is "
        f"{1e6 * fed['late_max_s']:.0f} µs (alone: {1e6 * alone['late_max_s']:.0f} µs), "
        f"{fed['late_samples']} samples late: the feed itself does not slow the stage. With the page open on "
        f"this 2-core machine the browser's software rendering competes for the CPU: {period_late} of "
        f"{watched['samples']:,} samples were more than one period late (at most "
        f"{1e3 * watched['late_max_s']:.0f} ms), and the motion ended {1e3 * watched['overrun_s']:.0f} ms after "
        f"its time instead of {1e3 * alone['overrun_s']:.0f} ms. With a GPU, or a viewer on another core, "
        f"that cost goes."
    )
    return section(head, body, tail)
