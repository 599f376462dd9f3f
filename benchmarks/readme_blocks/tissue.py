"""The interactive tissue block: one warm-started step of the retraction config's flap (``bench_tissue.py``)."""

from __future__ import annotations

from pathlib import Path

from .formatting import dims, find, load, met, wrap


def render_tissue(results: Path) -> str:
    data = load(results, "tissue")
    rows = [r for r in data["rows"] if r["part"] == "steps"]
    linear = next(r for r in rows if r["elements"].startswith("linear"))
    quadratic = next((r for r in rows if r["elements"].startswith("quadratic")), None)
    notes = data["notes"]
    paths = find(r"(\d+) paths of (\d+) steps", notes, "tissue.json notes")
    target = float(find(r"target ([\d.]+) ms median", notes, "tissue.json notes").group(1))

    def figures(r: dict) -> str:
        return (
            f"{r['median_ms']:.1f} ms median (p90 {r['p90_ms']:.1f}, max {r['max_ms']:.1f} ms; Newton "
            f"{r['newton_median_ms']:.1f} ms of it, {r['median_iterations']:g} iterations and "
            f"{r['median_factorizations']:g} factorisation{'s' if r['median_factorizations'] != 1 else ''} median)"
        )

    text = (
        f"Interactive tissue (`benchmarks/bench_tissue.py`, `benchmarks/results/tissue.json`): the left flap of "
        f"`configs/retraction_incision.yaml` ({dims(linear['elements'].split(' (')[0].split(' ', 1)[1])} linear "
        f"tetrahedra, {linear['nodes']:,} nodes, {linear['tetrahedra']:,} elements), its grasp moved 1 mm at a time "
        f"({paths.group(1)} paths of {paths.group(2)} steps: lift, then pull back and tilt), each equilibrium "
        f"warm-started from the last on one core, the whole solve timed (Newton and the state's validity checks): "
        f"{figures(linear)}, {linear['rate_hz_at_median']:g} Hz. Target (issue 34) at most {target:g} ms median "
        f"(30 Hz): {met(linear['within_target'])}."
    )
    if quadratic is not None:
        text += (
            f" The same flap in quadratic tetrahedra ({dims(quadratic['elements'].split(' ', 1)[1])}, "
            f"{quadratic['nodes']:,} nodes): {figures(quadratic)}."
        )
    return wrap(text)
