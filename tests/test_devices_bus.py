"""The CAN transport: frame lengths bit by bit, bus load, opening buses, fault settings."""

from __future__ import annotations

import can
import numpy as np
import pytest
from devices_support import reference_frame_bits
from pydantic import ValidationError
from surgiplan.plugins.devices.canopen.bus import (
    ArmedFaults,
    BusError,
    BusSettings,
    MonitoredBus,
    bus_load_percent,
    frame_bits,
    open_bus,
    worst_case_bits,
)


def test_frame_lengths_match_the_can_specification_bit_by_bit(rng):
    ids = rng.integers(0, 0x800, size=400)
    payloads = [bytes(rng.integers(0, 256, size=int(n), dtype=np.uint8)) for n in rng.integers(0, 9, size=400)]
    # frames with long runs of equal bits stuff the most
    ids = np.concatenate([ids, [0x000, 0x7FF, 0x080, 0x700]])
    payloads += [b"\x00" * 8, b"\xff" * 8, b"", b"\x05"]
    bits = frame_bits(ids, payloads)
    expected = [reference_frame_bits(int(i), p) for i, p in zip(ids, payloads, strict=True)]
    np.testing.assert_array_equal(bits, expected)
    lengths = np.array([len(p) for p in payloads])
    # between the unstuffed length and the worst-case bound of Davis et al. (2007)
    assert np.all(bits >= 47 + 8 * lengths)
    assert np.all(bits <= [worst_case_bits(n) for n in lengths])


def test_worst_case_of_an_8_byte_frame_is_135_bits():
    assert worst_case_bits(8) == 135
    assert worst_case_bits(0) == 55


def test_bus_load_is_bits_on_the_wire_over_the_bit_rate():
    # 1000 frames of 8 bytes in 0.5 s at 1 Mbit/s
    frames = [(i * 0.0005, 0x181, bytes([i % 256] * 8)) for i in range(1000)]
    exact, worst = bus_load_percent(frames, 0.5, 1_000_000)
    bits = sum(reference_frame_bits(f[1], f[2]) for f in frames)
    assert exact == pytest.approx(100.0 * bits / 0.5e6)
    assert worst == pytest.approx(100.0 * 1000 * 135 / 0.5e6)
    # the physical limit of the issue: about 8,000 8-byte frames per second fill 1 Mbit/s
    assert 1e6 / 135 == pytest.approx(7407, abs=1) and 1e6 / 111 == pytest.approx(9009, abs=1)


def test_a_real_interface_needs_a_channel():
    with pytest.raises(BusError, match="needs a channel"):
        open_bus(BusSettings(interface="socketcan"))


def test_a_bus_that_cannot_be_opened_is_a_clear_error_naming_interface_and_channel():
    with pytest.raises(BusError) as info:
        open_bus(BusSettings(interface="socketcan", channel="surgiplan-no-such-can"))
    message = str(info.value)
    assert "socketcan" in message and "surgiplan-no-such-can" in message
    # an interface python-can does not know is refused when the settings are validated (before any stage runs)
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="unknown python-can interface 'no_such_interface'; choose one of"):
        BusSettings(interface="no_such_interface", channel="x")


def test_the_virtual_bus_gets_a_channel_of_its_own():
    first, channel_a = open_bus(BusSettings())
    second, channel_b = open_bus(BusSettings())
    try:
        assert channel_a != channel_b
    finally:
        first.shutdown()
        second.shutdown()


def test_faults_are_validated_by_kind():
    settings = BusSettings.model_validate(
        {
            "faults": [
                {"kind": "heartbeat_loss", "node": 2, "at_s": 0.5},
                {"kind": "frame_loss", "rate": 0.01},
                {"kind": "following_error", "node": 1, "at_s": 1.0},
                {"kind": "dead_node", "node": 3},
                {"kind": "bus_off"},
            ]
        }
    )
    assert [f.kind for f in settings.faults] == [
        "heartbeat_loss",
        "frame_loss",
        "following_error",
        "dead_node",
        "bus_off",
    ]
    assert settings.faults[3].at_s is None and settings.faults[4].at_s is None
    with pytest.raises(ValidationError, match="heartbeat_los"):
        BusSettings.model_validate({"faults": [{"kind": "heartbeat_los", "node": 2}]})
    with pytest.raises(ValidationError):
        BusSettings.model_validate({"faults": [{"kind": "frame_loss", "rate": 1.5}]})
    with pytest.raises(ValidationError):
        BusSettings.model_validate({"faults": [{"kind": "heartbeat_loss", "node": 200}]})


def _monitored(faults, now):
    inner = can.Bus(interface="virtual", channel="test-monitored", receive_own_messages=False)
    peer = can.Bus(interface="virtual", channel="test-monitored")
    return MonitoredBus(inner, now, ArmedFaults(faults, now)), peer


def test_monitored_bus_logs_frames_both_ways_and_goes_bus_off_when_told():
    clock = {"t": 0.0}
    now = lambda: clock["t"]  # noqa: E731
    settings = BusSettings.model_validate({"faults": [{"kind": "bus_off", "at_s": 0.5}]})
    bus, peer = _monitored(settings.faults, now)
    try:
        bus.faults.arm(0.0)
        bus.send(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))
        peer.send(can.Message(arbitration_id=0x181, data=b"\x01\x02", is_extended_id=False))
        assert bus.recv(0.1).arbitration_id == 0x181
        assert [(f[1], f[2]) for f in bus.frames] == [(0x80, b""), (0x181, b"\x01\x02")]
        clock["t"] = 0.6
        with pytest.raises(can.CanOperationError, match="bus-off"):
            bus.send(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))
    finally:
        bus.shutdown()
        peer.shutdown()


def test_a_sent_frame_is_logged_with_the_time_it_was_handed_to_the_interface():
    """Taken before the send: a thread preempted while sending (the drives answering in between) still logs its
    SYNC before their answers, one by one and in a batch."""
    clock = {"t": 1.0}

    class Slow(can.BusABC):  # the interface: time passes while it sends
        def __init__(self) -> None:
            super().__init__(channel="slow")

        def send(self, msg, timeout=None) -> None:
            clock["t"] += 0.5

        def send_batch(self, messages) -> None:
            clock["t"] += 0.5

        def _recv_internal(self, timeout):
            return None, False

    bus = MonitoredBus(Slow(), lambda: clock["t"], ArmedFaults([], lambda: clock["t"]))
    try:
        bus.send(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))
        bus.send_batch([can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)] * 2)
        assert [f[0] for f in bus.frames] == [1.0, 1.5, 1.5]
    finally:
        bus.shutdown()


def test_monitored_bus_ignores_echoes_of_its_own_frames():
    """Interfaces such as udp_multicast loop a sender's frames back: they are not traffic twice."""
    clock = lambda: 0.0  # noqa: E731
    bus, peer = _monitored([], clock)
    bus.own_ids = {0x080, 0x201}
    try:
        peer.send(can.Message(arbitration_id=0x201, data=b"\x0f\x00", is_extended_id=False))  # as an echo
        peer.send(can.Message(arbitration_id=0x181, data=b"\x37\x02", is_extended_id=False))
        assert bus.recv(0.1).arbitration_id == 0x181
        assert [f[1] for f in bus.frames] == [0x181]
    finally:
        bus.shutdown()
        peer.shutdown()


def test_frame_loss_drops_the_given_fraction_with_a_seed():
    settings = BusSettings.model_validate({"faults": [{"kind": "frame_loss", "rate": 0.05, "seed": 3}]})
    armed = ArmedFaults(settings.faults, lambda: 1.0)
    first = armed.frame_loss(stream=0)
    assert not first.drop(0x181)  # not armed yet: nothing is lost before the trajectory starts
    armed.arm(0.0)
    drops = [first.drop(0x181) for _ in range(20000)]
    assert np.mean(drops) == pytest.approx(0.05, abs=0.005)
    again = ArmedFaults(settings.faults, lambda: 1.0)
    again.arm(0.0)
    second = again.frame_loss(stream=0)
    assert [second.drop(0x181) for _ in range(20000)] == drops  # reproducible
