"""``surgiplan run`` and ``surgiplan validate``: a pipeline file, checked and run."""

from __future__ import annotations

import logging
import sys
from pathlib import Path


def add_parsers(sub) -> None:
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
        help="feed what running stages do to `surgiplan view --live` (default ws://127.0.0.1:8765/feed; its token "
        "from SURGIPLAN_LIVE_TOKEN or the URL's ?token=)",
    )
    run.set_defaults(handler=_cmd_run)
    validate = sub.add_parser("validate", help="check a pipeline (or scene) file without running it")
    validate.add_argument("file", type=Path)
    validate.set_defaults(handler=_cmd_validate)


def _cmd_run(args) -> int:
    from rich.console import Console

    from ..outputs.summary import print_summary
    from ..pipeline import load_pipeline
    from ..progress import NullProgress, RichProgress
    from ..runner import run_pipeline
    from ..units import LENGTH_UNITS

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
        for warning in r.warnings:
            print(f"warning: {r.stage} stage '{r.name}': {warning}", file=sys.stderr)
        if not r.succeeded:
            print(f"{r.stage} stage '{r.name}': {r.status}" + (f": {r.message}" if r.message else ""), file=sys.stderr)
    return 0 if outcome.ok else 1


def _print_warnings(pipeline) -> None:
    """Deprecated spellings and the like: said once, with the file and line, on stderr."""
    for warning in pipeline.warnings:
        print(f"warning: {warning}", file=sys.stderr)


def _cmd_validate(args) -> int:
    from ..pipeline import load_pipeline, load_scene, looks_like_scene
    from ..yamlio import load_yaml

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


def _live_feed(url, pipeline):
    """The feed `run --live` hands to every stage (None without --live): the run and its scene first."""
    if url is None:
        return None
    from ..live import WebSocketFeed
    from ..outputs.report import scene_data
    from ..units import LENGTH_UNITS

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
