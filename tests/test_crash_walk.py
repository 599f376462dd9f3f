"""Crash at every write point (issue 32, item 1), in the suite's budget: a plan run and a guide run killed at
each kind of their points (the last point of each kind, then rerun; an I/O error at the last write and commit),
and at the last point of each kind in each kind of file (the plan run: every kind it writes, .json .npz .png
.glb .html; the guide run: the .csv it alone writes; the record's transaction steps), an optMIS build and a
retraction's FEM generation killed just after their first checkpoint is committed; each checked as
``crash_walk_support`` says. Only the plan run draws figures (it is killed in its .png); the others' crashes fall
in no .png, and drawing was half of each of their runs. The full walk, every point of every kind (figures
drawn), is ``benchmarks/crash_walk.py`` (its counts are in docs/howto/reliability.md).

The walk runs in its own process (it forks one child per run, which a pytest process with threads of other
tests must not do), all four kinds in one, so surgiplan is imported once."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from conftest import ROOT

KINDS = ("plan", "optmis", "retraction", "guide")


@pytest.fixture(scope="module")
def walked():
    done = subprocess.run(
        [
            sys.executable,
            str(ROOT / "tests" / "crash_walk_support.py"),
            *("plan:files", "optmis:work", "retraction:work", "guide:files=.csv"),
            *("--stride", "0", "--fail", "--json", "--no-figures", "optmis,retraction,guide"),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert done.stdout.strip(), done.stderr[-3000:]
    reports = json.loads(done.stdout.strip().splitlines()[-1])
    return {r["kind"]: r for r in reports}, done.returncode


@pytest.mark.slow
@pytest.mark.parametrize("kind", KINDS)
def test_a_crash_at_any_kind_of_write_point_loses_nothing_and_a_rerun_redoes_nothing(walked, kind):
    reports, code = walked
    report = reports[kind]
    assert report["problems"] == [], "\n".join(report["problems"])
    kinds = set(report["points_by_kind"])
    assert {"write", "fsync", "rename"} <= kinds
    if kind == "guide":
        assert {"sql", "commit", "committed"} <= kinds
    if kind in ("plan", "guide"):  # every kind of point was killed at; an I/O error in a write and in a commit
        assert {o["point"] for o in report["outcomes"] if o["action"] == "kill" and o["reran"]} == kinds
        killed = {f"{o['point']} {o['file']}" for o in report["outcomes"] if o["action"] == "kill"}
        if kind == "plan":  # every kind of point in every kind of file the run writes
            assert killed == set(report["points_by_file_kind"])
            assert {".json", ".npz", ".png", ".glb", ".html"} <= {pair.split()[1] for pair in killed}
        else:
            assert {"write .csv", "fsync .csv", "rename .csv", "sql .sqlite", "commit .sqlite"} <= killed
        fails = {o["point"] for o in report["outcomes"] if o["action"] == "fail"}
        assert fails == ({"write", "commit"} if kind == "guide" else {"write"})
    else:
        assert [o["action"] for o in report["outcomes"]] == ["kill"]
    if kind != "plan":  # the plan run's last points come after every file is rewritten: no old one is left
        assert report["states"].get("old", 0) > 0
    assert report["states"].get("new", 0) + report["states"].get("complete", 0) > 0
    assert report["states"].get("partial", 0) == 0
    if kind != "guide":
        assert report["work_files"] >= 1
        # a crash after work was committed: its rerun did only the rest (and none of it again: no problem above)
        assert any(o["rerun_work"] < report["work_files"] for o in report["outcomes"] if o["reran"])
    else:
        kills = {o["point"]: o["attempts"] for o in report["outcomes"] if o["action"] == "kill" and o["reran"]}
        assert kills["commit"] == 1 and kills["committed"] == 2  # before the COMMIT: not there; after: there
    assert code == 0 or any(r["problems"] for r in reports.values())
