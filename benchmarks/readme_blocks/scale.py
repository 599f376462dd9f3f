"""The scale block (docs/howto/large-scenes.md): many obstacles, many milestones (``bench_scale.py``)."""

from __future__ import annotations

from pathlib import Path

from .formatting import load, met, secs, section, sig, table

PHASES = [
    ("validate_s", "validate"),
    ("build_s", "build"),
    ("query_s", "query"),
    ("figure_s", "figure"),
    ("glb_s", "scene.glb"),
    ("report_s", "report.html"),
    ("run_s", "run (with outputs)"),
]

#: said of the wall times when other work shared the machine
LOADED = ": the machine was shared with other work, so wall times are longer than a quiet machine's"


def _exp(value) -> str:
    return "—" if value is None else f"{value:.2f}"


def render_scale(results: Path) -> str:
    data = load(results, "scale")
    rows = [r for r in data["rows"] if r.get("series") in ("obstacles", "milestones")]
    summary = next(r for r in data["rows"] if r.get("series") == "summary")
    prov = data.get("provenance", {})
    by_obstacles = [r for r in rows if r["series"] == "obstacles"]
    by_milestones = [r for r in rows if r["series"] == "milestones"]

    def case_rows(chosen):
        return [
            [f"{r['obstacles']:,}", f"{r['milestones']:,}", f"{r['edges']:,}"]
            + [secs(r[key]) for key, _ in PHASES]
            + [f"{r['peak_MB']:.0f}"]
            for r in chosen
        ]

    header = ["boxes", "milestones", "edges", *[label + " (s)" for _, label in PHASES], "peak MB"]
    body = table(header, case_rows(by_obstacles) + case_rows([r for r in by_milestones if r["milestones"] != 5000]))
    exps = summary["exponents"]
    body += "\n\n" + table(
        ["growth exponent (log-log slope)", *[label for _, label in PHASES], "peak memory"],
        [
            [f"over boxes ({by_obstacles[0]['obstacles']:,}-{by_obstacles[-1]['obstacles']:,}, 5,000 milestones)"]
            + [_exp(exps["obstacles"][key]) for key, _ in PHASES]
            + [_exp(exps["obstacles"]["peak_MB"])],
            [
                f"over milestones ({by_milestones[0]['milestones']:,}-{by_milestones[-1]['milestones']:,}, "
                f"{by_milestones[0]['obstacles']:,} boxes)"
            ]
            + [_exp(exps["milestones"][key]) for key, _ in PHASES]
            + [_exp(exps["milestones"]["peak_MB"])],
        ],
    )
    base = next(r for r in by_obstacles if r["obstacles"] == 10_000)
    whole, browser, peers, targets = (
        summary["whole_run"],
        summary["browser"],
        summary["broad_phase"],
        summary["targets"],
    )
    outputs = max(base["figure_s"], base["glb_s"], base["report_s"])
    load_before, load_after = prov.get("load_before", [0])[0], prov.get("load_after", [0])[0]
    head = (
        f"Measured by `benchmarks/bench_scale.py` (each case in a fresh process, on 2 cores; load average "
        f"{load_before:g} before and {load_after:g} after{LOADED if max(load_before, load_after) > 2 else ''}; "
        f"`benchmarks/results/scale.json`). Scenes of small boxes from `benchmarks/scale_scene.py`, "
        f"a safe PRM (1 mm threshold) from entry to target; validate is `load_pipeline` after the plugins are "
        f"imported, query the whole answer (links, search, repair, smoothing):"
    )
    skipped = summary.get("skipped_milestones") or []
    cap = (
        f" The {', '.join(f'{m:,}' for m in skipped)}-milestone case was skipped: the case before it took longer "
        f"than the {summary['budget_s']:g} s budget."
        if skipped
        else ""
    )
    tail = (
        f"On the 10,000-box scene with 5,000 milestones: validate {secs(base['validate_s'])} s"
        + (f", {secs(base['validate_cpu_s'])} s of CPU" if "validate_cpu_s" in base else "")
        + " (target "
        f"{targets['validate_s']:g} s: {met(base['validate_s'] <= targets['validate_s'])}), build "
        f"{secs(base['build_s'])} s ({targets['build_s']:g} s: {met(base['build_s'] <= targets['build_s'])}), query "
        f"{secs(base['query_s'])} s ({targets['query_s']:g} s: {met(base['query_s'] <= targets['query_s'])}), "
        f"each output at most {secs(outputs)} s ({targets['output_s']:g} s: {met(outputs <= targets['output_s'])}), "
        f"report.html {base['report_MB']:.1f} MB ({targets['report_MB']:g} MB: "
        f"{met(base['report_MB'] <= targets['report_MB'])}). The whole `surgiplan run` as a process, imports "
        f"included: {sig(whole['wall_s'])} s"
        + (f", {sig(whole['cpu_s'])} s of CPU" if "cpu_s" in whole else "")
        + f" ({targets['run_s']:g} s: {met(whole['wall_s'] <= targets['run_s'])}), "
        f"peak memory {whole['peak_MB']:.0f} MB. In headless Chromium (SwiftShader, no GPU) the report draws the "
        f"{browser['obstacles_drawn']:,} boxes as one merged mesh: first frame after "
        f"{secs(browser['first_frame_s'])} s, a frame of the turning view {browser['frame_ms_median']:.0f} ms "
        f"(median of {browser['frames']}, 90th percentile {browser['frame_ms_p90']:.0f} ms).{cap}\n\n"
        f"The broad phase on the {peers['obstacles']:,} boxes: a point's distance in "
        f"{sig(peers['tree_point_us'])} µs through the tree against {sig(peers['coal_manager_point_us'])} µs "
        f"through coal's `DynamicAABBTreeCollisionManager` (ours equal coal's pairwise distances to "
        f"{peers['coal_pairwise_max_abs_diff_m']:.0e} m; the manager, called with `DistanceCallBackDefault` and a "
        f"tiny sphere, answered a farther box for {peers['coal_manager_points_differing']:,} of "
        f"{peers['points']:,} points, by up to {1e3 * peers['coal_manager_max_abs_diff_m']:.2f} mm, not "
        f"investigated further); an edge's certified check in {sig(peers['tree_segment_us'])} µs "
        f"against {sig(peers['brute_force_segment_us'])} µs for the all-obstacle brute force it replaces."
    )
    return section(head, body, tail)
