"""``surgiplan can-decode TRACE``: a CAN trace's CANopen traffic, objects and states by name
(:mod:`surgiplan.outputs.candecode`).

The trace is any file python-can reads (``.blf``, ``.asc``, ``.log``, ``.csv``, ``.trc``): the traces
``record: {can: ...}`` writes, or one taken with ``python -m can.logger``, candump or CANalyzer. The object
names and data types come from EDS files: ``--device NAME`` takes a registered CiA 402 device's drives
(node-ids, joint names and EDS files as its default settings give them, ``--node-ids`` to change the
ids), ``--eds [NODE=]FILE`` any node's. Without either, CiA 301's frames are decoded and objects shown by
index.
"""

from __future__ import annotations

import json
from pathlib import Path


def add_parsers(sub) -> None:
    parser = sub.add_parser(
        "can-decode",
        help="print a CAN trace (blf, asc, log, ...) as CANopen objects and states by name",
        description="Decodes every frame of TRACE as CiA 301/402 (NMT, SYNC, EMCY, PDOs as their mapped objects, "
        "SDO transfers, heartbeats, CiA 402 states), with object names and types from the drives' EDS files.",
    )
    parser.add_argument("trace", type=Path, metavar="TRACE", help="a trace python-can reads (.blf .asc .log .csv .trc)")
    parser.add_argument("--device", help="a registered CiA 402 device (cast_gimbal, gripper6, ...): its drives' EDS")
    parser.add_argument("--node-ids", type=int, nargs="+", metavar="ID", help="the device's node-ids, one per joint")
    parser.add_argument("--eds", action="append", default=[], metavar="[NODE=]FILE", help="a node's EDS (repeatable)")
    parser.add_argument("--events", action="store_true", help="only NMT and CiA 402 state changes, EMCY, aborts")
    parser.add_argument("--node", type=int, action="append", metavar="ID", help="only frames of this node")
    parser.add_argument("--limit", type=int, metavar="N", help="stop after N printed frames")
    parser.add_argument("--json", action="store_true", help="one JSON object per frame")
    parser.set_defaults(handler=_cmd)


def _nodes(args) -> dict:
    from ..errors import ConfigError
    from ..outputs.candecode import load_nodes

    eds: dict[int, Path] = {}
    names: dict[int, str] = {}
    if args.device:
        from ..registry import default_registry

        info = default_registry().get("device", args.device, location="--device")
        settings = {"node_ids": args.node_ids} if args.node_ids else {}
        try:
            device = info.cls(info.cls.Settings.model_validate(settings))
            drives = device.can_nodes()
        except AttributeError:
            raise ConfigError(
                f"device '{args.device}' is not a CANopen device (no can_nodes)", location="--device"
            ) from None
        except ValueError as exc:
            raise ConfigError(f"--node-ids: {exc}", location="--node-ids") from None
        for node_id, name, path in drives:
            eds[node_id], names[node_id] = path, name
    for text in args.eds:
        node, sep, file = text.partition("=")
        if sep and not node.strip().isdigit():
            raise ConfigError(f"--eds {text}: expected NODE=FILE with a node-id 1-127, or FILE", location="--eds")
        ids = [int(node)] if sep else (sorted(eds) or [1])
        for node_id in ids:
            eds[node_id] = Path(file if sep else text)
    for node_id, path in eds.items():
        if not 1 <= node_id <= 127:
            raise ConfigError(f"--eds: node-id {node_id} is outside 1-127", location="--eds")
        if not path.is_file():
            raise ConfigError(f"no such EDS file: {path}", location="--eds")
    return load_nodes(eds, names)


def _cmd(args) -> int:
    from ..outputs.candecode import decode_trace

    nodes = _nodes(args)
    printed = 0
    events = 0
    total = 0
    for frame in decode_trace(args.trace, nodes):
        total += 1
        events += frame.event
        if args.events and not frame.event:
            continue
        if args.node and frame.node not in args.node:
            continue
        if args.limit is not None and printed >= args.limit:
            continue  # keep counting
        printed += 1
        if args.json:
            print(json.dumps(frame.__dict__))
        else:
            print(f"{frame.t:12.6f}  {frame.direction}  {frame.kind:<13} {frame.text}")
    if not args.json:
        print(f"{total} frame(s), {events} event(s); {printed} shown")
    return 0
