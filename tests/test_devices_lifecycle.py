"""The devices' lifecycle (ros2_control's): unconfigured -> inactive -> active -> finalized, and errors."""

from __future__ import annotations

import numpy as np
import pytest
from devices_support import FULCRUM, GAP_TIPS, context, gimbal_path, gimbal_space
from surgiplan.devices import LifecycleError, LifecycleState, Trajectory
from surgiplan.plugins.devices.canopen.bus import BusError
from surgiplan.plugins.devices.canopen.cia402 import OPERATION_ENABLED, READY, SWITCH_ON_DISABLED
from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice
from surgiplan.plugins.devices.gripper6 import Gripper6Device

START = [0.0, 0.6, 0.12, 0.0]


def gimbal(**settings) -> CastGimbalDevice:
    return CastGimbalDevice(
        CastGimbalDevice.Settings.model_validate(
            {"fulcrum": FULCRUM, "outputs": False, "simulation": {"initial": START}, **settings}
        )
    )


def test_lifecycle_states_and_what_each_allows(block_world, tmp_path):
    space = gimbal_space(block_world)
    path = gimbal_path(space, GAP_TIPS)
    trajectory = Trajectory(path, space, "test")
    device = gimbal()
    try:
        assert device.state is LifecycleState.UNCONFIGURED
        with pytest.raises(LifecycleError, match="unconfigured"):
            device.execute(trajectory)
        with pytest.raises(LifecycleError, match="configured"):
            device.joint_positions()

        device.configure(context(block_world, tmp_path))
        assert device.state is LifecycleState.INACTIVE
        # inactive: states are readable from the drives, commands are not accepted
        np.testing.assert_allclose(device.joint_positions(), START, atol=1e-4)
        assert set(device.drive_states().values()) == {SWITCH_ON_DISABLED}
        with pytest.raises(LifecycleError, match="inactive"):
            device.execute(trajectory)

        device.activate()
        assert device.state is LifecycleState.ACTIVE
        assert set(device.drive_states().values()) == {OPERATION_ENABLED}
        report = device.execute(trajectory)
        assert report.status == "completed", report.message
        reached = device.joint_positions()

        device.deactivate()
        assert device.state is LifecycleState.INACTIVE
        # disabled drives (READY TO SWITCH ON) with their brakes holding where the motion ended
        assert set(device.drive_states().values()) == {READY}
        np.testing.assert_allclose(device.joint_positions(), reached, atol=1e-4)
        with pytest.raises(LifecycleError):
            device.execute(trajectory)

        device.activate()  # and back again: commands accepted, from where it stands
        assert set(device.drive_states().values()) == {OPERATION_ENABLED}
        device.deactivate()
        device.cleanup()
        assert device.state is LifecycleState.UNCONFIGURED
        assert device.bus is None and device.master is None

        device.configure(context(block_world, tmp_path))  # a fresh bus after cleanup
        assert device.state is LifecycleState.INACTIVE
    finally:
        device.shutdown()
    assert device.state is LifecycleState.FINALIZED
    with pytest.raises(LifecycleError, match="finalized"):
        device.configure(context(block_world, tmp_path))


def test_transitions_out_of_order_are_refused(block_world, tmp_path):
    device = gimbal()
    with pytest.raises(LifecycleError, match="cannot activate a device that is unconfigured"):
        device.activate()
    with pytest.raises(LifecycleError, match="cannot deactivate"):
        device.deactivate()
    device.shutdown()
    assert device.state is LifecycleState.FINALIZED


def test_a_failed_configure_is_the_error_state_with_everything_released(block_world, tmp_path):
    import can.interfaces.virtual as virtual

    device = gimbal(bus={"faults": [{"kind": "dead_node", "node": 3}]})
    with pytest.raises(BusError, match=r"node 3 \(joint 'insertion'\).*does not answer"):
        device.configure(context(block_world, tmp_path))
    assert device.state is LifecycleState.ERROR
    assert device.bus is None and device.simulator is None
    assert device.channel not in virtual.channels  # both ends of the virtual bus were shut down
    device.shutdown()  # the error state's way out
    assert device.state is LifecycleState.FINALIZED


def test_settings_that_cannot_work_are_refused_when_configuring(block_world, tmp_path):
    cases = [
        ({"control_rate": 300}, "not representable"),
        ({"control_rate": 1000, "heartbeat_period": 0.005}, "at least 10 control periods"),
        ({"control_rate": 2000}, "lower control_rate to at most"),  # 4 drives do not fit on 1 Mbit/s
        ({"node_ids": [1, 2, 2, 4]}, "distinct CAN node ids"),
        ({"acceleration_limits": [1.0, 1.0]}, "give 4 values"),
        ({"simulation": {"initial": [0.0, 0.0, 0.5, 0.0]}}, "outside the joint limits"),
        ({"bus": {"interface": "socketcan", "channel": "can9", "faults": [{"kind": "bus_off"}]}}, "simulated bus"),
    ]
    for settings, message in cases:
        device = gimbal(**settings)
        with pytest.raises(Exception, match=message):
            device.configure(context(block_world, tmp_path))
        assert device.state is LifecycleState.ERROR
        device.shutdown()


def test_a_silent_drive_keeps_the_device_from_activating(block_world, tmp_path):
    """A drive that dies after configuration: its stale statusword must not pass for 'enabled'."""
    device = gimbal()
    try:
        device.configure(context(block_world, tmp_path))
        device.simulator._die(1)  # node 2 loses power
        with pytest.raises(BusError, match=r"node 2 \('pitch'\) does not answer SYNC"):
            device.activate()
        assert device.state is LifecycleState.ERROR
    finally:
        device.shutdown()
    assert device.state is LifecycleState.FINALIZED


def test_gripper6_has_the_same_lifecycle(block_world, tmp_path):
    device = Gripper6Device(Gripper6Device.Settings.model_validate({"outputs": False}))
    try:
        device.configure(context(block_world, tmp_path))
        assert len(device.drive_states()) == 6
        device.activate()
        assert set(device.drive_states().values()) == {OPERATION_ENABLED}
        device.deactivate()
    finally:
        device.shutdown()
    assert device.state is LifecycleState.FINALIZED
