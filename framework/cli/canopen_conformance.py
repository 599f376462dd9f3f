"""``surgiplan canopen-conformance DEVICE``: the CiA conformance test families on a CiA 402 device's drives.

The device is a registered device plugin (``cast_gimbal``, ``gripper6``, a third party's); the families are
its plugin's (the device class's ``conformance``, found through the registry: the core imports no plugin).
By default the device's simulated drives run in a process of their own on the loopback bus; with
``--interface`` and ``--channel`` the drives on any python-can bus are tested instead, the checks a lab
runs on its hardware before trusting it. Prints family, case, verdict and evidence (``--json`` for
machines); exit status 0 when no case fails, 1 otherwise, 2 for bad input.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def add_parsers(sub) -> None:
    parser = sub.add_parser(
        "canopen-conformance",
        help="run the CiA conformance test families on a CiA 402 device's drives (simulated, or on a real bus)",
        description="EDS, SDO, PDO, EMCY and error control, NMT, store/restore and LSS cases, as CiA's "
        "conformance test tool runs them, on every drive of DEVICE: its simulated drives (default) or the "
        "drives on the python-can bus --interface/--channel name.",
    )
    parser.add_argument("device", metavar="DEVICE", help="a CiA 402 device plugin (cast_gimbal, gripper6, ...)")
    parser.add_argument("--interface", help="python-can interface of real drives (socketcan, pcan, kvaser, ...)")
    parser.add_argument("--channel", help="the interface's channel (can0, PCAN_USBBUS1, ...)")
    parser.add_argument("--bitrate", type=int, default=1_000_000, help="bit rate (default 1000000)")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE", help="a python-can Bus option")
    parser.add_argument("--node-ids", type=int, nargs="+", metavar="ID", help="the drives' node-IDs (one per joint)")
    parser.add_argument("--eds", type=Path, nargs="+", metavar="FILE", help="the drives' EDS (one, or one per joint)")
    parser.add_argument(
        "--family", action="append", metavar="NAME", help="run only this family or case (SDO, PDO, NMT, 2.9, ...)"
    )
    parser.add_argument(
        "--scan",
        default="standard",
        choices=["standard", "full", "none"],
        help="the object dictionary scan: standard 0x1000-0x1FFF and 0x6000-0x67FF, full 0x1000-0x9FFF",
    )
    parser.add_argument("--unconfigured", action="store_true", help="real drives started without node-IDs (LSS)")
    parser.add_argument(
        "--allow-store", action="store_true", help="real drives: let store/restore change what they keep (0x1010/1011)"
    )
    parser.add_argument("--sdo-timeout", type=float, default=1.0, metavar="S", help="SDO answer time-out (s)")
    parser.add_argument("--lss-timeout", type=float, default=0.15, metavar="S", help="LSS fast scan step time-out (s)")
    parser.add_argument("--per-drive", action="store_true", help="one row per case and drive")
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.add_argument("--output", type=Path, metavar="FILE", help="also write the JSON report to FILE")
    parser.set_defaults(handler=_cmd)


def _option(text: str) -> tuple[str, object]:
    from ..errors import ConfigError

    key, _, value = text.partition("=")
    if not key or not value:
        raise ConfigError(f"--option {text}: expected KEY=VALUE", location="--option")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def _cmd(args) -> int:
    from ..errors import ConfigError
    from ..registry import default_registry

    info = default_registry().get("device", args.device, location="DEVICE")
    conformance = getattr(info.cls, "conformance", None)
    if conformance is None:
        raise ConfigError(
            f"device '{args.device}' is not a CANopen CiA 402 device: it has no conformance suite", location="DEVICE"
        )
    if args.interface is not None and args.channel is None:
        raise ConfigError(f"--interface {args.interface} needs --channel", location="--channel")
    if args.channel is not None and args.interface is None:
        raise ConfigError("--channel needs --interface (without both: the simulated drives)", location="--interface")
    settings = {
        "interface": args.interface,
        "channel": args.channel,
        "bitrate": args.bitrate,
        "options": dict(_option(o) for o in args.option),
        "node_ids": args.node_ids,
        "eds": [str(p) for p in args.eds] if args.eds else None,
        "families": args.family,
        "scan": args.scan,
        "unconfigured": args.unconfigured,
        "allow_store": args.allow_store,
        "sdo_timeout": args.sdo_timeout,
        "lss_timeout": args.lss_timeout,
    }
    quiet = args.json or not sys.stderr.isatty()

    def progress(text: str) -> None:
        if not quiet:
            print(f"  {text}", file=sys.stderr, flush=True)

    report = conformance(args.device, settings, progress)
    payload = report.as_dict()
    if args.output is not None:
        from ..storage import write_json_atomic

        write_json_atomic(args.output, payload)
    if args.json:
        print(json.dumps(payload, indent=2))
    else:
        _print(payload, args.per_drive)
    return 1 if report.failed else 0


def _print(payload: dict, per_drive: bool) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console() if sys.stdout.isatty() else Console(width=200)
    counts = ", ".join(f"{n} {verdict}" for verdict, n in payload["counts"].items() if n)
    table = Table(title=f"{payload['device']}: {payload['target']}", title_justify="left")
    for column in ("family", "case", "verdict", "drives" if not per_drive else "drive"):
        table.add_column(column, no_wrap=True)
    table.add_column("evidence")
    colour = {"pass": "green", "fail": "red", "warning": "yellow"}
    if per_drive:
        for row in payload["rows"]:
            verdict = f"[{colour.get(row['verdict'], 'white')}]{row['verdict']}[/]"
            where = f"{row['node']} {row['joint']}"
            table.add_row(row["family"], row["case"], verdict, where, f"{row['title']}: {row['evidence']}")
    else:
        for case in payload["cases"]:
            verdict = f"[{colour.get(case['verdict'], 'white')}]{case['verdict']}[/]"
            drives = f"{case['passed']}/{case['drives']}"
            table.add_row(case["family"], case["case"], verdict, drives, f"{case['title']}: {case['evidence']}")
    console.print(table)
    console.print(f"{len(payload['cases'])} cases on every drive: {counts} ({payload['seconds']:.0f} s)")
