"""Skill assessment: construct validity of the metrics on synthetic cohorts, the proficiency gate, learning curves.

**These are synthetic trainees** (``surgiplan.guidance.trainee``: seeded models of an expert, an
intermediate and a beginner that differ, by construction, in speed, drift and hesitation). That the metrics
separate them shows the metrics measure what the models vary, through the whole chain a lab uses; it is no
evidence about people. A lab reruns the same analysis on its own recorded attempts with
``surgiplan validity --task TASK --record its.sqlite`` (the levels from the record, or ``--group``).

1. **Construct validity**: ``--attempts`` attempts per level (default 32: eight trainees of each level, four
   attempts each, every attempt its own seed) follow one recommended path (the block world, safe_prm,
   d_thresh 4 mm, the port at the CAST gimbal's fulcrum so the depth metric is measured). Each attempt is
   measured by the guide's analysis and recorded as the guide stage records it; then ``surgiplan validity``
   reads them back from the record and reports, per metric and for the score, the two-sided Mann-Whitney U
   p-value and the AUC for expert vs intermediate and intermediate vs beginner (target: the score's AUC
   >= 0.9 for both).
2. **The gate**: ``surgiplan benchmark-task --from-level expert`` (mean ± 1 SD, 2 in a row); the share of
   each level's attempts within the benchmark.
   The same with a lenient ± 2 SD.
3. **Learning curves**: six synthetic learners whose parameters move from a beginner's to an expert's over
   their attempts (each at its own rate), twenty attempts each, judged by the ± 2 SD benchmark, their CUSUM
   with acceptable and unacceptable failure rates 0.2 and 0.5;
   ``surgiplan cohort`` writes the figures (copied to ``benchmarks/results/assessment_scores.png`` and
   ``assessment_cusum.png``).

    python benchmarks/bench_assessment.py [--attempts N] [--quick]   (--quick: 10 per level, writes nothing)
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from common import RESULTS, save, table
from pipeline_support import block_world_pipeline, recommended_stage
from surgiplan import load_pipeline, run_pipeline
from surgiplan.clearance import intervals
from surgiplan.guidance import GuidanceSettings, Guide
from surgiplan.guidance.assessment import record_attempt
from surgiplan.guidance.metrics import METRICS, AssessmentSettings
from surgiplan.guidance.trainee import LEVELS, TraineeModel, follow

ROOT = Path(__file__).resolve().parent.parent
SURGIPLAN = [sys.executable, "-m", "surgiplan.cli"]
FULCRUM = (0.150, 0.050, 0.130)
TASK = "block-world"
LEARNER_ATTEMPTS = 20
#: the learners' CUSUM: acceptable and unacceptable failure rates for a benchmark even experts miss at times
LEARNER_CUSUM = (0.2, 0.5)


class Trainee:
    def __init__(self, name: str, level: str | None) -> None:
        self.name, self.task, self.level = name, TASK, level


def recommended(tmp: Path):
    stages = [recommended_stage("intermediate", 2000, k=15)]
    pipeline = load_pipeline(block_world_pipeline(tmp / "plan.yaml", "assessment-plan", stages, tmp / "plan"))
    return pipeline.stages[0], run_pipeline(pipeline).results[0]


def attempt(spec, plan, record: Path, trainee: Trainee, model: TraineeModel) -> dict:
    guide = Guide(
        spec.space,
        plan.path,
        spec.scene,
        plan.clearance_threshold.value,
        intervals(plan.critical_regions),
        GuidanceSettings(),
        unit="mm",
        assessment=AssessmentSettings(),
        port=np.array(FULCRUM),
    )
    follow(guide, model)
    metrics = guide.metrics()
    status = "completed" if guide.reached_goal else "incomplete"
    record_attempt(record, trainee, guide, metrics, guide.events, status=status)
    return metrics


def within_shares(record: Path, tmp: Path) -> dict:
    """Per level: attempts, how many are within the task's current benchmark (from ``surgiplan cohort``), and per
    metric how many are outside its threshold."""
    cohort = json.loads(cli("cohort", "--task", TASK, "--record", str(record), "--json", "--out", str(tmp)))
    thresholds = cohort["benchmark"]["thresholds"]
    out = {}
    for level in ("expert", "intermediate", "beginner"):
        rows = [a for a in cohort["attempts"] if a["level"] == level]
        outside = {}
        for name, t in thresholds.items():
            ok = [
                a[name] is not None
                and (a[name] <= t["threshold"] if t["better"] == "lower" else a[name] >= t["threshold"])
                for a in rows
            ]
            outside[name] = ok.count(False)
        out[level] = {"attempts": len(rows), "within": sum(1 for a in rows if not a["failed"]), "outside": outside}
    return out


def cli(*args: str) -> str:
    done = subprocess.run([*SURGIPLAN, *args], capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        raise SystemExit(f"surgiplan {' '.join(args)}: {done.stderr}")
    return done.stdout


def learner(level_from: dict, level_to: dict, progress: float) -> dict:
    """Parameters a fraction ``progress`` of the way from one level to another (geometrically)."""
    return {k: float(level_from[k] * (level_to[k] / level_from[k]) ** progress) for k in ("speed", "deviation")} | {
        "hesitation_rate": float(level_from["hesitation_rate"] * (1 - progress)),
        "hesitation": float(level_from["hesitation"] * (level_to["hesitation"] / level_from["hesitation"]) ** progress),
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--attempts", type=int, default=32, help="attempts per level (at least 30 for the README)")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    per_level = 10 if args.quick else args.attempts
    per_trainee = 4
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        record = tmp / "trainees.sqlite"
        spec, plan = recommended(tmp)
        seed = 1000
        for level in ("expert", "intermediate", "beginner"):
            for k in range(per_level):
                seed += 1
                trainee = Trainee(f"{level}-{k // per_trainee + 1}", level)
                attempt(spec, plan, record, trainee, TraineeModel(level=level, seed=seed))
            print(f"{level}: {per_level} attempts ({time.perf_counter() - started:.0f} s)", flush=True)
        validity = json.loads(cli("validity", "--task", TASK, "--record", str(record), "--json"))
        benchmarks, within = {}, {}
        for k in ("1", "2"):  # the mean ± 1 SD, and a lenient ± 2 SD
            benchmarks[k] = json.loads(
                cli("benchmark-task", TASK, "--record", str(record), "--from-level", "expert", "--k", k, "--json")
            )
            within[k] = within_shares(record, tmp)
        # learners: beginner -> expert over 20 attempts, each at their own pace, judged by the ± 2 SD benchmark
        learning_record = tmp / "learners.sqlite"
        shutil.copy(record, learning_record)
        rates = [0.8, 1.0, 1.3, 1.7, 2.2, 3.0]
        for i, rate in enumerate(rates, start=1):
            for n in range(LEARNER_ATTEMPTS):
                seed += 1
                progress = min(1.0, n / (LEARNER_ATTEMPTS - 1) * rate)
                parameters = learner(LEVELS["beginner"], LEVELS["expert"], progress)
                model = TraineeModel(level="beginner", seed=seed, **parameters)
                attempt(spec, plan, learning_record, Trainee(f"learner-{i}", "learner"), model)
        print(
            f"learners: {len(rates)} x {LEARNER_ATTEMPTS} attempts ({time.perf_counter() - started:.0f} s)", flush=True
        )
        names = ",".join(f"learner-{i}" for i in range(1, len(rates) + 1))
        learning = json.loads(
            cli(
                "cohort",
                "--task",
                TASK,
                "--record",
                str(learning_record),
                "--trainees",
                names,
                *("--p0", str(LEARNER_CUSUM[0]), "--p1", str(LEARNER_CUSUM[1])),
                "--json",
                "--out",
                str(tmp),
            )
        )
        if not args.quick:
            for kind, name in (("learning_curves", "assessment_scores.png"), ("cusum", "assessment_cusum.png")):
                shutil.copy(learning["figures"][kind], RESULTS / name)
    rows = []
    for r in validity["separations"]:
        rows.append(
            {
                "metric": r["metric"],
                "levels": f"{r['higher']} vs {r['lower']}",
                "median_higher": r["median_higher"],
                "median_lower": r["median_lower"],
                "auc": None if r["auc"] is None else round(r["auc"], 4),
                "p": r["p"],
            }
        )
    print(table(rows, list(rows[0])))
    score = [r for r in rows if r["metric"] == "score"]
    print("score AUC:", [r["auc"] for r in score], "(target >= 0.9)")
    print("within the benchmark (k = 1, k = 2):", within)
    gates = {t["trainee"]: t["gate_passed_at"] for t in learning["trainees"]}
    cusums = {t["trainee"]: t["cusum"]["acceptable_at"] if t["cusum"] else None for t in learning["trainees"]}
    print("learners' gate passed at:", gates, "CUSUM acceptable at:", cusums)
    if args.quick:
        return
    summary = {
        "attempts_per_level": per_level,
        "trainees_per_level": -(-per_level // per_trainee),
        "task": TASK,
        "recommended_length_m": plan.metrics["length_m"],
        "d_thresh_m": plan.clearance_threshold.value,
        "benchmark": {
            "method": benchmarks["1"]["method"],
            "consecutive": benchmarks["1"]["consecutive"],
            "metrics": list(benchmarks["1"]["thresholds"]),
        },
        "within_benchmark": within,
        "learner_attempts": LEARNER_ATTEMPTS,
        "learner_benchmark_k": 2,
        "learner_cusum": {"p0": LEARNER_CUSUM[0], "p1": LEARNER_CUSUM[1], "alpha": 0.1, "beta": 0.1},
        "learners": [
            {
                "trainee": t["trainee"],
                "rate": rate,
                "gate_passed_at": gates[t["trainee"]],
                "cusum_acceptable_at": cusums[t["trainee"]],
                "last_score": t["last_score"],
            }
            for t, rate in zip(learning["trainees"], rates, strict=True)
        ],
        "metric_order": [m.name for m in METRICS],
        "run_s": round(time.perf_counter() - started, 1),
    }
    notes = "synthetic trainees (surgiplan.guidance.trainee); Mann-Whitney U two-sided (scipy), AUC = P(better)"
    print("wrote", save("assessment", rows, notes, peers={"scipy": {"version": _version("scipy")}}))
    path = RESULTS / "assessment.json"
    data = json.loads(path.read_text())
    data["summary"] = summary
    from surgiplan.storage import write_json_atomic

    write_json_atomic(path, data)


def _version(package: str) -> str:
    from importlib.metadata import version

    return version(package)


if __name__ == "__main__":
    main()
