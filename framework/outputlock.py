"""The output directory's lock: one run writes into a directory at a time.

A run claims its output directory before it writes anything: it creates (or opens) ``.surgiplan.lock`` there
and takes an exclusive ``flock`` on it, then writes into it its PID, host, command and start time. The kernel
drops the lock when the process ends, however it ends (``kill -9`` included), so:

* a second run into the same directory finds the lock held and is refused, with a message naming the first
  run (PID, host, command, start time); nothing of the second run is written;
* a lock file left by a run that died is *stale*: its lock is free; the next run takes it over, and says so
  (naming the run that left it).

The file is removed when the run ends. ``flock`` rather than a PID check: a PID can be reused by an unrelated
process after a crash, a held lock cannot outlive its holder.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import socket
import sys
import time
from pathlib import Path
from typing import Any

from .errors import OutputError

log = logging.getLogger(__name__)

#: the lock file a run keeps in its output directory
LOCK_FILE = ".surgiplan.lock"


class OutputLock:
    """A held output-directory lock (see the module); :meth:`release` it when the run ends."""

    def __init__(self, path: Path, fd: int, taken_over: dict | None) -> None:
        self.path, self._fd = path, fd
        #: what the stale lock this one replaced said (None: there was none)
        self.taken_over = taken_over

    def release(self) -> None:
        """Remove the lock file and drop the lock (once)."""
        if self._fd < 0:
            return
        with contextlib.suppress(OSError):
            self.path.unlink()  # while still holding it: a waiting run then finds the file gone, and retries
        os.close(self._fd)
        self._fd = -1

    def __enter__(self) -> OutputLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def describe(holder: dict) -> str:
    """A lock's holder in words: PID, host, command, pipeline file, start time."""
    return (
        f"pid {holder.get('pid', '?')} on {holder.get('host', '?')}, command `{holder.get('command', '?')}`, "
        f"pipeline {holder.get('pipeline_file', '?')}, started {holder.get('started', '?')}"
    )


def _alive(pid: Any) -> bool:
    if not isinstance(pid, int) or pid <= 0:
        return True  # unknown: assume it is
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _read(fd: int) -> dict:
    os.lseek(fd, 0, os.SEEK_SET)
    raw = os.read(fd, 1 << 16)
    try:
        value = json.loads(raw.decode())
    except (UnicodeDecodeError, ValueError):
        return {"unreadable": raw[:200].decode(errors="replace")} if raw else {}
    return value if isinstance(value, dict) else {}


def claim(directory: Path, pipeline_file: str | Path = "", wait_s: float = 2.0) -> OutputLock:
    """Lock ``directory`` for this process, or raise :class:`~surgiplan.errors.OutputError` naming its holder.

    ``wait_s``: how long to wait for a holder that is just writing its details (a lock held with an empty
    file), before naming it as unknown."""
    path = directory / LOCK_FILE
    deadline = time.monotonic() + wait_s
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read(fd)
            os.close(fd)
            if not holder and time.monotonic() < deadline:
                time.sleep(0.05)  # the holder has the lock and is writing who it is
                continue
            orphan = ""
            if holder.get("host") == socket.gethostname() and not _alive(holder.get("pid")):
                orphan = "; that process has ended, but a process it started (a worker?) still holds the lock"
            raise OutputError(
                f"another surgiplan run is writing to {directory}: {describe(holder) if holder else 'unknown run'} "
                f"(it holds {path}{orphan}); wait for it to end or choose another --out",
                location="output.dir",
            ) from None
        try:
            if os.fstat(fd).st_ino != os.stat(path).st_ino:  # released and removed between our open and flock
                os.close(fd)
                continue
        except FileNotFoundError:
            os.close(fd)
            continue
        stale = _read(fd) or None
        if stale is not None:
            log.warning(
                "output directory %s: took over the lock of a run that ended without releasing it (%s; that "
                "process is gone)",
                directory,
                describe(stale),
            )
        me = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "command": " ".join(sys.argv)[:300],
            "pipeline_file": str(pipeline_file),
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(me) + "\n").encode(), 0)
        os.fsync(fd)
        return OutputLock(path, fd, stale)
