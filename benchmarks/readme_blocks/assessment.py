"""The skill-assessment blocks: construct validity on synthetic cohorts and the gate (``bench_assessment.py``), and
the live cues' latency from sample to pixels (``bench_cues.py``)."""

from __future__ import annotations

from pathlib import Path

from .formatting import find, load, met, section, table, words

LABELS = {
    "score": "score",
    "duration_s": "task time",
    "path_length_m": "path length",
    "economy": "economy of motion",
    "idle_s": "idle time",
    "jerk": "dimensionless jerk",
    "sparc": "SPARC",
    "corrections": "corrections",
    "depth_reversals": "depth reversals",
    "deviation_rms_m": "deviation RMS",
    "below_threshold_s": "time below d_thresh",
    "below_threshold_m": "length below d_thresh",
    "contacts": "contacts",
    "completion": "completion",
}


def _p(p: float | None) -> str:
    if p is None:
        return "—"
    return "< 0.001" if p < 0.001 else f"{p:.2g}"


def _share(entry: dict) -> str:
    return f"{entry['within']}/{entry['attempts']}"


def render_assessment(results: Path) -> str:
    data = load(results, "assessment")
    summary = data["summary"]
    rows = data["rows"]
    pairs = ["expert vs intermediate", "intermediate vs beginner"]
    by = {(r["metric"], r["levels"]): r for r in rows}
    metrics = list(dict.fromkeys(r["metric"] for r in rows))
    body_rows = []
    for metric in metrics:
        cells = [LABELS.get(metric, metric)]
        for pair in pairs:
            r = by[(metric, pair)]
            cells.append("—" if r["auc"] is None else f"{r['auc']:.2f} (p {_p(r['p'])})")
        body_rows.append(cells)
    body = table(["metric", "AUC expert vs intermediate (p)", "AUC intermediate vs beginner (p)"], body_rows)
    n, trainees = summary["attempts_per_level"], summary["trainees_per_level"]
    head = (
        f"`benchmarks/bench_assessment.py` (`benchmarks/results/assessment.json`) follows {n} attempts per level "
        f"({trainees} trainees of each level, every attempt its own seed) against one recommended path of the block "
        f"world, records them as the guide stage does, and reads them back with `surgiplan validity`. **These are "
        f"synthetic trainees** (`surgiplan.guidance.trainee`: models of an expert, an intermediate and a beginner "
        f"that differ, by construction, in speed, drift and hesitation), not people: the table shows the metrics "
        f"measure what the models vary, through the whole chain a lab uses. A lab reruns it on its own recorded "
        f"attempts with `surgiplan validity --task TASK` (levels from the record, or `--group`). AUC: the chance an "
        f"attempt of the more experienced level is better on the metric (0.5: none; two-sided Mann-Whitney U p):"
    )
    score = [by[("score", pair)]["auc"] for pair in pairs]
    weak = [
        LABELS.get(m, m)
        for m in metrics
        if any(by[(m, pair)]["auc"] is not None and by[(m, pair)]["auc"] < 0.7 for pair in pairs)
    ]
    within = summary["within_benchmark"]
    one, two = within["1"], within["2"]
    learners = summary["learners"]
    passed = [entry for entry in learners if entry["gate_passed_at"] is not None]
    acceptable = [entry for entry in learners if entry["cusum_acceptable_at"] is not None]
    gate = (
        f"The score separates expert from intermediate and intermediate from beginner with AUC {score[0]:.2f} and "
        f"{score[1]:.2f} (target ≥ 0.9: {met(min(score) >= 0.9)})."
    )
    if weak:
        gate += f" Below 0.7 for one of the pairs: {', '.join(weak)}."
    gate += (
        f"\n\nThe gate: `surgiplan benchmark-task --from-level expert` sets thresholds at the expert mean ± 1 SD on "
        f"{words(len(summary['benchmark']['metrics']))} metrics at once; within it are {_share(one['expert'])} of "
        f"the experts' own attempts, {_share(one['intermediate'])} of the intermediates' and "
        f"{_share(one['beginner'])} of the beginners' (± 2 SD: {_share(two['expert'])}, "
        f"{_share(two['intermediate'])}, {_share(two['beginner'])}). Six synthetic learners moving from a "
        f"beginner's parameters to an expert's at different rates ({summary['learner_attempts']} attempts each, "
        f"judged by the ± 2 SD benchmark): {words(len(passed))} passed the gate"
    )
    if passed:
        gate += f" (at attempts {', '.join(str(e['gate_passed_at']) for e in passed)})"
    c = summary["learner_cusum"]
    gate += (
        f", and the CUSUM (p0 {c['p0']:g}, p1 {c['p1']:g}) called {words(len(acceptable))} of them acceptable; "
        f"their curves: `benchmarks/results/assessment_scores.png`, `assessment_cusum.png` "
        f"([the assessment reference](../assessment.md))."
    )
    return section(head, body, gate)


def render_cues(results: Path) -> str:
    data = load(results, "cues")
    rows = data["rows"]
    pooled = rows[0]
    labels = {
        "sample to pixels": "the pixels of the live view's cues (headless chromium, software WebGL)",
        "sample to the page's handling": "the page's handling of its message (stage, feed, relay, the page's queue)",
        "sample to a watcher": "a watcher in Python (stage, feed, relay)",
    }

    def label(case: str) -> str:
        return next((text for start, text in labels.items() if case.startswith(start)), case)

    body = table(
        ["from a sample to", "runs", "samples", "median", "p95", "p99", "max"],
        [
            [
                label(r["case"]),
                str(r["runs"]),
                f"{r['samples']:,}",
                f"{r['median_ms']:.1f} ms",
                f"{r['p95_ms']:.1f} ms",
                f"{r['p99_ms']:.1f} ms",
                f"{r['max_ms']:.0f} ms",
            ]
            for r in rows
        ],
    )
    loads = find(r"load average before ([\d./]+) and after ([\d./]+)", data["notes"], "cues.json notes")
    head = (
        f"`benchmarks/bench_cues.py` (`benchmarks/results/cues.json`) runs a guide stage with a synthetic "
        f"beginner paced at 100 samples/s and an expert ghost into `surgiplan view --live`, watched by a headless "
        f"chromium page (no GPU); each sample's latency runs from its arrival at the stage to the end of the first "
        f"frame drawn after the page got it, read back from the canvas (load average {loads.group(1)} before and "
        f"{loads.group(2)} after, 1/5/15 min, 2 shared cores):"
    )
    tail = f"Target p99 under 50 ms: {met(pooled['p99_ms'] < 50)} ({pooled['p99_ms']:.1f} ms over every sample)."
    arrived = next((r for r in rows if r["case"].startswith("sample to the page's handling")), None)
    watcher = next((r for r in rows if r["case"].startswith("sample to a watcher")), None)
    if arrived is not None and watcher is not None:
        tail += (
            f" Of the median {pooled['median_ms']:.1f} ms, {arrived['median_ms']:.1f} ms pass before the page's "
            f"script handles the sample's message (a Python watcher has it after {watcher['median_ms']:.1f} ms); "
            "the rest is the frame that draws it."
        )
    return section(head, body, tail)
