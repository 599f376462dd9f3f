"""Shared helpers for benchmarks: repeated timing with medians, and result files that carry their provenance.

Every results file records what produced it (:func:`provenance`): the commit and whether the tree had
uncommitted changes, the machine and Python, the load average and the time of a fixed reference workload
(:func:`host_reference`) when the benchmark started (this module's import) and when it saved, and the peers it
was measured against with their versions and settings.
"""

from __future__ import annotations

import gzip
import os
import platform
import statistics
import subprocess
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from surgiplan.allocator import policy as allocator_policy

RESULTS = Path(__file__).resolve().parent / "results"
ROOT = RESULTS.parent.parent
#: the load average (1, 5, 15 min) when the benchmark started
START_LOAD = os.getloadavg()
START_TIME = time.strftime("%Y-%m-%dT%H:%M:%S%z")
#: the reference workload (:func:`host_reference`): what it is, and how many times it runs at each probe
REFERENCE = "numpy argsort of 262,144 seeded random doubles (quicksort), 7 runs: the fastest and the median (ms)"
_REFERENCE_RUNS = 7


def host_reference() -> dict[str, float]:
    """How fast this machine is now, on one fixed workload (:data:`REFERENCE`): a virtual machine's neighbours
    can halve its speed without any load of its own (the load average does not see it), and every absolute time
    of a results file moves with it; the same workload timed when a benchmark starts and when it saves lets runs
    on the same machine be compared."""
    import numpy as np

    values = np.random.default_rng(0).random(1 << 18)
    times = []
    for _ in range(_REFERENCE_RUNS):
        started = time.perf_counter()
        np.argsort(values, kind="quicksort")
        times.append(time.perf_counter() - started)
    return {"fastest_ms": round(1e3 * min(times), 3), "median_ms": round(1e3 * statistics.median(times), 3)}


#: the reference workload when the benchmark started
START_REFERENCE = host_reference()


#: what the dirty flag ignores: files that a benchmark's own results change
CLEAN_PATHS = (":(exclude)benchmarks/results", ":(exclude)*.md")


def git_state() -> dict[str, Any]:
    """The commit the benchmark ran on and whether the tracked tree differed from it."""

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30).stdout.strip()

    try:
        commit = git("rev-parse", "HEAD")
        # results files and prose do not change what is measured: a benchmark run after another one's results
        # (or the README's blocks) changed is still on a clean tree
        dirty = bool(git("status", "--porcelain", "--untracked-files=no", "--", ".", *CLEAN_PATHS))
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}
    return {"commit": commit or None, "dirty": dirty if commit else None}


#: the commit and dirty flag when the benchmark started (what it measures; a commit made while it runs is not)
START_GIT = git_state()


def preemption(config: str, cmdline: str) -> str:
    """The kernel's preemption model from its build configuration (``/proc/config.gz`` or ``/boot/config-*``) and
    boot command line: ``preempt=`` on the command line wins where the build lets it choose (PREEMPT_DYNAMIC).
    Under "none" (and "voluntary") kernel code runs until it yields: a kernel worker can hold a CPU for
    milliseconds, and no SCHED_FIFO thread preempts it (a real-time loop's missed cycles then say nothing about
    the loop). "unknown" where neither says."""
    chosen = next((word.split("=", 1)[1] for word in cmdline.split() if word.startswith("preempt=")), None)
    options = dict(line.split("=", 1) for line in config.splitlines() if line.startswith("CONFIG_") and "=" in line)
    dynamic = options.get("CONFIG_PREEMPT_DYNAMIC") == "y"
    if options.get("CONFIG_PREEMPT_RT") == "y":
        return "full, real-time (PREEMPT_RT)"
    if chosen and dynamic:
        return f"{chosen} (boot option; dynamic)"
    for model in ("LAZY", "NONE", "VOLUNTARY"):  # PREEMPT alone is "full"
        if options.get(f"CONFIG_PREEMPT_{model}") == "y":
            return f"{model.lower()}{' (build default; dynamic)' if dynamic else ''}"
    if options.get("CONFIG_PREEMPT") == "y":
        return f"full{' (build default; dynamic)' if dynamic else ''}"
    return "unknown"


def kernel() -> dict[str, Any]:
    """The kernel as a real-time result depends on it: release, preemption model (:func:`preemption`), how many
    DAMON workers (``kdamond``: memory monitoring, kernel threads that take a CPU for their sampling) run, the
    cpuidle driver (how an idle CPU waits: ``haltpoll`` on a KVM guest), and whether a real-time loop here may keep
    the CPUs out of slow idle states (:func:`surgiplan.scheduling.cpu_latency_request`: root only)."""
    config = ""
    for path in (Path("/proc/config.gz"), Path(f"/boot/config-{platform.release()}")):
        try:
            config = gzip.decompress(path.read_bytes()).decode() if path.suffix == ".gz" else path.read_text()
            break
        except OSError:
            continue
    try:
        cmdline = Path("/proc/cmdline").read_text()
    except OSError:
        cmdline = ""
    try:
        kdamonds = int(Path("/sys/kernel/mm/damon/admin/kdamonds/nr_kdamonds").read_text())
    except (OSError, ValueError):
        kdamonds = None
    try:
        cpuidle = Path("/sys/devices/system/cpu/cpuidle/current_driver").read_text().strip()
    except OSError:
        cpuidle = None
    from surgiplan.scheduling import CPU_LATENCY_FILE

    return {
        "release": platform.release(),
        "preemption": preemption(config, cmdline),
        "kdamonds": kdamonds,
        "cpuidle": cpuidle,
        "cpu_latency_request": os.access(CPU_LATENCY_FILE, os.W_OK),
    }


def provenance(peers: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """What produced a result: commit, dirty flag, machine, load before and after, the peers' versions and
    settings (``{"OMPL": {"version": "1.7.0", "configuration": "..."}}``)."""
    return {
        **START_GIT,
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "kernel": kernel(),
        "python": platform.python_version(),
        "started": START_TIME,
        "saved": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "load_before": [round(x, 2) for x in START_LOAD],
        "load_after": [round(x, 2) for x in os.getloadavg()],
        "peers": dict(peers or {}),
        "allocator": allocator_policy(),  # the whole process's, peers included (surgiplan.allocator)
        "reference": REFERENCE,
        "reference_before": START_REFERENCE,
        "reference_after": host_reference(),
    }


def package_version(name: str) -> str | None:
    """An installed distribution's version (a peer's, for :func:`provenance`), or None."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return None


def median_time(fn: Callable[[], object], repeat: int = 5, warmup: int = 1) -> tuple[float, list[float]]:
    """Median wall time (s) of ``fn()`` over ``repeat`` runs after ``warmup`` runs."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), times


def save(
    name: str,
    rows: list[dict],
    notes: str = "",
    peers: Mapping[str, Any] | None = None,
    extra: Mapping[str, Any] | None = None,
) -> Path:
    """Write ``results/<name>.json`` atomically, with its :func:`provenance` (and ``extra`` top-level keys)."""
    from surgiplan.storage import write_json_atomic

    path = RESULTS / f"{name}.json"
    info = provenance(peers)
    write_json_atomic(
        path,
        {
            "benchmark": name,
            "machine": info["machine"],
            "python": info["python"],
            "provenance": info,
            "notes": notes,
            **dict(extra or {}),
            "rows": rows,
        },
    )
    return path


def table(rows: list[dict], columns: list[str]) -> str:
    widths = [max(len(c), *(len(str(r.get(c, ""))) for r in rows)) for c in columns]
    line = "| " + " | ".join(c.ljust(w) for c, w in zip(columns, widths, strict=True)) + " |"
    rule = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    body = [
        "| " + " | ".join(str(r.get(c, "")).ljust(w) for c, w in zip(columns, widths, strict=True)) + " |" for r in rows
    ]
    return "\n".join([line, rule, *body])


def paced_run_arguments(description: str, argv: list[str] | None = None) -> tuple[int, float, bool]:
    """The command line of the benchmarks that pace an attempt in real time: ``--runs N`` (default 3), ``--seconds
    S`` per attempt (default 20), ``--quick`` (1 run of 8 s; the caller writes nothing). Returns (runs, seconds,
    quick)."""
    import argparse

    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--quick", action="store_true", help="1 run of 8 s, writes nothing")
    args = parser.parse_args(argv)
    return (1, 8.0, True) if args.quick else (args.runs, args.seconds, False)


def steal_ticks() -> int:
    """The machine's stolen time so far (clock ticks, /proc/stat): time the hypervisor ran other guests while
    this one had work; a real-time loop cannot be on time through it."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
        return int(fields[8])
    except (OSError, IndexError, ValueError):
        return 0
