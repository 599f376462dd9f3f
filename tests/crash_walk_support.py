"""The crash walk (issue 32): every write point of a run of each kind, crashed at, one by one.

For a run kind (a pipeline that writes: a plan stage's stored artifact, an optMIS repository build, a FEM
generation for retraction, a guide stage into a trainee record; report.html and result.json in every one):

1. the *old* state: the kind's first pipeline is run once into a fresh directory;
2. the *reference*: a copy of the old state, the kind's second pipeline (changed settings, so every file is
   rewritten) run over it with a trace (``SURGIPLAN_FAULT_TRACE``): N points, each write, fsync, rename and
   record transaction step, in order;
3. for n = 1..N (every ``stride``-th, and always each kind of point's first and last): a fresh copy of the old
   state, the second pipeline crashed at point n (``kill``: SIGKILL, a write's half on disk first; ``fail``:
   EIO), then checked: every file that existed still does; every file is its old version, its new version,
   or (where a file's bytes differ run to run: times in result.json, zip dates in .npz) a complete one by its
   format's reader, never partial; the trainee record passes ``PRAGMA integrity_check`` and holds exactly the
   attempts committed before point n; then a rerun succeeds and rewrites none of the work files (checkpoints,
   artifacts) renamed into place before the crash, and all of the others.

Each run is a child forked from one process that imported surgiplan once (:func:`surgiplan.faults.arm`), so
a walk costs the runs, not the imports. Run as a script: ``python tests/crash_walk_support.py [KIND ...]
--stride S --json``; ``benchmarks/crash_walk.py`` walks every point of every kind.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import json
import os
import shutil
import sqlite3
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pipeline_support import guide_stages, retraction_pipeline

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "configs" / "scenes" / "block_world.yaml"
#: files a crashed run may have withdrawn on purpose: a run removes the previous result.json and report.html
#: when it starts (the directory must not show an old run's result beside new files; .in-progress.json says so)
WITHDRAWN = {"result.json", "report.html"}
#: files with their own rules: the lock (flock, not atomic), the in-progress marker, the record (checked by SQL)
SKIPPED_SUFFIXES = (".surgiplan.lock", ".in-progress.json", ".sqlite", ".sqlite-wal", ".sqlite-shm")


@dataclass
class RunKind:
    """A run kind of the walk: its two pipelines and which of its files are committed work."""

    name: str
    old: dict[str, Any]
    new: dict[str, Any]
    #: path fragments of the files that are committed work: a rerun must not write them again
    work: tuple[str, ...] = ()
    record: str | None = None


def _plan(seed: int, figures: bool) -> dict[str, Any]:
    return {
        "name": "walk-plan",
        "length_unit": "mm",
        "scene": str(SCENE),
        "pipeline": [
            {
                "stage": "plan",
                "name": "route",
                "plugin": "safe_prm",
                "settings": {"proficiency": "beginner", "milestones": 300, "seed": seed},
                "start": "entry",
                "goal": "target",
                "artifact": "store/roadmap.npz",
            }
        ],
        "output": {"dir": "out", "figures": figures},
    }


def _optmis(grid_mm: float, figures: bool) -> dict[str, Any]:
    return {
        "name": "walk-optmis",
        "length_unit": "mm",
        "scene": {
            "bounds": {"min": [0, 0, 0], "max": [60, 40, 30]},
            "obstacles": [{"name": "wall", "box": {"min": [18, 0, 0], "max": [24, 28, 22]}}],
            "points": {  # nine: three tasks (groups of sources), so a crash can fall between two
                "a": [5, 10, 5],
                "b": [30, 10, 5],
                "c": [10, 35, 20],
                "d": [45, 8, 15],
                "e": [50, 30, 25],
                "f": [35, 32, 3],
                "g": [5, 30, 3],
                "h": [30, 30, 12],
                "i": [55, 35, 10],
            },
        },
        "pipeline": [
            {
                "stage": "plan",
                "name": "query",
                "plugin": "optmis",
                "settings": {"grid_spacing": grid_mm, "surface_spacing": 3, "neighbours": 8, "seed": 3},
                "space": {"kind": "r3", "tip_radius": 0.2},
                "start": "a",
                "goal": "e",
                "artifact": "store/repository.npz",
            }
        ],
        "executor": {"kind": "local", "workers": 1},
        "output": {"dir": "out", "gltf": False, "figures": figures},
    }


def _retraction(samples: int, figures: bool) -> dict[str, Any]:
    pipeline = retraction_pipeline("walk-retraction", (6, 6, 1), samples, chunk=4, artifact="store/page.npz")
    pipeline["pipeline"][0]["settings"]["figures"] = figures  # the planner's own figures (Figs. 5-7)
    return {**pipeline, "output": {"dir": "out", "gltf": False, "figures": figures}}


def _guide(seed: int, figures: bool) -> dict[str, Any]:
    return {
        "name": "walk-guide",
        "length_unit": "mm",
        "scene": str(SCENE),
        "pipeline": guide_stages(seed, trainee="alice"),
        "output": {"dir": "out", "gltf": False, "figures": figures},
        "record": "record/trainees.sqlite",
    }


def run_kinds(figures: bool = True) -> dict[str, RunKind]:
    """The run kinds, by name. ``figures=False``: their runs draw no figure (no .png among their points): a run
    costs a third to a half as much, for a walk that kills in no .png."""
    f = figures
    return {
        "plan": RunKind("plan", _plan(1, f), _plan(2, f), work=("store/roadmap.npz",)),
        "optmis": RunKind("optmis", _optmis(8, f), _optmis(7, f), work=("store/repository.npz", "out/.work/")),
        "retraction": RunKind(
            "retraction", _retraction(8, f), _retraction(9, f), work=("store/page.npz", "out/.work/")
        ),
        "guide": RunKind("guide", _guide(7, f), _guide(8, f), record="record/trainees.sqlite"),
    }


KINDS = run_kinds()


# ----------------------------------------------------------------------------- running one child


def run_child(root: Path, pipeline: Path, fault: str = "", trace: Path | None = None, log: Path | None = None):
    """Run ``surgiplan run pipeline --quiet`` in a forked child (cwd ``root``); returns (exit code or -signal,
    stderr text)."""
    log = log or root.parent / f"{root.name}.log"
    pid = os.fork()
    if pid == 0:  # the child: never returns
        code = 70
        try:
            fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            os.dup2(fd, 1)
            os.dup2(fd, 2)
            os.chdir(root)
            from surgiplan import faults
            from surgiplan.cli import main

            faults.arm(fault, trace)
            code = main(["run", str(pipeline), "--quiet"])
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
        except BaseException:
            import traceback

            traceback.print_exc()
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    code = -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)
    return code, log.read_text(errors="replace")


def run_here(root: Path, pipeline: Path) -> int:
    """Run ``surgiplan run pipeline --quiet`` in this process (cwd ``root``): the walk's first run, which also
    loads every compiled kernel the children then inherit."""
    from surgiplan.cli import main

    here = Path.cwd()
    os.chdir(root)
    try:
        return main(["run", str(pipeline), "--quiet"])
    finally:
        os.chdir(here)


# ----------------------------------------------------------------------------- checking files


def _is_temporary(path: Path) -> bool:
    return path.name.startswith(".") and (".tmp" in path.name or ".partial" in path.name or path.suffix == ".vtu")


def snapshot(root: Path) -> dict[str, str]:
    """Every file under ``root`` the walk checks, by relative path: its SHA-256."""
    out = {}
    for path in sorted(root.rglob("*")):
        if path.is_file() and not path.name.endswith(SKIPPED_SUFFIXES) and not _is_temporary(path):
            out[str(path.relative_to(root))] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def temporaries(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob(".*") if p.is_file() and _is_temporary(p))


def complete(path: Path) -> bool:
    """Whether ``path`` is a whole file of its format, by that format's reader (or its end marker)."""
    data = path.read_bytes()
    suffix = path.suffix
    try:
        if suffix == ".json":
            json.loads(data)
        elif suffix == ".npz":
            with np.load(path, allow_pickle=False) as bundle:
                for key in bundle.files:
                    bundle[key]
        elif suffix == ".png":
            return data.startswith(b"\x89PNG\r\n\x1a\n") and data.endswith(b"IEND\xaeB`\x82")
        elif suffix == ".html":
            return data.rstrip().endswith(b"</html>")
        elif suffix in (".vtu", ".pvd"):
            return data.rstrip().endswith(b"</VTKFile>")
        elif suffix == ".glb":
            return data[:4] == b"glTF" and int.from_bytes(data[8:12], "little") == len(data)
        elif suffix == ".csv":
            text = data.decode()
            widths = {len(line.split(",")) for line in text.splitlines()}
            return text.endswith("\n") and len(widths) == 1
        else:
            return False
    except Exception:
        return False
    return True


def record_state(path: Path) -> tuple[str, int]:
    """The record's ``PRAGMA integrity_check`` and its number of attempts (0 when it does not exist)."""
    if not path.exists():
        return "ok", 0
    db = sqlite3.connect(path)
    try:
        check = db.execute("PRAGMA integrity_check").fetchone()[0]
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        attempts = db.execute("SELECT count(*) FROM attempts").fetchone()[0] if "attempts" in tables else 0
    finally:
        db.close()
    return check, attempts


def committed_before(points, n: int) -> int:
    """Record transactions committed when the run stopped at point ``n``: a ``committed`` point comes after
    its COMMIT returned, so a crash at it (n itself) has one more."""
    return sum(1 for seq, point, _, _ in points if point == "committed" and seq <= n)


def _trace(path: Path) -> list[tuple[int, str, int, str]]:
    from surgiplan.faults import read_trace

    return read_trace(path) if path.exists() else []


def _work_renames(kind: RunKind, root: Path, points) -> set[str]:
    out = set()
    for _, point, _, target in points:
        if point != "rename" or not target:
            continue
        rel = target  # relative to the run's directory (the runs' paths are)
        if Path(target).is_absolute():
            try:
                rel = str(Path(target).resolve().relative_to(root.resolve()))
            except ValueError:
                pass
        if any(rel.startswith(w) or rel == w for w in kind.work):
            out.add(rel)
    return out


# ----------------------------------------------------------------------------- the walk


@dataclass
class Outcome:
    n: int
    point: str
    action: str
    exit: int
    #: the kind of file the point wrote (its suffix: ``.png``, ``.sqlite``, ...)
    file: str = ""
    problems: list[str] = field(default_factory=list)
    states: dict[str, int] = field(default_factory=dict)
    temporaries: int = 0
    attempts: int | None = None
    redone: int = 0
    rerun_work: int = 0
    #: whether the run was rerun after the crash (and the rerun checked)
    reran: bool = False


def _write_pipelines(kind: RunKind, base: Path) -> tuple[Path, Path]:
    old, new = base / "old.yaml", base / "new.yaml"
    old.write_text(yaml.safe_dump(copy.deepcopy(kind.old), sort_keys=False))
    new.write_text(yaml.safe_dump(copy.deepcopy(kind.new), sort_keys=False))
    return old, new


def chosen_points(points, stride: int) -> list[int]:
    """Every ``stride``-th point, and each kind of point's first and last (so every kind is exercised); stride
    0: only each kind of point's last (the quickest walk that still crashes at every kind of point)."""
    chosen = {seq for seq, *_ in points[::stride]} if stride else set()
    by_kind: dict[str, list[int]] = {}
    for seq, point, _, _ in points:
        by_kind.setdefault(point, []).append(seq)
    for seqs in by_kind.values():
        chosen.update((seqs[0], seqs[-1]) if stride else (seqs[-1],))
    return sorted(chosen)


#: where the quickest walk (stride 0) injects I/O errors: the last of these kinds of point
FAIL_POINTS = ("write", "commit")


def file_kind(target: str) -> str:
    """The kind of file a point wrote: its suffix (``-`` for none)."""
    return Path(target).suffix or "-" if target else "-"


def points_by_file_kind(points) -> dict[str, list[int]]:
    """The points of each (kind of point, kind of file) pair, ``"write .png"``: their numbers, in order."""
    out: dict[str, list[int]] = {}
    for seq, point, _, target in points:
        out.setdefault(f"{point} {file_kind(target)}", []).append(seq)
    return out


def file_kind_points(points, files: tuple[str, ...]) -> list[int]:
    """The last point of each kind of point in a file of each kind in ``files`` (``("*",)``: every kind the run
    writes): the quickest walk's crashes at every kind of file."""
    return sorted(
        seqs[-1] for pair, seqs in points_by_file_kind(points).items() if "*" in files or pair.split(" ", 1)[1] in files
    )


def after_first_work(kind: RunKind, points) -> list[int]:
    """The point just after the first work file's rename: a crash there has committed work a rerun must keep."""
    for seq, point, _, target in points:
        if point == "rename" and _work_renames(kind, Path("."), [(seq, point, 0, target)]):
            return [seq + 1]
    return []


def walk(
    kind: RunKind,
    base: Path,
    stride: int = 1,
    actions: tuple[str, ...] = ("kill",),
    select: str = "stride",
    files: tuple[str, ...] = (),
) -> dict[str, Any]:
    """Walk ``kind``'s points (see the module) in ``base``; returns the counts and every problem found.

    ``select``: ``stride`` (every ``stride``-th point, see :func:`chosen_points`), or ``work`` (one point: just
    after the first work file is committed; the quickest check that a rerun keeps committed work). ``files``
    (suffixes, or ``*``): also kill at the last point of each kind in a file of each of these kinds
    (:func:`file_kind_points`), checking the files and the record after the crash (the rerun is checked after
    the crashes ``select`` chose)."""
    started = time.monotonic()
    old_yaml, new_yaml = _write_pipelines(kind, base)
    pristine = base / "pristine"
    pristine.mkdir()
    code = run_here(pristine, old_yaml)
    assert code == 0, f"the old run of {kind.name} failed ({code})"
    old = snapshot(pristine)
    old_attempts = record_state(pristine / kind.record)[1] if kind.record else 0

    reference = base / "reference"
    shutil.copytree(pristine, reference, symlinks=True)
    trace_file = base / "reference.trace"
    code, err = run_child(reference, new_yaml, trace=trace_file)
    assert code == 0, f"the reference run of {kind.name} failed ({code}):\n{err[-3000:]}"
    new = snapshot(reference)
    points = _trace(trace_file)
    all_work = _work_renames(kind, reference, points)
    counts: dict[str, int] = {}
    for _, point, _, _ in points:
        counts[point] = counts.get(point, 0) + 1

    outcomes: list[Outcome] = []
    for action in actions:
        rerun: set[int] | None = None  # None: after every crash
        if select == "work":
            chosen = after_first_work(kind, points)
        elif action == "fail" and not stride:  # the quickest walk: an I/O error in a file's write, and in a commit
            chosen = [max(seq for seq, point, *_ in points if point == p) for p in FAIL_POINTS if p in counts]
        else:
            chosen = chosen_points(points, stride if action == "kill" else stride * 3)
        if files and action == "kill":
            rerun = set(chosen)
            chosen = sorted(rerun | set(file_kind_points(points, files)))
        for n in chosen:
            _, point, _, target = points[n - 1]
            work = base / f"{action}-{n}"
            shutil.copytree(pristine, work, symlinks=True)
            outcome = _crash_and_check(kind, work, new_yaml, f"{action}:any:{n}", old, new, points, n, old_attempts)
            outcome.point, outcome.action, outcome.file = point, action, file_kind(target)
            if action == "kill" and (rerun is None or n in rerun):
                _rerun_and_check(kind, work, new_yaml, points, n, all_work, old_attempts, outcome)
            outcomes.append(outcome)
            shutil.rmtree(work)
    return {
        "kind": kind.name,
        "stride": stride,
        "points": len(points),
        "points_by_kind": counts,
        "points_by_file_kind": {pair: len(seqs) for pair, seqs in points_by_file_kind(points).items()},
        "exercised": {a: sum(o.action == a for o in outcomes) for a in actions},
        "work_files": len(all_work),
        "problems": [f"{o.action} at point {o.n} ({o.point}): {p}" for o in outcomes for p in o.problems],
        "states": _sum_states(outcomes),
        "temporaries_left": sum(o.temporaries for o in outcomes),
        "redone": sum(o.redone for o in outcomes),
        "seconds": round(time.monotonic() - started, 1),
        "outcomes": [o.__dict__ for o in outcomes],
    }


def _sum_states(outcomes: list[Outcome]) -> dict[str, int]:
    total: dict[str, int] = {}
    for o in outcomes:
        for k, v in o.states.items():
            total[k] = total.get(k, 0) + v
    return total


def _crash_and_check(kind, work, new_yaml, fault, old, new, points, n, old_attempts) -> Outcome:
    code, err = run_child(work, new_yaml, fault=fault)
    outcome = Outcome(n, "", "", code)
    killed = fault.startswith("kill")
    if killed and code != -9:
        outcome.problems.append(f"expected the kill at point {n}, the run ended with {code}")
    if not killed and "Traceback" in err:
        outcome.problems.append(f"a traceback on an injected I/O error: {err[-1500:]}")
    now = snapshot(work)
    for rel in old:
        if rel not in now and Path(rel).name not in WITHDRAWN:
            outcome.problems.append(f"{rel} existed before the run and is missing")
    for rel, digest in now.items():
        state = "old" if digest == old.get(rel) else "new" if digest == new.get(rel) else None
        if state is None:
            state = "complete" if complete(work / rel) else "partial"
            if state == "partial":
                outcome.problems.append(f"{rel} is neither its old nor its new version, nor a complete file")
        outcome.states[state] = outcome.states.get(state, 0) + 1
    outcome.temporaries = len(temporaries(work))
    if not killed and outcome.temporaries:
        outcome.problems.append(f"an I/O error left temporary files: {temporaries(work)}")
    if kind.record:
        check, attempts = record_state(work / kind.record)
        committed = committed_before(points, n)
        outcome.attempts = attempts
        if check != "ok":
            outcome.problems.append(f"the record's integrity_check says {check}")
        if attempts != old_attempts + committed:
            outcome.problems.append(
                f"the record holds {attempts} attempts; {old_attempts + committed} were committed before the crash"
            )
    return outcome


def _rerun_and_check(kind, work, new_yaml, points, n, all_work, old_attempts, outcome) -> None:
    trace = work.parent / f"{work.name}.rerun.trace"
    code, err = run_child(work, new_yaml, trace=trace)
    outcome.reran = True
    if code != 0:
        outcome.problems.append(f"the rerun after the crash failed ({code}): {err[-1500:]}")
        return
    done = _work_renames(kind, work, [p for p in points if p[0] < n])
    again = _work_renames(kind, work, _trace(trace))
    outcome.redone = len(done & again)
    outcome.rerun_work = len(again)
    if done & again:
        outcome.problems.append(f"the rerun redid committed work: {sorted(done & again)}")
    if (done | again) != all_work:
        outcome.problems.append(f"work never done: {sorted(all_work - done - again)}")
    left = [t for t in temporaries(work) if t.startswith("out/") and t.endswith(".tmp")]
    if left:
        outcome.problems.append(f"the rerun left the crashed run's temporary files: {left}")
    result = json.loads((work / "out" / "result.json").read_text())
    if result["status"] != "succeeded":
        outcome.problems.append(f"the rerun's result.json says {result['status']}")
    if kind.record:
        committed = committed_before(points, n)
        check, attempts = record_state(work / kind.record)
        if check != "ok" or attempts != old_attempts + committed + 1:
            outcome.problems.append(f"after the rerun the record holds {attempts} attempts ({check})")
    trace.unlink(missing_ok=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "kinds",
        nargs="*",
        default=list(KINDS),
        help="KIND, KIND:work (one crash, after its first committed work) or KIND:files[=.png,.csv] (also the last "
        "point of each kind in each kind of file, or in these)",
    )
    parser.add_argument("--stride", type=int, default=1)
    parser.add_argument("--fail", action="store_true", help="also inject I/O errors (every 3rd chosen stride)")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--keep", type=Path, default=None, help="walk in this directory (kept)")
    parser.add_argument(
        "--no-figures",
        default="",
        metavar="KIND,...",
        help="these kinds' runs draw no figures (quicker; their walks then have no .png point)",
    )
    args = parser.parse_args(argv)
    without_figures = run_kinds(figures=False)
    plain = set(filter(None, args.no_figures.split(",")))
    import surgiplan.cli  # noqa: F401 - imported once, before the children are forked
    from surgiplan.registry import default_registry

    default_registry()  # every plugin imported once, too
    reports = []
    for spec in args.kinds:
        name, _, select = spec.partition(":")
        select, _, suffixes = select.partition("=")
        files = tuple(suffixes.split(",")) if suffixes else ("*",) if select == "files" else ()
        select = "stride" if select in ("", "files") else select
        base = Path(tempfile.mkdtemp(prefix=f"walk-{name}-", dir=args.keep))
        try:
            actions = ("kill", "fail") if args.fail and select != "work" else ("kill",)
            kind = without_figures[name] if name in plain else KINDS[name]
            reports.append(walk(kind, base, args.stride, actions, select, files))
        finally:
            if args.keep is None:
                shutil.rmtree(base, ignore_errors=True)
    if args.json:
        print(json.dumps(reports))
    else:
        for r in reports:
            print(
                f"{r['kind']}: {r['points']} points {r['points_by_kind']}, exercised {r['exercised']}, "
                f"{len(r['problems'])} problems, {r['seconds']} s"
            )
            for p in r["problems"]:
                print("  ", p)
    return 0 if not any(r["problems"] for r in reports) else 1


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT / "tests"))
    raise SystemExit(main())
