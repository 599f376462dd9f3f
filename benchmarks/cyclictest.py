"""The machine's floor as rt-tests' ``cyclictest`` measures it: the Linux real-time community's latency test, not
ours. Every real-time benchmark here runs it in the same session as its own loop, at that loop's rate, priority and
deadline, so that a result says how often a bare C loop on the same machine was on time: a loop of ours whose CPUs
idle the same way cannot be on time more often than that.

    floor = cyclictest_floor(10, 8.0, polling=False, priority=30, interval_us=2000)
    floor["runs_without_lapse"]  # "7/10": runs with no wake-up more than ``late_us`` late

README blocks say it with ``readme_blocks.formatting.floor_words``.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

from common import steal_ticks

#: the histogram's range (µs): wake-ups later than this are counted from the cycles it leaves out
_HISTOGRAM_US = 20000


def cyclictest_floor(
    runs: int,
    seconds: float,
    polling: bool,
    *,
    priority: int,
    interval_us: int = 1000,
    late_us: int | None = None,
) -> dict:
    """``runs`` runs of ``seconds`` of one cyclictest thread under SCHED_FIFO ``priority``, waking every
    ``interval_us``, memory locked. ``polling``: with cyclictest's default CPU wake-up latency request of 0 (idle
    CPUs poll, as with ``SURGIPLAN_CPU_LATENCY_US=0``), else with ``--laptop`` (no request: surgiplan's default).
    A wake-up more than ``late_us`` late (default: a period, as the control loop counts a missed cycle; cyclictest
    skips the missed intervals alike) is a lapse. The row names the command, so that anyone can run it again."""
    late_us = interval_us if late_us is None else late_us
    how = "CPU latency request 0 (its default)" if polling else "no CPU latency request (--laptop)"
    rate = f"{1e6 / interval_us:g} Hz"
    name = f"cyclictest (rt-tests), {rate}, SCHED_FIFO {priority}, {how}, {runs} x {seconds:g} s"
    exe = shutil.which("cyclictest")
    if exe is None:
        return {"loop": name, "error": "cyclictest not installed (Debian: apt-get install rt-tests)"}
    banner = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=30)
    found = re.search(r"cyclictest V ?(\S+)", banner.stdout + banner.stderr)
    cycles = max(1, round(seconds * 1e6 / interval_us))
    command = ["cyclictest", "-m", "-q", "-t1", "-p", str(priority), "-i", str(interval_us), "-l", str(cycles)]
    command += [] if polling else ["--laptop"]
    lapses, worst = [], []
    stolen = steal_ticks()
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "cyclictest.json"
        for _ in range(runs):
            out.unlink(missing_ok=True)  # a run that writes no report must not be read as the run before it
            done = subprocess.run(
                [exe, *command[1:], "-h", str(_HISTOGRAM_US), f"--json={out}"],
                capture_output=True,
                text=True,
                timeout=seconds + 60,
            )
            if done.returncode != 0 or not out.exists():
                return {"loop": name, "error": f"cyclictest failed: {(done.stderr or done.stdout).strip()[:300]}"}
            thread = json.loads(out.read_text())["thread"]["0"]
            histogram = {int(k): int(v) for k, v in thread["histogram"].items()}
            beyond = thread["cycles"] - sum(histogram.values())  # later than the histogram's range
            lapses.append(sum(v for k, v in histogram.items() if k > late_us) + beyond)
            worst.append(round(thread["max"] / 1000, 2))
    return {
        "loop": name,
        "version": found.group(1) if found else "unknown",
        "command": " ".join(command),
        "late_over_ms": late_us / 1000,
        "runs_without_lapse": f"{sum(n == 0 for n in lapses)}/{runs}",
        "lapses_per_run": lapses,
        "max_latency_ms_per_run": worst,
        "steal_ticks": steal_ticks() - stolen,
    }
