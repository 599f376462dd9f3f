"""The mission and command protocols as state machines, over pymavlink's real encoding, without sockets.

A ground station's :class:`MissionUpload` and a vehicle's :class:`MissionReceiver`
talk through an in-memory link that packs every message with pymavlink (MAVLink 2),
parses it back on the other side, and drops a seeded share of them in each
direction. Time is simulated, so every run is the same on any machine.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from surgiplan.plugins.devices.mavlink.link import enum_value, mavlink, signing_key
from surgiplan.plugins.devices.mavlink.mission import MissionItem, compare_missions, result_text
from surgiplan.plugins.devices.mavlink.mission_gcs import MissionDownload, MissionUpload
from surgiplan.plugins.devices.mavlink.mission_vehicle import MissionReceiver, MissionSender, ReceiverFaults
from surgiplan.plugins.devices.mavlink.transactions import CommandTransaction

GCS = (255, 190)
VEHICLE = (1, 1)


class Wire:
    """Two MAVLink 2 endpoints in memory: pack, drop (seeded), parse."""

    def __init__(self, loss: float = 0.0, seed: int = 0) -> None:
        self.gcs = mavlink.MAVLink(None, *GCS)
        self.vehicle = mavlink.MAVLink(None, *VEHICLE)
        self.rng = np.random.default_rng(seed)
        self.loss = loss
        self.delivered = 0
        self.dropped = 0

    def carry(self, messages, sender, receiver) -> list:
        out = []
        for message in messages:
            buf = message.pack(sender)
            if self.loss and self.rng.random() < self.loss:
                self.dropped += 1
                continue
            parsed = receiver.parse_char(bytearray(buf))
            assert parsed is not None and parsed.get_type() == message.get_type()
            self.delivered += 1
            out.append(parsed)
        return out


def items(n: int) -> list[MissionItem]:
    """A mission of ``n`` waypoints with distinct local coordinates."""
    return [
        MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_FRAME_LOCAL_NED, 0.37 * i, -1.25 * i, -1.5, param2=0.1)
        for i in range(n)
    ]


def transfer(upload: MissionUpload, receiver: MissionReceiver, wire: Wire, limit: float = 600.0, dt: float = 0.01):
    """Run both machines on a simulated clock until the upload finishes; returns the time it took."""
    now = 0.0
    to_vehicle = wire.carry(upload.start(now), wire.gcs, wire.vehicle)
    to_gcs: list = []
    while not upload.finished and now < limit:
        for message in to_vehicle:
            to_gcs += wire.carry(receiver.on_message(message, GCS, now), wire.vehicle, wire.gcs)
        to_vehicle = []
        for message in to_gcs:
            to_vehicle += wire.carry(upload.on_message(message, now), wire.gcs, wire.vehicle)
        to_gcs = []
        now += dt
        to_gcs += wire.carry(receiver.on_timer(now), wire.vehicle, wire.gcs)
        to_vehicle += wire.carry(upload.on_timer(now), wire.gcs, wire.vehicle)
    return now


def same_mission(received: list[MissionItem], sent: list[MissionItem]) -> bool:
    return len(received) == len(sent) and all(a.same_as(b) for a, b in zip(received, sent, strict=True))


# ----------------------------------------------------------------------------- items on the wire


def test_local_items_are_sent_in_tenths_of_a_millimetre():
    """mavlink.io: local-frame positions in MISSION_ITEM_INT are metres * 1e4."""
    item = MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_FRAME_LOCAL_NED, 5.0, -2.34567, -1.5)
    message = item.encode(3, 1, 1)
    assert (message.x, message.y, message.z, message.seq) == (50000, -23457, -1.5, 3)
    back = MissionItem.decode(message)
    assert back.x == pytest.approx(5.0) and back.y == pytest.approx(-2.3457)
    assert back.same_as(item)


def test_global_items_are_sent_in_units_of_1e7_degrees():
    item = MissionItem(
        mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 47.3977419, 8.5455938, 10
    )
    message = item.encode(0, 1, 1)
    assert (message.x, message.y) == (473977419, 85455938)
    assert MissionItem.decode(message).x == pytest.approx(47.3977419, abs=1e-9)


def test_result_and_enum_names():
    assert result_text(mavlink.MAV_MISSION_NO_SPACE).startswith("MAV_MISSION_NO_SPACE (4)")
    assert enum_value("MAV_MISSION_RESULT", "NO_SPACE") == 4
    assert enum_value("MAV_MISSION_RESULT", "MAV_MISSION_DENIED") == mavlink.MAV_MISSION_DENIED
    with pytest.raises(ValueError, match=r"choose one of: .*MAV_MISSION_NO_SPACE"):
        enum_value("MAV_MISSION_RESULT", "NO_ROOM")


def test_signing_keys_from_hex_or_passphrase():
    hexkey = "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff"
    assert signing_key(hexkey) == bytes.fromhex(hexkey)
    import hashlib

    assert signing_key("my passphrase") == hashlib.sha256(b"my passphrase").digest()
    with pytest.raises(ValueError):
        signing_key("   ")


# ----------------------------------------------------------------------------- uploads


def test_clean_upload_needs_one_request_per_item():
    wire = Wire()
    upload = MissionUpload(items(12), *VEHICLE)
    receiver = MissionReceiver(*VEHICLE)
    transfer(upload, receiver, wire)
    assert upload.state == "done"
    assert same_mission(receiver.mission, items(12))
    assert upload.stats.requests == 12 and upload.stats.retransmissions == 0
    # COUNT, 12 items; 12 requests and the ACK
    assert wire.delivered == 1 + 12 + 12 + 1


@pytest.mark.parametrize("loss", [0.2, 0.4])
def test_upload_survives_heavy_loss_both_ways(loss):
    """Every message dropped with probability ``loss`` in each direction; the mission still arrives intact."""
    for seed in range(3):
        wire = Wire(loss=loss, seed=seed)
        upload = MissionUpload(items(40), *VEHICLE, retries=10)
        receiver = MissionReceiver(*VEHICLE, retries=20)
        transfer(upload, receiver, wire)
        assert upload.state == "done", upload.error
        assert same_mission(receiver.mission, items(40))
        assert wire.dropped > 0
        assert receiver.stats.rerequests > 0  # the vehicle asked again for what was lost


def test_upload_answers_shuffled_and_repeated_requests():
    wire = Wire()
    upload = MissionUpload(items(30), *VEHICLE)
    receiver = MissionReceiver(*VEHICLE, faults=ReceiverFaults(shuffle=True, repeat=0.5, seed=4))
    transfer(upload, receiver, wire)
    assert upload.state == "done"
    assert same_mission(receiver.mission, items(30))
    assert upload.stats.out_of_order_requests > 10
    assert upload.stats.repeated_requests == receiver.stats.rerequests > 5


def test_out_of_sequence_item_is_dropped_and_the_expected_one_requested_again():
    receiver = MissionReceiver(*VEHICLE)
    [request] = receiver.on_message(mavlink.MAVLink_mission_count_message(*VEHICLE, 3, 0), GCS, 0.0)
    assert request.seq == 0
    [again] = receiver.on_message(items(3)[2].encode(2, *VEHICLE), GCS, 0.1)
    assert again.get_type() == "MISSION_REQUEST_INT" and again.seq == 0
    assert receiver.stats.out_of_sequence == 1
    [next_request] = receiver.on_message(items(3)[0].encode(0, *VEHICLE), GCS, 0.2)
    assert next_request.seq == 1
    # a late duplicate of item 0 changes nothing and asks for nothing
    assert receiver.on_message(items(3)[0].encode(0, *VEHICLE), GCS, 0.3) == []
    assert receiver.stats.duplicates == 1


def test_lost_final_ack_is_repeated_when_the_last_item_comes_again():
    receiver = MissionReceiver(*VEHICLE)
    mission = items(2)
    receiver.on_message(mavlink.MAVLink_mission_count_message(*VEHICLE, 2, 0), GCS, 0.0)
    receiver.on_message(mission[0].encode(0, *VEHICLE), GCS, 0.1)
    [ack] = receiver.on_message(mission[1].encode(1, *VEHICLE), GCS, 0.2)
    assert ack.type == mavlink.MAV_MISSION_ACCEPTED
    # the ground station did not get it and sends the last item again after its timeout
    [again] = receiver.on_message(mission[1].encode(1, *VEHICLE), GCS, 1.7)
    assert again.get_type() == "MISSION_ACK" and again.type == mavlink.MAV_MISSION_ACCEPTED
    # any other item while idle: the vehicle cancels, so that the ground station learns at once
    [cancel] = receiver.on_message(mission[0].encode(0, *VEHICLE), GCS, 1.8)
    assert cancel.type == mavlink.MAV_MISSION_OPERATION_CANCELLED


def test_stray_accepted_ack_does_not_end_an_upload():
    upload = MissionUpload(items(3), *VEHICLE)
    upload.start(0.0)
    upload.on_message(mavlink.MAVLink_mission_ack_message(*GCS, mavlink.MAV_MISSION_ACCEPTED, 0), 0.1)
    assert upload.state == "sending" and upload.stats.stray_acks == 1


def test_deprecated_mission_request_is_answered_with_mission_item_int():
    upload = MissionUpload(items(2), *VEHICLE)
    upload.start(0.0)
    [answer] = upload.on_message(mavlink.MAVLink_mission_request_message(*GCS, 1, 0), 0.1)
    assert answer.get_type() == "MISSION_ITEM_INT" and answer.seq == 1
    assert upload.on_message(mavlink.MAVLink_mission_request_int_message(*GCS, 7, 0), 0.2) == []
    assert upload.stats.invalid_requests == 1


def test_vehicle_refusing_at_count_fails_the_upload_with_its_result():
    wire = Wire()
    upload = MissionUpload(items(5), *VEHICLE)
    receiver = MissionReceiver(*VEHICLE, capacity=4)
    transfer(upload, receiver, wire)
    assert upload.state == "failed" and upload.result == mavlink.MAV_MISSION_NO_SPACE
    assert "MAV_MISSION_NO_SPACE (4)" in upload.error
    assert receiver.mission == []  # the previous (empty) mission stays


def test_vehicle_refusing_an_item_keeps_its_previous_mission():
    wire = Wire()
    receiver = MissionReceiver(*VEHICLE)
    transfer(MissionUpload(items(3), *VEHICLE), receiver, wire)
    unsupported = MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_FRAME_BODY_FRD, 1, 2, 3)

    def validate(item, seq, mission_type, int_form):
        return mavlink.MAV_MISSION_UNSUPPORTED_FRAME if item.frame == mavlink.MAV_FRAME_BODY_FRD else None

    receiver.validate = validate
    upload = MissionUpload([*items(2), unsupported], *VEHICLE)
    transfer(upload, receiver, wire)
    assert upload.result == mavlink.MAV_MISSION_UNSUPPORTED_FRAME
    assert same_mission(receiver.mission, items(3))


def test_silent_vehicle_fails_the_upload_after_the_retries():
    upload = MissionUpload(items(3), *VEHICLE, timeout=1.5, retries=5)
    sent = upload.start(0.0)
    now = 0.0
    while not upload.finished:
        now += 0.01
        sent += upload.on_timer(now)
    assert [m.get_type() for m in sent] == ["MISSION_COUNT"] * 6
    assert now == pytest.approx(6 * 1.5, abs=0.1)
    assert upload.error == (
        "the vehicle stopped answering: waited for an answer to MISSION_COUNT through 6 attempts, 1.5 s apart; "
        "0 of 3 items had been requested"
    )


def test_vehicle_gives_up_and_cancels_when_items_stop_coming():
    receiver = MissionReceiver(*VEHICLE, timeout=0.25, retries=3)
    receiver.on_message(mavlink.MAVLink_mission_count_message(*VEHICLE, 3, 0), GCS, 0.0)
    sent = []
    now = 0.0
    while receiver.busy:
        now += 0.05
        sent += receiver.on_timer(now)
    assert [m.get_type() for m in sent] == ["MISSION_REQUEST_INT"] * 3 + ["MISSION_ACK"]
    assert sent[-1].type == mavlink.MAV_MISSION_OPERATION_CANCELLED


def test_empty_upload_clears_the_mission():
    wire = Wire()
    receiver = MissionReceiver(*VEHICLE)
    transfer(MissionUpload(items(3), *VEHICLE), receiver, wire)
    upload = MissionUpload([], *VEHICLE)
    transfer(upload, receiver, wire)
    assert upload.state == "done" and receiver.mission == []


# ----------------------------------------------------------------------------- commands


def test_command_is_resent_with_increasing_confirmation_until_acknowledged():
    command = CommandTransaction(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [1], VEHICLE, timeout=1.5, retries=5)
    [first] = command.start(0.0)
    assert first.confirmation == 0 and first.param1 == 1
    [second] = command.on_timer(1.5)
    [third] = command.on_timer(3.0)
    assert (second.confirmation, third.confirmation) == (1, 2)
    ack = mavlink.MAVLink_command_ack_message(
        mavlink.MAV_CMD_COMPONENT_ARM_DISARM, mavlink.MAV_RESULT_ACCEPTED, 0, 0, *GCS
    )
    command.on_message(ack, 3.1)
    assert command.finished and command.result == mavlink.MAV_RESULT_ACCEPTED


def test_command_in_progress_waits_longer_then_takes_the_final_result():
    command = CommandTransaction(mavlink.MAV_CMD_MISSION_START, [], VEHICLE, timeout=1.5, in_progress_timeout=10)
    command.start(0.0)
    progress = mavlink.MAVLink_command_ack_message(
        mavlink.MAV_CMD_MISSION_START, mavlink.MAV_RESULT_IN_PROGRESS, 40, 0, *GCS
    )
    command.on_message(progress, 1.0)
    assert not command.finished and command.progress == 40
    assert command.on_timer(5.0) == []  # no resend while the vehicle works on it
    other = mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_NAV_LAND, mavlink.MAV_RESULT_DENIED, 0, 0, *GCS)
    command.on_message(other, 6.0)
    assert not command.finished  # an acknowledgement of another command
    denied = mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_MISSION_START, mavlink.MAV_RESULT_DENIED, 0, 0, *GCS)
    command.on_message(denied, 7.0)
    assert command.result == mavlink.MAV_RESULT_DENIED


def test_command_times_out_after_its_retries():
    command = CommandTransaction(mavlink.MAV_CMD_NAV_LAND, [], VEHICLE, timeout=1.0, retries=2)
    sent = command.start(0.0)
    now = 0.0
    while not command.finished:
        now += 0.25
        sent += command.on_timer(now)
    assert len(sent) == 3 and command.timed_out and math.isclose(now, 3.0)


# ----------------------------------------------------------------------------- downloads and clears


def download_over(wire: Wire, sender: MissionSender, download: MissionDownload, limit: float = 600.0, dt=0.01):
    """Run a download on a simulated clock until it finishes; returns the time it took."""
    now = 0.0
    to_vehicle = wire.carry(download.start(now), wire.gcs, wire.vehicle)
    while not download.finished and now < limit:
        to_gcs = []
        for message in to_vehicle:
            to_gcs += wire.carry(sender.on_message(message, GCS, now), wire.vehicle, wire.gcs)
        to_vehicle = []
        for message in to_gcs:
            to_vehicle += wire.carry(download.on_message(message, now), wire.gcs, wire.vehicle)
        now += dt
        sender.on_timer(now)
        to_vehicle += wire.carry(download.on_timer(now), wire.gcs, wire.vehicle)
    return now


def stored_sender(mission: list[MissionItem]) -> MissionSender:
    return MissionSender(lambda mission_type: len(mission), lambda seq, mission_type, int_form: mission[seq])


@pytest.mark.parametrize("loss", [0.2, 0.4])
def test_download_survives_heavy_loss_and_brings_back_the_mission(loss):
    """The ground station re-requests a lost item every 0.5 s, as often as the list's own patience allows
    (1.5 s x 6 attempts): at 40 % loss each way a round trip fails 64 % of the time, and still every item
    of every seed arrives, and equal to what the vehicle holds."""
    mission = items(40)
    for seed in range(3):
        wire = Wire(loss=loss, seed=seed)
        download = MissionDownload(*VEHICLE, timeout=1.5, retries=5, item_timeout=0.5)
        download_over(wire, stored_sender(mission), download)
        assert download.state == "done", download.error
        assert compare_missions(mission, download.items) is None
        assert download.retransmissions > 0 and wire.dropped > 0


def test_download_of_an_empty_list_and_a_vehicle_that_refuses():
    download = MissionDownload(*VEHICLE)
    download_over(Wire(), stored_sender([]), download)
    assert download.state == "done" and download.items == []
    refused = MissionDownload(*VEHICLE)
    refused.start(0.0)
    refused.on_message(mavlink.MAVLink_mission_ack_message(*GCS, mavlink.MAV_MISSION_DENIED, 0), 0.1)
    assert refused.state == "failed" and "MAV_MISSION_DENIED" in refused.error


def test_verification_compares_what_a_vehicle_keeps():
    """PX4 answers a MISSION_REQUEST_INT with frame 6 for an item uploaded in frame 3, keeps a waypoint's
    hold time, radius and yaw (wrapped to [0, 360)) but not its param3: the same mission. A moved waypoint,
    a changed radius or a missing item is a difference, named."""
    sent = [
        MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, 3, 47.3977419, 8.5455938, 3.0, 1.0, 0.4, 0.7, -90.0),
        MissionItem(mavlink.MAV_CMD_DO_CHANGE_SPEED, mavlink.MAV_FRAME_MISSION, 0, 0, 0, 1, 2.5, -1, 0),
    ]
    kept = [
        MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, 6, 47.3977419, 8.5455938, 3.0, 1.0, 0.4, 0.0, 270.0),
        sent[1],
    ]
    assert compare_missions(sent, kept) is None
    moved = [MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, 6, 47.3977420, 8.5455938, 3.0, 1.0, 0.4, 0.0, 270.0), sent[1]]
    assert compare_missions(sent, moved).startswith("item 0 (MAV_CMD_NAV_WAYPOINT): x 47.3977419 came back as")
    radius = [MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, 6, 47.3977419, 8.5455938, 3.0, 1.0, 0.5, 0.0, 270.0), sent[1]]
    assert "param2 0.4 came back as 0.5" in compare_missions(sent, radius)
    assert compare_missions(sent, sent[:1]) == "2 items were uploaded, the vehicle holds 1"
    absolute = [MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, 5, 47.3977419, 8.5455938, 3.0, 1.0, 0.4, 0.0, 270.0), sent[1]]
    assert "frame MAV_FRAME_GLOBAL_RELATIVE_ALT came back as MAV_FRAME_GLOBAL_INT" in compare_missions(sent, absolute)


def test_items_in_the_current_global_frames_are_scaled_in_mission_item_int():
    """Frames 0 and 3 (not only their deprecated _INT twins) carry degrees * 1e7 in MISSION_ITEM_INT; the
    deprecated MISSION_ITEM carries floats; NaN (use the current position) travels as INT32_MAX."""
    for frame in (0, 3, 5, 6):
        message = MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, frame, 47.3977419, 8.5455938, 10).encode(0, 1, 1)
        assert (message.x, message.y) == (473977419, 85455938)
        assert MissionItem.decode(message).x == pytest.approx(47.3977419, abs=1e-9)
    legacy = MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, 3, 47.3977419, 8.5455938, 10).encode(0, 1, 1, legacy=True)
    assert legacy.get_type() == "MISSION_ITEM" and legacy.x == pytest.approx(47.3977419, abs=4e-6)
    here = MissionItem(mavlink.MAV_CMD_NAV_TAKEOFF, 3, math.nan, math.nan, 3).encode(0, 1, 1)
    assert (here.x, here.y) == (2**31 - 1, 2**31 - 1) and math.isnan(MissionItem.decode(here).x)
