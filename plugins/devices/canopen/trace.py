"""CAN traces: the bus traffic of a stage, written by python-can's writers in the formats CAN tools open.

``record: {can: blf | asc | log}`` in a CiA 402 device's settings (``cast_gimbal``, ``gripper6``, and the
``cast_gimbal`` pose source, which runs the same device) writes every frame the master sent or received,
from the NMT reset at configure to the bus's release, as ``<stage>.can.<format>`` in the run's output
directory:

- ``blf``: Vector's binary logging format (CANalyzer, CANoe, SavvyCAN, asammdf);
- ``asc``: Vector's ASCII trace (the same tools, and a text editor);
- ``log``: can-utils' ``candump -l`` format (``canplayer``, ``log2asc``).

All three are python-can's own writers, so ``can.LogReader`` reads them back, ``python -m can.player``
replays them onto a bus and ``python -m can.logconvert`` converts them. Time stamps are the stage's clock
(simulated or real time), placed at the wall-clock time the device was configured so that tools show the
date of the run; a frame the master sent is marked transmitted (``Tx``), one it received ``Rx``.
``surgiplan can-decode TRACE`` prints the frames as CANopen objects and states by name.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Literal

import can
from surgiplan.models import StrictModel
from surgiplan.storage import commit_file

#: the formats and python-can's writer of each
WRITERS = {"blf": can.BLFWriter, "asc": can.ASCWriter, "log": can.CanutilsLogWriter}


class RecordSettings(StrictModel):
    """What a device records besides its own outputs (off by default)."""

    #: the CAN bus traffic as a trace: blf (Vector binary), asc (Vector ASCII) or log (candump -l); None: none
    can: Literal["blf", "asc", "log"] | None = None


def trace_name(stage: str, fmt: str) -> str:
    """The trace's file name for a stage: ``<stage>.can.<format>``."""
    return f"{stage}.can.{fmt}"


def trace_messages(
    frames: Iterable[tuple[float, int, bytes]], transmitted: set[int], epoch: float
) -> Iterable[can.Message]:
    """python-can messages of logged frames ``(time s, arbitration id, data)``: time stamps ``epoch + time``,
    ``is_rx`` False for the identifiers in ``transmitted`` (what this end of the bus sends)."""
    for t, arbitration_id, data in frames:
        yield can.Message(
            timestamp=epoch + t,
            arbitration_id=arbitration_id,
            is_extended_id=arbitration_id > 0x7FF,
            data=data,
            is_rx=arbitration_id not in transmitted,
        )


def write_trace(
    path: Path, fmt: str, frames: Iterable[tuple[float, int, bytes]], transmitted: set[int], epoch: float
) -> int:
    """Write the frames as a ``fmt`` trace at ``path`` (atomically: a complete file or none); returns the count.

    The writer writes a temporary file next to ``path`` (with the format's suffix, which python-can's readers
    go by), which is synced and renamed over ``path`` only once complete.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.partial.{fmt}")
    count = 0
    try:
        writer = WRITERS[fmt](tmp)
        try:
            for message in trace_messages(frames, transmitted, epoch):
                writer.on_message_received(message)
                count += 1
        finally:
            writer.stop()
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    commit_file(tmp, path)  # synced, renamed into place, the directory synced
    return count
