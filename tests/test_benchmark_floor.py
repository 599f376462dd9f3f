"""benchmarks/cyclictest.cyclictest_floor: the machine's floor as rt-tests' cyclictest measures it, counted as each
loop counts its own lapses (a wake-up more than a period late, or more than the loop's deadline)."""

from __future__ import annotations

import json
import os
import shutil
import stat
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

from cyclictest import cyclictest_floor

#: a stand-in for cyclictest: writes the JSON it is asked for (--json=PATH), from FAKE_CYCLICTEST_JSON
FAKE = """#!/bin/sh
case "$1" in --help) echo "cyclictest V 9.99"; exit 0;; esac
[ -n "$FAKE_CYCLICTEST_FAIL" ] && { echo "Unable to change scheduling policy!" >&2; exit 255; }
for a in "$@"; do case "$a" in --json=*) cp "$FAKE_CYCLICTEST_JSON" "${a#--json=}";; esac; done
"""


@pytest.fixture
def fake_cyclictest(tmp_path, monkeypatch):
    exe = tmp_path / "bin" / "cyclictest"
    exe.parent.mkdir()
    exe.write_text(FAKE)
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PATH", f"{exe.parent}{os.pathsep}{os.environ['PATH']}")
    report = tmp_path / "report.json"
    monkeypatch.setenv("FAKE_CYCLICTEST_JSON", str(report))
    return report


def test_wake_ups_more_than_a_period_late_and_beyond_the_histogram_are_lapses(fake_cyclictest):
    # 1,000 cycles: 990 on time, 5 at exactly a period (not late by more), 3 beyond it, 2 past the 20 ms histogram
    histogram = {"12": 990, "1000": 5, "1001": 2, "9870": 1}
    thread = {"cycles": 1000, "min": 7, "max": 25000, "avg": 20.0, "histogram": histogram}
    fake_cyclictest.write_text(json.dumps({"thread": {"0": thread}}))
    row = cyclictest_floor(3, 1.0, polling=False, priority=30)
    assert row["version"] == "9.99"
    assert row["lapses_per_run"] == [5, 5, 5] and row["runs_without_lapse"] == "0/3"
    assert row["max_latency_ms_per_run"] == [25.0] * 3
    assert row["command"].endswith("-l 1000 --laptop")  # halting, as the control loop by default
    thread.update(histogram={"12": 999, "800": 1}, max=800)
    fake_cyclictest.write_text(json.dumps({"thread": {"0": thread}}))
    row = cyclictest_floor(2, 1.0, polling=True, priority=30)
    assert row["lapses_per_run"] == [0, 0] and row["runs_without_lapse"] == "2/2"
    assert "--laptop" not in row["command"] and "request 0" in row["loop"]


def test_a_cyclictest_that_fails_or_is_missing_is_a_row_saying_so(fake_cyclictest, monkeypatch):
    monkeypatch.setenv("FAKE_CYCLICTEST_FAIL", "1")
    row = cyclictest_floor(2, 1.0, polling=False, priority=30)
    assert row["error"] == "cyclictest failed: Unable to change scheduling policy!" and "lapses_per_run" not in row
    monkeypatch.setenv("PATH", "/nonexistent")
    assert cyclictest_floor(2, 1.0, polling=False, priority=30)["error"].startswith("cyclictest not installed")


@pytest.mark.skipif(shutil.which("cyclictest") is None, reason="rt-tests' cyclictest not installed")
def test_the_real_cyclictests_worst_latency_agrees_with_the_lapses_counted_from_its_histogram():
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except OSError as exc:
        pytest.skip(f"this system does not allow SCHED_FIFO: {exc}")
    row = cyclictest_floor(2, 0.3, polling=False, priority=30)
    assert "error" not in row, row
    for lapses, worst in zip(row["lapses_per_run"], row["max_latency_ms_per_run"], strict=True):
        # cyclictest's own maximum and the histogram it wrote tell the same story
        assert (lapses > 0) == (worst > 1.0)


def test_a_deadline_shorter_than_the_period_counts_wake_ups_later_than_it(fake_cyclictest):
    # the live view's floor: 100 Hz, a sample late by more than 2 ms is a lapse, though the period is 10 ms
    histogram = {"40": 1990, "2000": 4, "2001": 3, "9000": 2}
    thread = {"cycles": 1999, "min": 7, "max": 9000, "avg": 45.0, "histogram": histogram}
    fake_cyclictest.write_text(json.dumps({"thread": {"0": thread}}))
    row = cyclictest_floor(2, 20.0, polling=False, priority=10, interval_us=10000, late_us=2000)
    assert row["lapses_per_run"] == [5, 5] and row["late_over_ms"] == 2.0
    assert row["command"] == "cyclictest -m -q -t1 -p 10 -i 10000 -l 2000 --laptop"
    assert row["loop"].startswith("cyclictest (rt-tests), 100 Hz, SCHED_FIFO 10,")
    # the deadline defaults to a period: at 500 Hz, 2 ms
    row = cyclictest_floor(1, 8.0, polling=False, priority=30, interval_us=2000)
    assert row["lapses_per_run"] == [5] and row["late_over_ms"] == 2.0 and "-i 2000 -l 4000" in row["command"]
