"""``surgiplan view``: a run's report.html served on 127.0.0.1, or the live viewer ``run --live`` feeds."""

from __future__ import annotations

import functools
from pathlib import Path


def add_parsers(sub) -> None:
    view = sub.add_parser(
        "view",
        help="show a run's report.html (served on 127.0.0.1), or with --live what a running stage does",
        description="Serve OUT_DIR's report.html on 127.0.0.1 and open it in the browser (Ctrl-C stops); "
        "with --live, the live viewer that `surgiplan run --live` feeds. Only the holder of the random token "
        "in the printed address is served (403 otherwise); a run feeds the live viewer with that token in "
        "SURGIPLAN_LIVE_TOKEN (or the feed URL's ?token=).",
    )
    view.add_argument("out_dir", nargs="?", type=Path, metavar="OUT_DIR", help="a run's output directory")
    view.add_argument("--live", action="store_true", help="the live viewer: watch a running execute or guide stage")
    view.add_argument("--port", type=int, default=None, help="port on 127.0.0.1 (default: any free one; --live 8765)")
    view.add_argument("--no-browser", action="store_true", help="print the address, do not open a browser")
    view.add_argument(
        "--fps",
        type=float,
        default=None,
        metavar="N",
        help="--live: the page draws at most N frames a second (0: every frame the display offers; default: 30 "
        "when the browser renders WebGL in software, as without a GPU, where each frame takes CPU the stage needs)",
    )
    view.add_argument("--exit-after", type=float, default=None, metavar="S", help="stop after S seconds")
    view.set_defaults(handler=_cmd_view)


def _cmd_view(args) -> int:
    from ..errors import ConfigError

    if args.port is not None and not 0 <= args.port <= 65535:
        raise ConfigError(f"--port {args.port}: choose 0 to 65535", location="--port")
    announce = functools.partial(print, flush=True)
    if args.live:
        from ..live import DEFAULT_PORT
        from ..outputs.report.server import serve_live

        if args.out_dir is not None:
            raise ConfigError("give OUT_DIR or --live, not both", location="view")
        if args.fps is not None and not (args.fps == 0 or 1 <= args.fps <= 240):
            raise ConfigError(f"--fps {args.fps:g}: give 0 (the display's rate) or 1 to 240", location="--fps")
        announce("surgiplan live view (Ctrl-C stops):")
        serve_live(
            port=DEFAULT_PORT if args.port is None else args.port,
            open_browser=not args.no_browser,
            exit_after=args.exit_after,
            announce=announce,
            fps=args.fps,
        )
        return 0
    if args.fps is not None:
        raise ConfigError("--fps is the live view's (surgiplan view --live --fps N)", location="--fps")
    if args.out_dir is None:
        raise ConfigError("give a run's output directory (surgiplan view OUT_DIR), or --live", location="view")
    from ..outputs.report.server import serve_directory
    from ..outputs.report.view import ensure_report

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
