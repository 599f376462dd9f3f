"""The safe_prm block: safe_prm against every configuration of OMPL's PRM (``bench_safe_prm.py``)."""

from __future__ import annotations

from pathlib import Path

from .formatting import find, load, met, section, sig, span, table

#: the targets of issue 34
BUILD_RATIO = 10.0
QUERY_MS = 0.1


def render_safe_prm(results: Path) -> str:
    data = load(results, "safe_prm_vs_ompl")
    notes = data["notes"]
    configs = data.get("provenance", {}).get("peers", {}).get("OMPL", {}).get("configurations", {})
    by: dict[tuple[str, int], dict] = {}
    stage = []
    runs = []  # each run's figures when the benchmark ran more than once in a row (--runs)
    for r in data["rows"]:
        if r["planner"].startswith("safe_prm, plan stage"):
            stage.append(r)
            continue
        if r["planner"] == "safe_prm, every run":
            runs.append(r)
            continue
        kind = (
            "safe" if r["planner"].startswith("safe_prm") else find(r"\(([\w-]+)\)", r["planner"], "planner").group(1)
        )
        by[(kind, r["milestones"])] = r
    sizes = sorted({m for _, m in by})
    order = [c for c in configs if any((c, m) in by for m in sizes)] or sorted({k for k, _ in by if k != "safe"})
    f = float

    def ratio(r: dict, key: str = "build_ratio") -> float:
        return float(r[key].rstrip("x"))

    rows = []
    for m in sizes:
        s = by[("safe", m)]
        strongest = by[(s["strongest_ompl"], m)]
        builds = " / ".join(
            f"{sig(f(by[(c, m)]['build_s']))} s" + (" **(strongest)**" if c == s["strongest_ompl"] else "")
            for c in order
        )
        rows.append(
            [
                f"{m:,}",
                f"{sig(f(s['build_s']), 2)} s",
                builds,
                f"{ratio(s, 'build_ratio_vs_strongest'):.1f}×",
                f"{sig(1e3 * f(s['query_ms']), 2)} µs",
                f"{sig(1e3 * f(s['query_repair_ms_4mm']), 2)} / {sig(1e3 * f(s['query_repair_ms_8mm']), 2)} µs",
                f"{sig(f(strongest['query_ms']), 2)} ms",
                f"{sig(f(s['simplify_ms']), 2)} / {sig(f(strongest['simplify_ms']), 2)} ms",
            ]
        )
    body = table(
        [
            "milestones",
            "safe_prm: build R + R_safe",
            "OMPL PRM build: " + " / ".join(order),
            "OMPL's strongest / safe_prm",
            "safe_prm query (expert)",
            "safe_prm query + repair 4 / 8 mm",
            "OMPL query (strongest)",
            "smoothing QP / OMPL simplifyMax",
        ],
        rows,
    )
    load_avg = find(r"[Ll]oad average at start ([\d./]+)", notes, "safe_prm_vs_ompl.json notes").group(1)
    took = find(r"run took (\d+) s", notes, "safe_prm_vs_ompl.json notes").group(1)
    largest = sizes[-1]
    s_big = by[("safe", largest)]
    # the targets hold only if they hold in every run: judged on the worst run where there were several
    every = [r for r in runs if r["milestones"] == largest] or [s_big]
    count = len(every)
    head = (
        f"Measured by `python benchmarks/bench_safe_prm.py{f' --runs {count}' if count > 1 else ''}` "
        f"(`benchmarks/results/safe_prm_vs_ompl.json`): medians of {s_big['seeds']} seeds, queries and simplification "
        f"medians of 21 repeats; {'one run' if count == 1 else f'{count} runs in a row (the table: the last)'}, side "
        f"by side, {took} s, "
        f"load average {load_avg} (1/5/15 min) at the start on the 2 shared cores. OMPL's configurations: "
        + "; ".join(f"`{c}`: {configs[c]}" for c in order if c in configs)
        + ". The strongest at a size is the one that builds fastest there."
    )
    strongest = s_big["strongest_ompl"]
    build_ok = min(ratio(r, "build_ratio_vs_strongest") for r in every) >= BUILD_RATIO
    repair = [f(s_big["query_repair_ms_4mm"]), f(s_big["query_repair_ms_8mm"])]

    def worst(*keys: str) -> float:
        """The slowest of these figures over every run."""
        return max(f(r[key]) for r in every for key in keys)

    repair_worst = worst("query_repair_ms_4mm", "query_repair_ms_8mm")
    warm_worst = worst("query_repair_warm_ms_4mm", "query_repair_warm_ms_8mm") if "query_warm_ms" in s_big else None
    several = ""
    if count > 1:
        several = (
            f" Every run ({count} in a row, each against OMPL's own builds; the table is the last, and the "
            "targets here are judged on the worst): build ratio "
            + ", ".join(f"{ratio(r, 'build_ratio_vs_strongest'):.1f}× (`{r['strongest_ompl']}`)" for r in every)
            + "; warm query with repair 4 / 8 mm "
            + ", ".join(
                f"{sig(1e3 * f(r['query_repair_warm_ms_4mm']), 2)} / {sig(1e3 * f(r['query_repair_warm_ms_8mm']), 2)}"
                for r in every
            )
            + " µs; ticks stolen "
            + ", ".join(str(r["steal_ticks"]) for r in every)
            + "."
        )
    clipping = by[(strongest, largest)].get("raw_paths_clipping", "—")
    ompl_margin = by[(strongest, largest)]["success_0_4_8mm"].split()[0].split("/")
    safe_margin = s_big["success_0_4_8mm"].split()[0].split("/")
    seeds = s_big["seeds"]
    pipeline = ""
    if stage:
        builds = [r["pipeline_build_s"] / r["benchmark_build_s"] for r in stage]
        queries = [r["pipeline_query_ms"] for r in stage]
        pipeline = (
            f" As the plan stage reports them (`surgiplan run`, one stage per level, {largest:,} milestones, seed 1): "
            f"builds {span([1e3 * r['pipeline_build_s'] for r in stage], lambda v: f'{v:.1f}')} ms, "
            f"{span(builds, lambda v: f'{v:.2f}')} times this benchmark's builds of the same roadmaps, and queries "
            f"{span([1e3 * q for q in queries], lambda v: f'{v:.0f}')} µs (the first query of a process, compiled "
            f"code loaded at import; this benchmark's first queries "
            f"{span([1e3 * r['benchmark_first_query_ms'] for r in stage], lambda v: f'{v:.0f}')} µs, its medians "
            f"{span([1e3 * r['benchmark_query_ms'] for r in stage], lambda v: f'{v:.0f}')} µs)."
        )
    tail = (
        f"Targets (issue 34): R + R_safe at least {BUILD_RATIO:g}× faster than OMPL's strongest configuration "
        f"builds its one roadmap at {largest:,} milestones: {met(build_ok)} "
        f"({ratio(s_big, 'build_ratio_vs_strongest'):.1f}× against `{strongest}`; "
        + ", ".join(f"{ratio(by[(c, largest)]):.1f}× against `{c}`" for c in order if c != strongest)
        + (
            f"; safe_prm on {s_big['threads']} threads; on one it builds in "
            f"{sig(f(s_big['build_one_thread_s']), 2)} s, "
            f"{ratio(s_big, 'build_ratio_vs_strongest_one_thread'):.1f}× against `{strongest}`, which grows its "
            "roadmap on one"
            if "build_one_thread_s" in s_big
            else ""
        )
        + f"). Query with path repair at most {1e3 * QUERY_MS:g} µs median at {largest:,} milestones: "
        f"{met(repair_worst <= QUERY_MS)} ({sig(1e3 * repair[0], 2)} / {sig(1e3 * repair[1], 2)} µs)."
        + (
            f" The same queries back to back, caches warm (as VAMP's 35 µs and OMPL's `solve` here are measured): "
            f"{sig(1e3 * f(s_big['query_warm_ms']), 2)} µs expert, {sig(1e3 * f(s_big['query_repair_warm_ms_4mm']), 2)}"
            f" / {sig(1e3 * f(s_big['query_repair_warm_ms_8mm']), 2)} µs with repair (the target measured this way: "
            f"{met(warm_worst <= QUERY_MS)}); "
            "the plan stage's query follows the previous query's smoothing, which leaves the roadmap's arrays out of "
            "cache."
            if "query_warm_ms" in s_big
            else ""
        )
        + several
        + pipeline
        + f" Both planners find the same {s_big['length_mm']} mm path for the expert (the straight line through the "
        f"three gaps, {s_big['min_clear_mm']} mm clearance; safe_prm's length against OMPL's: "
        f"{s_big.get('length_vs_ompl', '—')}); {clipping.split('/')[0]} of OMPL's {seeds} raw roadmap paths at "
        f"{largest:,} milestones clip an obstacle between checked states (measured with coal), "
        f"{s_big['raw_paths_clipping'].split('/')[0]} of safe_prm's. With a 4 or 8 mm margin OMPL's PRM solves "
        f"{ompl_margin[1]}/{seeds} and {ompl_margin[2]}/{seeds} (the target lies behind a 6 mm gap); safe_prm "
        f"solves {safe_margin[1]}/{seeds} and {safe_margin[2]}/{seeds} and reports the critical region."
    )
    return section(head, body, tail)
