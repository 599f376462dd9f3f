"""MAVLink telemetry logs (``.tlog``): every packet of a flight, as MAVProxy and QGroundControl write them.

The format is MAVProxy's: each packet as it went over the link, preceded by its arrival (or sending) time as
a 64-bit big-endian count of microseconds since the Unix epoch. pymavlink reads it
(``mavutil.mavlink_connection("flight.tlog")``), and so do its tools (``mavlogdump.py``,
``mavflightmodes.py``, ``mavgraph.py``), MAVExplorer, QGroundControl's and Mission Planner's log replay.

The ground station side of the ``mavlink_vehicle`` device writes ``<stage>.tlog`` of every flight (setting
``tlog``): the packets it received from the vehicle (those an injected loss dropped never arrived, so they
are not in it) and those it sent. The flight's samples are the vehicle's LOCAL_POSITION_NED received while
the flight is recorded; two STATUSTEXT notes of the ground station (its own system and component id,
written in the log only, never sent) mark where that starts and ends, so that a replay
(:func:`flight_samples`) takes exactly the samples the stage's metrics were computed from.

The file is written as ``.<name>.partial`` and renamed when the link closes: a flight cut short by a crash
leaves that partial file (every complete packet in it readable), never a truncated ``<stage>.tlog``.
"""

from __future__ import annotations

import contextlib
import struct
import time
from pathlib import Path

from surgiplan.storage import commit_file

#: the notes that mark the flight's samples (STATUSTEXT of the ground station, in the log only)
RECORDING_STARTED = "surgiplan: flight samples start"
RECORDING_STOPPED = "surgiplan: flight samples end"
_STAMP = struct.Struct(">Q")


class TelemetryLog:
    """A ``.tlog`` being written (see the module)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.partial = self.path.with_name(f".{self.path.name}.partial")
        self._file = open(self.partial, "wb")  # open for the flight; close() closes it
        self.packets = 0

    def write(self, packet: bytes, when: float | None = None) -> None:
        """One packet, time-stamped now (or at ``when``, s since the epoch) as MAVProxy does (usec, low bits 0)."""
        usec = int((time.time() if when is None else when) * 1e6) & ~3
        self._file.write(_STAMP.pack(usec) + bytes(packet))
        self.packets += 1

    def close(self) -> Path:
        """Flush, sync and rename into place; returns the final path."""
        if not self._file.closed:
            self._file.close()
            commit_file(self.partial, self.path)  # synced, renamed into place, the directory synced
        return self.path

    def abandon(self) -> None:
        with contextlib.suppress(OSError):
            self._file.close()


def flight_samples(path: Path, vehicle_system: int | None = None) -> list[tuple[float, tuple, tuple]]:
    """Replay a ``.tlog`` with pymavlink: the flight's LOCAL_POSITION_NED samples, ``(time s, (x, y, z),
    (vx, vy, vz))`` in NED, between the ground station's start and end notes (the whole log without them).
    ``vehicle_system``: only this system's messages (default: the first that sends a HEARTBEAT as a vehicle)."""
    from .link import mavlink, mavutil

    log = mavutil.mavlink_connection(str(path), dialect="common")
    samples: list[tuple[float, tuple, tuple]] = []
    marked = recording = False
    try:
        while True:
            message = log.recv_match(type=["LOCAL_POSITION_NED", "STATUSTEXT", "HEARTBEAT"])
            if message is None:
                break
            kind = message.get_type()
            if kind == "HEARTBEAT":
                if vehicle_system is None and message.type != mavlink.MAV_TYPE_GCS:
                    vehicle_system = message.get_srcSystem()
            elif kind == "STATUSTEXT":
                text = message.text if isinstance(message.text, str) else message.text.decode(errors="replace")
                if text.startswith(RECORDING_STARTED):
                    if not marked:
                        samples.clear()  # before the first note: not the flight's
                    marked = recording = True
                elif text.startswith(RECORDING_STOPPED):
                    recording = False
            elif message.get_srcSystem() == vehicle_system and (recording or not marked):
                samples.append(
                    (
                        message.time_boot_ms / 1000.0,
                        (message.x, message.y, message.z),
                        (message.vx, message.vy, message.vz),
                    )
                )
    finally:
        log.close()
    return samples
