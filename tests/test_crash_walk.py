"""Crash at every write point (issue 32, item 1): each run kind that writes, crashed at a stride of its points
(each kind of point's first and last always), checked as ``crash_walk_support`` says. The full walk, every
point, is ``benchmarks/crash_walk.py``.

The walk runs in its own process (it forks one child per run, which a pytest process with threads of other
tests must not do)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from conftest import ROOT

#: every how-many-th point the suite crashes at, per kind (a plan run has ~40 points, a guide run ~60)
STRIDES = {"plan": 13, "optmis": 17, "retraction": 40, "guide": 9}


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(STRIDES))
def test_a_crash_at_any_write_point_loses_nothing_and_a_rerun_redoes_nothing(kind):
    args = [sys.executable, str(ROOT / "tests" / "crash_walk_support.py"), kind, "--stride", str(STRIDES[kind])]
    done = subprocess.run(
        [*args, "--json", *(["--fail"] if kind in ("plan", "guide") else [])],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.stdout.strip(), done.stderr[-3000:]
    (report,) = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["problems"] == [], "\n".join(report["problems"])
    assert done.returncode == 0
    kinds = set(report["points_by_kind"])
    assert {"write", "fsync", "rename"} <= kinds
    if kind == "guide":
        assert {"sql", "commit", "committed"} <= kinds
    # every kind of point was crashed at (its first and last), and the crashes found both versions of files
    crashed = {o["point"] for o in report["outcomes"] if o["action"] == "kill"}
    assert crashed == kinds
    assert (
        report["states"].get("old", 0) > 0 and report["states"].get("new", 0) + report["states"].get("complete", 0) > 0
    )
    if kind in ("optmis", "retraction", "plan"):
        assert report["work_files"] >= 1
        # some crash fell after a work file was committed: its rerun did less than all of the work
        assert any(o["rerun_work"] < report["work_files"] for o in report["outcomes"] if o["action"] == "kill")
    if kind == "guide":
        attempts = {o["attempts"] for o in report["outcomes"] if o["action"] == "kill"}
        assert len(attempts) == 2  # crashes before the commit (old count) and after it (one more)
