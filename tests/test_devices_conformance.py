"""CiA 301 / CiA 402 details of the simulated drives, on the simulated clock, through canopen's own SDO
client and PDO objects (``canopen.RemoteNode`` with the shipped EDS), and the EDS files themselves.

The slower end-to-end checks (drives in another process, canopen's BaseNode402) are in
tests/interop/test_canopen_conformance.py.
"""

from __future__ import annotations

import math
import struct
import uuid

import can
import canopen
import numpy as np
import pytest
from canopen.sdo import SdoAbortedError, SdoCommunicationError
from surgiplan.plugins.devices.canopen import cia402
from surgiplan.plugins.devices.canopen.bus import ArmedFaults, MonitoredBus
from surgiplan.plugins.devices.canopen.clock import SimulatedClock
from surgiplan.plugins.devices.canopen.network import PumpedNetwork, SimulationLink
from surgiplan.plugins.devices.canopen.sim import eds
from surgiplan.plugins.devices.canopen.sim.drives import AxisHardware, DriveSimulator
from surgiplan.plugins.devices.canopen.sim.motor import MotorModel

CPU = 2**17 / (2 * math.pi)


class Bench:
    """One simulated yaw drive (node 1) and canopen's RemoteNode for it, on the simulated clock."""

    def __init__(self) -> None:
        self.clock = SimulatedClock()
        link = SimulationLink()
        channel = f"conformance-{uuid.uuid4().hex[:8]}"
        self.axis = AxisHardware(
            1, CPU, 12.0, 1.5, 0.0, name="yaw", lower=-1.0, upper=1.0, following_error_window=0.01,
            profile_velocity=1.0, profile_acceleration=4.0, serial=1,
        )  # fmt: skip
        faults = ArmedFaults([], self.clock.now)
        self.sim = DriveSimulator(can.Bus(interface="virtual", channel=channel), [self.axis], MotorModel(),
                                  self.clock, faults, link, device="test")  # fmt: skip
        self.bus = MonitoredBus(can.Bus(interface="virtual", channel=channel), self.clock.now, faults)
        self.network = PumpedNetwork(self.bus, self.clock.scheduler, self.clock.now, link)
        self.dictionary = cia402.drive_object_dictionary(1, self.axis.defaults("test"))
        self.node = canopen.RemoteNode(1, self.dictionary)
        self.node.sdo.RESPONSE_TIMEOUT, self.node.sdo.MAX_RETRIES = 0.05, 1
        self.network.add_node(self.node)

    def frames(self, can_id: int, since: float = 0.0) -> list[bytes]:
        return [d for t, i, d in self.bus.frames if i == can_id and t >= since]

    def controlword(self, *words: int) -> None:
        for word in words:
            self.node.sdo[0x6040].raw = word

    def state(self) -> str:
        return cia402.state_of(self.node.sdo[0x6041].raw)

    def run(self, seconds: float, sync: float | None = None) -> None:
        """Let simulated time pass, with a SYNC every ``sync`` s (None: none)."""
        end = self.clock.now() + seconds
        while sync is not None and self.clock.now() + sync <= end + 1e-12:
            self.clock.sleep_until(self.clock.now() + sync)
            self.network.send_message(0x080, b"")
        self.clock.sleep_until(end)

    def close(self) -> None:
        self.sim.close()
        self.bus.shutdown()


@pytest.fixture
def bench():
    b = Bench()
    try:
        yield b
    finally:
        b.close()


def abort_code(action) -> int:
    with pytest.raises(SdoAbortedError) as info:
        action()
    return info.value.code


# ----------------------------------------------------------------------------- PDO configuration (CiA 301)
def test_pdo_mapping_follows_the_cia_301_procedure_and_refuses_the_rest(bench):
    node = bench.node
    tpdo_cob = node.sdo[0x1800][1]
    mapping = node.sdo[0x1A00]
    # mapping a valid PDO: refused (0x06010000, a code CiA's conformance test accepts)
    assert abort_code(lambda: setattr(mapping[0], "raw", 0)) == 0x06010000
    assert abort_code(lambda: setattr(tpdo_cob, "raw", 0x181 | (1 << 31))) == 0x06090030  # TPDOs are not RTR'd
    tpdo_cob.raw = 0x40000181 | (1 << 31)  # invalidate (bit 30: no RTR)
    assert abort_code(lambda: setattr(mapping[1], "raw", 0x60410010)) == 0x06010000  # number of entries first
    mapping[0].raw = 0
    assert abort_code(lambda: setattr(mapping[1], "raw", 0x60650020)) == 0x06040041  # 0x6065 is not mappable
    assert abort_code(lambda: setattr(mapping[1], "raw", 0x60410020)) == 0x06040041  # wrong length
    for sub, entry in enumerate([0x60640020, 0x60640020, 0x60410010], start=1):
        mapping[sub].raw = entry
    assert abort_code(lambda: setattr(mapping[0], "raw", 3)) == 0x06040042  # 80 bits > 64
    mapping[0].raw = 2
    tpdo_cob.raw = 0x40000181
    assert abort_code(lambda: setattr(tpdo_cob, "raw", 0x40000191)) == 0x06090030  # the COB-ID of a valid PDO
    assert abort_code(lambda: setattr(node.sdo[0x1800][2], "raw", 252)) == 0x06090030  # RTR-only: not offered
    node.nmt.send_command(0x01)  # OPERATIONAL: no PDO changes at all
    assert abort_code(lambda: setattr(node.sdo[0x1800][2], "raw", 1)) == 0x08000022
    bench.run(0.05, sync=0.01)
    tpdos = bench.frames(0x181)
    assert len(tpdos) == 5 and all(len(d) == 8 for d in tpdos)  # the new mapping: two positions


def test_event_driven_tpdo_goes_on_change_and_on_its_event_timer(bench):
    node = bench.node
    node.tpdo.read()
    tpdo = node.tpdo[2]
    tpdo.clear()
    tpdo.add_variable(0x6041)
    tpdo.trans_type = 255
    tpdo.event_timer = 20  # ms
    tpdo.enabled = True
    node.tpdo.save()
    node.nmt.send_command(0x01)
    start = bench.clock.now()
    bench.run(0.1)
    timed = bench.frames(0x281, start)
    assert 4 <= len(timed) <= 6  # every 20 ms (the drive's 5 ms tick)
    before = len(bench.frames(0x281))
    bench.controlword(0x06)  # the statusword changes: sent at once
    assert len(bench.frames(0x281)) == before + 1
    assert cia402.state_of(struct.unpack("<H", bench.frames(0x281)[-1])[0]) == cia402.READY


# ----------------------------------------------------------------------------- NMT and the drive
def test_a_stopped_node_is_silent_on_sdo_and_emcy_and_a_reset_brings_it_back(bench):
    node = bench.node
    node.nmt.send_command(0x02)
    with pytest.raises(SdoCommunicationError):
        node.sdo[0x1000].raw  # noqa: B018
    node.nmt.send_command(0x82)  # reset communication: boot-up, PRE-OPERATIONAL
    assert bench.frames(0x701)[-1] == b"\x00"
    assert node.sdo[0x1000].raw == cia402.DEVICE_TYPE


def test_reset_communication_while_enabled_quick_stops_and_reset_node_switches_off(bench):
    node = bench.node
    node.sdo[0x6060].raw = cia402.PP
    bench.controlword(0x06, 0x07, 0x0F)
    assert bench.state() == cia402.OPERATION_ENABLED
    node.nmt.send_command(0x82)  # 0x6007 = 3: quick stop
    assert bench.state() == cia402.QUICK_STOP_ACTIVE
    bench.controlword(0x0F)  # transition 16
    assert bench.state() == cia402.OPERATION_ENABLED
    node.sdo[0x6065].raw = 77
    node.nmt.send_command(0x81)  # reset node: the drive restarts, every object at its default
    assert bench.state() == cia402.SWITCH_ON_DISABLED
    assert node.sdo[0x6065].raw == round(0.01 * CPU)
    assert [t[2:] for t in bench.sim.transitions[-2:]] == [
        (cia402.OPERATION_ENABLED, cia402.NOT_READY),
        (cia402.NOT_READY, cia402.SWITCH_ON_DISABLED),
    ]


@pytest.mark.parametrize(
    ("option", "after"),
    [(0, cia402.SWITCH_ON_DISABLED), (2, cia402.SWITCH_ON_DISABLED), (6, cia402.QUICK_STOP_ACTIVE)],
)
def test_quick_stop_option_codes(bench, option, after):
    node = bench.node
    node.sdo[0x605A].raw = option
    node.sdo[0x6060].raw = cia402.PV
    bench.controlword(0x06, 0x07, 0x0F)
    node.sdo[0x60FF].raw = round(0.8 * CPU)
    bench.run(0.5)
    assert node.sdo[0x606C].raw == pytest.approx(0.8 * CPU, abs=node.sdo[0x606D].raw)  # the velocity window
    bench.controlword(0x02)  # quick stop
    ramp = 0.8 / (2 * 4.0)  # at 0x6085, twice the profile acceleration
    bench.run(ramp + 0.05)
    assert bench.state() == after
    assert abs(node.sdo[0x606C].raw) <= node.sdo[0x606D].raw  # at rest (within the velocity window)
    if option:  # a ramp: it stopped about 0.8^2 / (2 * 8) = 40 mrad later; option 0 stops at once
        moved = [t for t in bench.sim.transitions if t[3] in (cia402.QUICK_STOP_ACTIVE, cia402.SWITCH_ON_DISABLED)]
        assert moved
    assert abort_code(lambda: setattr(node.sdo[0x605A], "raw", 3)) == 0x06090030


def test_a_lost_sync_is_an_error_in_0x603f_0x1001_and_0x1003_and_is_reset_with_emcy_0000(bench):
    node = bench.node
    node.nmt.send_command(0x01)
    bench.run(0.05, sync=0.004)
    bench.controlword(0x06, 0x07, 0x0F)
    bench.run(0.05, sync=0.004)
    silent = bench.clock.now()
    bench.run(0.1)  # no SYNC: the 50 ms watchdog (0x2000) trips
    assert bench.state() == cia402.QUICK_STOP_ACTIVE
    emcy = bench.frames(0x81, silent)
    assert [struct.unpack_from("<HB", d) for d in emcy] == [(cia402.EMCY_SYNC_LOST, 0x11)]
    assert node.sdo[0x603F].raw == cia402.EMCY_SYNC_LOST
    assert node.sdo[0x1001].raw == 0x11  # generic + communication
    assert node.sdo[0x1003][0].raw == 1 and node.sdo[0x1003][1].raw & 0xFFFF == cia402.EMCY_SYNC_LOST
    bench.controlword(0x00)  # acknowledged: disable voltage (transition 12)
    assert struct.unpack_from("<HB", bench.frames(0x81)[-1]) == (0x0000, 0)
    assert node.sdo[0x603F].raw == 0 and node.sdo[0x1001].raw == 0
    assert node.sdo[0x1003][0].raw == 1  # the history keeps it until cleared


def test_cyclic_synchronous_velocity_follows_each_syncs_target_velocity(bench):
    node = bench.node
    node.rpdo.read()
    rpdo = node.rpdo[4]  # controlword + target velocity (CiA 402's default mapping), at SYNC
    rpdo.trans_type = 1
    rpdo.enabled = True
    node.rpdo.save()
    node.sdo[0x6060].raw = cia402.CSV
    node.nmt.send_command(0x01)
    for word in (0x06, 0x07, 0x0F):
        rpdo[0x6040].raw = word
        rpdo.transmit()
        bench.run(0.004, sync=0.004)
    assert bench.state() == cia402.OPERATION_ENABLED and node.sdo[0x6061].raw == cia402.CSV
    speeds, targets = [], []
    for k in range(150):
        targets.append(min(0.5, 0.005 * k))  # a ramp to 0.5 rad/s
        rpdo[0x60FF].raw = round(targets[-1] * CPU)
        rpdo.transmit()
        bench.run(0.004, sync=0.004)
        speeds.append(bench.sim.vel[0])
    # applied at the next SYNC and reached over one period: at each SYNC the speed is the previous target's,
    # within what a one-count encoder step moves the position loop's correction (150/s x 48 urad = 7 mrad/s)
    np.testing.assert_allclose(speeds[10:], targets[9:-1], atol=0.005)
    assert np.mean(np.abs(np.array(speeds[10:]) - targets[9:-1])) < 0.002
    assert speeds[-1] == pytest.approx(0.5, rel=0.01)


def test_limits_take_effect_when_written_while_enabled(bench):
    node = bench.node
    node.sdo[0x6060].raw = cia402.PP
    bench.controlword(0x06, 0x07, 0x0F)
    node.sdo[0x607D][2].raw = round(0.1 * CPU)  # while enabled
    node.sdo[0x607F].raw = round(0.2 * CPU)  # max profile velocity, while enabled
    node.sdo[0x607A].raw = round(0.5 * CPU)
    bench.controlword(0x1F, 0x0F)
    top = 0.0
    for _ in range(100):
        bench.run(0.01)
        top = max(top, abs(bench.sim.vel[0]))
    assert bench.sim.pos[0] == pytest.approx(0.1, abs=2 / CPU)  # stopped at the new limit
    assert node.sdo[0x6041].raw & cia402.SW_INTERNAL_LIMIT
    assert 0.15 < top <= 0.2 * 1.001  # the new speed limit held


# ----------------------------------------------------------------------------- the EDS files
def test_the_shipped_eds_files_are_the_dictionaries_the_simulator_serves(tmp_path):
    """One source of truth: the files are today's export; a change to the dictionary without
    regenerating them (python -m surgiplan.plugins.devices.canopen.sim.eds --write) fails here."""
    devices = eds.simulated_devices()
    assert {"cast_gimbal", "gripper6"} <= set(devices)
    files = 0
    for name, cls in devices.items():
        for path, text in eds.device_eds(cls, name).items():
            assert path.read_text() == text, f"{path} is out of date"
            files += 1
    assert files == 10
    # and canopen loads each as a node's dictionary, with the values the simulated drive serves
    path = devices["cast_gimbal"].eds_folder() / "cast_gimbal_insertion.eds"
    loaded = canopen.import_od(str(path), 3)
    assert loaded[0x1800][1].default == 0x40000183 and loaded[0x1018][4].default == 3
    assert loaded[0x607D][2].default == 300_000  # 300 mm at 1 um per count
    assert loaded[0x6502].default == 0x0385 and loaded[0x6060].data_type == canopen.objectdictionary.INTEGER8


# ----------------------------------------------------------------------------- what the CTT families cannot see
def test_an_abandoned_segmented_transfer_is_aborted_after_the_protocol_time_out(bench):
    """A client that starts a segmented upload and goes quiet: the drive aborts 0x05040000 after 1 s (simulated
    clock), and serves the next request."""
    bench.network.send_message(0x601, bytes([0x40, 0x08, 0x10, 0, 0, 0, 0, 0]))  # initiate upload of 0x1008
    assert bench.frames(0x581)[-1][0] == 0x41  # segmented: size indicated
    answered = len(bench.frames(0x581))
    bench.run(0.9)
    assert len(bench.frames(0x581)) == answered
    bench.run(0.2)
    aborts = bench.frames(0x581)[answered:]
    assert len(aborts) == 1 and aborts[0][0] == 0x80 and struct.unpack("<L", aborts[0][4:])[0] == 0x05040000
    assert bench.node.sdo[0x1000].raw == cia402.DEVICE_TYPE


def _lss(bench, *payload: int) -> bytes | None:
    before = len(bench.frames(0x7E4))
    bench.network.send_message(0x7E5, bytes(payload).ljust(8, b"\x00"))
    answers = bench.frames(0x7E4)[before:]
    return answers[-1] if answers else None


def test_lss_renumbers_a_configured_drive_at_its_next_reset_communication(bench):
    """CiA 305: a configured drive's new node-ID becomes active at NMT reset communication (a non-configured one's
    on returning to the waiting state, which the conformance suite checks); the application's values stay."""
    bench.node.sdo[0x6065].raw = 1234
    _lss(bench, 0x04, 1)  # every drive to the configuration state
    assert _lss(bench, 0x5E)[:2] == bytes([0x5E, 1])  # inquire node-ID
    assert _lss(bench, 0x11, 5)[:3] == bytes([0x11, 0, 0])
    assert _lss(bench, 0x5E)[:2] == bytes([0x5E, 1])  # still the active one: the new one is pending
    _lss(bench, 0x04, 0)
    assert not bench.frames(0x705)  # a configured drive keeps its node-ID until a reset
    bench.network.send_message(0x000, bytes([0x82, 1]))
    assert bench.frames(0x705) == [b"\x00"]  # boot-up as node 5
    node = canopen.RemoteNode(5, bench.dictionary)
    node.sdo.RESPONSE_TIMEOUT, node.sdo.MAX_RETRIES = 0.05, 1
    bench.network.add_node(node)
    assert node.sdo[0x6065].raw == 1234 and node.sdo[0x1018][4].raw == 1  # its serial number stays
    with pytest.raises(SdoCommunicationError):
        bench.node.sdo[0x1000].raw  # noqa: B018  (nobody at node-ID 1 now)


def test_a_bit_rate_other_than_the_bus_s_takes_the_drive_off_the_bus(bench):
    _lss(bench, 0x04, 1)
    assert _lss(bench, 0x13, 0, 2)[:2] == bytes([0x13, 0])  # 500 kbit/s: supported (the EDS's BaudRate_500)
    start = bench.clock.now()
    bench.node.sdo[0x1017].raw = 10
    _lss(bench, 0x15, 20, 0)  # activate, switch delay 20 ms
    bench.run(0.2)
    assert bench.frames(0x701, start) == []  # at 500 kbit/s on a 1 Mbit/s bus: nothing from it
    assert _lss(bench, 0x5E) is None
    with pytest.raises(SdoCommunicationError):
        bench.node.sdo[0x1000].raw  # noqa: B018


def test_a_damaged_memory_file_is_the_factory_defaults(tmp_path, caplog):
    from surgiplan.plugins.devices.canopen.sim.storage import Memory

    path = tmp_path / "test_yaw.json"
    path.write_text('{"parameters": {"6065:0": "zz"}}')
    with caplog.at_level("WARNING"):
        memory = Memory(path)
    assert memory.parameters == {} and "unreadable" in caplog.text
    memory.store_lss(7, 500_000)
    assert Memory(path).lss == {"node_id": 7, "bit_rate": 500_000}
