"""Fault injection for the crash walk: make the n-th write, fsync, rename or record commit fail or kill the
process (``docs/howto/reliability.md``).

Read once, at import, from the environment; nothing else sets it, and with neither variable set every write
point costs one test of a module constant (:data:`ARMED`).

``SURGIPLAN_FAULT_AT=[ACTION:]POINT:N``
    ``ACTION`` is ``fail`` (default: the operation raises ``OSError(EIO)``, as a full or failing disk does) or
    ``kill`` (the process sends itself SIGKILL: a power cut as far as its files are concerned; a ``write``
    point writes half of its data to the file first, so the kill lands inside a write). ``POINT`` is one of
    :data:`POINTS`, or ``any`` (the N-th point of any kind). ``N`` counts from 1.
``SURGIPLAN_FAULT_TRACE=FILE``
    Append one line per point reached (``seq kind n target``) to ``FILE``: a run with only this set counts the
    points a run has, which the walk then visits one by one.

Only the process that imported this module with the variables set is faulted: they are removed from the
environment (the helper programs and workers it starts run clean), and a forked child does not count.
"""

from __future__ import annotations

import errno
import os
import signal
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .errors import SurgiplanError

FAULT_ENV = "SURGIPLAN_FAULT_AT"
TRACE_ENV = "SURGIPLAN_FAULT_TRACE"

#: the kinds of point: a file's write (each call), its fsync, its rename into place, and in the trainee record a
#: transaction's statements (``sql``, every few thousand SQLite VM steps), the moment before its COMMIT
#: (``commit``) and the moment after (``committed``)
POINTS = ("write", "fsync", "rename", "sql", "commit", "committed")
ACTIONS = ("fail", "kill")


class FaultSpecError(SurgiplanError):
    """``SURGIPLAN_FAULT_AT`` is not ``[fail|kill:]POINT:N``."""


@dataclass(frozen=True)
class Fault:
    """Where to inject: the ``n``-th point of ``kind`` (``any``: of every kind), and what to do there."""

    action: str
    kind: str
    n: int


def parse(text: str) -> Fault | None:
    """``[fail|kill:]POINT:N`` as a :class:`Fault` (None for an empty text)."""
    text = text.strip()
    if not text:
        return None
    parts = text.split(":")
    if len(parts) == 2:
        parts = ["fail", *parts]
    if len(parts) != 3 or parts[0] not in ACTIONS or parts[1] not in (*POINTS, "any") or not parts[2].isdigit():
        raise FaultSpecError(
            f"{FAULT_ENV}={text!r}: expected [fail|kill:]POINT:N with POINT one of {', '.join(POINTS)} or any, "
            "N a whole number from 1"
        )
    if int(parts[2]) < 1:
        raise FaultSpecError(f"{FAULT_ENV}={text!r}: N counts from 1")
    return Fault(parts[0], parts[1], int(parts[2]))


FAULT: Fault | None = parse(os.environ.pop(FAULT_ENV, ""))
TRACE: str | None = os.environ.pop(TRACE_ENV, "") or None
#: whether any point does anything (the write paths test this, and nothing else, when it is off)
ARMED = FAULT is not None or TRACE is not None
_PID = os.getpid()
_counts: dict[str, int] = {}


def point(kind: str, target: str | Path = "", partial: Callable[[], None] | None = None) -> None:
    """One fault point of ``kind`` at ``target``: counted, traced, and faulted when it is the chosen one.

    ``partial``: what a kill does first (a write writes half of its data)."""
    if not ARMED or os.getpid() != _PID:
        return
    n = _counts[kind] = _counts.get(kind, 0) + 1
    seq = _counts["any"] = _counts.get("any", 0) + 1
    if TRACE is not None:
        fd = os.open(TRACE, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
        try:
            os.write(fd, f"{seq} {kind} {n} {target}\n".encode())
        finally:
            os.close(fd)
    if FAULT is None or (FAULT.kind, FAULT.n) not in ((kind, n), ("any", seq)):
        return
    if FAULT.action == "kill":
        if partial is not None:
            partial()
        os.kill(os.getpid(), signal.SIGKILL)
    raise OSError(errno.EIO, f"injected fault at {kind} point {n} ({FAULT_ENV})", str(target))


def read_trace(path: str | Path) -> list[tuple[int, str, int, str]]:
    """A trace file's points: ``(seq, kind, n, target)`` in order."""
    out = []
    for line in Path(path).read_text().splitlines():
        seq, kind, n, target = [*line.split(" ", 3), ""][:4]
        out.append((int(seq), kind, int(n), target))
    return out


def arm(fault: str = "", trace: str | Path | None = None) -> None:
    """Arm this process as the variables would at import: for a harness that forks one child per run of the
    walk (a new interpreter per run would spend most of the walk importing)."""
    global FAULT, TRACE, ARMED, _PID
    FAULT, TRACE = parse(fault), (str(trace) if trace else None)
    ARMED, _PID = FAULT is not None or TRACE is not None, os.getpid()
    _counts.clear()
