"""``surgiplan benchmark PIPELINE --runs N``: every plan stage run N times, written as OMPL's benchmark log and
the SQLite database Planner Arena reads (:mod:`surgiplan.plannerarena`)."""

from __future__ import annotations

import sys
from pathlib import Path


def add_parsers(sub) -> None:
    bench = sub.add_parser(
        "benchmark",
        help="run a pipeline's plan stages N times; OMPL's benchmark log and the Planner Arena database",
        description="Runs every plan stage of PIPELINE --runs times (a fresh build and query each, the planner's "
        "seed advanced by the run's index) and writes OMPL's benchmark log (<name>.log) and, with OMPL's own "
        "ompl_benchmark_statistics parser, the SQLite database Planner Arena reads (<name>.db).",
    )
    bench.add_argument("file", type=Path, metavar="PIPELINE")
    bench.add_argument("--runs", type=int, default=10, help="runs per plan stage (default 10)")
    bench.add_argument(
        "--out", type=Path, default=None, help="directory (default: the pipeline's output dir/benchmark)"
    )
    bench.set_defaults(handler=_cmd_benchmark)


def _cmd_benchmark(args) -> int:
    import statistics

    from ..pipeline import load_pipeline
    from ..plannerarena import benchmark_pipeline, write_database, write_log
    from ..storage import prepare_output_dir

    pipeline = load_pipeline(args.file)
    out = prepare_output_dir(args.out or Path(pipeline.output_dir) / "benchmark")

    def said(stage, k, result):
        print(f"{stage} run {k + 1}/{args.runs}: {result.status}", file=sys.stderr, flush=True)

    experiment = benchmark_pipeline(pipeline, args.runs, on_run=said)
    log = write_log(out / f"{pipeline.name}.log", experiment)
    database = out / f"{pipeline.name}.db"
    database.unlink(missing_ok=True)  # OMPL's parser appends to an existing database
    write_database(database, [log])
    for planner in experiment.planners:
        solved = [r for r in planner.runs if r.get("solved BOOLEAN")]
        times = [r["time REAL"] for r in planner.runs]
        lengths = [r["solution length REAL"] for r in solved]
        length = f", length median {statistics.median(lengths) * 1e3:.4g} mm" if lengths else ""
        print(
            f"{planner.name}: {len(solved)} of {len(planner.runs)} solved, time median "
            f"{statistics.median(times):.4g} s{length}"
        )
    print(f"OMPL benchmark log: {log}\nPlanner Arena database: {database} (plannerarena.org, or OMPL's plannerarena)")
    return 0
