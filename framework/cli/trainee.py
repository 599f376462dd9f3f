"""``surgiplan trainee NAME``: a trainee's attempts from the trainee record, each metric against the task's
benchmark with the gate, and figures (progression; per task the metrics' history against their thresholds)."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def add_parsers(sub) -> None:
    trainee = sub.add_parser(
        "trainee",
        help="a trainee's attempts from the trainee record, their metrics against the task's benchmark and the "
        "proficiency gate, and figures",
    )
    trainee.add_argument("name", nargs="?", default=None, help="the trainee (with --export: only them)")
    trainee.add_argument("--record", type=Path, default=Path("out/trainees.sqlite"), help="the trainee record")
    trainee.add_argument("--task", default=None, help="only this task")
    trainee.add_argument(
        "--level",
        default=None,
        help="set the trainee's level in the record first (the group a lab puts them in: expert, intermediate, "
        "beginner, ...; 'none' clears it)",
    )
    trainee.add_argument(
        "--out", type=Path, default=None, help="where to write the figures (default: beside the record)"
    )
    trainee.add_argument("--json", action="store_true", help="machine-readable output")
    trainee.add_argument(
        "--export",
        type=Path,
        default=None,
        metavar="CSV",
        help="write every attempt in the record (of NAME, at --task, when given), one row each, to this CSV "
        "(mode 0600)",
    )
    trainee.add_argument(
        "--pseudonymise",
        "--pseudonymize",
        action="store_true",
        help="with --export: stable pseudonyms (HMAC of the name with the record's own secret key) instead of names",
    )
    trainee.set_defaults(handler=_cmd_trainee)


def _cmd_trainee(args) -> int:
    from ..errors import ConfigError
    from ..guidance.assessment import standing
    from ..guidance.assessment_figures import metric_history_figure
    from ..guidance.progression import cumulative_proficiency, history_rows, progression_figure, safe_name
    from ..guidance.record import RecordError, TraineeRecord

    if not args.record.is_file():
        raise RecordError(f"no trainee record at {args.record} (a guide stage with trainee: writes one)")
    if args.export is not None:
        return _cmd_export(args)
    if args.pseudonymise:
        raise ConfigError("--pseudonymise changes what --export writes; give --export CSV", location="--pseudonymise")
    if args.name is None:
        raise ConfigError("name the trainee (or --export CSV for every attempt in the record)", location="NAME")
    out = args.out or args.record.parent
    assessment = {}
    with TraineeRecord(args.record) as record:
        if args.level is not None:
            record.set_level(args.name, None if args.level == "none" else args.level)
        rows = history_rows(record, args.name, args.task)
        if not rows:
            raise RecordError(f"trainee '{args.name}' has no attempt at task '{args.task}' in {args.record}")
        proficiency = cumulative_proficiency(record, rows)
        level = record.levels().get(args.name)
        for task in sorted({r["task"] for r in rows}):
            history = record.history(args.name, task)
            benchmark = record.benchmark(task)
            result = standing(benchmark, history)
            figure = out / f"trainee-{safe_name(args.name)}-{safe_name(task)}-metrics.png"
            status = result["status"] if result else "not judged (no benchmark for the task)"
            metric_history_figure(figure, args.name, task, history, benchmark, status)
            assessment[task] = {"gate": result, "figure": str(figure), "last": history[-1]["metrics"]}
    figure = out / f"trainee-{safe_name(args.name)}.png"
    progression_figure(figure, args.name, rows, proficiency)
    if args.json:
        print(
            json.dumps(
                {
                    "trainee": args.name,
                    "level": level,
                    "attempts": rows,
                    "proficiency": proficiency,
                    "assessment": assessment,
                    "figure": str(figure),
                },
                indent=2,
                default=str,
            )
        )
        return 0
    from rich.console import Console

    console = Console() if sys.stdout.isatty() else Console(width=160)
    console.print(_history_table(args, rows, proficiency, figure, level))
    for task, entry in assessment.items():
        console.print(_standing_table(args.name, task, entry))
    return 0


def _cmd_export(args) -> int:
    from ..guidance.export import export_rows, write_rows_csv
    from ..guidance.record import TraineeRecord

    with TraineeRecord(args.record) as record:
        rows = export_rows(record, trainee=args.name, task=args.task, pseudonymise=args.pseudonymise)
    write_rows_csv(args.export, rows)
    trainees = len({r["trainee"] for r in rows})
    what = "pseudonymised" if args.pseudonymise else "named"
    if args.json:
        print(json.dumps({"csv": str(args.export), "attempts": len(rows), "trainees": trainees, "names": what}))
    else:
        print(f"{args.export}: {len(rows)} attempts of {trainees} trainees ({what}), mode 0600")
    return 0


def _history_table(args, rows, proficiency, figure, level):
    from rich.table import Table

    table = Table(
        title=f"trainee {args.name}{f' ({level})' if level else ''} ({args.record})",
        title_justify="left",
        caption=f"lengths in mm; progression figure: {figure}",
        caption_justify="left",
    )
    for column in (
        "#",
        "started",
        "task",
        "status",
        "score",
        "time s",
        "dev. rms",
        "dev. p95",
        "min clear.",
        "< d_thresh s",
        "contacts",
        "d_thresh",
        "own p95",
    ):
        table.add_column(column, justify="right" if column not in ("started", "task", "status") else "left")
    seen: dict[str, int] = {}
    for r in rows:
        i = seen[r["task"]] = seen.get(r["task"], -1) + 1
        table.add_row(
            str(r["n"]),
            r["started"],
            r["task"],
            r["status"],
            f"{r['score']:.0f}",
            f"{r['duration_s']:.1f}",
            f"{1000 * r['deviation_rms_m']:.2f}",
            f"{1000 * r['deviation_p95_m']:.2f}",
            f"{1000 * r['min_clearance_m']:.2f}",
            f"{r['below_threshold_s']:.2f}",
            str(r["contacts"]),
            f"{1000 * r['d_thresh_m']:.2f}",
            f"{1000 * proficiency[r['task']][i]:.2f}",
        )
    return table


def _standing_table(name: str, task: str, entry: dict):
    """The last attempt's metrics against the task's thresholds, and the gate."""
    from rich.table import Table

    from ..guidance.metrics import METRIC_BY_NAME, METRICS

    result = entry["gate"]
    caption = f"metrics' history against their thresholds: {entry['figure']}"
    if result is None:
        title = f"{name} at {task}: last attempt (no benchmark for the task: surgiplan benchmark-task {task} ...)"
    else:
        title = f"{name} at {task}: gate {result['status']}"
        caption = f"benchmark: {result['benchmark_rule']}\n{caption}"
    table = Table(title=title, title_justify="left", caption=caption, caption_justify="left")
    for column in ("metric", "last attempt", "threshold", "within"):
        table.add_column(column, justify="left" if column == "metric" else "right")
    names = list(result["last"]) if result else [m.name for m in METRICS if m.name in entry["last"]]
    for metric in names:
        value = entry["last"].get(metric)
        judged = result["last"].get(metric) if result else None
        threshold, within = "—", ""
        if judged is not None:
            threshold = ("≤ " if judged["better"] == "lower" else "≥ ") + format_metric(metric, judged["threshold"])
            within = "[green]yes[/green]" if judged["within"] else "[red]no[/red]"
        table.add_row(METRIC_BY_NAME[metric].label, format_metric(metric, value), threshold, within)
    return table


def format_metric(name: str, value) -> str:
    """A metric's value as tables print it (lengths in mm)."""
    from ..guidance.metrics import METRIC_BY_NAME

    if value is None:
        return "—"
    unit = METRIC_BY_NAME[name].unit
    if unit == "m":
        return f"{1000 * value:.3g} mm"
    if unit == "s":
        return f"{value:.3g} s"
    if unit == "count":
        return f"{value:.3g}"
    return f"{value:.4g}"
