"""The fault-injection switch (surgiplan.faults) at each kind of point, in this process: an injected I/O error
leaves the old file and no temporary one behind; the trace counts every point. The walk of whole runs, with
kills, is tests/test_crash_walk.py."""

from __future__ import annotations

import errno
import os
import sqlite3
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT
from surgiplan import faults
from surgiplan.faults import FaultSpecError, parse
from surgiplan.guidance import TraineeRecord
from surgiplan.storage import save_bundle, write_text_atomic
from test_record_privacy import add


@pytest.fixture
def armed():
    yield faults.arm
    faults.arm()  # disarmed again
    assert not faults.ARMED


@pytest.mark.parametrize("text", ["write", "write:0", "kil:write:1", "write:x", "flush:1", "kill:write:1:2"])
def test_a_bad_fault_spec_is_named(text):
    with pytest.raises(FaultSpecError, match="SURGIPLAN_FAULT_AT"):
        parse(text)


def test_fault_specs():
    assert parse("") is None
    assert parse("write:7") == faults.Fault("fail", "write", 7)
    assert parse("kill:any:12") == faults.Fault("kill", "any", 12)


@pytest.mark.parametrize("point", ["write", "fsync", "rename"])
def test_an_io_error_at_each_point_of_a_file_leaves_the_old_file_and_no_temporary(tmp_path, armed, point):
    target = tmp_path / "doc.txt"
    write_text_atomic(target, "old\n")
    armed(f"fail:{point}:1")
    with pytest.raises(OSError) as caught:
        write_text_atomic(target, "new\n")
    assert caught.value.errno == errno.EIO and f"injected fault at {point} point 1" in str(caught.value)
    assert target.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["doc.txt"]
    armed("")
    write_text_atomic(target, "new\n")
    assert target.read_text() == "new\n"


def test_the_trace_counts_every_point_in_order(tmp_path, armed):
    trace = tmp_path / "trace"
    armed("", trace)
    write_text_atomic(tmp_path / "a.txt", "a")
    save_bundle(tmp_path / "b.npz", {"x": np.arange(3)})
    points = faults.read_trace(trace)
    assert [p[1] for p in points] == ["write", "fsync", "rename"] * 2
    assert [p[0] for p in points] == list(range(1, 7))
    assert points[-1][3] == str(tmp_path / "b.npz")


@pytest.mark.parametrize("point", ["sql", "commit"])
def test_a_fault_inside_a_record_transaction_leaves_no_part_of_the_attempt(tmp_path, armed, point):
    path = tmp_path / "record.sqlite"
    with TraineeRecord(path) as record:
        add(record, "alice")
        armed(f"fail:{point}:1")
        with pytest.raises((OSError, sqlite3.OperationalError)):
            add(record, "alice", seed=1, n=400)  # enough statements for a few sql points
        armed("")
        add(record, "alice", seed=2)
        assert len(record.attempts("alice")) == 2
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    assert db.execute("SELECT count(*) FROM samples").fetchone()[0] == 40
    db.close()


def test_the_environment_variable_is_read_once_and_not_passed_on(tmp_path):
    """A process started with SURGIPLAN_FAULT_AT is faulted at that point; its children are not."""
    code = (
        "import os, sys\n"
        "from surgiplan.storage import write_text_atomic\n"
        "assert 'SURGIPLAN_FAULT_AT' not in os.environ\n"
        "write_text_atomic(sys.argv[1] + '/a', 'a')\n"
        "write_text_atomic(sys.argv[1] + '/b', 'b')\n"
    )
    env = {**os.environ, "SURGIPLAN_FAULT_AT": "kill:rename:2"}
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path)], cwd=ROOT, env=env, timeout=120)
    assert done.returncode == -9
    assert (tmp_path / "a").read_text() == "a" and not (tmp_path / "b").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".b.")]  # the killed write's temporary file
