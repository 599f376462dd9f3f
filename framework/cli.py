"""The ``surgiplan`` command line: run, validate, plugins, trainee.

Exit status: 0 success; 1 a stage did not succeed or a plugin failed;
2 bad input (the message names the file, the key and the problem);
130 interrupted. No traceback unless ``--debug`` or ``SURGIPLAN_DEBUG=1``.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import traceback
from pathlib import Path

from . import __version__
from .errors import SurgiplanError


class _Formatter(logging.Formatter):
    def format(self, record):
        return f"{record.levelname.lower()}: {record.getMessage()}"


def _setup_logging(verbose: bool):
    """Log surgiplan's warnings to stderr for this command; returns the undo."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_Formatter())
    logger = logging.getLogger("surgiplan")
    saved = (logger.handlers[:], logger.level, logger.propagate)
    logger.handlers[:] = [handler]
    logger.setLevel(logging.INFO if verbose else logging.WARNING)
    logger.propagate = False
    logging.getLogger("trimesh").setLevel(logging.ERROR)

    def restore() -> None:
        logger.handlers[:], logger.level, logger.propagate = saved

    return restore


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="surgiplan", description="Plugin-based planning for surgical training and robotics."
    )
    parser.add_argument("--version", action="version", version=f"surgiplan {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    parser.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="log what happens: each stage's outcome, artifacts reused or stored, the executor, files written",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run a pipeline file and write result.json, figures and scene.glb")
    run.add_argument("file", type=Path)
    run.add_argument("--out", type=Path, default=None, help="output directory (default: output.dir of the file)")
    run.add_argument(
        "--quiet",
        action="store_true",
        help="no progress bars and no summary table: one line saying where the results are",
    )

    validate = sub.add_parser("validate", help="check a pipeline (or scene) file without running it")
    validate.add_argument("file", type=Path)

    trainee = sub.add_parser("trainee", help="a trainee's attempts from the trainee record, and a progression figure")
    trainee.add_argument("name")
    trainee.add_argument("--record", type=Path, default=Path("out/trainees.sqlite"), help="the trainee record")
    trainee.add_argument("--task", default=None, help="only this task")
    trainee.add_argument(
        "--out", type=Path, default=None, help="where to write the figure (default: beside the record)"
    )
    trainee.add_argument("--json", action="store_true", help="machine-readable output")

    plugins = sub.add_parser("plugins", help="list installed plugins")
    plugins.add_argument("--json", action="store_true", help="machine-readable output")
    return parser


def _cmd_run(args) -> int:
    from rich.console import Console

    from .outputs.summary import print_summary
    from .pipeline import load_pipeline
    from .progress import NullProgress, RichProgress
    from .runner import run_pipeline
    from .units import LENGTH_UNITS

    pipeline = load_pipeline(args.file, output_dir=args.out)
    progress = NullProgress() if args.quiet else RichProgress()
    outcome = run_pipeline(pipeline, progress=progress)
    if not args.quiet:
        unit = pipeline.model.length_unit
        # piped output (CI logs, files) has no terminal width: do not fold the table into 80 columns
        print_summary(
            Console() if sys.stdout.isatty() else Console(width=140),
            pipeline.name,
            outcome.results,
            unit=unit,
            unit_scale=LENGTH_UNITS[unit],
            output_dir=str(outcome.output_dir),
        )
    else:
        succeeded = sum(r.succeeded for r in outcome.results)
        print(
            f"{pipeline.name}: {succeeded} of {len(outcome.results)} stages succeeded; "
            f"results in {outcome.output_dir / 'result.json'}"
        )
    logging.getLogger("surgiplan").info("wrote in %s: %s", outcome.output_dir, ", ".join(outcome.files))
    for r in outcome.results:
        if not r.succeeded:
            print(f"{r.stage} stage '{r.name}': {r.status}" + (f": {r.message}" if r.message else ""), file=sys.stderr)
    return 0 if outcome.ok else 1


def _cmd_validate(args) -> int:
    from .pipeline import load_pipeline, load_scene, looks_like_scene
    from .yamlio import load_yaml

    data, _ = load_yaml(args.file)
    if looks_like_scene(data):
        scene = load_scene(args.file)
        print(
            f"{args.file}: ok: scene '{scene.name}' (a scene file): {len(scene.obstacles)} obstacles, "
            f"{len(scene.points)} points"
        )
        return 0
    pipeline = load_pipeline(args.file)
    stages = ", ".join(f"{s.kind} {s.name} ({s.plugin.name})" for s in pipeline.stages)
    scene = pipeline.scene
    print(
        f"{args.file}: ok: pipeline '{pipeline.name}': {stages}; scene: {len(scene.obstacles)} obstacles, "
        f"{len(scene.points)} points"
    )
    return 0


def _cmd_trainee(args) -> int:
    from .guidance.progression import cumulative_proficiency, history_rows, progression_figure, safe_name
    from .guidance.record import RecordError, TraineeRecord

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


def _cmd_plugins(args) -> int:
    from .registry import default_registry

    registry = default_registry()
    rows = [
        {
            "name": p.name,
            "kind": p.kind,
            "package": p.package,
            "version": p.version,
            "description": p.description,
            "available": not p.unavailable,
            "unavailable": p.unavailable,
        }
        for p in registry.all()
    ]
    if args.json:
        print(json.dumps({"plugins": rows, "failures": [f.__dict__ for f in registry.failures]}, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title="surgiplan plugins", title_justify="left")
    for column in ("name", "kind", "package", "version"):
        table.add_column(column, no_wrap=True)
    table.add_column("description")
    for row in rows:
        description = row["description"] if row["available"] else f"[yellow]unavailable: {row['unavailable']}[/yellow]"
        table.add_row(row["name"], row["kind"], row["package"], row["version"], description)
    # a pipe or a CI log is not a terminal: do not squeeze the table into 80 columns
    console = Console() if sys.stdout.isatty() else Console(width=160)
    console.print(table)
    for failure in registry.failures:
        console.print(f"[red]failed:[/red] {failure.error}")
    return 0


def _where_the_record_is(exc: BaseException) -> None:
    outcome = getattr(exc, "outcome", None)
    if outcome is not None:
        print(f"the stages so far are recorded in {outcome.output_dir / 'result.json'}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from .runner import debug_enabled

    debug = args.debug or debug_enabled()
    restore_logging = _setup_logging(args.verbose)
    commands = {"run": _cmd_run, "validate": _cmd_validate, "plugins": _cmd_plugins, "trainee": _cmd_trainee}
    try:
        return commands[args.command](args)
    except SurgiplanError as exc:
        if debug:
            traceback.print_exc()
        print(f"error: {exc}", file=sys.stderr)
        _where_the_record_is(exc)
        return exc.exit_code
    except KeyboardInterrupt as exc:
        print("interrupted: finished offline work is kept in checkpoints; run again to resume", file=sys.stderr)
        _where_the_record_is(exc)
        return 130
    except Exception as exc:
        if debug:
            traceback.print_exc()
        print(
            f"internal error: {type(exc).__name__}: {exc} (this is a bug in surgiplan; "
            "run with --debug for the traceback)",
            file=sys.stderr,
        )
        _where_the_record_is(exc)
        return 1
    finally:
        restore_logging()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
