"""``surgiplan trainee NAME``: a trainee's attempts from the trainee record, and a progression figure."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def add_parsers(sub) -> None:
    trainee = sub.add_parser("trainee", help="a trainee's attempts from the trainee record, and a progression figure")
    trainee.add_argument("name")
    trainee.add_argument("--record", type=Path, default=Path("out/trainees.sqlite"), help="the trainee record")
    trainee.add_argument("--task", default=None, help="only this task")
    trainee.add_argument(
        "--out", type=Path, default=None, help="where to write the figure (default: beside the record)"
    )
    trainee.add_argument("--json", action="store_true", help="machine-readable output")
    trainee.set_defaults(handler=_cmd_trainee)


def _cmd_trainee(args) -> int:
    from ..guidance.progression import cumulative_proficiency, history_rows, progression_figure, safe_name
    from ..guidance.record import RecordError, TraineeRecord

    if not args.record.is_file():
        raise RecordError(f"no trainee record at {args.record} (a guide stage with trainee: writes one)")
    with TraineeRecord(args.record) as record:
        rows = history_rows(record, args.name, args.task)
        if not rows:
            raise RecordError(f"trainee '{args.name}' has no attempt at task '{args.task}' in {args.record}")
        proficiency = cumulative_proficiency(record, rows)
    figure = (args.out or args.record.parent) / f"trainee-{safe_name(args.name)}.png"
    progression_figure(figure, args.name, rows, proficiency)
    if args.json:
        print(
            json.dumps(
                {"trainee": args.name, "attempts": rows, "proficiency": proficiency, "figure": str(figure)},
                indent=2,
                default=str,
            )
        )
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(
        title=f"trainee {args.name} ({args.record})",
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
    (Console() if sys.stdout.isatty() else Console(width=160)).print(table)
    return 0
