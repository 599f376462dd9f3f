"""The safe_prm block: safe_prm against OMPL's PRM (``bench_safe_prm.py``)."""

from __future__ import annotations

from pathlib import Path

from .formatting import find, load, met, section, sig, span, table


def render_safe_prm(results: Path) -> str:
    data = load(results, "safe_prm_vs_ompl")
    notes = data["notes"]
    by = {}
    for r in data["rows"]:
        kind = "safe" if r["planner"].startswith("safe_prm") else find(r"\((\w+)\)", r["planner"], "planner").group(1)
        by[(kind, r["milestones"])] = r
    sizes = sorted({m for _, m in by})
    f = float
    rows = []
    for m in sizes:
        s, v, c, b = by[("safe", m)], by[("vectorised", m)], by[("certified", m)], by[("scalar", m)]
        rows.append(
            [
                f"{m:,}",
                f"{sig(f(s['build_s']), 2)} s",
                f"{sig(f(v['build_s']))} s ({v['build_ratio']}) / {sig(f(c['build_s']))} s ({c['build_ratio']}) / "
                f"{sig(f(b['build_s']))} s ({b['build_ratio']})",
                f"{sig(f(s['query_ms']), 2)} ms",
                f"{sig(f(s['query_repair_ms_4mm']), 2)} / {sig(f(s['query_repair_ms_8mm']), 2)} ms",
                f"{sig(f(v['query_ms']), 2)} ms",
                f"{sig(f(s['simplify_ms']), 2)} / {sig(f(v['simplify_ms']), 2)} ms",
            ]
        )
    body = table(
        [
            "milestones",
            "safe_prm: build R + R_safe",
            "OMPL PRM build: vectorised / certified motions / box-only scalar",
            "safe_prm query (expert)",
            "safe_prm query + repair 4 / 8 mm",
            "OMPL query (vectorised)",
            "smoothing QP / OMPL simplifyMax",
        ],
        rows,
    )
    load_avg = find(r"[Ll]oad average at start ([\d./]+)", notes, "safe_prm_vs_ompl.json notes").group(1)
    took = find(r"run took (\d+) s", notes, "safe_prm_vs_ompl.json notes").group(1)
    head = (
        f"Measured by `python benchmarks/bench_safe_prm.py` (`benchmarks/results/safe_prm_vs_ompl.json`): medians of "
        f"{by[('safe', sizes[-1])]['seeds']} seeds, queries and simplification medians of 21 repeats; one run, side "
        f"by side, {took} s, load average {load_avg} (1/5/15 min) at the start on the 2 shared cores."
    )

    def ratio(r: dict) -> float:
        return float(r["build_ratio"].rstrip("x"))

    big = [m for m in sizes if m >= 2000]
    build_ok = all(ratio(by[("vectorised", m)]) >= 10 for m in big)
    largest = sizes[-1]
    s_big = by[("safe", largest)]
    repair = [float(s_big["query_repair_ms_4mm"]), float(s_big["query_repair_ms_8mm"])]
    clipping = {k: by[(k, largest)]["raw_paths_clipping"] for k in ("vectorised", "safe")}
    ompl_margin = by[("vectorised", largest)]["success_0_4_8mm"].split()[0].split("/")
    safe_margin = s_big["success_0_4_8mm"].split()[0].split("/")
    seeds = s_big["seeds"]
    clip_ompl = clipping["vectorised"].split("/")[0]
    scalar = [ratio(by[("scalar", m)]) for m in big]
    tail = (
        f"Targets (issue 20): R + R_safe at least 10x faster than that OMPL PRM builds its one roadmap at "
        f"{' and '.join(f'{m:,}' for m in big)} milestones: {met(build_ok)} "
        f"({' and '.join(by[('vectorised', m)]['build_ratio'] for m in big)} against the vectorised checker); "
        f"against the box-only scalar checker OMPL's C++ core is only {span(scalar, lambda v: f'{v:.1f}')}x slower, "
        f"so most of OMPL's build time here is Python callbacks. Query with path repair at most 2 ms at "
        f"{largest:,} milestones: {met(max(repair) <= 2)} ({sig(repair[0], 2)} / {sig(repair[1], 2)} ms). "
        f"Both planners find the same {s_big['length_mm']} mm path for the expert (the straight line through the "
        f"three gaps, {s_big['min_clear_mm']} mm clearance; safe_prm's length against OMPL's: "
        f"{s_big['length_vs_ompl']}); {clip_ompl} of OMPL's {seeds} raw roadmap paths at {largest:,} milestones "
        f"{'clips' if clip_ompl == '1' else 'clip'} an obstacle between checked states (measured with coal), "
        f"{clipping['safe'].split('/')[0]} of safe_prm's. With a 4 or 8 mm margin OMPL's PRM solves "
        f"{ompl_margin[1]}/{seeds} and {ompl_margin[2]}/{seeds} (the target lies behind a 6 mm gap); safe_prm "
        f"solves {safe_margin[1]}/{seeds} and {safe_margin[2]}/{seeds} and reports the critical region."
    )
    return section(head, body, tail)
