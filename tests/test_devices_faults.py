"""Faults, each injected from the simulated bus's settings (as a pipeline file does), each checked on
the simulated hardware's ground truth (state transitions, positions) and the frames on the wire."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from conftest import CONFIGS, assert_error_record
from devices_support import FULCRUM, GAP_TIPS, active, context, execute, gimbal_path, gimbal_space
from surgiplan.devices import LifecycleState, Trajectory
from surgiplan.plugins.devices.canopen import cia402 as p402
from surgiplan.plugins.devices.canopen.bus import BusError
from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice

STOPPED = {p402.QUICK_STOP_ACTIVE, p402.FAULT, p402.SWITCH_ON_DISABLED}


def with_faults(*faults, **settings):
    return {"fulcrum": FULCRUM, "bus": {"faults": list(faults)}, **settings}


@pytest.fixture
def gap_path(block_world):
    space = gimbal_space(block_world)
    return gimbal_path(space, GAP_TIPS), space


def stop_times(truth) -> dict[int, float]:
    """When each node (ground truth) left OPERATION ENABLED for a stopped state, after the start."""
    origin = truth["trajectory_start"]
    out = {}
    for t, node, old, new in truth["transitions"]:
        if t > origin and old == p402.OPERATION_ENABLED and new in STOPPED and node not in out:
            out[node] = t - origin
    return out


def assert_standstill(truth):
    np.testing.assert_allclose(truth["velocities"], 0.0, atol=5e-3)


def test_heartbeat_loss_quick_stops_every_axis_within_two_heartbeat_periods(block_world, tmp_path, gap_path):
    path, space = gap_path
    settings = with_faults({"kind": "heartbeat_loss", "node": 2, "at_s": 0.3}, heartbeat_period=0.1)
    report, truth = execute(CastGimbalDevice, settings, path, space, block_world, tmp_path)
    assert report.status == "stopped"
    assert "heartbeat timeout on node 2" in report.message
    first = report.faults[0]
    assert (first["kind"], first["node"], first["action"]) == ("heartbeat_timeout", 2, "quick stop of every axis")
    # on the wire: node 2's heartbeats stop at 0.3 s, the others' go on
    origin = truth["trajectory_start"]
    beats = {n: [t - origin for t, i, _ in truth["frames"] if i == 0x700 + n and t > origin] for n in (1, 2, 3, 4)}
    assert max(beats[2]) <= 0.3 and max(beats[1]) > 0.4
    # ground truth: every axis quick-stopped within two heartbeat periods of the loss
    stops = stop_times(truth)
    assert set(stops) == {1, 2, 3, 4}
    assert max(stops.values()) <= 0.3 + 2 * 0.1
    assert all(s == p402.QUICK_STOP_ACTIVE for s in truth["states"])
    assert_standstill(truth)
    assert first["all_axes_quick_stopped_s"] <= 0.5 and first["standstill_s"] >= first["all_axes_quick_stopped_s"]


def test_following_error_sends_emcy_and_stops_every_axis(block_world, tmp_path, gap_path):
    path, space = gap_path
    settings = with_faults({"kind": "following_error", "node": 3, "at_s": 0.3, "load": 2.0, "duration_s": 0.2})
    report, truth = execute(CastGimbalDevice, settings, path, space, block_world, tmp_path)
    assert report.status == "stopped"
    assert "emcy on node 3: following error" in report.message
    first = report.faults[0]
    assert (first["kind"], first["node"], first["code"]) == ("emcy", 3, "0x8611")
    # the EMCY frame of node 3 (0x83) with the following-error code, after the jam began
    origin = truth["trajectory_start"]
    emcy = [(t - origin, d) for t, i, d in truth["frames"] if i == 0x83 and t > origin]
    assert emcy and struct.unpack_from("<H", emcy[0][1])[0] == p402.EMCY_FOLLOWING_ERROR
    assert 0.3 < emcy[0][0] < 0.3 + 0.1
    # node 3 faulted (brake), the others quick-stopped right after the EMCY
    states = dict(zip(truth["node_ids"], truth["states"], strict=True))
    assert states[3] == p402.FAULT
    assert {states[n] for n in (1, 2, 4)} == {p402.QUICK_STOP_ACTIVE}
    stops = stop_times(truth)
    assert all(stops[n] <= emcy[0][0] + 3 * truth["period"] for n in (1, 2, 4))
    assert_standstill(truth)


@pytest.mark.parametrize(("seed", "outcome"), [(0, "completed"), (14, "stopped")])
def test_one_percent_frame_loss_completes_within_tolerance_or_stops_safely(
    block_world, tmp_path, gap_path, seed, outcome
):
    """A lost SYNC, RPDO or TPDO costs a cycle of a stale target or reading: the motion completes.
    A lost heartbeat looks like a silent node within the time-out: the device stops safely and says
    why. Seed 0 loses no heartbeat during the motion, seed 14 loses one of node 4's."""
    path, space = gap_path
    settings = with_faults({"kind": "frame_loss", "rate": 0.01, "seed": seed})
    report, truth = execute(CastGimbalDevice, settings, path, space, block_world, tmp_path)
    m = report.metrics
    assert m["frames_dropped"] > 10
    assert report.status == outcome
    if outcome == "completed":
        # within the drives' following-error window (1 mm, 0.01 rad) and ending where the path ends
        assert m["tracking_error_max_m"] < 1e-3
        assert np.all(np.abs(truth["positions"] - path[-1]) <= 3.0 / truth["counts_per_unit"])
        assert m["samples_missing"] > 0  # lost TPDOs were noticed, not counted as tracking
    else:
        first = report.faults[0]
        assert first["kind"] == "heartbeat_timeout" and first["node"] == 4
        assert "dropped this node's heartbeat" in first["cause"]
        assert all(s == p402.QUICK_STOP_ACTIVE for s in truth["states"])
        assert_standstill(truth)


def test_a_node_dying_during_the_motion_stops_every_axis(block_world, tmp_path, gap_path):
    path, space = gap_path
    report, truth = execute(
        CastGimbalDevice,
        with_faults({"kind": "dead_node", "node": 4, "at_s": 0.3}),
        path,
        space,
        block_world,
        tmp_path,
    )
    assert report.status == "stopped"
    first = report.faults[0]
    assert first["node"] == 4 and first["kind"] in ("pdo_timeout", "heartbeat_timeout")
    assert "node 4" in report.message
    stops = stop_times(truth)
    assert set(stops) >= {1, 2, 3} and max(stops[n] for n in (1, 2, 3)) <= 0.3 + 0.2
    assert_standstill(truth)


def test_bus_off_during_the_motion_stops_the_drives_by_their_own_watchdog(block_world, tmp_path, gap_path):
    path, space = gap_path
    report, truth = execute(
        CastGimbalDevice, with_faults({"kind": "bus_off", "at_s": 0.3}), path, space, block_world, tmp_path
    )
    assert report.status == "stopped"
    assert report.message.startswith("CAN bus error") and "bus-off" in report.message
    assert report.faults[-1]["kind"] == "bus_error"
    # the drives see no more SYNC: their commands freeze where the last target left them. An axis moving
    # fast cannot stop that abruptly: following error, FAULT, brake (EMCY 0x8611); the others quick-stop
    # by their SYNC watchdog (50 ms, checked every 10 ms; EMCY 0x8730). Either way within 60 ms.
    origin = truth["trajectory_start"]
    last_sync = max(t for t, i, _ in truth["frames"] if i == 0x80) - origin
    assert 0.3 - truth["period"] <= last_sync < 0.3
    stops = stop_times(truth)
    assert set(stops) == {1, 2, 3, 4}
    assert all(last_sync < t <= last_sync + 0.05 + 0.01 + 1e-9 for t in stops.values())
    states = dict(zip(truth["node_ids"], truth["states"], strict=True))
    expected = {p402.QUICK_STOP_ACTIVE: p402.EMCY_SYNC_LOST, p402.FAULT: p402.EMCY_FOLLOWING_ERROR}
    for node in (1, 2, 3, 4):
        emcy = [d for t, i, d in truth["frames"] if i == 0x80 + node and t > origin]
        assert struct.unpack_from("<H", emcy[0])[0] == expected[states[node]]
        if states[node] == p402.QUICK_STOP_ACTIVE:
            assert stops[node] > last_sync + 0.05
    assert p402.QUICK_STOP_ACTIVE in states.values()
    assert_standstill(truth)


@pytest.mark.parametrize(
    ("bus", "match"),
    [
        ({"interface": "virtual", "faults": [{"kind": "bus_off"}]}, "bus-off"),
        ({"interface": "virtual", "faults": [{"kind": "dead_node", "node": 2}]}, "node 2 \\(joint 'pitch'\\)"),
        ({"interface": "socketcan", "channel": "surgiplan-can9"}, "socketcan' channel 'surgiplan-can9'"),
    ],
)
def test_no_bus_or_a_bus_error_is_a_clear_error_before_any_motion(block_world, tmp_path, bus, match):
    device = CastGimbalDevice(CastGimbalDevice.Settings.model_validate({"fulcrum": FULCRUM, "bus": bus}))
    with pytest.raises(BusError, match=match):
        device.configure(context(block_world, tmp_path))
    assert device.state is LifecycleState.ERROR
    assert device.simulator is None and device.bus is None  # nothing left running, nothing moved
    device.shutdown()


def test_a_fault_reset_brings_the_drive_back(block_world, tmp_path, gap_path):
    path, space = gap_path
    settings = with_faults({"kind": "following_error", "node": 3, "at_s": 0.3, "duration_s": 0.1})
    with active(CastGimbalDevice, settings, block_world, tmp_path) as device:
        report = device.execute(Trajectory(path, space, "test"))
        assert report.status == "stopped"
        states = device.drive_states()
        assert states["insertion"] == p402.FAULT
        # a stopped device does not start again by itself
        refused = device.execute(Trajectory(path, space, "test"))
        assert refused.metrics["refused"] and "reset_faults() (a fault reset and re-enable) first" in refused.message
        assert "'insertion' is FAULT" in refused.message
        device.reset_faults()
        assert set(device.drive_states().values()) == {p402.OPERATION_ENABLED}
        # and it moves again: the rest of the way to the goal from where it stopped
        rest = np.concatenate([device.joint_positions()[None], path[-1:]])
        again = device.execute(Trajectory(rest, space, "test"))
        assert again.status == "completed", again.message
        assert np.all(np.abs(device.simulator.positions() - path[-1]) <= 2.0 / device.controller.cpu)


def test_fault_reset_after_a_stop_can_be_rehearsed_from_the_settings(block_world, tmp_path, gap_path):
    path, space = gap_path
    settings = with_faults({"kind": "following_error", "node": 1, "at_s": 0.2}, fault_reset=True)
    report, truth = execute(CastGimbalDevice, settings, path, space, block_world, tmp_path)
    assert report.status == "stopped"
    assert report.metrics["fault_reset"]["ok"] is True
    assert set(report.metrics["fault_reset"]["states"].values()) == {p402.OPERATION_ENABLED}
    assert set(truth["states"]) == {p402.OPERATION_ENABLED}  # ground truth: every drive is back


# ----------------------------------------------------------------------------- the pipeline files
FAULT_PIPELINES = [
    ("faults_following_error.yaml", "stopped", "emcy on node 3: following error"),
    ("faults_frame_loss.yaml", "completed", None),
    ("faults_dead_node.yaml", BusError, "CAN node 3 (joint 'insertion')"),
    ("faults_bus_off.yaml", "stopped", "CAN bus error"),
    ("faults_no_bus.yaml", BusError, "cannot open CAN bus interface 'socketcan' channel 'can0'"),
]


@pytest.fixture(scope="module")
def roadmap(tmp_path_factory):
    """The fault files share their plan stage: build its roadmap once, load it in the others."""
    return tmp_path_factory.mktemp("roadmap") / "gimbal-roadmap.npz"


def test_the_heartbeat_loss_file_rehearses_it_from_the_command_line(cli, tmp_path):
    out = tmp_path / "out"
    status, stdout, stderr = cli("run", CONFIGS / "faults_heartbeat_loss.yaml", "--out", out)
    assert status == 1, stdout + stderr  # a stage did not succeed
    assert "heartbeat timeout on node 2" in stdout + stderr
    stage = json.loads((out / "result.json").read_text())["stages"][1]
    assert stage["status"] == "stopped"
    first = stage["metrics"]["faults"][0]
    assert (first["kind"], first["node"], first["action"]) == ("heartbeat_timeout", 2, "quick stop of every axis")
    assert first["all_axes_quick_stopped_s"] <= 0.3 + 2 * 0.1
    assert {"gimbal.png", "gimbal-execution.csv"} <= set(stage["files"])
    assert (out / "gimbal.png").stat().st_size > 10_000


@pytest.mark.slow
@pytest.mark.parametrize(("name", "outcome", "message"), FAULT_PIPELINES)
def test_every_fault_can_be_rehearsed_from_its_pipeline_file(tmp_path, roadmap, name, outcome, message):
    from surgiplan import load_pipeline, run_pipeline

    out = tmp_path / "out"
    pipeline = load_pipeline(CONFIGS / name, output_dir=out)
    pipeline.model.output.figures = pipeline.model.output.gltf = False  # the files' content is what is tested
    pipeline.stages[0].artifact = roadmap
    if outcome is BusError:  # a user error before any motion: the CLI prints it (exit 2); the record is kept
        with pytest.raises(BusError) as info:
            run_pipeline(pipeline)
        assert message in str(info.value) and "pipeline[1] (execute stage 'gimbal')" in str(info.value)
        document = assert_error_record(out, message, stage="gimbal")
        assert document["stages"][0]["status"] == "solved"  # the plan before it survives, intact
        return
    outcome_run = run_pipeline(pipeline)
    execute_stage = json.loads((out / "result.json").read_text())["stages"][1]
    assert execute_stage["status"] == outcome == outcome_run.results[1].status
    metrics = execute_stage["metrics"]
    for key in ("tracking_error_max_m", "executed_min_clearance_m", "bus_load_percent", "cycles", "faults"):
        assert key in metrics
    if outcome == "stopped":
        assert message in execute_stage["message"] and metrics["faults"]
        if name == "faults_following_error.yaml":  # it also rehearses the recovery
            assert metrics["fault_reset"]["ok"] is True
            assert set(metrics["fault_reset"]["states"].values()) == {p402.OPERATION_ENABLED}
    else:
        assert metrics["faults"] == [] and metrics["frames_dropped"] > 0
