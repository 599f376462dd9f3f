"""CiA 301 / CiA 402 conformance of the simulated drives, tested as a third-party master sees them.

The drives run in another process (``surgiplan-sim-drives``) on the loopback bus (a hub on 127.0.0.1);
this process drives them with canopen's own master classes only (``canopen.Network``,
``BaseNode402``, its NMT, SDO, PDO, SYNC and EMCY objects), each node's dictionary loaded from the EDS
shipped in the package. Each test starts from an NMT reset of the nodes it uses, as a master would.
"""

from __future__ import annotations

import math
import time

import can
import canopen
import pytest
from canopen.sdo import SdoAbortedError, SdoCommunicationError
from canopen_support import (
    GIMBAL_INITIAL,
    GIMBAL_JOINTS,
    MASTER_ID,
    capture,
    cia301_violations,
    drives_process,
    eds_path,
    master,
    node402,
    read_log,
    wait_for,
)

pytestmark = pytest.mark.slow

DEVICE_TYPE = 0x00020192
#: objects whose value is the drive's live state, not a parameter (not compared with the EDS defaults)
LIVE = {0x1001, 0x1003, 0x603F, 0x6041, 0x6061, 0x6062, 0x6064, 0x606C, 0x60F4, 0x6077}
CSP, PP, PV = "CYCLIC SYNCHRONOUS POSITION", "PROFILED POSITION", "PROFILED VELOCITY"
CST = "CYCLIC SYNCHRONOUS TORQUE"


@pytest.fixture(scope="module")
def port():
    with drives_process("cast_gimbal", initial=GIMBAL_INITIAL) as channel:
        yield channel


@pytest.fixture
def network(port):
    with master(port) as net:
        yield net


def reset(node, command: str = "RESET") -> None:
    """NMT reset (node, or communication) and the boot-up that must follow it."""
    states = []
    node.nmt.add_heartbeat_callback(states.append)
    node.nmt.state = command
    assert wait_for(lambda: 0 in states, timeout=5.0), f"no boot-up from node {node.id} after {command}"
    node.nmt._callbacks.remove(states.append)


def fresh(network, node_id: int):
    node = node402(network, node_id, GIMBAL_JOINTS[node_id - 1])
    reset(node)
    node.sdo[0x2000].raw = 1000  # the SYNC watchdog (manufacturer object in the EDS): lenient on a loaded machine
    return node


def map_for_402(node, tpdo2_first: int = 0x6061, rpdo2: int = 0x607A) -> dict[int, int]:
    """PDOs a CiA 402 application maps (PRE-OPERATIONAL, canopen's procedure); returns COB-ID -> bytes.

    RPDO1 controlword (acted on at reception), RPDO2 ``rpdo2`` (the target position by default, at SYNC),
    TPDO1 statusword + position, TPDO2 ``tpdo2_first`` (the mode display by default) + velocity (every SYNC)."""
    node.tpdo.read()
    node.rpdo.read()
    layout = [
        (node.tpdo, 1, (0x6041, 0x6064), 1),
        (node.tpdo, 2, (tpdo2_first, 0x606C), 1),
        (node.rpdo, 1, (0x6040,), 255),
        (node.rpdo, 2, (rpdo2,), 1),
    ]
    for maps, number, objects, trans in layout:
        pdo = maps[number]
        pdo.clear()
        for index in objects:
            pdo.add_variable(index)
        pdo.trans_type = trans
        pdo.enabled = True
    node.tpdo.save()
    node.rpdo.save()
    node.setup_402_state_machine(read_pdos=False)
    return {0x180 + node.id: 6, 0x280 + node.id: 5, 0x200 + node.id: 2, 0x300 + node.id: 4}


def operational_csp(network, node):
    """Mapped, OPERATIONAL, SYNC at 100 Hz, RPDO2 holding the position, CSP, OPERATION ENABLED."""
    lengths = map_for_402(node)
    node.nmt.state = "OPERATIONAL"
    network.sync.start(0.01)
    position = node.sdo[0x6064].raw
    node.rpdo[2][0x607A].raw = position
    node.rpdo[2].start(0.01)
    node.op_mode = CSP
    node.state = "OPERATION ENABLED"
    return position, lengths


def test_boot_up_identity_and_the_dictionary_match_the_eds(network):
    nodes = [node402(network, i + 1, joint) for i, joint in enumerate(GIMBAL_JOINTS)]
    for node in nodes:
        reset(node)
        assert node.nmt.state == "PRE-OPERATIONAL"
        eds = canopen.import_od(str(eds_path("cast_gimbal", GIMBAL_JOINTS[node.id - 1])), node.id)
        assert node.sdo[0x1000].raw == eds[0x1000].default == DEVICE_TYPE
        identity = [node.sdo[0x1018][sub].raw for sub in (1, 2, 3, 4)]
        assert identity == [eds[0x1018][sub].default for sub in (1, 2, 3, 4)]
        assert identity[3] == node.id  # the serial number is the node id ($NODEID in the EDS)
        assert node.sdo[0x1008].raw == eds[0x1008].default
        modes = node.sdo[0x6502].raw
        assert modes == eds[0x6502].default and modes & 0x0185 == 0x0185  # pp, pv, csp, csv
    # after a reset every parameter the drive serves is its EDS default: the EDS is the drive's dictionary
    node = nodes[0]
    eds = canopen.import_od(str(eds_path("cast_gimbal", "yaw")), 1)
    compared = 0
    for obj in eds.values():
        members = [obj] if isinstance(obj, canopen.objectdictionary.ODVariable) else list(obj.values())
        for var in members:
            if var.index in LIVE or not var.readable:
                continue
            assert node.sdo.upload(var.index, var.subindex) == var.encode_raw(var.default), var.qualname
            compared += 1
    assert compared > 80


def test_reset_communication_restores_the_communication_area_and_reset_node_everything(network):
    node = fresh(network, 1)
    default_window = node.sdo[0x6065].raw
    node.sdo[0x1017].raw = 20  # heartbeat producer (communication area)
    node.sdo[0x6065].raw = 1234  # following error window (profile area)
    assert node.nmt.wait_for_heartbeat(timeout=2.0) == "PRE-OPERATIONAL"
    reset(node, "RESET COMMUNICATION")
    assert node.sdo[0x1017].raw == 0 and node.sdo[0x6065].raw == 1234
    reset(node, "RESET")
    assert node.sdo[0x6065].raw == default_window != 1234


def test_a_stopped_node_answers_no_sdo(network):
    node = fresh(network, 2)
    node.sdo[0x1017].raw = 20
    node.nmt.state = "STOPPED"
    assert wait_for(lambda: node.nmt.state == "STOPPED" and node.nmt.wait_for_heartbeat(1.0) == "STOPPED")
    node.sdo.RESPONSE_TIMEOUT, node.sdo.MAX_RETRIES = 0.3, 1
    with pytest.raises(SdoCommunicationError):
        node.sdo[0x1000].raw  # noqa: B018 (the read is the test)
    node.nmt.state = "PRE-OPERATIONAL"
    assert node.sdo[0x1000].raw == DEVICE_TYPE


def test_modes_of_operation_through_base_node_402_and_an_unsupported_mode_is_aborted(network):
    node = fresh(network, 3)
    node.setup_402_state_machine()
    for mode in (PP, PV, "CYCLIC SYNCHRONOUS VELOCITY", CST, CSP):
        node.op_mode = mode
        assert node.op_mode == mode
    with pytest.raises(TypeError, match="not suppported"):  # canopen reads 0x6502 and refuses it itself
        node.op_mode = "HOMING"
    for code in (2, 4, 6, 7, -1):  # velocity, profile torque, homing, interpolated, vendor
        with pytest.raises(SdoAbortedError) as info:
            node.sdo[0x6060].raw = code
        assert info.value.code == 0x06090030  # value range of parameter exceeded
    assert node.sdo[0x6061].raw == 8  # the mode in force is still CSP


def test_enable_and_cyclic_synchronous_position_motion(network):
    node = fresh(network, 1)
    node.sdo[0x6065].raw = round(0.05 * 2**17 / (2 * math.pi))  # 50 mrad following window: a loaded machine
    start, _ = operational_csp(network, node)
    assert node.state == "OPERATION ENABLED"
    assert node.tpdo_values[0x6061] == 8
    counts = round(0.2 * 2**17 / (2 * math.pi))  # 0.2 rad of the 17-bit encoder
    for k in range(1, 121):  # a ramp over 1 s at 100 Hz, then hold
        node.rpdo[2][0x607A].raw = start + round(counts * min(1.0, k / 100))
        time.sleep(0.01)
    assert wait_for(lambda: abs(node.tpdo_values[0x6064] - (start + counts)) <= 3, timeout=3.0)
    assert node.statusword & 0x1000  # CSP: the drive follows the target
    node.state = "SWITCH ON DISABLED"
    node.rpdo[2].stop()


def test_cyclic_synchronous_torque_through_base_node_402(network):
    """Mode 10 selected with canopen's op_mode, the target torque 0x6071 by RPDO at SYNC: the axis accelerates
    the way the torque says, 0x6077 reports it, and the max torque 0x6072 caps it."""
    node = fresh(network, 2)  # pitch: 0.1 N·m rated through 10:1, 0.004 kg·m²
    map_for_402(node, tpdo2_first=0x6077, rpdo2=0x6071)  # TPDO2 the actual torque, RPDO2 the target torque
    assert node.sdo[0x6502].raw & 0x0200  # bit 9: cyclic synchronous torque
    assert node.sdo[0x6076].raw == 100  # the rated torque, mN·m (the EDS's)
    node.nmt.state = "OPERATIONAL"
    network.sync.start(0.01)
    node.rpdo[2][0x6071].raw = 0
    node.rpdo[2].start(0.01)
    try:
        node.op_mode = CST
        assert node.op_mode == CST
        node.state = "OPERATION ENABLED"
        assert node.state == "OPERATION ENABLED"
        start = node.sdo[0x6064].raw
        node.rpdo[2][0x6071].raw = 200  # 0.2 of 0.1 N·m rated, times 10: 0.2 N·m at the joint
        assert wait_for(lambda: node.tpdo_values.get(0x6077) == 200, timeout=3.0)
        assert wait_for(lambda: node.sdo[0x6064].raw - start > 2000, timeout=5.0)  # it turns forward
        node.sdo[0x6072].raw = 50  # max torque below the target: the drive caps it
        assert wait_for(lambda: node.tpdo_values.get(0x6077) == 50, timeout=3.0)
        with pytest.raises(SdoAbortedError):
            node.sdo[0x6072].raw = 4000  # above the peak torque the EDS states
        node.rpdo[2][0x6071].raw = 0
    finally:
        node.state = "SWITCH ON DISABLED"
        node.rpdo[2].stop()
        network.sync.stop()
    assert node.sdo[0x6077].raw == 0  # torque off


def test_profile_position_motion(network):
    node = fresh(network, 2)
    map_for_402(node)
    node.nmt.state = "OPERATIONAL"
    network.sync.start(0.01)
    node.op_mode = PP
    velocity = node.sdo[0x607F].raw // 4
    node.sdo[0x6081].raw = velocity
    node.sdo[0x6083].raw = node.sdo[0x6084].raw = velocity * 4
    node.state = "OPERATION ENABLED"
    start = node.sdo[0x6064].raw
    target = start - velocity // 2
    node.sdo[0x607A].raw = target
    peak = []
    node.tpdo[2].add_callback(lambda pdo: peak.append(abs(pdo[0x606C].raw)))
    node.controlword = 0x1F  # enable operation + new set-point
    assert wait_for(lambda: node.statusword & 0x1000)  # set-point acknowledge
    node.controlword = 0x0F
    assert wait_for(lambda: node.statusword & 0x0400 and not node.statusword & 0x1000, timeout=5.0)  # reached
    assert abs(node.sdo[0x6064].raw - target) <= node.sdo[0x6067].raw
    # the trapezoid keeps to the profile velocity (the motor's speed, sampled at every SYNC)
    assert 0.5 * velocity < max(peak) <= 1.02 * velocity
    # a relative set-point (bit 6) moves on from the target
    node.sdo[0x607A].raw = 500
    node.controlword = 0x5F
    assert wait_for(lambda: node.statusword & 0x1000)
    node.controlword = 0x4F
    assert wait_for(lambda: abs(node.sdo[0x6064].raw - (target + 500)) <= node.sdo[0x6067].raw, timeout=5.0)


def test_profile_velocity_and_a_software_limit_written_while_enabled(network):
    node = fresh(network, 3)  # insertion, in um
    map_for_402(node)
    node.nmt.state = "OPERATIONAL"
    network.sync.start(0.01)
    node.op_mode = PV
    node.state = "OPERATION ENABLED"
    start = node.sdo[0x6064].raw
    limit = start + 20_000  # 20 mm further in, written while enabled: effective at once
    node.sdo[0x607D][2].raw = limit
    node.sdo[0x60FF].raw = 50_000  # 50 mm/s
    window = node.sdo[0x606D].raw
    # pv: target reached (statusword bit 10) with the velocity actual value within the velocity window
    assert wait_for(lambda: node.statusword & 0x0400 and abs(node.tpdo_values[0x606C] - 50_000) <= window, 3.0)
    # the drive brakes before the limit and says so (statusword bit 11: internal limit active)
    assert wait_for(lambda: node.statusword & 0x0800 and node.tpdo_values[0x606C] == 0, timeout=5.0)
    assert limit - 50 <= node.sdo[0x6064].raw <= limit + 20
    node.sdo[0x60FF].raw = 0


def test_controlword_and_statusword_by_sdo_alone(network):
    node = fresh(network, 4)
    node.rpdo.read()
    node.tpdo.read()
    node.rpdo[1].enabled = node.tpdo[1].enabled = False
    node.rpdo.save()
    node.tpdo.save()
    node.setup_402_state_machine(read_pdos=False)
    assert 0x6040 not in node.rpdo_pointers and 0x6041 not in node.tpdo_values  # BaseNode402 falls back to SDO
    node.op_mode = PP
    node.state = "OPERATION ENABLED"  # every controlword and statusword by SDO
    assert node.sdo[0x6041].raw & 0x6F == 0x27
    start = node.sdo[0x6064].raw
    node.sdo[0x607A].raw = start + 3000
    node.sdo[0x6040].raw = 0x1F
    node.sdo[0x6040].raw = 0x0F
    assert wait_for(lambda: node.sdo[0x6041].raw & 0x0400, timeout=5.0)
    assert abs(node.sdo[0x6064].raw - (start + 3000)) <= node.sdo[0x6067].raw
    node.state = "SWITCH ON DISABLED"
    assert node.sdo[0x6041].raw & 0x4F == 0x40


def test_a_following_error_faults_with_emcy_and_a_fault_reset_clears_it(network):
    node = fresh(network, 4)
    start, _ = operational_csp(network, node)
    node.rpdo[2][0x607A].raw = start + 400_000  # 3 rad in one period: the drive cannot follow
    assert wait_for(lambda: any(e.code == 0x8611 for e in node.emcy.log), timeout=5.0)
    emcy = next(e for e in node.emcy.log if e.code == 0x8611)
    assert emcy.register & 0x01 and emcy.register & 0x20  # generic + device profile specific
    assert wait_for(lambda: node.state == "FAULT")
    assert node.statusword & 0x2000  # following error
    assert node.sdo[0x603F].raw == 0x8611 and node.sdo[0x1001].raw == emcy.register
    assert node.sdo[0x1003][0].raw >= 1 and node.sdo[0x1003][1].raw & 0xFFFF == 0x8611
    node.rpdo[2][0x607A].raw = node.sdo[0x6064].raw  # hold where it stopped
    faults = len(node.emcy.log)
    node.state = "OPERATION ENABLED"  # BaseNode402: fault reset (rising edge of bit 7), then enable
    assert wait_for(lambda: any(e.code == 0 for e in node.emcy.log[faults:]))  # EMCY 0x0000: error reset
    assert node.emcy.active == []
    assert node.sdo[0x603F].raw == 0 and node.sdo[0x1001].raw == 0
    assert node.state == "OPERATION ENABLED"
    node.sdo[0x1003][0].raw = 0  # CiA 301: writing 0 clears the history
    assert node.sdo[0x1003][0].raw == 0
    with pytest.raises(SdoAbortedError):
        node.sdo[0x1003][0].raw = 3  # only 0 may be written
    node.state = "SWITCH ON DISABLED"
    node.rpdo[2].stop()


@pytest.mark.parametrize(("option", "state"), [(3, "QUICK STOP ACTIVE"), (1, "FAULT")])
def test_a_drive_that_loses_its_masters_heartbeat_acts_as_0x6007_says(network, option, state):
    node = fresh(network, 3)
    map_for_402(node)
    node.nmt.state = "OPERATIONAL"
    network.sync.start(0.01)
    node.sdo[0x6007].raw = option
    node.sdo[0x1016][1].raw = (MASTER_ID << 16) | 500  # consume our heartbeat, 500 ms (a loaded machine)
    beat = network.send_periodic(0x700 + MASTER_ID, b"\x05", 0.05)
    node.op_mode = PP
    node.state = "OPERATION ENABLED"
    time.sleep(0.3)  # the drive has heard the heartbeat (monitoring starts with the first one)
    assert node.state == "OPERATION ENABLED"
    beat.stop()
    assert wait_for(lambda: any(e.code == 0x8130 for e in node.emcy.log), timeout=5.0)  # heartbeat error
    assert wait_for(lambda: node.state == state, timeout=3.0)
    assert node.sdo[0x1001].raw & 0x10  # communication error
    node.sdo[0x1016][1].raw = 0


def test_the_captured_traffic_follows_cia_301(port, tmp_path):
    """A whole session on every node, as python-can's logger wrote it (BLF) and its reader reads it back."""
    log = tmp_path / "session.blf"
    lengths: dict[int, int] = {}
    with capture(port, log), master(port) as network:
        nodes = [fresh(network, i + 1) for i in range(4)]
        for node in nodes:
            node.sdo[0x1017].raw = 50
            lengths |= map_for_402(node)
        for node in nodes:
            node.nmt.state = "OPERATIONAL"
        network.sync.start(0.01)
        starts = {}
        for node in nodes:
            starts[node.id] = node.sdo[0x6064].raw
            node.rpdo[2][0x607A].raw = starts[node.id]
            node.rpdo[2].start(0.01)
            node.op_mode = CSP
            node.state = "OPERATION ENABLED"
        time.sleep(0.2)
        nodes[1].rpdo[2][0x607A].raw = starts[2] + 400_000  # node 2 faults
        assert wait_for(lambda: nodes[1].state == "FAULT", timeout=5.0)
        nodes[1].rpdo[2][0x607A].raw = nodes[1].sdo[0x6064].raw
        nodes[1].state = "OPERATION ENABLED"
        for node in nodes:
            node.state = "SWITCH ON DISABLED"
            node.rpdo[2].stop()
        network.sync.stop()
        nodes[3].nmt.state = "STOPPED"
        nodes[3].sdo.RESPONSE_TIMEOUT, nodes[3].sdo.MAX_RETRIES = 0.2, 1
        with pytest.raises(SdoCommunicationError):
            nodes[3].sdo[0x1000].raw  # noqa: B018
        time.sleep(0.1)
    frames = read_log(log)
    assert cia301_violations(frames, {1, 2, 3, 4}, lengths) == []
    ids = [m.arbitration_id for m in frames]
    data = [bytes(m.data) for m in frames]
    for node in (1, 2, 3, 4):
        assert (0x700 + node, b"\x00") in zip(ids, data, strict=True)  # its boot-up
        assert ids.count(0x180 + node) > 20  # TPDO1 at every SYNC while operational
    emcy = [d for i, d in zip(ids, data, strict=True) if i == 0x82]
    assert [int.from_bytes(d[:2], "little") for d in emcy] == [0x8611, 0x0000]  # error, then its reset
    assert ids.count(0x080) > 20 and all(len(d) == 0 for i, d in zip(ids, data, strict=True) if i == 0x080)
    stopped_at = max(k for k, (i, d) in enumerate(zip(ids, data, strict=True)) if i == 0 and d == b"\x02\x04")
    assert 0x604 in ids[stopped_at:] and 0x584 not in ids[stopped_at:]  # asked, never answered in STOPPED
    assert can.LogReader  # the frames above came from python-can's BLF reader


def _frame(can_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False)


GOOD_SESSION = [
    _frame(0x000, b"\x82\x01"),  # reset communication of node 1
    _frame(0x701, b"\x00"),  # its boot-up
    _frame(0x601, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0])),  # SDO upload request 0x1000
    _frame(0x581, bytes([0x43, 0x00, 0x10, 0, 0x92, 0x01, 0x02, 0x00])),
    _frame(0x000, b"\x01\x01"),  # start
    _frame(0x080, b""),
    _frame(0x181, bytes(6)),
    _frame(0x081, bytes(8)),  # EMCY 0x0000, register 0
    _frame(0x701, b"\x05"),
]


@pytest.mark.parametrize(
    ("change", "complaint"),
    [
        ({6: _frame(0x181, bytes(8))}, "mapped to 6 bytes, carries 8"),
        ({8: _frame(0x701, b"\x05\x00")}, "a heartbeat is 1 byte"),
        ({8: _frame(0x701, b"\x03")}, "a heartbeat is 1 byte"),
        ({0: _frame(0x000, b"\x82\x01\x00")}, "NMT command must be 2 bytes"),
        ({3: _frame(0x581, bytes(7))}, "SDO frames are 8 bytes"),
        ({7: _frame(0x081, bytes(6))}, "EMCY is 8 bytes"),
        ({7: _frame(0x081, bytes([0, 0, 0x21, 0, 0, 0, 0, 0]))}, "an error reset EMCY (0x0000) with error register"),
        ({1: _frame(0x181, bytes(6))}, "between a reset command and its boot-up"),
        ({4: _frame(0x000, b"\x80\x01")}, "which is not OPERATIONAL"),
        ({5: _frame(0x100, bytes(6))}, "outside the predefined connection set"),
        ({3: _frame(0x701, b"\x7f")}, "never answered"),
        ({2: _frame(0x000, b"\x02\x01")}, "answered an SDO in STOPPED"),
    ],
)
def test_the_cia_301_check_finds_what_breaks_the_standard(change, complaint):
    """The traffic check above can fail: each change to a conforming session is one violation."""
    assert cia301_violations(GOOD_SESSION, {1}, {0x181: 6}) == []
    frames = [change.get(k, frame) for k, frame in enumerate(GOOD_SESSION)]
    problems = cia301_violations(frames, {1}, {0x181: 6})
    assert any(complaint in p for p in problems), problems
