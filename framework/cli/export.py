"""``surgiplan export mcap RUN_DIR``: a run's motions, scene and events as an MCAP file for Foxglove and ROS 2
tooling (:mod:`surgiplan.outputs.mcap`)."""

from __future__ import annotations

from pathlib import Path


def add_parsers(sub) -> None:
    export = sub.add_parser("export", help="a run in a format other tools open: mcap (Foxglove, ROS 2)")
    formats = export.add_subparsers(dest="format", required=True)
    mcap = formats.add_parser(
        "mcap",
        help="the run's scene, paths, motions, joints and events as MCAP (Foxglove's schemas)",
        description="Writes RUN_DIR's scene, plan paths (critical regions in red), and every execute and guide "
        "stage's samples (tip poses, joints, clearance and deviation, events) as one MCAP file.",
    )
    mcap.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="a run's output directory (with result.json)")
    mcap.add_argument("--stage", action="append", default=None, help="only this stage (repeatable): one attempt")
    mcap.add_argument("--out", type=Path, default=None, help="the file (default: RUN_DIR/<run or stage>.mcap)")
    mcap.set_defaults(handler=_cmd_mcap)


def _cmd_mcap(args) -> int:
    import json

    from ..errors import OutputError
    from ..outputs.mcap import export_mcap

    if not (args.run_dir / "result.json").is_file():
        raise OutputError(f"{args.run_dir} has no result.json: give a finished run's output directory")
    name = json.loads((args.run_dir / "result.json").read_text()).get("name", "run")
    default = args.stage[0] if args.stage and len(args.stage) == 1 else name
    out = args.out or args.run_dir / f"{default}.mcap"
    counts = export_mcap(args.run_dir, out, args.stage)
    for topic, (messages, first, last) in counts.items():
        print(f"{topic}: {messages} message(s), {first:.3f} s to {last:.3f} s")
    print(f"wrote {out} (open it in Foxglove, or with ros2 bag / the mcap CLI)")
    return 0
