"""How the trainee record writes: a private file, and transactions that wait for each other.

Two guide stages in two processes (two benches of one lab) may write one record at once. Every write is one
``BEGIN IMMEDIATE`` transaction (it takes SQLite's write lock first, so two writers never deadlock on an
upgrade from reading to writing), with SQLite's busy timeout; a lock still held when the timeout expires is
tried again, up to :data:`LOCK_WAIT_S` in all, then refused with a message naming the record. The record is
personal data: a new file is created mode 0600 (its ``-wal`` and ``-shm`` files take the same mode), and
nothing else on the machine reads it unless its owner says so.

The crash walk (:mod:`surgiplan.faults`) has its points here: the transaction's statements (``sql``), just
before its COMMIT (``commit``) and just after (``committed``).
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

from .. import faults
from ..errors import SurgiplanError

T = TypeVar("T")

#: SQLite's busy timeout on each attempt to take the write lock (s)
BUSY_TIMEOUT_S = 10.0
#: how long a writer waits in all for another one to finish (s)
LOCK_WAIT_S = 120.0
#: SQLite VM steps between two ``sql`` fault points
SQL_POINT_STEPS = 2000


class RecordBusyError(SurgiplanError):
    """Another process held the trainee record's write lock for longer than :data:`LOCK_WAIT_S`."""


def create_private(path: Path) -> None:
    """Create ``path`` empty, mode 0600, unless it exists (an empty file is an empty SQLite database)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(FileExistsError):
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))


def _busy(exc: sqlite3.OperationalError) -> bool:
    return "locked" in str(exc) or "busy" in str(exc)


def wait_for_lock(action: Callable[[], T], path: Path, wait_s: float = LOCK_WAIT_S) -> T:
    """``action()``, tried again while it meets the record locked by another process, up to ``wait_s`` in all.

    Some statements fail at once on a lock instead of waiting out SQLite's busy timeout: ``BEGIN IMMEDIATE``
    after its timeout, and switching a new file to WAL (``PRAGMA journal_mode=WAL``) while another process
    creates and migrates the same file."""
    deadline = time.monotonic() + wait_s
    delay = 0.01
    while True:
        try:
            return action()
        except sqlite3.OperationalError as exc:
            if not _busy(exc) or time.monotonic() + delay > deadline:
                raise RecordBusyError(
                    f"the trainee record {path} is locked by another process (waited {wait_s:.0f} s): {exc}"
                ) from None
            time.sleep(delay)
            delay = min(2 * delay, 1.0)


@contextlib.contextmanager
def immediate(db: sqlite3.Connection, path: Path, wait_s: float = LOCK_WAIT_S) -> Iterator[sqlite3.Connection]:
    """One write transaction on ``db``: all of it or none. Waits for another writer (see the module)."""
    wait_for_lock(lambda: db.execute("BEGIN IMMEDIATE"), path, wait_s)
    if faults.ARMED:
        db.set_progress_handler(lambda: faults.point("sql", path), SQL_POINT_STEPS)
    try:
        yield db
        if faults.ARMED:
            db.set_progress_handler(None, 0)
            faults.point("commit", path)
        db.commit()
    except BaseException:
        db.rollback()
        raise
    finally:
        if faults.ARMED:
            db.set_progress_handler(None, 0)
    if faults.ARMED:
        faults.point("committed", path)
