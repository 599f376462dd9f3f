"""Formatting for the README's generated blocks: numbers as the README writes them, tables, re-flowed paragraphs.

Also the loading of a benchmark's results file and of a benchmark module (for the blocks a benchmark renders
itself), and :class:`ReadmeError`, which names the block or the file that cannot be rendered.
"""

from __future__ import annotations

import importlib
import json
import re
import sys
from collections.abc import Callable
from pathlib import Path

BENCH = Path(__file__).resolve().parent.parent


class ReadmeError(Exception):
    """A README or results file that cannot be rendered: the message names the block and the file."""


def sig(x: float, n: int = 3) -> str:
    """``x`` to ``n`` significant digits, never in exponent form, thousands separated."""
    x = float(x)
    if x == 0:
        return "0"
    s = f"{x:#.{n}g}".rstrip(".")  # trailing zeros kept: 0.40 ms, not 0.4 ms
    if "e" in s:
        s = f"{x:.{max(n - 1 - int(f'{x:e}'.split('e')[1]), 0)}f}"
    if "." not in s and abs(x) >= 1000:
        return f"{round(x):,}"
    if abs(x) >= 1000:
        whole, frac = s.split(".")
        return f"{int(whole):,}.{frac}"
    return s


def secs(x: float) -> str:
    """A time in seconds as the tables print it: three decimals below a second, three digits above."""
    return f"{float(x):.3f}" if x < 1 else sig(x, 3)


def find(pattern: str, text: str, what: str) -> re.Match:
    match = re.search(pattern, text)
    if match is None:
        raise ReadmeError(f"{what}: expected {pattern!r} in {text!r}")
    return match


def load(results: Path, name: str) -> dict:
    path = results / f"{name}.json"
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise ReadmeError(f"{path}: missing (run benchmarks/bench_{name.split('_')[0]}.py)") from None
    except json.JSONDecodeError as err:
        raise ReadmeError(f"{path}: not JSON ({err})") from None


def table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def wrap(text: str, width: int = 78) -> str:
    """Paragraphs (blank-line separated) re-flowed to ``width`` columns; tables and lists kept as they are."""
    out = []
    for para in text.strip().split("\n\n"):
        if para.startswith(("|", "- ")):
            out.append(para)
            continue
        tokens: list[str] = []
        for token in para.split():
            if tokens and (token[0] in "%×" or tokens[-1].count("`") % 2):  # units and code spans stay whole
                tokens[-1] += " " + token
            else:
                tokens.append(token)
        lines, line = [], ""
        for word in tokens:
            if line and len(line) + 1 + len(word) > width:
                lines.append(line)
                line = word
            else:
                line = f"{line} {word}" if line else word
        lines.append(line)
        out.append("\n".join(lines))
    return "\n\n".join(out)


def section(head: str, body: str, tail: str = "") -> str:
    """A block: the conditions paragraph, the table, and the paragraph that reads it (each re-flowed)."""
    return "\n\n".join(part for part in (wrap(head), body, wrap(tail) if tail else "") if part)


def dims(text: str) -> str:
    """Mesh sizes as the README writes them: 40x4x4 -> 40×4×4."""
    return re.sub(r"(?<=\d)x(?=\d)", "×", text)


def met(ok: bool) -> str:
    return "met" if ok else "not met"


def words(n: int) -> str:
    return ["no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine"][n] if 0 <= n < 10 else str(n)


def span(values: list[float], fmt: Callable[[float], str] = lambda v: f"{v:g}") -> str:
    lo, hi = fmt(min(values)), fmt(max(values))
    return lo if lo == hi else f"{lo}-{hi}"


def bench_module(name: str):
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))
    return importlib.import_module(name)


def percent_span(fractions: list[float]) -> str:
    """0.61, 0.76 -> '61-76 %'; one value or equal values -> '61 %'."""
    low, high = round(100 * min(fractions)), round(100 * max(fractions))
    return f"{low} %" if low == high else f"{low}-{high} %"


def provenance_note(results: Path, sources: tuple[str, ...]) -> str:
    """The line that opens a block: the commit each of its results files came from (``benchmarks/common.py``
    records it, and whether the tree had uncommitted changes), and the load average and the reference workload's
    time (the host's speed, where recorded) around the measurement."""
    parts = []
    for name in sources:
        info = load(results, name).get("provenance") or {}
        commit = info.get("commit")
        if commit:
            dirty = " plus uncommitted changes" if info.get("dirty") else ""
            load_avg = ""
            if info.get("load_before") and info.get("load_after"):
                load_avg = f", load {info['load_before'][0]:g} → {info['load_after'][0]:g}"
            speed = ""
            if info.get("reference_before") and info.get("reference_after"):  # the host's speed (common.py)
                before, after = info["reference_before"]["fastest_ms"], info["reference_after"]["fastest_ms"]
                speed = f", reference workload {before:.3g} → {after:.3g} ms"
            parts.append(f"`{name}.json`: commit `{commit[:10]}`{dirty}{load_avg}{speed}")
        else:
            parts.append(f"`{name}.json`: commit not recorded")
    return "*Measured at " + "; ".join(parts) + ".*"


def witness_per_cpu(policy: str | None) -> bool:
    """Whether a result ran with a stall witness on each CPU (``policy`` as the results record it), not a single one."""
    return bool(policy) and "one per CPU" in policy


def witness_words(policy: str | None) -> str:
    """What ran beside a real-time benchmark as its stall witness (``benchmarks/witness.py``; ``policy`` as the
    results record it), and what its lateness means."""
    if witness_per_cpu(policy):
        return (
            "on each CPU a process pinned to it under SCHED_FIFO 99 woke every millisecond (`benchmarks/witness.py`); "
            "nothing inside the machine can delay it, so its lateness means that CPU stopped (the host ran something "
            "else on it)"
        )
    return (
        "a process under SCHED_FIFO 99 woke every millisecond (`benchmarks/witness.py`); nothing inside the machine "
        "can delay it, so its lateness means the CPU it ran on stopped (the host ran something else on it; a stall "
        "of the other CPU alone escapes it)"
    )


#: a wake-up whose delivery (sched_waking to sched_wakeup, ``benchmarks/schedtrace.py``) took this long (ms) was the
#: host's doing: a halted virtual CPU run again late
HOST_DELIVERY_MS = 0.5
#: ... and one that waited this long (ms) in all, its delivery short, waited in a run queue (this machine's threads,
#: or the host preempting a running virtual CPU: the witnesses tell those apart)
QUEUED_MS = 1.0


def wakeup_cause(wait_ms: float | None, delivery_ms: float | None) -> str:
    """What the slowest wake-up during a missed deadline says: "host" (its delivery), "queue" (a run queue), "none"."""
    if (delivery_ms or 0.0) >= HOST_DELIVERY_MS:
        return "host"
    return "queue" if (wait_ms or 0.0) >= QUEUED_MS else "none"


def thread_label(name: str | None) -> str:
    """A benchmark thread's name as the tables say it (the master's receive thread is python-can's Notifier)."""
    if name is None:
        return "-"
    for prefix, label in (("Notifier for bus", "master's receive thread"), ("Cyclic send task", "master's heartbeat"),
                          ("surgiplan-simulated-drives", "drives' thread"), ("loop", "master's loop")):  # fmt: skip
        if name.startswith(prefix):
            return label
    return name


def floor_words(row: dict) -> str:
    """One sentence for a README block: ``cyclictest.cyclictest_floor``'s row as measured, or why
    there is none."""
    if "error" in row:
        return f"The machine's floor ({row['loop']}) was not measured: {row['error']}."
    late = row.get("late_over_ms", 1.0)
    loop = row["loop"].replace("--laptop", "`--laptop`")  # an option, not prose: Markdown would make "--" a dash
    return (
        f"The machine's floor in the same session, measured by a tool we did not write ({loop}; "
        f"`{row['command']}`): runs with no wake-up more than {late:g} ms late {row['runs_without_lapse']}; such "
        f"wake-ups per run {', '.join(str(n) for n in row['lapses_per_run'])}; worst latency per run "
        f"{', '.join(f'{x:g}' for x in row['max_latency_ms_per_run'])} ms; {row['steal_ticks']} ticks stolen by "
        "the hypervisor meanwhile. A loop of ours whose CPUs idle the same way cannot be on time more often."
    )
