"""Simulated CiA 402 drives and the CANopen master, on the simulated clock.

Every check reads what went over the bus (the master's frame log) or the simulated hardware's
ground truth (positions, velocities, state transitions), never the master's own bookkeeping.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
from devices_support import configured_gimbal
from surgiplan.plugins.devices.canopen import cia402


@pytest.fixture
def gimbal(block_world, tmp_path):
    with configured_gimbal(block_world, tmp_path, {"simulation": {"initial": [0.0, 0.6, 0.12, 0.0]}}) as device:
        yield device


def frames(device, can_id, start=0.0, end=np.inf):
    return [f for f in device.bus.frames if f[1] == can_id and start <= f[0] < end]


def cycle(device, k, targets, words=cia402.CW_ENABLE_OPERATION):
    """Cycle k at t = k T: SYNC, then the RPDOs (controlword, target counts) of every axis."""
    device.clock.sleep_until(k * device.master.period)
    n = len(device.master.axes)
    device.master.exchange([words] * n, np.asarray(targets, dtype=np.int64))


def enabled(device):
    device.controller.enable()
    return device.controller.hold.copy(), round(device.clock.now() / device.master.period) + 1


def test_master_configures_every_drive_by_sdo_and_starts_them(gimbal):
    period = gimbal.master.period
    for axis in gimbal.master.axes:
        node = gimbal.simulator.nodes[axis.node_id]  # the drive's own object dictionary
        assert node.nmt.state == "OPERATIONAL"
        assert node.sdo[0x6060].raw == cia402.CSP
        value, index = node.sdo[0x60C2][1].raw, node.sdo[0x60C2][2].raw
        assert value * 10.0**index == pytest.approx(period)
        assert node.sdo[0x1017].raw == 100  # ms
        assert node.sdo[0x6065].raw == round(axis.following_error_window * axis.counts_per_unit)
        assert node.sdo[0x607D][1].raw <= axis.lower * axis.counts_per_unit
        assert node.sdo[0x607D][2].raw >= axis.upper * axis.counts_per_unit
        assert node.sdo[0x605A].raw == 6
        # PDO mappings: RPDO1 controlword + target, TPDO1 statusword + position, both on SYNC
        assert [node.sdo[0x1600][i].raw for i in (0, 1, 2)] == [2, 0x60400010, 0x607A0020]
        assert [node.sdo[0x1A00][i].raw for i in (0, 1, 2)] == [2, 0x60410010, 0x60640020]
        assert node.sdo[0x1400][2].raw == 1 and node.sdo[0x1800][2].raw == 1
    # NMT start (command 0x01 to all or each node) went over the bus
    assert any(data[:1] == b"\x01" for _, _, data in frames(gimbal, 0x000))
    # the standard start-up, in order on the wire: reset communication, boot-up, SDO configuration, start
    log = [(i, d) for _, i, d in gimbal.bus.frames]
    for axis in gimbal.master.axes:
        n = axis.node_id
        reset = log.index((0x000, bytes([0x82, n])))
        boot = log.index((0x700 + n, b"\x00"), reset)
        sdo = next(k for k, (i, _) in enumerate(log) if i == 0x600 + n)
        start = log.index((0x000, bytes([0x01, n])))
        assert reset < boot < sdo < start
        # the drive consumes the master's heartbeat (node 127) with 1.5 x its period
        assert gimbal.simulator.nodes[n].sdo[0x1016][1].raw == (127 << 16) | 150
    # the master's own heartbeat (node 127, operational) every heartbeat period
    start = gimbal.clock.now()
    gimbal.clock.sleep_until(start + 0.35)
    beats = frames(gimbal, 0x77F, start)
    assert len(beats) == 3 and all(data == b"\x05" for _, _, data in beats)
    np.testing.assert_allclose(np.diff([t for t, _, _ in beats]), 0.1, atol=1e-9)


def test_each_drive_produces_heartbeats_at_its_period(gimbal):
    start = gimbal.clock.now() + 1e-6  # after the boot-up messages (0x700 + id, data 0x00)
    gimbal.clock.sleep_until(start + 1.0)
    for axis in gimbal.master.axes:
        beats = frames(gimbal, 0x700 + axis.node_id, start, start + 1.0)
        assert len(beats) == 10
        assert all(data == b"\x05" for _, _, data in beats)  # NMT state operational
        np.testing.assert_allclose(np.diff([t for t, _, _ in beats]), 0.1, atol=1e-9)


def test_every_sync_is_answered_by_a_tpdo_with_statusword_and_encoder_counts(gimbal):
    hold, k0 = enabled(gimbal)
    start = gimbal.clock.now()
    truth = []
    for k in range(k0, k0 + 50):
        cycle(gimbal, k, hold)
        truth.append(gimbal.simulator.positions())  # the true positions at this SYNC
    syncs = frames(gimbal, 0x080, start)
    assert len(syncs) == 50
    for j, axis in enumerate(gimbal.master.axes):
        tpdos = frames(gimbal, 0x180 + axis.node_id, start)
        assert len(tpdos) == 50
        for (_, _, data), true in zip(tpdos, truth, strict=True):
            statusword, counts = struct.unpack("<Hl", data)
            assert cia402.state_of(statusword) == cia402.OPERATION_ENABLED
            # an incremental encoder: whole counts, within half a count of the true position
            assert abs(counts - true[j] * axis.counts_per_unit) <= 0.5 + 1e-9


def test_motor_respects_its_velocity_and_current_limits_and_faults_on_following_error(gimbal):
    simulator = gimbal.simulator
    hold, k0 = enabled(gimbal)
    target = hold.copy()
    target[0] += int(0.5 * gimbal.master.axes[0].counts_per_unit)  # a 0.5 rad step of the yaw axis
    period = gimbal.master.period
    velocity, times = [], []
    for k in range(k0, k0 + 40):
        cycle(gimbal, k, target)
        for t in k * period + np.arange(16) * period / 16:  # the ground truth between SYNCs
            simulator.advance(t)
            velocity.append(simulator.vel[0])
            times.append(t)
    velocity, times = np.array(velocity), np.array(times)
    # a 0.5 rad step cannot be followed: the error stays beyond the 0.01 rad window for 10 ms
    node = gimbal.master.axes[0].node_id
    assert simulator_state(gimbal, 0) == cia402.FAULT
    fault = [tr for tr in simulator.transitions if tr[1] == node and tr[3] == cia402.FAULT]
    assert len(fault) == 1
    # while powered (before the fault reaction's brake), speed and torque stay within the drive's limits
    powered = times < fault[0][0] - 1e-9
    peak, vmax = simulator.peak[0], simulator.vmax[0]
    assert np.max(np.abs(velocity[powered])) <= vmax * (1 + 1e-9)
    assert np.max(np.abs(velocity[powered])) > 0.05  # it did move
    acceleration = np.abs(np.diff(velocity[powered])) / np.diff(times[powered])
    assert np.max(acceleration) <= peak + simulator.model.damping * vmax + 1e-6
    assert np.max(acceleration) > 0.9 * peak  # the step saturates the current
    emcy = frames(gimbal, 0x80 + node)
    assert emcy, "no EMCY on the bus"
    code, register = struct.unpack_from("<HB", emcy[-1][2])
    assert code == cia402.EMCY_FOLLOWING_ERROR and register & 0x01
    assert emcy[-1][0] == pytest.approx(fault[0][0], abs=period)
    # the fault reaction holds the axis (brake): no motion after the fault
    stopped_at = simulator.positions()[0]
    for k in range(k0 + 40, k0 + 60):
        cycle(gimbal, k, target)
    assert simulator.positions()[0] == stopped_at
    # the master's statusword says FAULT with the following-error bit; a fault reset brings it back
    assert gimbal.drive_states()["yaw"] == cia402.FAULT
    gimbal.controller.enable()
    assert set(gimbal.drive_states().values()) == {cia402.OPERATION_ENABLED}
    after_fault = [tr[2:] for tr in simulator.transitions if tr[1] == node and tr[0] > fault[0][0]]
    assert after_fault[0] == (cia402.FAULT, cia402.SWITCH_ON_DISABLED)  # transition 15: fault reset
    assert after_fault[-1][1] == cia402.OPERATION_ENABLED
    assert simulator_state(gimbal, 0) == cia402.OPERATION_ENABLED


def simulator_state(device, i):
    from surgiplan.plugins.devices.canopen.sim import statemachine

    return statemachine._STATES[device.simulator.state[i]]


def test_position_loop_settles_a_small_step_to_within_a_count(gimbal):
    simulator = gimbal.simulator
    hold, k0 = enabled(gimbal)
    target = hold.copy()
    target[2] += 500  # insertion: 0.5 mm at 1 count per um
    for k in range(k0, k0 + 100):  # 0.4 s
        cycle(gimbal, k, target)
    axis = gimbal.master.axes[2]
    assert abs(simulator.positions()[2] * axis.counts_per_unit - target[2]) <= 1.0
    assert simulator_state(gimbal, 2) == cia402.OPERATION_ENABLED


def test_quick_stop_ramps_down_at_the_configured_deceleration(gimbal):
    simulator = gimbal.simulator
    hold, k0 = enabled(gimbal)
    axis = gimbal.master.axes[0]
    period = gimbal.master.period
    speed = 0.8  # rad/s, reached with a ramp at 3 rad/s^2 (inside the 4 rad/s^2 limit)
    targets = hold.astype(float).copy()
    k = k0
    velocity = 0.0
    for k in range(k0, k0 + 150):
        velocity = min(speed, velocity + 3.0 * period)
        targets[0] += velocity * period * axis.counts_per_unit
        cycle(gimbal, k, np.round(targets))
    assert simulator.vel[0] == pytest.approx(speed, rel=0.02)
    cycle(gimbal, k + 1, np.round(targets), words=cia402.CW_QUICK_STOP)  # applied at the next SYNC
    cycle(gimbal, k + 2, np.round(targets), words=cia402.CW_QUICK_STOP)
    assert simulator_state(gimbal, 0) == cia402.QUICK_STOP_ACTIVE
    start = gimbal.clock.now()
    times = start + np.arange(1, 400) * 5e-4
    speeds, positions = [], []
    for t in times:
        gimbal.clock.sleep_until(t)
        simulator.advance(t)
        speeds.append(simulator.vel[0])
        positions.append(simulator.pos[0])
    speeds, positions = np.array(speeds), np.array(positions)
    moving = speeds > 0.1 * speed
    deceleration = -np.polyfit(times[moving], speeds[moving], 1)[0]
    assert deceleration == pytest.approx(axis.quick_stop_deceleration, rel=0.1)
    # at rest 0.8 / 8 = 0.1 s later: the position loop holds it within a count or two
    rest = positions[times > start + 0.15] * axis.counts_per_unit
    assert np.ptp(rest) <= 3.0
    assert simulator_state(gimbal, 0) == cia402.QUICK_STOP_ACTIVE  # option code 6 stays there


def test_a_drive_without_sync_quick_stops_by_itself_and_says_so(gimbal):
    simulator = gimbal.simulator
    hold, k0 = enabled(gimbal)
    for k in range(k0, k0 + 5):
        cycle(gimbal, k, hold)
    last_sync = gimbal.clock.now()
    gimbal.clock.sleep_until(last_sync + 0.1)  # the master falls silent
    timeout = simulator.model.sync_timeout
    for j, axis in enumerate(gimbal.master.axes):
        assert simulator_state(gimbal, j) == cia402.QUICK_STOP_ACTIVE
        entered = [tr[0] for tr in simulator.transitions if tr[1] == axis.node_id and tr[3] == "QUICK STOP ACTIVE"]
        # the watchdog runs every 10 ms: it trips within one round of the 50 ms time-out
        assert last_sync + timeout < entered[-1] <= last_sync + timeout + 0.01 + 1e-9
        emcy = frames(gimbal, 0x80 + axis.node_id, last_sync)
        assert struct.unpack_from("<H", emcy[0][2])[0] == cia402.EMCY_SYNC_LOST


def test_the_hand_is_interpolated_exactly_as_numpy_interpolates():
    """HandMotion (the compiled interpolation the motor model pulls torque-mode axes with) against np.interp, bit
    for bit: inside, on the knots, at and beyond both ends, repeated times, before it starts (its first row)."""
    from surgiplan.plugins.devices.canopen.sim.motor import HandMotion

    rng = np.random.default_rng(3)
    times = np.cumsum(rng.uniform(0.0, 0.02, 200))
    times[50] = times[49]  # a repeated time: np.interp takes the later row
    joints = rng.normal(size=(200, 4))
    hand = HandMotion(times, joints, start=10.0)
    u = np.concatenate([rng.uniform(times[0] - 0.5, times[-1] + 0.5, 500), times, [times[0], times[-1]]])
    clock = 10.0 + u
    expected = np.stack([np.interp(clock - 10.0, times, joints[:, k]) for k in range(4)], axis=1)
    assert np.array_equal(hand(clock), expected)  # an array of clock times: one row per time
    assert np.array_equal(hand(clock[7]), expected[7])  # one clock time: the axes' positions
    on_knots = HandMotion(times, joints, start=0.0)(times)  # each knot's row; the repeated time's later one
    assert np.array_equal(on_knots, joints[np.r_[:49, 50, 50:200]])
    assert np.array_equal(HandMotion(times, joints)(123.0), joints[0])  # not started: where it begins


def test_the_drives_kernels_compile_nothing_after_import():
    """In a fresh process: importing the motor model compiles its kernels (or loads them from numba's cache) for
    the types the simulator passes, so that drives in torque mode with a hand, and in position mode, compile no
    other specialisation (a drives' process would pay it at a SYNC)."""
    import json
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(
        """
        import json
        import can
        from surgiplan.plugins.devices.canopen.bus import ArmedFaults
        from surgiplan.plugins.devices.canopen.clock import SimulatedClock
        from surgiplan.plugins.devices.canopen.sim import motor
        from surgiplan.plugins.devices.canopen.sim.drives import AxisHardware, DriveSimulator
        from surgiplan.plugins.devices.canopen.sim.statemachine import OE

        before = [len(motor._integrate.signatures), len(motor._hand_at.signatures)]
        clock = SimulatedClock()
        bus = can.Bus(interface="virtual", channel="kernels")
        axes = [AxisHardware(k + 1, 1e4, 100.0, 50.0) for k in range(4)]
        sim = DriveSimulator(bus, axes, motor.MotorModel(), clock, ArmedFaults([], clock.now), None)
        sim.state[:] = OE
        for mode, hand in ((10, motor.HandMotion([0.0, 1.0], [[0.0] * 4, [0.1] * 4], 0.0)), (8, None)):
            sim.mode[:] = mode
            sim.move_by_hand(hand, 1.0, 0.1)
            sim.advance(clock.now() + 0.0123)
            clock.sleep(0.0123)
        sim.close()
        print(json.dumps({"before": before, "after": [len(motor._integrate.signatures),
                                                        len(motor._hand_at.signatures)]}))
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, check=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["before"] == [1, 1] and result["after"] == [1, 1]
