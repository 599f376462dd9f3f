"""Planner Arena: safe_prm, optMIS and OMPL's planners side by side, in OMPL's benchmark formats.

Runs ``benchmarks/plannerarena/hand_eye.yaml`` (one query of paper 001's hand-eye task: safe_prm as expert
and beginner, optMIS, OMPL's PRM, RRT-Connect and RRT* through the bridge, every one on surgiplan's
certified checks) ``--runs`` times each with :func:`surgiplan.plannerarena.benchmark_pipeline`, and writes

- ``results/plannerarena/hand-eye-arena.log``: OMPL's benchmark log format (what
  ``ompl::tools::Benchmark::saveResultsToFile`` writes);
- ``results/plannerarena/hand-eye-arena.db``: the SQLite database OMPL's ``ompl_benchmark_statistics.py``
  makes of it (made by that very parser), which plannerarena.org and OMPL's ``plannerarena`` open;
- ``results/plannerarena.json``: per planner the solved share, median time, length and clearance, with the
  provenance (commit, load, OMPL's version).

Usage: ``python benchmarks/bench_plannerarena.py [--runs 10]``. Every run is a fresh build and query: optMIS
builds its whole all-pairs repository each time (its query alone is the optmis benchmark's business).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import RESULTS, save

PIPELINE = Path(__file__).resolve().parent / "plannerarena" / "hand_eye.yaml"


def write_arena(name: str, planners: dict[str, list[dict]], properties: dict | None = None) -> tuple[Path, Path]:
    """Runs another benchmark measured, in OMPL's log and Planner Arena's database (``results/plannerarena/``).

    ``planners`` maps a planner's name to its runs, each a record with ``build_s`` and optionally
    ``query_ms``, ``solved``, ``length_m``, ``min_clearance_m``, ``edges`` (what bench_safe_prm measures).
    """
    from surgiplan.plannerarena import Experiment, PlannerRuns, write_database, write_log

    def run(record: dict) -> dict:
        query = record.get("query_ms")
        out = {
            "time REAL": record["build_s"] + (query or 0.0) / 1e3,
            "build time REAL": record["build_s"],
            "query time REAL": None if query is None else query / 1e3,
            "solved BOOLEAN": record.get("solved"),
            "solution length REAL": record.get("length_m"),
            "solution clearance REAL": record.get("min_clearance_m"),
            "graph motions INTEGER": record.get("edges"),
        }
        return {key: value for key, value in out.items() if value is not None}

    runs = [PlannerRuns(planner, runs=[run(r) for r in records]) for planner, records in planners.items()]
    experiment = Experiment(name, runs, dict(properties or {}), runs=max(len(p.runs) for p in runs))
    out = RESULTS / "plannerarena"
    log = write_log(out / f"{name}.log", experiment)
    database = out / f"{name}.db"
    database.unlink(missing_ok=True)  # OMPL's parser appends to an existing database
    return log, write_database(database, [log])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10)
    args = parser.parse_args(argv)

    import ompl
    from surgiplan import load_pipeline
    from surgiplan.plannerarena import benchmark_pipeline, write_database, write_log

    pipeline = load_pipeline(PIPELINE)
    out = RESULTS / "plannerarena"
    out.mkdir(parents=True, exist_ok=True)

    def said(stage, k, result):
        print(f"{stage} run {k + 1}/{args.runs}: {result.status}", file=sys.stderr, flush=True)

    experiment = benchmark_pipeline(pipeline, args.runs, on_run=said)
    log = write_log(out / f"{pipeline.name}.log", experiment)
    database = out / f"{pipeline.name}.db"
    database.unlink(missing_ok=True)  # OMPL's parser appends to an existing database
    write_database(database, [log])
    rows = []
    for planner in experiment.planners:
        runs = planner.runs
        solved = [r for r in runs if r.get("solved BOOLEAN")]

        def median(key: str, scale: float = 1.0, of=solved) -> float | None:
            values = [r[key] for r in of if r.get(key) is not None]
            return round(statistics.median(values) * scale, 4) if values else None

        rows.append(
            {
                "planner": planner.name,
                "solved": f"{len(solved)}/{len(runs)}",
                "time_s": median("time REAL", of=runs),
                "length_mm": median("solution length REAL", 1e3),
                "clearance_mm": median("solution clearance REAL", 1e3),
                "smoothness": median("solution smoothness REAL"),
            }
        )
    version = getattr(ompl, "__version__", "unknown")
    peers = {"OMPL": {"version": version, "configuration": "PRM 1000 milestones, RRT-Connect, RRT* 5 s; certified"}}
    notes = f"{args.runs} runs per planner; log {log.name}, database {database.name} (Planner Arena)"
    path = save("plannerarena", rows, notes, peers)
    for row in rows:
        print(row)
    print(f"wrote {log}, {database} and {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
