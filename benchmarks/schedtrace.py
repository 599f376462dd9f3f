"""The kernel's own account of a real-time attempt's wake-ups: ftrace's scheduler events, read back per thread.

A thread that sleeps (a drive waiting for its SYNC, a master waiting for the answers) is woken by another CPU:
the waker's CPU notes ``sched_waking``; the sleeper's CPU, once it takes the wake-up, ``sched_wakeup``; the thread
runs at ``sched_switch``. On a virtual machine a CPU with nothing to do halts, and the hypervisor must run it
again to deliver the wake-up: the gap from ``sched_waking`` to ``sched_wakeup`` is that delivery, the host's; the
gap from ``sched_wakeup`` to ``sched_switch`` is the guest's own scheduling (a higher priority running there).
The stall witnesses (:mod:`witness`) cannot see the first kind: each wakes by its own timer, and is on time.

    with SchedTrace() as trace:
        ...  # the real-time attempt
    trace.wakeups(tids)  # per thread: (waking, delivery s, run-queue s), in time order

A thread switched out while still runnable (preempted: ``prev_state=R``) waits in the run queue too, from then
until it runs again; :meth:`SchedTrace.wakeups` lists those waits beside the wake-ups (no delivery).

With ``tids`` the kernel records only those threads' events (a filter on each event), and the trace is read
back in chunks of :data:`CHUNK` bytes and parsed line by line: no single call holds the interpreter's lock for
long. A benchmark that reads a whole 30 MB trace at once (one decode, one ``splitlines``) stops every other thread
of its process for some 100 ms, the master's holding loop among them; the drives' SYNC watchdog then trips.

Needs root and tracefs (``/sys/kernel/tracing`` or ``/sys/kernel/debug/tracing``); elsewhere ``available`` is
False and every answer empty. The trace clock is CLOCK_MONOTONIC (``mono``): ``time.perf_counter`` on Linux, the
loop's clock. The tracer's settings are restored on exit.
"""

from __future__ import annotations

import codecs
import re
import threading
from pathlib import Path

import numpy as np

ROOTS = (Path("/sys/kernel/tracing"), Path("/sys/kernel/debug/tracing"))
EVENTS = "sched:sched_waking sched:sched_wakeup sched:sched_switch\n"
#: bytes read from the trace at a time (each read and decode a short hold of the interpreter's lock)
CHUNK = 1 << 18
_LINE = re.compile(r"^\s*.+?-\d+\s+\[(\d+)\]\s+\S+\s+(\d+\.\d+): (sched_\w+): (.*)$")
_PID = re.compile(r"(?:^| )pid=(\d+)")
_NEXT = re.compile(r"next_pid=(\d+)")
_PREV = re.compile(r"prev_pid=(\d+) .*?prev_state=(\S+)")
_WRITTEN = re.compile(r"entries-in-buffer/entries-written: (\d+)/(\d+)")


class SchedTrace:
    """Trace the scheduler for the ``with`` block (see the module); ``buffer_kb`` per CPU; only the threads
    ``tids`` if given (the kernel filters), else every thread."""

    def __init__(self, buffer_kb: int = 60_000, tids=None) -> None:
        self.buffer_kb = buffer_kb
        self.tids = sorted({int(t) for t in tids}) if tids is not None else None
        self.root = next((r for r in ROOTS if (r / "tracing_on").exists()), None)
        self.available = False
        #: the trace's lines (its header's comment lines first)
        self.lines: list[str] = []
        self._saved: dict[str, str] = {}
        self._filtered: list[str] = []

    def _write(self, name: str, value: str) -> None:
        (self.root / name).write_text(value)

    def filters(self) -> dict[str, str]:
        """The kernel's filter per event for ``tids`` (a wake-up names its thread ``pid``; a switch, the thread
        leaving and the one taking the CPU)."""
        if not self.tids:
            return {}
        mine = " || ".join(f"pid == {t}" for t in self.tids)
        switch = " || ".join(f"prev_pid == {t} || next_pid == {t}" for t in self.tids)
        return {"sched_waking": mine, "sched_wakeup": mine, "sched_switch": switch}

    def __enter__(self) -> SchedTrace:
        if self.root is None:
            return self
        try:
            for name in ("trace_clock", "buffer_size_kb", "set_event", "tracing_on"):
                text = (self.root / name).read_text()
                if name == "trace_clock":  # "[local] global mono ...": the one in brackets is in force
                    text = re.search(r"\[(\w+)\]", text).group(1)
                self._saved[name] = text
            self._write("tracing_on", "0")
            self._write("trace_clock", "mono")
            self._write("buffer_size_kb", str(self.buffer_kb))
            for event, condition in self.filters().items():
                self._filtered.append(event)
                self._write(f"events/sched/{event}/filter", condition)
            self._write("set_event", EVENTS)
            self._write("trace", "")
            self._write("tracing_on", "1")
            self.available = True
        except (OSError, AttributeError):
            self._restore()
        return self

    def __exit__(self, *exc) -> None:
        if not self.available:
            return
        self._write("tracing_on", "0")
        self.lines = self._read()
        self._restore()

    def _read(self) -> list[str]:
        """The trace's lines, read and decoded a chunk at a time (see the module)."""
        lines: list[str] = []
        rest = ""
        decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")  # a character may span two chunks
        with open(self.root / "trace", "rb") as f:
            while chunk := f.read(CHUNK):
                part = (rest + decoder.decode(chunk)).split("\n")
                rest = part.pop()
                lines += part
        rest += decoder.decode(b"", final=True)
        if rest:
            lines.append(rest)
        return lines

    def _restore(self) -> None:
        for event in self._filtered:
            try:
                self._write(f"events/sched/{event}/filter", "0")  # "0" clears an event's filter
            except OSError:
                pass
        self._filtered = []
        for name in ("set_event", "buffer_size_kb", "trace_clock", "tracing_on"):
            if name in self._saved:
                try:
                    self._write(name, self._saved[name] or "\n")  # no events: an empty line clears them
                except OSError:
                    pass
        if self.root is not None:
            try:
                self._write("trace", "")
            except OSError:
                pass

    def events_lost(self) -> int | None:
        """Events the trace's buffer could not hold (its header's count; None if it has none)."""
        for line in self.lines:
            if not line.startswith("#"):
                break
            written = _WRITTEN.search(line)
            if written:
                return int(written.group(2)) - int(written.group(1))
        return None

    def wakeups(self, tids) -> dict[int, np.ndarray]:
        """Per thread id: every wake-up as (waking time, delivery, run-queue delay) in s (delivery nan when the
        wake-up was taken on the waker's CPU), in time order; and every preemption (switched out still runnable,
        ``prev_state=R``) as (switched out, 0, until it ran again): time it wanted the CPU and waited, as a woken
        thread waits in the run queue."""
        wanted = {int(t) for t in tids}
        pending: dict[int, list] = {}
        preempted: dict[int, float] = {}
        out: dict[int, list] = {t: [] for t in wanted}
        for line in self.lines:
            m = _LINE.match(line)
            if m is None:
                continue
            event, rest, ts = m.group(3), m.group(4), float(m.group(2))
            if event == "sched_switch":
                previous = _PREV.search(rest)
                if previous and int(previous.group(1)) in wanted and previous.group(2).startswith("R"):
                    preempted[int(previous.group(1))] = ts
                n = _NEXT.search(rest)
                tid = int(n.group(1)) if n else -1
                if tid in pending:
                    waking, wakeup = pending.pop(tid)
                    delivery = wakeup - waking if wakeup is not None else np.nan
                    out[tid].append((waking, delivery, ts - (wakeup if wakeup is not None else waking)))
                elif tid in preempted:
                    out[tid].append((preempted[tid], 0.0, ts - preempted[tid]))
                preempted.pop(tid, None)
                continue
            p = _PID.search(rest)
            tid = int(p.group(1)) if p else -1
            if tid not in wanted:
                continue
            if event == "sched_waking":
                pending[tid] = [ts, None]
            elif event == "sched_wakeup" and tid in pending:
                pending[tid][1] = ts
        return {t: np.array(v, dtype=float).reshape(-1, 3) for t, v in out.items()}


def benchmark_threads(drives_pid: int | None = None) -> dict[int, str]:
    """The threads to trace, by id: this process's now (their Python names; the main thread, which runs the loop:
    "loop") and, with ``drives_pid``, every thread of the drives' process ("drives' process", from /proc)."""
    names = {t.native_id: "loop" if t is threading.main_thread() else t.name for t in threading.enumerate()}
    if drives_pid is not None:
        for task in Path(f"/proc/{drives_pid}/task").glob("*"):
            if task.name.isdigit():
                names[int(task.name)] = "drives' process"
    return names


def slowest_during(rows: dict[int, np.ndarray], start: float, end: float) -> tuple[float, int | None, float]:
    """Of :meth:`SchedTrace.wakeups`' rows, the slowest wake-up that overlapped ``start``..``end`` (perf_counter s:
    woken before its end, running only after its start): (its wait s, thread id, its delivery part s)."""
    worst, who, delivery = 0.0, None, 0.0
    for tid, r in rows.items():
        for waking, d, q in r:
            d = 0.0 if np.isnan(d) else d
            if waking < end and waking + d + q > start and d + q > worst:
                worst, who, delivery = d + q, tid, d
    return worst, who, delivery


def summary(trace: SchedTrace, threads: dict[int, str], span: tuple[float, float] | None = None) -> dict:
    """The slowest wake-up of the ``threads`` (ms; delivery and run-queue parts) overall and, with ``span``
    (perf_counter s), the slowest that overlapped it (:func:`slowest_during`): what a deadline missed in that span
    can be laid to."""
    if not trace.available:
        return {"sched_trace": "not available (needs root and tracefs)"}
    rows = trace.wakeups(threads)
    every = np.vstack([r for r in rows.values() if len(r)] or [np.zeros((0, 3))])
    total = np.nan_to_num(every[:, 1]) + every[:, 2]
    out = {
        "wakeups": len(every),
        "wakeups_over_1ms": int(np.sum(total > 1e-3)),
        "wakeup_max_ms": round(1e3 * float(total.max()), 3) if len(total) else 0.0,
        "delivery_max_ms": round(1e3 * float(np.nanmax(every[:, 1], initial=0.0)), 3),
    }
    if span is not None:
        worst, who, delivery = slowest_during(rows, *span)
        out["span_wakeup_max_ms"] = round(1e3 * worst, 3)
        out["span_wakeup_thread"] = threads.get(who, str(who)) if who is not None else None
        out["span_delivery_ms"] = round(1e3 * delivery, 3)
    return out
