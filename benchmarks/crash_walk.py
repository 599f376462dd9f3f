"""The crash walk at full size: every write point of a run of each kind crashed at (issue 32).

For each run kind of ``tests/crash_walk_support.py`` (a plan stage with a stored artifact, an optMIS
repository build, a FEM generation for retraction, a guide stage into a trainee record; report.html and
result.json in each), the second run is killed (SIGKILL, half of a write on disk first) at each of its N
points in turn, n = 1..N (``--stride S``: every S-th, plus each kind of point's first and last), and, at every
third of those, made to fail instead (an I/O error, EIO). After each crash the files, the record and a rerun
are checked as that module says. Writes ``benchmarks/results/crash_walk.json`` (per kind: the points by kind,
crashes exercised, what each file was found to be, temporaries left, problems, the time); the table in
``docs/howto/reliability.md`` is rendered from it.

    python benchmarks/crash_walk.py                # every point; the retraction walk every 3rd
    python benchmarks/crash_walk.py --stride 4     # quicker
    python benchmarks/crash_walk.py guide          # one kind: its row replaces the kind's row in the file

Each kind's row is saved as soon as its walk ends (the file's other kinds kept), so a long walk keeps what
it finished, and kinds can be walked by separate processes.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import shutil
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))

from common import RESULTS, save  # noqa: E402
from crash_walk_support import KINDS, walk  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("kinds", nargs="*", default=list(KINDS))
    parser.add_argument("--stride", type=int, default=1)
    parser.add_argument(
        "--retraction-stride",
        type=int,
        default=3,
        help="the retraction walk's stride (default 3: each of its runs solves FEM equilibria for ~20 s on 2 "
        "loaded cores)",
    )
    args = parser.parse_args(argv)
    import surgiplan.cli  # noqa: F401 - imported once, before the walk forks its runs
    from surgiplan.registry import default_registry

    default_registry()
    rows = []
    for name in args.kinds:
        base = Path(tempfile.mkdtemp(prefix=f"crash-walk-{name}-"))
        try:
            stride = args.retraction_stride if name == "retraction" else args.stride
            report = walk(KINDS[name], base, stride, ("kill", "fail"))
        finally:
            shutil.rmtree(base, ignore_errors=True)
        report.pop("outcomes")
        rows.append(report)
        _save(report, args)
        print(
            f"{name}: {report['points']} points {report['points_by_kind']}, exercised {report['exercised']}, "
            f"files {report['states']}, {len(report['problems'])} problems, {report['seconds']} s",
            flush=True,
        )
        for problem in report["problems"]:
            print("  ", problem)
    return 0 if not any(r["problems"] for r in rows) else 1


def _save(report: dict, args) -> None:
    """Replace ``report``'s kind in ``results/crash_walk.json`` (other kinds kept), under a lock: kinds may be
    walked by processes of their own."""
    with open(RESULTS / ".crash_walk.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            rows = json.loads((RESULTS / "crash_walk.json").read_text())["rows"]
        except (OSError, ValueError, KeyError):
            rows = []
        rows = [r for r in rows if r["kind"] != report["kind"]] + [report]
        rows.sort(key=lambda r: list(KINDS).index(r["kind"]) if r["kind"] in KINDS else 99)
        notes = (
            "kill at every chosen point (stride per kind in its row; each kind of point's first and last always), "
            "an I/O error (EIO) at every third; each run a forked child of one process that imported surgiplan once"
        )
        save("crash_walk", rows, notes)


if __name__ == "__main__":
    sys.exit(main())
