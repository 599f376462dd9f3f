"""The ``surgiplan`` command line: run, validate, plugins, trainee, view.

Exit status: 0 success; 1 a stage did not succeed or a plugin failed;
2 bad input (the message names the file, the key and the problem);
130 interrupted. No traceback unless ``--debug`` or ``SURGIPLAN_DEBUG=1``.
"""

from __future__ import annotations

import argparse
import functools
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

    run.add_argument(
        "--live",
        nargs="?",
        const="ws://127.0.0.1:8765/feed",
        default=None,
        metavar="URL",
        help="feed what running stages do to `surgiplan view --live` (default ws://127.0.0.1:8765/feed)",
    )
    _add_view_parser(sub)

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
    _print_warnings(pipeline)
    progress = NullProgress() if args.quiet else RichProgress()
    live = _live_feed(args.live, pipeline)
    ended = "error"
    try:
        outcome = run_pipeline(pipeline, progress=progress, live=live)
        ended = outcome.status.value
    except KeyboardInterrupt:
        ended = "interrupted"
        raise
    finally:
        _close_live_feed(live, ended)
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


def _print_warnings(pipeline) -> None:
    """Deprecated spellings and the like: said once, with the file and line, on stderr."""
    for warning in pipeline.warnings:
        print(f"warning: {warning}", file=sys.stderr)


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
    _print_warnings(pipeline)
    stages = ", ".join(f"{s.kind} {s.name}" + (f" ({s.plugin.name})" if s.plugin else "") for s in pipeline.stages)
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
    rows += [
        {
            "name": info.name,
            "kind": "stage kind",
            "package": info.package,
            "version": info.version,
            "description": info.kind.description,
            "available": True,
            "unavailable": "",
        }
        for info in sorted(registry.stage_kinds.values(), key=lambda i: i.name)
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


# ----------------------------------------------------------------------------- the report and the live view (issue 18)


def _add_view_parser(sub) -> None:
    view = sub.add_parser(
        "view",
        help="show a run's report.html (served on 127.0.0.1), or with --live what a running stage does",
        description="Serve OUT_DIR's report.html on 127.0.0.1 and open it in the browser (Ctrl-C stops); "
        "with --live, the live viewer that `surgiplan run --live` feeds.",
    )
    view.add_argument("out_dir", nargs="?", type=Path, metavar="OUT_DIR", help="a run's output directory")
    view.add_argument("--live", action="store_true", help="the live viewer: watch a running execute or guide stage")
    view.add_argument("--port", type=int, default=None, help="port on 127.0.0.1 (default: any free one; --live 8765)")
    view.add_argument("--no-browser", action="store_true", help="print the address, do not open a browser")
    view.add_argument("--exit-after", type=float, default=None, metavar="S", help="stop after S seconds")


def _cmd_view(args) -> int:
    from .errors import ConfigError

    if args.port is not None and not 0 <= args.port <= 65535:
        raise ConfigError(f"--port {args.port}: choose 0 to 65535", location="--port")
    announce = functools.partial(print, flush=True)
    if args.live:
        from .live import DEFAULT_PORT
        from .outputs.report.server import serve_live

        if args.out_dir is not None:
            raise ConfigError("give OUT_DIR or --live, not both", location="view")
        announce("surgiplan live view (Ctrl-C stops):")
        serve_live(
            port=DEFAULT_PORT if args.port is None else args.port,
            open_browser=not args.no_browser,
            exit_after=args.exit_after,
            announce=announce,
        )
        return 0
    if args.out_dir is None:
        raise ConfigError("give a run's output directory (surgiplan view OUT_DIR), or --live", location="view")
    from .outputs.report.server import serve_directory
    from .outputs.report.view import ensure_report

    report = ensure_report(args.out_dir, announce)
    announce(f"{report} (Ctrl-C stops):")
    serve_directory(
        args.out_dir,
        port=args.port or 0,
        open_browser=not args.no_browser,
        exit_after=args.exit_after,
        announce=announce,
    )
    return 0


def _live_feed(url, pipeline):
    """The feed `run --live` hands to every stage (None without --live): the run and its scene first."""
    if url is None:
        return None
    from .live import WebSocketFeed
    from .outputs.report import scene_data
    from .units import LENGTH_UNITS

    feed = WebSocketFeed(url)
    unit = pipeline.model.length_unit
    stages = [
        {
            "name": s.name,
            "kind": s.kind,
            "plugin": s.plugin.name if s.plugin else "",
            "path_from": getattr(s, "path_from", None),
        }
        for s in pipeline.stages
    ]
    run = {"name": pipeline.name, "pipeline_file": str(pipeline.file), "length_unit": unit, "stages": stages}
    feed.publish("run", {**run, "unit_scale": LENGTH_UNITS[unit]})
    feed.publish("scene", scene_data(pipeline.scene))
    return feed


def _close_live_feed(feed, status: str) -> None:
    if feed is not None:
        feed.publish("run_end", {"status": status})
        feed.close()
        if feed.dropped:
            logging.getLogger("surgiplan").warning(
                "live feed: %d samples dropped (the viewer was not keeping up)", feed.dropped
            )


def _where_the_record_is(exc: BaseException) -> None:
    outcome = getattr(exc, "outcome", None)
    if outcome is not None:
        print(f"the stages so far are recorded in {outcome.output_dir / 'result.json'}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from .runner import debug_enabled

    debug = args.debug or debug_enabled()
    restore_logging = _setup_logging(args.verbose)
    commands = {
        "run": _cmd_run,
        "validate": _cmd_validate,
        "plugins": _cmd_plugins,
        "trainee": _cmd_trainee,
        "view": _cmd_view,
    }
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
