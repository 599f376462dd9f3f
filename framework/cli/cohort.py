"""``surgiplan cohort --task TASK``: a cohort's learning curves, gates and CUSUM charts from the record; and
``surgiplan validity --task TASK``: whether the metrics separate the record's levels (construct validity)."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def add_parsers(sub) -> None:
    cohort = sub.add_parser(
        "cohort",
        help="a cohort at a task from the trainee record: attempts, last score, the gate, learning curves and "
        "CUSUM charts (figures, --json, --csv)",
    )
    cohort.add_argument("--task", required=True)
    cohort.add_argument("--record", type=Path, default=Path("out/trainees.sqlite"), help="the trainee record")
    cohort.add_argument("--trainees", default=None, help="only these trainees, comma-separated")
    cohort.add_argument(
        "--pass-score",
        type=float,
        default=None,
        help="without a benchmark for the task: an attempt below this score is a failure in the CUSUM",
    )
    cohort.add_argument("--p0", type=float, default=0.1, help="CUSUM: acceptable failure rate (0.1)")
    cohort.add_argument("--p1", type=float, default=0.3, help="CUSUM: unacceptable failure rate (0.3)")
    cohort.add_argument("--alpha", type=float, default=0.1, help="CUSUM: type I error (0.1)")
    cohort.add_argument("--beta", type=float, default=0.1, help="CUSUM: type II error (0.1)")
    cohort.add_argument(
        "--out", type=Path, default=None, help="where to write the figures (default: beside the record)"
    )
    cohort.add_argument("--csv", type=Path, default=None, help="also write every attempt, one row each, to this CSV")
    cohort.add_argument("--json", action="store_true", help="machine-readable output (every attempt too)")
    cohort.set_defaults(handler=_cmd_cohort)

    validity = sub.add_parser(
        "validity",
        help="construct validity from the trainee record: whether each metric separates adjacent levels "
        "(Mann-Whitney U p-value and AUC)",
    )
    validity.add_argument("--task", required=True)
    validity.add_argument("--record", type=Path, default=Path("out/trainees.sqlite"), help="the trainee record")
    validity.add_argument(
        "--levels",
        default="expert,intermediate,beginner",
        help="the levels compared, most experienced first (default: expert,intermediate,beginner)",
    )
    validity.add_argument(
        "--group",
        action="append",
        default=[],
        metavar="LEVEL=NAME,...",
        help="the trainees of a level (default: those whose recorded level it is); repeat for each level",
    )
    validity.add_argument("--json", action="store_true", help="machine-readable output")
    validity.set_defaults(handler=_cmd_validity)


def _cusum_settings(args):
    from pydantic import ValidationError

    from ..errors import ConfigError
    from ..guidance.cusum import CusumSettings

    try:
        return CusumSettings(p0=args.p0, p1=args.p1, alpha=args.alpha, beta=args.beta)
    except ValidationError as exc:
        error = exc.errors()[0]
        option = f"--{error['loc'][0]}" if error["loc"] else "--p0/--p1"
        raise ConfigError(error["msg"].removeprefix("Value error, "), location=option) from None


def _cmd_cohort(args) -> int:
    from ..guidance.assessment_figures import cusum_figure, learning_curves_figure, verdict_of
    from ..guidance.cohort import cohort, write_csv
    from ..guidance.progression import safe_name
    from ..guidance.record import RecordError, TraineeRecord

    settings = _cusum_settings(args)
    if not args.record.is_file():
        raise RecordError(f"no trainee record at {args.record} (a guide stage with trainee: writes one)")
    names = [n.strip() for n in args.trainees.split(",") if n.strip()] if args.trainees else None
    with TraineeRecord(args.record) as record:
        result = cohort(record, args.task, settings, pass_score=args.pass_score, trainees=names)
    out = args.out or args.record.parent
    figures = {"learning_curves": out / f"cohort-{safe_name(args.task)}-scores.png"}
    learning_curves_figure(figures["learning_curves"], result)
    if any(c.cusum is not None for c in result.trainees):
        figures["cusum"] = out / f"cohort-{safe_name(args.task)}-cusum.png"
        cusum_figure(figures["cusum"], result)
    if args.csv:
        write_csv(args.csv, result)
    if args.json:
        document = {**result.to_json(), "figures": {k: str(v) for k, v in figures.items()}}
        if args.csv:
            document["csv"] = str(args.csv)
        print(json.dumps(document, indent=2, default=str))
        return 0
    from rich.console import Console
    from rich.table import Table

    if result.benchmark:
        rule = f"benchmark: {result.benchmark.describe()}"
    elif args.pass_score is not None:
        rule = f"no benchmark; CUSUM failures: score below {args.pass_score:g}"
    else:
        rule = f"no benchmark for {args.task} (surgiplan benchmark-task {args.task} ...): no gate, no CUSUM"
    lines = [rule, *(f"{k.replace('_', ' ')}: {v}" for k, v in figures.items())]
    if args.csv:
        lines.append(f"every attempt: {args.csv}")
    table = Table(
        title=f"cohort at {args.task} ({args.record})",
        title_justify="left",
        caption="\n".join(lines),
        caption_justify="left",
    )
    for column in ("trainee", "level", "attempts", "last score", "gate passed at attempt #", "CUSUM"):
        table.add_column(column, justify="left" if column in ("trainee", "level", "CUSUM") else "right")
    for curve in result.trainees:
        if curve.passed_at is not None:
            gate = str(curve.passed_at)
        elif result.benchmark:
            gate = f"not yet ({curve.streak}/{result.benchmark.consecutive} in a row)"
        else:
            gate = "—"
        verdict = "—" if curve.cusum is None else verdict_of(curve.cusum)
        score = curve.last_score
        table.add_row(
            curve.name,
            curve.level or "",
            str(len(curve.attempts)),
            "—" if score is None else f"{score:.0f}",
            gate,
            verdict,
        )
    (Console() if sys.stdout.isatty() else Console(width=160)).print(table)
    return 0


def _groups(args) -> dict[str, list[str]]:
    from ..errors import ConfigError

    groups = {}
    for item in args.group:
        level, sep, names = item.partition("=")
        if not sep or not level.strip() or not names.strip():
            raise ConfigError(f"--group {item!r}: give LEVEL=NAME,NAME,...", location="--group")
        groups[level.strip()] = [n.strip() for n in names.split(",") if n.strip()]
    return groups


def _cmd_validity(args) -> int:
    from ..errors import ConfigError
    from ..guidance.record import RecordError, TraineeRecord
    from ..guidance.validity import groups_from_record, validity

    levels = [lv.strip() for lv in args.levels.split(",") if lv.strip()]
    if len(levels) < 2:
        raise ConfigError(f"--levels {args.levels!r}: give at least two levels, most experienced first")
    groups = _groups(args)
    unknown = [g for g in groups if g not in levels]
    if unknown:
        raise ConfigError(f"--group {unknown[0]}: not one of --levels ({', '.join(levels)})", location="--group")
    if not args.record.is_file():
        raise RecordError(f"no trainee record at {args.record} (a guide stage with trainee: writes one)")
    with TraineeRecord(args.record) as record:
        attempts, members = groups_from_record(record, args.task, groups, levels)
    result = validity(attempts, levels, task=args.task, trainees=members)
    if args.json:
        print(json.dumps(result.to_json(), indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    from .trainee import format_metric

    counts = ", ".join(f"{lv}: {result.attempts[lv]} attempts by {len(members[lv])} trainee(s)" for lv in levels)
    table = Table(
        title=f"construct validity at {args.task} ({args.record})",
        title_justify="left",
        caption=f"{counts}\nAUC: the chance an attempt of the more experienced level is better on the metric "
        "(0.5: no separation); p: two-sided Mann-Whitney U",
        caption_justify="left",
    )
    table.add_column("metric")
    for column in ("levels", "medians", "AUC", "p"):
        table.add_column(column, justify="left" if column in ("levels", "medians") else "right")
    for row in result.rows:
        table.add_row(
            row.metric,
            f"{row.higher} vs {row.lower}",
            f"{format_metric(row.metric, row.median_higher)} vs {format_metric(row.metric, row.median_lower)}",
            "—" if row.auc is None else f"{row.auc:.2f}",
            "—" if row.p is None else f"{row.p:.2g}",
        )
    (Console() if sys.stdout.isatty() else Console(width=160)).print(table)
    return 0
