"""Concurrent users of one output (issue 32, item 2): a second run into a directory another run holds is
refused naming the first (nothing written); a lock a killed run left is taken over, with a message."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest
import yaml
from conftest import ROOT
from pipeline_support import block_world_pipeline, safe_prm_stage

HOLD = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from surgiplan.outputlock import claim
    lock = claim(Path(sys.argv[1]), "first.yaml")
    print("held", flush=True)
    sys.stdin.readline()  # until the test says so (or is killed)
    lock.release()
    """
)


def _pipeline(tmp_path, out):
    return block_world_pipeline(tmp_path / "second.yaml", "lock-probe", [safe_prm_stage("route", 200)], out)


def _holder(out):
    process = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(out)],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert process.stdout.readline().strip() == "held"
    return process


def _listing(directory):
    return sorted((str(p.relative_to(directory)), p.stat().st_size, p.stat().st_mtime_ns) for p in directory.rglob("*"))


def test_a_second_run_into_a_held_directory_is_refused_naming_the_first_and_writes_nothing(cli, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "result.json").write_text('{"status": "succeeded"}\n')  # a finished run's record stays as it is
    holder = _holder(out)
    try:
        before = _listing(out)
        code, _, err = cli("run", _pipeline(tmp_path, out), "--quiet")
        assert code == 2
        assert f"another surgiplan run is writing to {out}: pid {holder.pid} on " in err
        assert "pipeline first.yaml, started 20" in err and "choose another --out" in err
        assert "Traceback" not in err
        assert _listing(out) == before  # nothing written, nothing removed
        assert json.loads((out / ".surgiplan.lock").read_text())["pid"] == holder.pid
    finally:
        holder.communicate("\n", timeout=30)
    assert holder.returncode == 0
    assert not (out / ".surgiplan.lock").exists()  # released: removed
    code, _, err = cli("run", _pipeline(tmp_path, out), "--quiet")  # and the directory is free again
    assert code == 0, err
    assert json.loads((out / "result.json").read_text())["status"] == "succeeded"
    assert not (out / ".surgiplan.lock").exists()


def test_the_lock_of_a_killed_run_is_taken_over_with_a_message(cli, tmp_path, caplog):
    out = tmp_path / "out"
    out.mkdir()
    holder = _holder(out)
    os.kill(holder.pid, signal.SIGKILL)
    holder.wait(timeout=30)
    assert json.loads((out / ".surgiplan.lock").read_text())["pid"] == holder.pid  # left behind by the kill
    code, _, err = cli("run", _pipeline(tmp_path, out), "--quiet")
    assert code == 0, err
    assert f"took over the lock of a run that ended without releasing it (pid {holder.pid} on " in err
    assert not (out / ".surgiplan.lock").exists()


@pytest.mark.slow
def test_two_real_runs_at_once_one_is_refused(tmp_path):
    """Two `surgiplan run` processes started together into one directory: exactly one runs, the other is
    refused with exit status 2 naming it (a slow guide attempt, pace 1, keeps the first one busy)."""
    out = tmp_path / "out"
    data = yaml.safe_load(_pipeline(tmp_path, out).read_text())
    data["pipeline"].append(
        {
            "stage": "guide",
            "name": "attempt",
            "plugin": "synthetic_trainee",
            "path_from": "route",
            "settings": {"level": "beginner", "seed": 1, "pace": 1},
        }
    )
    path = tmp_path / "slow.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    command = [sys.executable, "-m", "surgiplan.cli", "run", str(path), "--quiet"]
    # the second run's interpreter is started (and has imported surgiplan) first, and told to run once the
    # first holds the directory: on a loaded machine its start-up could otherwise outlast the first run
    ready = "import sys; from surgiplan.cli import main; print('ready', flush=True); sys.stdin.readline(); "
    second = subprocess.Popen(
        [sys.executable, "-c", ready + f"sys.exit(main(['run', {str(path)!r}, '--quiet']))"],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert second.stdout.readline().strip() == "ready"
    first = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for _ in range(1200):  # the first run holds the directory once its lock file names it
            lock = out / ".surgiplan.lock"
            if lock.exists() and lock.read_text().strip():
                break
            assert first.poll() is None, first.communicate()
            time.sleep(0.1)
        _, err = second.communicate("go\n", timeout=300)
        assert second.returncode == 2, err
        assert f"pid {first.pid} on" in err and str(path) in err
        assert first.poll() is None  # the first was still running: this was a refusal, not a queue
    finally:
        if first.poll() is None:
            first.kill()
        first.communicate(timeout=30)
        if second.poll() is None:
            second.kill()


@pytest.mark.parametrize("content", ["", "not json"])
def test_an_unreadable_stale_lock_is_taken_over(cli, tmp_path, content):
    out = tmp_path / "out"
    out.mkdir()
    (out / ".surgiplan.lock").write_text(content)
    code, _, err = cli("run", _pipeline(tmp_path, out), "--quiet")
    assert code == 0, err
    assert not (out / ".surgiplan.lock").exists()
