"""The ``surgiplan`` command line: run, validate, plugins, trainee, benchmark-task, cohort, validity, view,
canopen-conformance; one module per command group.

Each module of this package adds its subcommands (``add_parsers(sub)``, each with ``set_defaults(handler=...)``);
:func:`main` parses, dispatches, and turns errors into exit statuses.

Exit status: 0 success; 1 a stage did not succeed or a plugin failed;
2 bad input (the message names the file, the key and the problem);
130 interrupted. No traceback unless ``--debug`` or ``SURGIPLAN_DEBUG=1``.
"""

from __future__ import annotations

import argparse
import logging
import sys
import traceback

from ..allocator import keep_freed_memory
from ..errors import SurgiplanError, debug_enabled
from . import benchmark, benchmark_task, can_decode, canopen_conformance, cohort, export, plugins, run, trainee, view

#: the command groups, in the order --help lists them
COMMANDS = (run, view, trainee, benchmark_task, cohort, benchmark, export, can_decode, canopen_conformance, plugins)


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


class _VersionAction(argparse.Action):
    """``--version``: the installed version, read from the distribution's metadata only when asked."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help="show the version and exit")

    def __call__(self, parser, namespace, values, option_string=None):
        from .. import __version__

        print(f"surgiplan {__version__}")  # to stdout, as argparse's own version action does
        parser.exit()


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="surgiplan", description="Plugin-based planning for surgical training and robotics."
    )
    parser.add_argument("--version", action=_VersionAction)
    parser.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    parser.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="log what happens: each stage's outcome, artifacts reused or stored, the executor, files written",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for module in COMMANDS:
        module.add_parsers(sub)
    return parser


def _where_the_record_is(exc: BaseException) -> None:
    outcome = getattr(exc, "outcome", None)
    if outcome is not None:
        print(f"the stages so far are recorded in {outcome.output_dir / 'result.json'}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    keep_freed_memory()  # a command's stages allocate and free tens of megabytes each (surgiplan.allocator)
    debug = args.debug or debug_enabled()
    restore_logging = _setup_logging(args.verbose)
    try:
        return args.handler(args)
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
