"""Trust boundaries: the framework verifies what plugins return, refuses hostile input, never loses a run's record.

A hostile third-party package (``tests/plugins/surgiplan_hostile``, put on the path with a ``.dist-info``
as ``pip install`` would) returns every kind of bad answer; each is refused with the documented status and
a message naming the plugin, its package and what is wrong; the earlier stages survive in ``result.json``;
a device never receives a refused path.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import CONFIGS, ROOT

PLUGINS = Path(__file__).resolve().parent / "plugins"


def pipeline(tmp_path, mode, *, start="entry", goal="target", execute=None, extra=None, workers=1, out=None):
    stages = [
        {"stage": "plan", "name": "first", "plugin": "hostile", "settings": {"mode": "honest"}},
        {"stage": "plan", "name": "bad", "plugin": "hostile", "settings": {"mode": mode}, "start": start, "goal": goal},
    ]
    stages[0].update(start="entry", goal="target")
    if execute:
        stages.append({"stage": "execute", "name": "device", "path_from": "bad", **execute})
    stages += extra or []
    data = {
        "name": "hostile",
        "length_unit": "mm",
        "scene": str(CONFIGS / "scenes" / "block_world.yaml"),
        "pipeline": stages,
        "executor": {"kind": "local", "workers": workers},
        "output": {"dir": str(out or tmp_path / "out"), "figures": False, "gltf": False},
    }
    path = tmp_path / "pipeline.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


GIMBAL = {
    "plugin": "cast_gimbal",
    "settings": {"fulcrum": {"xyz": [150, 50, 130], "rpy": [0, "90 deg", 0]}, "control_rate": 100},
}

BAD_PATHS = [
    ("collide_waypoint", {}, "waypoint 1 of 3 at (40, 42, 20) mm collides with obstacle 'A1' (clearance -5 mm)"),
    (
        "through_blocks",
        {"start": [10, 30, 20], "goal": [140, 30, 20]},
        "segment 0 of 1, from (10, 30, 20) mm to (140, 30, 20) mm, is not certified clear: its clearance is -",
    ),
    ("wrong_start", {}, "the path starts at (10, 52, 20) mm, 2 mm from the stage's start (10, 50, 20) mm"),
    ("wrong_goal", {}, "the path ends at (140, 52, 20) mm, 2 mm from the stage's goal (140, 50, 20) mm"),
    ("out_of_bounds", {}, "waypoint 1 of 3 puts the tip at (75, 50, 1.002e+04) mm, outside the scene bounds"),
    ("nan", {}, "waypoint 1 of 3 is not finite: [nan, 0.05, 0.02]"),
    ("wrong_dimension", {}, "the path has shape (2, 2); a r3 path is (n, 3)"),
    ("single_waypoint", {}, "the path has 1 waypoint(s); a solved path has at least 2"),
    ("not_a_result", {}, "query returned a dict, not a PlanResult"),
    ("bad_status", {}, "status 'done' is not a plan status (solved, no_path, invalid_start, invalid_goal, timeout)"),
]


@pytest.mark.parametrize(("mode", "ends", "problem"), BAD_PATHS, ids=[m for m, _, _ in BAD_PATHS])
def test_a_bad_plugin_path_is_refused_and_never_reaches_the_device(cli, tmp_path, hostile, mode, ends, problem):
    code, _, err = cli("run", pipeline(tmp_path, mode, execute=GIMBAL, **ends), "--quiet")
    assert code == 1, err
    assert "Traceback" not in err and "internal error" not in err
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    first, bad, device = document["stages"]
    # the earlier stage survives intact; its clearance is measured on the scene (3 mm in the left gap),
    # not the plugin's claim (0.5 m)
    assert first["status"] == "solved" and len(first["path"]) == 2
    assert first["metrics"]["min_clearance_m"] == pytest.approx(0.003, abs=1e-9)
    assert bad["status"] == "invalid_result" and bad["path"] == []
    expected = "plan plugin 'hostile' (surgiplan-hostile 1.0) returned an invalid result: "
    assert bad["message"].startswith(expected) and problem in bad["message"], bad["message"]
    assert f"plan stage 'bad': invalid_result: {expected}" in err
    # nothing downstream ran on it: the gimbal was never even configured
    assert device["status"] == "skipped" and "plan stage 'bad' ended 'invalid_result'" in device["message"]
    assert document["status"] == "failed" and not (tmp_path / "out" / ".in-progress.json").exists()


def test_a_plugin_that_raises_ends_its_stage_with_error_and_the_record_is_kept(cli, tmp_path, hostile):
    extra = [{"stage": "plan", "name": "later", "plugin": "hostile", "start": "entry", "goal": "target"}]
    code, _, err = cli("run", pipeline(tmp_path, "raises", extra=extra), "--quiet")
    assert code == 1
    assert (
        "plugin 'hostile' (surgiplan-hostile 1.0) failed in query of plan stage 'bad': "
        "RuntimeError: the hostile planner fails on purpose" in err
    )
    assert "result.json" in err and "Traceback" not in err
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    assert document["status"] == "error"
    assert [s["status"] for s in document["stages"]] == ["solved", "error"]
    assert document["stages"][1]["message"].startswith("plugin 'hostile' (surgiplan-hostile 1.0) failed in query")
    assert document["not_run"] == [{"stage": "plan", "name": "later", "plugin": "hostile"}]


@pytest.mark.parametrize(
    ("stage", "status", "message"),
    [
        (
            {"stage": "execute", "plugin": "hostile_device", "path_from": "first"},
            "invalid_result",
            "execute plugin 'hostile_device' (surgiplan-hostile 1.0) returned an invalid result: status 'done' "
            "is not an execute status (completed, refused, stopped)",
        ),
        (
            {"stage": "execute", "plugin": "hostile_device", "path_from": "first", "settings": {"mode": "raises"}},
            "error",
            "plugin 'hostile_device' (surgiplan-hostile 1.0) failed in execute of execute stage",
        ),
        (
            {"stage": "simulate", "plugin": "hostile_model"},
            "invalid_result",
            "simulate plugin 'hostile_model' (surgiplan-hostile 1.0) returned an invalid result: status 'ok' is "
            "not a simulate status (completed, converged, failed)",
        ),
        (
            {"stage": "simulate", "plugin": "hostile_model", "settings": {"mode": "raises"}},
            "error",
            "plugin 'hostile_model' (surgiplan-hostile 1.0) failed in run_stage of simulate stage",
        ),
    ],
    ids=["device-status", "device-raises", "model-status", "model-raises"],
)
def test_devices_and_models_with_unknown_statuses_or_crashes(cli, tmp_path, hostile, stage, status, message):
    path = pipeline(tmp_path, "honest", extra=[{"name": "x", **stage}])
    code, _, err = cli("run", path, "--quiet")
    assert code == 1 and "Traceback" not in err
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    assert [s["status"] for s in document["stages"]] == ["solved", "solved", status]
    assert message in document["stages"][-1]["message"], document["stages"][-1]["message"]


# ----------------------------------------------------------------------------- no orphans, no stale records


def _children(pid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _start_and_kill(tmp_path, hostile, out) -> tuple[list[int], subprocess.Popen]:
    """Run a pipeline whose planner hangs in two workers; kill -9 the run once both workers are busy."""
    path = pipeline(tmp_path, "hang", workers=2, out=out)
    process = subprocess.Popen(
        [sys.executable, "-m", "surgiplan.cli", "run", str(path), "--quiet"],
        env=hostile,
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    workers: list[int] = []
    for _ in range(600):  # up to 60 s for the pool to start
        workers = [c for c in _children(process.pid) if "python" in Path(f"/proc/{c}/cmdline").read_bytes().decode()]
        if len(workers) >= 2 or process.poll() is not None:
            break
        time.sleep(0.1)
    assert process.poll() is None, process.stderr.read().decode()
    assert len(workers) >= 2, workers
    time.sleep(0.5)  # the tasks are running (each sleeps 120 s)
    os.kill(process.pid, signal.SIGKILL)
    process.wait(timeout=10)
    return workers, process


@pytest.mark.slow
def test_kill_9_of_a_run_leaves_no_worker_behind_and_no_stale_record(tmp_path, hostile):
    out = tmp_path / "out"
    # a finished run first: its result.json must not survive beside the next run's files
    done = subprocess.run(
        [sys.executable, "-m", "surgiplan.cli", "run", str(pipeline(tmp_path, "honest", out=out)), "--quiet"],
        env=hostile,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert (out / "result.json").exists()

    workers, process = _start_and_kill(tmp_path, hostile, out)
    for _ in range(100):  # the workers notice within PARENT_POLL_S (0.2 s); allow 10 s
        if not any(_alive(pid) for pid in workers):
            break
        time.sleep(0.1)
    left = [pid for pid in workers if _alive(pid)]
    for pid in left:  # do not leave them to the next test
        os.kill(pid, signal.SIGKILL)
    assert not left, f"worker processes {left} outlived the killed run"
    # the directory says what it is: a run that did not finish, never the previous run's result
    assert not (out / "result.json").exists()
    marker = json.loads((out / ".in-progress.json").read_text())
    assert marker["pid"] == process.pid and [s["name"] for s in marker["stages_so_far"]] == ["first"]

    # the next run into the same directory completes and clears the marker
    again = subprocess.run(
        [sys.executable, "-m", "surgiplan.cli", "run", str(pipeline(tmp_path, "honest", out=out)), "--quiet"],
        env=hostile,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert again.returncode == 0, again.stderr
    assert json.loads((out / "result.json").read_text())["status"] == "succeeded"
    assert not (out / ".in-progress.json").exists()


def test_a_stale_in_progress_marker_alone_does_not_refuse_a_directory(cli, tmp_path, hostile):
    """Who writes to a directory is the lock's business (tests/test_output_lock.py), not a marker's PID: a
    killed run's marker whose PID was reused by another process must not lock the directory forever."""
    out = tmp_path / "out"
    out.mkdir()
    (out / ".in-progress.json").write_text(json.dumps({"pid": 1, "pipeline_file": "other.yaml", "started": "x"}))
    code, _, err = cli("run", pipeline(tmp_path, "honest"), "--quiet")
    assert code == 0, err
    assert not (out / ".in-progress.json").exists() and (out / "result.json").exists()


# ----------------------------------------------------------------------------- hostile files


def _bomb(levels: int = 9, width: int = 9) -> str:
    text = "name: bomb\nlol0: &l0 [" + ", ".join(['"lol"'] * width) + "]\n"
    for i in range(1, levels + 1):
        text += f"lol{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * width) + "]\n"
    return text + f"pipeline: *l{levels}\n"


def test_an_alias_bomb_is_refused_with_bounded_memory(cli, tmp_path):
    path = tmp_path / "bomb.yaml"
    path.write_text(_bomb())  # 9^10 = 3.5e9 values if expanded
    tracemalloc.start()
    try:
        code, _, err = cli("validate", path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert code == 2
    assert "bomb.yaml:" in err and "expands to more than 1,000,000 values" in err
    assert peak < 20e6, f"{peak / 1e6:.1f} MB"  # the expansion would take gigabytes


def test_a_billion_laughs_just_below_the_budget_still_loads():
    from surgiplan.yamlio import parse_yaml

    data, _ = parse_yaml(_bomb(levels=5, width=8))  # 8^6 = 262,144 scalars, twice: within the budget
    assert len(data["pipeline"]) == 8 and data["pipeline"][0][0][0][0][0] == data["lol0"]


@pytest.mark.parametrize(
    ("text", "value"),
    [("1.4e2", 140.0), ("1e-3", 0.001), ("-2.5E+3", -2500.0), (".5", 0.5), ("1_000", 1000), ("'1e3'", "1e3")],
)
def test_yaml_1_2_numbers_are_numbers(text, value):
    from surgiplan.yamlio import parse_yaml

    data, _ = parse_yaml(f"x: {text}\n")
    assert data["x"] == value and type(data["x"]) is type(value)


def test_exponent_lengths_are_read_as_numbers_in_the_files_unit(tmp_path, hostile):
    from surgiplan import load_pipeline

    path = pipeline(tmp_path, "honest")
    data = yaml.safe_load(path.read_text())
    data["scene"] = str(CONFIGS / "scenes" / "block_world.yaml")
    data["pipeline"][1]["goal"] = [140, 50, 20]
    text = yaml.safe_dump(data, sort_keys=False).replace("- 140\n", "- 1.4e2\n", 1)
    assert "1.4e2" in text
    path.write_text(text)
    loaded = load_pipeline(path)
    np.testing.assert_allclose(loaded.stages[1].goal, [0.140, 0.050, 0.020])


def test_random_bytes_as_an_stl_are_not_an_obstacle(cli, tmp_path):
    import struct

    rng = np.random.default_rng(7)
    count = 300
    (tmp_path / "noise.stl").write_bytes(b"\0" * 80 + struct.pack("<I", count) + rng.bytes(50 * count))
    scene = {
        "bounds": {"min": [0, 0, 0], "max": [150, 100, 40]},
        "obstacles": [{"name": "noise", "mesh": "noise.stl"}],
        "points": {"a": [1, 1, 1], "b": [9, 9, 9]},
    }
    path = tmp_path / "p.yaml"
    stage = {"stage": "plan", "plugin": "safe_prm", "start": "a", "goal": "b"}
    data = {
        "name": "n",
        "length_unit": "mm",
        "scene": scene,
        "pipeline": [stage],
        "output": {"dir": str(tmp_path / "o")},
    }
    path.write_text(yaml.safe_dump(data))
    code, _, err = cli("validate", path)
    assert code == 2
    assert "scene.obstacles[0].mesh:" in err and "noise.stl" in err and "non-finite coordinates" in err
    assert not (tmp_path / "o").exists()


def test_memory_estimates_refuse_work_the_machine_cannot_hold(cli, tmp_path, with_example_plugin, monkeypatch):
    from conftest import write

    text = (
        "name: big\nlength_unit: mm\n"
        "scene: {bounds: {min: [0, 0, 0], max: [150, 100, 40]}, points: {a: [1, 1, 1], b: [9, 9, 9]}}\n"
        "pipeline:\n  - stage: plan\n    plugin: via_point\n    settings:\n      via_points: 1000000000000\n"
        "    start: a\n    goal: b\n"
    )
    path = write(tmp_path / "p.yaml", text)
    monkeypatch.setenv("SURGIPLAN_MEMORY_LIMIT", "16G")
    code, _, err = cli("validate", path)
    assert code == 2
    assert "p.yaml:8: pipeline[0].settings.via_points: 1,000,000,000,000 via points" in err
    assert "needs about" in err and "TiB of memory; this machine allows 12.8 GiB (80% of 16 GiB)" in err
