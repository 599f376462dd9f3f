"""surgiplan's master starts drives in another process the standard way (CiA 301/302): NMT reset
communication, every boot-up, SDO configuration from the EDS, PDO mapping, NMT start, 402 enable.

The drives are left by a "previous master" (canopen's own classes) in states a master cannot
configure without that sequence: one STOPPED (it answers no SDO), one with its TPDO1 invalidated
and remapped, one enabled and moving in CSP. The traffic, captured by python-can's logger, shows the
sequence and follows CiA 301.
"""

from __future__ import annotations

import numpy as np
import pytest
from canopen.sdo import SdoCommunicationError
from canopen_support import (
    GIMBAL_INITIAL,
    capture,
    cia301_violations,
    drives_process,
    master,
    node402,
    read_log,
)
from devices_support import FULCRUM, GAP_TIPS, active, context, gimbal_path, gimbal_space
from surgiplan.devices import Trajectory
from surgiplan.plugins.devices.canopen.bus import BusError
from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice

pytestmark = pytest.mark.slow

#: lenient supervision for a shared, loaded machine (see tests/test_devices_realtime.py)
LENIENT = {
    "control_rate": 100,
    "velocity_scale": 0.3,
    "pdo_timeout_cycles": 30,
    "heartbeat_period": 0.5,
    "following_error_window": [0.1, 0.1, 0.01, 0.1],
    "following_error_timeout": 0.1,
    "settle_time": 1.0,
    "sdo_timeout": 1.0,
}


def test_the_standard_start_up_configures_drives_a_previous_master_left_in_any_state(block_world, tmp_path):
    space = gimbal_space(block_world)
    path = gimbal_path(space, GAP_TIPS)
    log = tmp_path / "start-up.blf"
    with drives_process("cast_gimbal", initial=path[0], sync_timeout=1.0) as port:
        with master(port) as network:  # the previous master
            nodes = [node402(network, i + 1, joint) for i, joint in enumerate(["yaw", "pitch", "insertion", "roll"])]
            node1, node2, node3 = nodes[:3]
            node3.tpdo.read()
            node3.tpdo[1].clear()
            node3.tpdo[1].add_variable(0x6041)
            node3.tpdo[1].enabled = False
            node3.tpdo.save()
            node3.sdo[0x1017].raw = 0
            # node 1 enabled in CSP, following a SYNC stream, when the previous master goes away
            node1.sdo[0x2000].raw = 2000
            node1.tpdo.read()
            node1.rpdo.read()
            node1.setup_402_state_machine(read_pdos=False)
            node1.rpdo[1][0x607A].raw = node1.sdo[0x6064].raw  # RPDO1 (controlword + target) holds
            node1.nmt.state = "OPERATIONAL"
            network.sync.start(0.01)
            node1.op_mode = "CYCLIC SYNCHRONOUS POSITION"
            node1.state = "OPERATION ENABLED"
            assert node1.state == "OPERATION ENABLED"
            node2.nmt.state = "STOPPED"
            node2.sdo.RESPONSE_TIMEOUT, node2.sdo.MAX_RETRIES = 0.3, 1
            with pytest.raises(SdoCommunicationError):  # without an NMT reset, nothing configures node 2
                node2.sdo[0x1000].raw  # noqa: B018
        bus = {"interface": "loopback", "channel": port, "options": {"hub": "join"}}
        with capture(port, log):
            with active(CastGimbalDevice, {"fulcrum": FULCRUM, "bus": bus, **LENIENT}, block_world, tmp_path) as dev:
                report = dev.execute(Trajectory(path, space, "test"))
                assert report.status == "completed", report.message
                np.testing.assert_allclose(dev.joint_positions(), path[-1], atol=1e-4)
                configured = list(dev.master.configuration)
    frames = read_log(log)
    ids = [m.arbitration_id for m in frames]
    data = [bytes(m.data) for m in frames]
    pairs = list(zip(ids, data, strict=True))

    def first(can_id: int, payload: bytes | None = None, after: int = 0) -> int:
        return next(k for k in range(after, len(pairs)) if ids[k] == can_id and payload in (None, data[k]))

    for node in (1, 2, 3, 4):
        reset = first(0x000, bytes([0x82, node]))  # reset communication, addressed to the node
        boot = first(0x700 + node, b"\x00", after=reset)
        first_sdo = first(0x600 + node, after=reset)
        start = first(0x000, bytes([0x01, node]))
        assert reset < boot < first_sdo < start  # reset, boot-up, SDO configuration, then start
        assert 0x180 + node not in ids[reset:start]  # no PDO before it is started
    # what the master configured, from the EDS (a DCF's values): heartbeat, consumer of ours, CSP, ...
    names = {name for _, name, _ in configured}
    expected = {"Producer heartbeat time 0x1017", "Consumer heartbeat time 1 0x1016:1", "Modes of operation 0x6060"}
    assert expected <= names
    lengths = {cob + n: 6 for n in (1, 2, 3, 4) for cob in (0x180, 0x200)}
    assert cia301_violations(frames, {1, 2, 3, 4}, lengths) == []
    # the drives consumed our heartbeat (node 127) at the period configured
    assert ids.count(0x77F) >= 2


def test_a_node_that_sends_no_boot_up_is_named_before_anything_moves(block_world, tmp_path):
    with drives_process("cast_gimbal", initial=GIMBAL_INITIAL, node_ids=[1, 2, 3, 9]) as port:
        bus = {"interface": "loopback", "channel": port, "options": {"hub": "join"}}
        device = CastGimbalDevice(
            CastGimbalDevice.Settings.model_validate({"fulcrum": FULCRUM, "bus": bus, "outputs": False, **LENIENT})
        )
        with pytest.raises(BusError) as info:
            device.configure(context(block_world, tmp_path))
        device.shutdown()
    message = str(info.value)
    assert "CAN node 4 (joint 'roll')" in message and "no boot-up message within 1 s" in message
    assert "node 1 " not in message and "node 9" not in message
