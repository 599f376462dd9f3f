"""Real-time mode: the control loop paced by the monotonic clock, the drives in a thread or in a
process of their own reached over a real python-can interface (surgiplan's ``loopback``: a hub on
127.0.0.1, so nothing leaves the machine).

This machine is shared and loaded, so these tests give the supervision generous time-outs and check
what real time must deliver regardless: the pacing (median cycle period), the frames per cycle, and
that the motion arrives; timings themselves are measured in benchmarks/bench_devices.py.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest
from devices_support import FULCRUM, GAP_TIPS, active, gimbal_path, gimbal_space
from surgiplan.devices import Trajectory
from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice

#: lenient supervision for a shared, loaded machine, where a process may be descheduled for tens of
#: milliseconds: 100 Hz, a third of the speed limits, 1 s without TPDO, 1 s heartbeats, and a
#: following-error window (0.1 rad, 10 mm for 0.1 s) that a stalled master's frozen command stays in
LENIENT = {
    "control_rate": 100,
    "velocity_scale": 0.3,
    "pdo_timeout_cycles": 100,
    "heartbeat_period": 1.0,
    "following_error_window": [0.1, 0.1, 0.01, 0.1],
    "following_error_timeout": 0.1,
    "settle_time": 1.0,
}


def test_real_time_clock_paces_the_loop_at_the_control_rate(block_world, tmp_path):
    space = gimbal_space(block_world)
    path = gimbal_path(space, GAP_TIPS)
    settings = {"fulcrum": FULCRUM, "clock": "realtime", **LENIENT, "simulation": {"sync_timeout": 0.5}}
    with active(CastGimbalDevice, settings, block_world, tmp_path) as device:
        assert device.clock.realtime and device.simulator._thread is not None
        report = device.execute(Trajectory(path, space, "test"))
        log = device.last_log
        assert report.status == "completed", report.message
        # wall-clock pacing: the median cycle is the control period (sleeps are coarse, then spin)
        period = np.diff(log.wakeups)
        assert np.median(period) == pytest.approx(0.01, abs=5e-4)
        # the motion arrived: the drives' ground truth at the path's end
        assert np.all(np.abs(device.simulator.positions() - path[-1]) <= 3.0 / device.controller.cpu)
        assert report.metrics["tracking_error_rms_m"] < 1e-3  # within the following-error window


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.mark.slow
def test_drives_in_another_process_over_the_loopback_bus_with_the_real_hardware_code_path(block_world, tmp_path):
    """Real drives are a configuration change away: the same device, a real python-can interface,
    no simulator in this process (canopen's own receive thread), the drives in another process
    reached through the loopback hub on 127.0.0.1 that the drives' process hosts."""
    space = gimbal_space(block_world)
    path = gimbal_path(space, GAP_TIPS)
    port = _free_port()
    command = [sys.executable, "-m", "surgiplan.plugins.devices.canopen.sim.process", "--device", "cast_gimbal"]
    command += ["--interface", "loopback", "--channel", str(port), "--option", "hub=host"]
    command += ["--sync-timeout", "1.0", "--initial", *map(str, path[0])]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline().strip() == "ready"
        bus = {"interface": "loopback", "channel": port, "options": {"hub": "join"}}
        settings = {"fulcrum": FULCRUM, "bus": bus, **LENIENT}
        with active(CastGimbalDevice, settings, block_world, tmp_path) as device:
            assert device.simulator is None and device.clock.realtime  # the hardware code path
            np.testing.assert_allclose(device.joint_positions(), path[0], atol=1e-4)  # read by SDO
            report = device.execute(Trajectory(path, space, "test"))
            assert report.status == "completed", report.message
            np.testing.assert_allclose(device.joint_positions(), path[-1], atol=1e-4)
            m = report.metrics
            assert m["tracking_error_rms_m"] < 1e-3
            # per cycle on the wire: SYNC, 4 RPDOs, 4 TPDOs
            assert m["frames"] == pytest.approx(9 * m["cycles"], rel=0.05)
    finally:
        process.terminate()
        process.wait(timeout=10)
    assert process.returncode == 0


def test_realtime_priority_the_system_refuses_is_a_clear_error_before_anything_opens(
    block_world, tmp_path, monkeypatch
):
    import os

    from devices_support import context
    from surgiplan.errors import ConfigError

    def refuse(*_args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    settings = {"fulcrum": FULCRUM, "clock": "realtime", "realtime_priority": 20, "outputs": False}
    device = CastGimbalDevice(CastGimbalDevice.Settings.model_validate(settings))
    with pytest.raises(ConfigError, match=r"realtime_priority 20: .*SCHED_FIFO .*CAP_SYS_NICE"):
        device.configure(context(block_world, tmp_path))
    assert device.bus is None and device.simulator is None
    device.shutdown()


def test_realtime_priority_puts_the_loop_and_the_feedback_under_sched_fifo(block_world, tmp_path):
    import os

    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except OSError as exc:
        pytest.skip(f"this system does not allow SCHED_FIFO: {exc}")
    settings = {"fulcrum": FULCRUM, "clock": "realtime", **LENIENT, "realtime_priority": 5}
    settings["simulation"] = {"sync_timeout": 0.5}
    with active(CastGimbalDevice, settings, block_world, tmp_path) as device:
        hold = device.controller._hold_thread.native_id
        drives = device.simulator._thread.native_id
        assert os.sched_getscheduler(hold) == os.SCHED_FIFO and os.sched_getparam(hold).sched_priority == 5
        assert os.sched_getscheduler(drives) == os.SCHED_FIFO
        receive = [t.native_id for t in device.master.network.notifier._readers]
        assert receive and all(os.sched_getscheduler(tid) == os.SCHED_FIFO for tid in receive)
        assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the caller's thread only while a trajectory runs


def test_at_ordinary_priority_the_loops_threads_ask_for_a_short_slice(block_world, tmp_path):
    """Without realtime_priority the loop's threads stay ordinary (SCHED_OTHER) and ask EEVDF for the shortest slice
    (clock.LOOP_SLICE), so that their wake-up preempts a task that has run longer; the caller's thread only while a
    trajectory runs, as it was afterwards."""
    import os

    from surgiplan.plugins.devices.canopen.clock import LOOP_SLICE, restore_priority, sched_attr, set_realtime_priority

    before = sched_attr()
    asked = set_realtime_priority(None)
    granted = sched_attr()
    restore_priority(asked)
    if before is None or granted is None or granted.runtime != round(LOOP_SLICE * 1e9):
        pytest.skip(f"this kernel grants no slice to an ordinary thread ({os.uname().release})")
    assert sched_attr() == before
    space = gimbal_space(block_world)
    path = gimbal_path(space, GAP_TIPS)
    settings = {"fulcrum": FULCRUM, "clock": "realtime", **LENIENT, "simulation": {"sync_timeout": 0.5}}
    with active(CastGimbalDevice, settings, block_world, tmp_path) as device:
        threads = [device.controller._hold_thread.native_id, device.simulator._thread.native_id]
        threads += [t.native_id for t in device.master.network.notifier._readers]
        for tid in threads:
            attr = sched_attr(tid)
            assert attr.policy == os.SCHED_OTHER and attr.runtime == round(LOOP_SLICE * 1e9)
        assert device.execute(Trajectory(path, space, "test")).status == "completed"
        assert sched_attr() == before  # the caller's thread asked while the trajectory ran, and gave it back


def test_asked_to_the_drives_and_the_loops_keep_the_cpus_out_of_slow_idle_states_while_the_device_runs(
    block_world, tmp_path, monkeypatch
):
    """With SURGIPLAN_CPU_LATENCY_US=0 the drives' thread and the master's loops ask the kernel for a CPU wake-up
    latency of 0 (PM QoS, as cyclictest does): for as long as the device is active, and no longer."""
    from surgiplan.scheduling import CPU_LATENCY_ENV, cpu_latency_now

    before = cpu_latency_now()
    if before is None:
        pytest.skip("no PM QoS CPU latency interface to read here (not Linux, or not root)")
    assert before > 0
    monkeypatch.setenv(CPU_LATENCY_ENV, "0")
    space = gimbal_space(block_world)
    path = gimbal_path(space, GAP_TIPS)
    settings = {"fulcrum": FULCRUM, "clock": "realtime", **LENIENT, "simulation": {"sync_timeout": 0.5}}
    with active(CastGimbalDevice, settings, block_world, tmp_path) as device:
        assert cpu_latency_now() == 0
        assert device.execute(Trajectory(path[:20], space, "test")).status == "completed"
        assert cpu_latency_now() == 0
    assert cpu_latency_now() == before


def test_the_master_waits_for_a_syncs_answers_no_longer_than_it_is_told(block_world, tmp_path):
    """A real-time loop judges a SYNC's answers a whole period after the SYNC went (a SYNC that went late must not
    leave the drives less): DriveMaster.wait_for_answers returns as soon as every drive has answered the latest
    SYNC, and after its timeout, False, when one has not."""
    settings = {"fulcrum": FULCRUM, "clock": "realtime", **LENIENT, "simulation": {"sync_timeout": 0.5}}
    with active(CastGimbalDevice, settings, block_world, tmp_path) as device:
        master = device.master
        master.sync()
        assert master.wait_for_answers(2.0)
        assert master.feedback().current.all()
        device.simulator.sync_drop = SimpleNamespace(drop=lambda cob_id: True)  # every drive misses the next SYNC
        master.sync()
        started = time.perf_counter()
        assert not master.wait_for_answers(0.05)
        assert time.perf_counter() - started >= 0.05 - 1e-3
        assert not master.feedback().current.any()
        device.simulator.sync_drop = None
        master.sync()
        assert master.wait_for_answers(2.0)  # answered again: at once, not after the timeout


def test_a_fault_while_holding_quick_stops_every_axis_and_the_next_motion_is_refused_naming_it(block_world, tmp_path):
    """Between trajectories the device holds (SYNC and the hold targets go on in a thread). A node whose heartbeat
    stops then is a fault while holding: every axis is quick-stopped at once, the drives stay so, and the next
    trajectory is refused before any motion, naming the drives' states and the fault (which node, what)."""
    from surgiplan.plugins.devices.canopen import cia402 as p402

    space = gimbal_space(block_world)
    path = gimbal_path(space, GAP_TIPS)
    settings = {"fulcrum": FULCRUM, "clock": "realtime", **LENIENT, "heartbeat_period": 0.2}
    settings["simulation"] = {"sync_timeout": 0.5, "initial": list(map(float, path[0]))}
    with active(CastGimbalDevice, settings, block_world, tmp_path) as device:
        simulator = device.simulator
        assert set(device.drive_states().values()) == {p402.OPERATION_ENABLED}
        held = simulator.positions().copy()
        simulator.scheduler.call_at(device.clock.now(), simulator.nodes[2].nmt.stop_heartbeat)
        for _ in range(300):  # bounded: 3 s, the timeout is 0.3 s
            if set(device.drive_states().values()) == {p402.QUICK_STOP_ACTIVE}:
                break
            time.sleep(0.01)
        assert set(device.drive_states().values()) == {p402.QUICK_STOP_ACTIVE}
        faults = device.controller.pending_faults  # (a stall of this shared machine may add others)
        assert any(f["kind"] == "heartbeat_timeout" and f["node"] == 2 for f in faults), faults
        report = device.execute(Trajectory(path, space, "test"))
        assert report.metrics["refused"] and report.status != "completed"
        message = report.message
        assert "'pitch' is QUICK STOP ACTIVE" in message and "'yaw' is QUICK STOP ACTIVE" in message
        assert "while holding: heartbeat timeout on node 2 (no heartbeat for" in message
        assert "reset_faults()" in message
        # nothing moved: the axes stayed where they were held (quick stop from standstill)
        assert np.all(np.abs(simulator.positions() - held) <= 3.0 / device.controller.cpu)
