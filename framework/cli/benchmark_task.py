"""``surgiplan benchmark-task TASK``: set a task's proficiency benchmark from expert attempts in the record."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def add_parsers(sub) -> None:
    bench = sub.add_parser(
        "benchmark-task",
        help="set a task's proficiency benchmark (per-metric thresholds, the gate) from expert attempts in the record",
    )
    bench.add_argument("task")
    bench.add_argument("--record", type=Path, default=Path("out/trainees.sqlite"), help="the trainee record")
    who = bench.add_mutually_exclusive_group()
    who.add_argument("--from-trainees", default=None, help="the experts: trainee names, comma-separated")
    who.add_argument(
        "--from-level",
        default=None,
        help="the experts: every trainee of this level in the record (default: expert, when --from-trainees is not "
        "given)",
    )
    bench.add_argument(
        "--method",
        choices=("mean_sd", "percentile"),
        default="mean_sd",
        help="thresholds at the expert mean -/+ k SD (default), or at a percentile of the expert attempts",
    )
    bench.add_argument("--k", type=float, default=1.0, help="mean_sd: standard deviations from the mean (default 1)")
    bench.add_argument(
        "--percentile", type=float, default=90.0, help="percentile: the share (%%) of expert attempts within (90)"
    )
    bench.add_argument(
        "--consecutive", type=int, default=2, help="attempts in a row within every threshold to pass the gate (2)"
    )
    bench.add_argument("--metrics", default=None, help="the metrics to set thresholds on, comma-separated")
    bench.add_argument("--last", type=int, default=None, help="only each expert's last N attempts")
    bench.add_argument("--json", action="store_true", help="machine-readable output")
    bench.set_defaults(handler=_cmd_benchmark_task)


def settings_from(args):
    """The options as :class:`BenchmarkSettings` (a bad value is a ConfigError naming the option)."""
    from pydantic import ValidationError

    from ..errors import ConfigError
    from ..guidance.benchmark import BenchmarkSettings

    values = {
        "method": args.method,
        "k": args.k,
        "percentile": args.percentile,
        "consecutive": args.consecutive,
        "last": args.last,
    }
    if args.metrics:
        values["metrics"] = [m.strip() for m in args.metrics.split(",") if m.strip()]
    try:
        return BenchmarkSettings.model_validate(values)
    except ValidationError as exc:
        error = exc.errors()[0]
        option = "--" + str(error["loc"][0]).replace("_", "-") if error["loc"] else "the options"
        raise ConfigError(error["msg"].removeprefix("Value error, "), location=option) from None


def _cmd_benchmark_task(args) -> int:
    from ..guidance.benchmark import Benchmark, thresholds
    from ..guidance.record import RecordError, TraineeRecord

    settings = settings_from(args)
    if not args.record.is_file():
        raise RecordError(f"no trainee record at {args.record} (a guide stage with trainee: writes one)")
    with TraineeRecord(args.record) as record:
        if args.from_trainees:
            experts = [n.strip() for n in args.from_trainees.split(",") if n.strip()]
        else:
            level = args.from_level or "expert"
            experts = [n for n, lv in record.levels().items() if lv == level]
            if not experts:
                raise RecordError(
                    f"no trainee of level '{level}' in {args.record}: name the experts with --from-trainees, or set "
                    f"their level (surgiplan trainee NAME --level {level}, or level: in a guide stage's trainee:)"
                )
        values = []
        for name in experts:
            history = record.history(name, args.task)
            if not history:
                raise RecordError(f"expert '{name}' has no attempt at task '{args.task}' in {args.record}")
            values += [h["metrics"] for h in (history[-settings.last :] if settings.last else history)]
        found = thresholds(values, settings)
        if not found:
            raise RecordError(
                f"the experts' {len(values)} attempt(s) at '{args.task}' give no threshold: a threshold needs at "
                "least two expert attempts with the metric"
            )
        benchmark = Benchmark(
            task=args.task,
            method=settings.method,
            k=settings.k if settings.method == "mean_sd" else None,
            percentile=settings.percentile if settings.method == "percentile" else None,
            consecutive=settings.consecutive,
            experts=experts,
            attempts=len(values),
            thresholds=found,
        )
        benchmark.id = record.add_benchmark(benchmark)
        benchmark = record.benchmark(args.task)
    if args.json:
        print(json.dumps(benchmark.to_json(), indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    from ..guidance.metrics import METRIC_BY_NAME
    from .trainee import format_metric

    table = Table(
        title=f"benchmark {benchmark.id} of task {args.task} ({args.record})",
        title_justify="left",
        caption=benchmark.describe(),
        caption_justify="left",
    )
    for column in ("metric", "expert mean", "SD", "threshold", "attempts"):
        table.add_column(column, justify="left" if column == "metric" else "right")
    for name, t in benchmark.thresholds.items():
        sign = "≤ " if t.better == "lower" else "≥ "
        table.add_row(
            METRIC_BY_NAME[name].label,
            format_metric(name, t.mean),
            format_metric(name, t.sd),
            sign + format_metric(name, t.value),
            str(t.n),
        )
    (Console() if sys.stdout.isatty() else Console(width=160)).print(table)
    return 0
