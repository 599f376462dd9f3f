"""How quickly the command line answers: ``surgiplan --help``, ``validate`` of a small pipeline, ``plugins``.

Each command runs as a fresh process (as a user types it), ``--repeat`` times after one warm-up run (which fills
the operating system's file cache and Python's bytecode cache); the wall time is the median, and the peak
resident memory of each process comes from ``os.wait4``. Then, once per command, ``python -X importtime``
says where the time goes: the modules with the largest cumulative import time, and the third-party libraries
the command loaded. Last, what a small run's process holds just before its first planner is constructed
(``StageRun.call("construction", ...)`` records the resident set and the libraries loaded, then the process
ends): the figure the issue quoted as 436 MB.

Targets (issue #38, item 4, medians on this machine): ``--help`` <= 0.3 s, ``validate`` <= 1 s, ``plugins``
<= 1 s.

    python benchmarks/bench_cli.py               # 7 runs each; writes benchmarks/results/cli.json
    python benchmarks/bench_cli.py --repeat 3    # quicker
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

from common import ROOT, save

#: a small pipeline (the main job: six boxes, four plan stages); validate reads and checks it, plans nothing
SMALL = "configs/block_world_proficiency.yaml"

#: the commands and their targets (median wall time, s)
COMMANDS = {
    "--help": (["--help"], 0.3),
    "validate": (["validate", SMALL], 1.0),
    "plugins": (["plugins"], 1.0),
}

#: the libraries a stage loads when it needs them (the breakdown says which of them a command loaded)
HEAVY = (
    "numpy",
    "scipy",
    "numba",
    "pinocchio",
    "coal",
    "matplotlib",
    "trimesh",
    "pydantic",
    "pymavlink",
    "canopen",
    "can",
    "dask",
    "distributed",
    "osqp",
    "rich",
    "meshio",
    "networkx",
)

#: run in the small run's process: the resident set when the first planner is about to be constructed
RSS_PROBE = """
import json, os, sys
from surgiplan.kinds import StageRun
from surgiplan.cli import main

real_call = StageRun.call

def vm(key):
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024
    return None

def call(self, what, fn, *args, **kwargs):
    if what == "construction":
        heavy = sorted({m.split(".")[0] for m in sys.modules} & set(HEAVY))
        print(json.dumps({"rss": vm("VmRSS"), "peak": vm("VmHWM"), "stage": self.spec.name,
                          "plugin": self.spec.plugin.name, "modules": len(sys.modules), "loaded": heavy}))
        sys.stdout.flush()
        os._exit(0)
    return real_call(self, what, fn, *args, **kwargs)

StageRun.call = call
main(["run", sys.argv[1], "--out", sys.argv[2], "--quiet"])
"""


#: the commands' environment: as a user's shell has it, Python writes and reuses its bytecode cache (this machine's
#: sessions set PYTHONDONTWRITEBYTECODE, under which every run compiles the editable checkout's sources again)
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def _surgiplan() -> list[str]:
    return [sys.executable, "-m", "surgiplan.cli"]


def timed_run(args: list[str]) -> tuple[float, int, float]:
    """Wall time (s), peak resident memory (bytes) and CPU time (user + system, s) of one process; it must
    succeed. On a loaded machine the CPU time is the steadier figure: waiting for a core is not counted."""
    start = time.perf_counter()
    proc = subprocess.Popen(args, cwd=ROOT, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    elapsed = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode() if proc.stderr else ""
    proc.stderr.close()
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed ({proc.returncode}): {err[-2000:]}")
    return elapsed, usage.ru_maxrss * 1024, usage.ru_utime + usage.ru_stime  # Linux reports kilobytes


def import_breakdown(args: list[str], top: int = 12) -> dict:
    """``python -X importtime``: total import time, the modules with the largest cumulative time, and the
    third-party libraries loaded (with their cumulative time where each was first imported)."""
    done = subprocess.run(
        [sys.executable, "-X", "importtime", *args], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=600
    )
    rows = []
    for line in done.stderr.splitlines():
        if not line.startswith("import time:") or "imported package" in line:
            continue
        head, cum_us, name = line.split("|", 2)
        self_us = head.split(":", 1)[1]
        depth = (len(name) - len(name.lstrip(" ")) - 1) // 2
        rows.append({"module": name.strip(), "depth": depth, "self_s": int(self_us) / 1e6, "cum_s": int(cum_us) / 1e6})
    total = sum(r["cum_s"] for r in rows if r["depth"] == 0)
    biggest = sorted(rows, key=lambda r: -r["cum_s"])[:top]
    libraries = {}
    for r in rows:
        root = r["module"].split(".")[0]
        if root in HEAVY and r["module"] == root:
            libraries[root] = round(r["cum_s"], 4)
    return {
        "total_s": round(total, 4),
        "modules": len(rows),
        "top": [{k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()} for r in biggest],
        "libraries": dict(sorted(libraries.items(), key=lambda kv: -kv[1])),
    }


def small_run_memory(config: str = SMALL) -> dict:
    """The resident set of ``surgiplan run <config>`` when its first planner is about to be constructed."""
    probe = f"HEAVY = {HEAVY!r}\n{RSS_PROBE}"
    with tempfile.TemporaryDirectory(prefix="bench-cli-") as out:
        done = subprocess.run(
            [sys.executable, "-c", probe, config, out], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=900
        )
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    if not lines:
        raise SystemExit(f"the run of {config} ended before its first planner: {done.stderr[-2000:]}")
    found = json.loads(lines[-1])
    return {"config": config, **found}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7, help="timed runs of each command (after one warm-up)")
    args = parser.parse_args(argv)
    rows = []
    for name, (cli_args, target) in COMMANDS.items():
        command = [*_surgiplan(), *cli_args]
        timed_run(command)  # warm-up: file cache, bytecode, numba's on-disk cache
        runs = [timed_run(command) for _ in range(args.repeat)]
        times = [t for t, _, _ in runs]
        median = statistics.median(times)
        breakdown = import_breakdown(["-m", "surgiplan.cli", *cli_args])
        rows.append(
            {
                "command": "surgiplan " + " ".join(cli_args),
                "name": name,
                "median_s": round(median, 4),
                "runs_s": [round(t, 4) for t in times],
                "target_s": target,
                "met": median <= target,
                "cpu_median_s": round(statistics.median(c for _, _, c in runs), 4),
                "peak_rss_MB": round(statistics.median(m for _, m, _ in runs) / 2**20, 1),
                "imports": breakdown,
            }
        )
        print(
            f"{rows[-1]['command']}: median {median:.3f} s (target {target} s; CPU {rows[-1]['cpu_median_s']:.3f} s) "
            f"over {len(times)} runs, "
            f"imports {breakdown['total_s']:.3f} s, peak RSS {rows[-1]['peak_rss_MB']} MB; "
            f"loaded {', '.join(breakdown['libraries']) or 'no heavy library'}",
            flush=True,
        )
    memory = small_run_memory()
    print(
        f"a small run ({memory['config']}) holds {memory['rss'] / 2**20:.0f} MB before its first planner "
        f"(stage {memory['stage']}); loaded {', '.join(memory['loaded'])}",
        flush=True,
    )
    path = save(
        "cli",
        rows,
        notes=f"fresh processes, median of {args.repeat} runs after one warm-up; import breakdown from "
        "python -X importtime (one run each); memory: VmRSS of a small run when its first planner is constructed",
        extra={"small_run": memory, "python_startup_s": round(_python_startup(args.repeat), 4)},
    )
    print(f"wrote {path.relative_to(ROOT)}")
    return 0


def _python_startup(repeat: int) -> float:
    """The floor: a bare ``python -c pass`` with this interpreter and its site-packages (median)."""
    timed_run([sys.executable, "-c", "pass"])
    return statistics.median(timed_run([sys.executable, "-c", "pass"])[0] for _ in range(repeat))


if __name__ == "__main__":
    sys.exit(main())
