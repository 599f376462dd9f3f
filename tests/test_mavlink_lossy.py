"""Lossy links: every list and the parameters get through 30 % loss each way, and every retry is bounded.

Over UDP to the simulated vehicle, whose link drops 30 % of the messages in each direction (seeded): the
whole parameter list, a fence, rally points and a mission, each uploaded and downloaded back, all complete
and arrive intact, compared with what the vehicle holds. The protocol timeouts are shortened for the test
(loopback answers in microseconds); benchmarks/bench_mavlink.py measures the defaults (the README's table).
Then the bounds, without I/O: a vehicle that keeps asking, or never answers, ends each transfer within its
retries and its time.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from surgiplan.plugins.devices.mavlink.gcs import GroundStation
from surgiplan.plugins.devices.mavlink.link import Endpoint, mavlink
from surgiplan.plugins.devices.mavlink.mission import FENCE, MISSION, RALLY, MissionItem, compare_missions
from surgiplan.plugins.devices.mavlink.mission_gcs import MissionDownload, MissionUpload
from surgiplan.plugins.devices.mavlink.sim.settings import SimSettings
from surgiplan.plugins.devices.mavlink.sim.vehicle import SimulatedVehicle
from surgiplan.plugins.devices.mavlink.transactions import ParamDownload
from surgiplan.plugins.devices.mavlink.zones import Zone, fence_items, rally_items

LOSS = 0.3


def hall_like_fence(projection) -> list[MissionItem]:
    zones = [Zone.polygon([[0, 0], [24, 0], [24, 12], [0, 12]], inclusion=True)]
    zones += [Zone.circle((3.0 + 2 * k, 5.0), 1.0) for k in range(7)]
    zones += [Zone.polygon([[11, 0], [12, 0], [12.3, 2], [12, 5], [11, 5]])]
    return fence_items(zones, projection)


def test_parameters_fence_rally_and_mission_get_through_thirty_percent_loss_each_way():
    settings = SimSettings(speed=5.0, packet_loss=LOSS, seed=11, mission_timeout=0.05)
    with SimulatedVehicle(settings).start() as vehicle:
        link = Endpoint(f"udpout:127.0.0.1:{vehicle.port}", system_id=255, component_id=190)
        try:
            gcs = GroundStation(link, missed_heartbeats=30, command_timeout=0.3, mission_timeout=0.3, item_timeout=0.1)
            gcs.connect(20)
            download = gcs.download_params()
            fence = hall_like_fence(vehicle.projection)
            rally = rally_items(np.array([[1.0, 1.0], [20.0, 5.0]]), vehicle.projection, [0.0, 0.0])
            lat, lon = vehicle.projection.reproject(np.arange(16) * 1.5, np.zeros(16))
            mission = [
                MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, 3, float(a), float(o), 2.0)
                for a, o in zip(lat, lon, strict=True)
            ]
            results = {}
            for kind, items in ((FENCE, fence), (RALLY, rally), (MISSION, mission)):
                stats, transfers = gcs.upload(items, mission_type=kind)
                results[kind] = (items, gcs.download(kind), stats, transfers)
            held = {kind: list(vehicle.receiver.stored[kind]) for kind in (FENCE, RALLY, MISSION)}
            values = {p: np.float32(vehicle.params.value(p)) for p in download.values}  # REAL32 on the wire
            vehicle_link = vehicle.link_statistics()
        finally:
            link.close()
    # every parameter, with the value the vehicle has (INT32 decoded bytewise), though a third went missing
    assert len(download.values) == download.count == 26
    assert {name: np.float32(value) for name, (value, _) in download.values.items()} == values
    assert download.read_requests > 0  # what the list's stream lost was asked for again, by index
    for kind, (items, back, stats, transfers) in results.items():
        assert compare_missions(items, back) is None, kind  # downloaded back as sent
        assert compare_missions(items, held[kind]) is None, kind  # and that is what the vehicle holds
        assert transfers <= 3 and stats.requests >= len(items)
    # the loss was real: the vehicle dropped about 30 % of what it sent and of what it received
    sent = vehicle_link["messages_sent"]  # counted before the link drops them
    received = vehicle_link["messages_received"] + vehicle_link["injected_drops_in"]
    # each message is dropped with probability LOSS: the share dropped is binomial, within 4 standard deviations
    # (a fixed 0.05 failed one run in five at the ~140 messages a direction this flight sends)
    for dropped, total in ((vehicle_link["injected_drops_out"], sent), (vehicle_link["injected_drops_in"], received)):
        assert dropped / total == pytest.approx(LOSS, abs=max(0.05, 4 * math.sqrt(LOSS * (1 - LOSS) / total)))


def items(n: int) -> list[MissionItem]:
    return [MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, 3, 47.0 + 1e-5 * k, 8.0, 2.0) for k in range(n)]


def request(seq: int, mission_type: int = MISSION):
    return mavlink.MAVLink_mission_request_int_message(255, 190, seq, mission_type)


def test_an_upload_to_a_vehicle_that_keeps_asking_ends_in_bounded_time():
    """Each request restarts the wait for the next one: without a bound on the whole transfer, a vehicle that
    asks for item 0 for ever would hold the ground station for ever."""
    upload = MissionUpload(items(4), 1, 1, timeout=1.5, retries=5)
    upload.start(0.0)
    limit = 1.5 * 6 * (4 + 1) + 1.5  # timeout x (retries + 1) x (items + 1), and one more timeout
    now = 0.0
    while upload.state == "sending" and now < 10 * limit:
        now += 0.5
        upload.on_message(request(0), now)
        upload.on_timer(now)
    assert upload.state == "failed" and now == pytest.approx(limit, abs=0.5)
    assert upload.error.startswith("the transfer did not finish within 46.5 s, the time its timeouts and retries allow")
    assert upload.stats.repeated_requests > 80


def test_downloads_and_parameter_lists_from_a_silent_vehicle_end_after_their_retries():
    download = MissionDownload(1, 1, timeout=1.5, retries=5, mission_type=FENCE)
    sent = download.start(0.0)
    times = [t / 10 for t in range(1, 200)]
    for now in times:
        sent += download.on_timer(now)
        if download.finished:
            break
    # MISSION_REQUEST_LIST, then 5 more, 1.5 s apart; given up after the sixth wait
    assert download.state == "failed" and len(sent) == 6 and now == pytest.approx(9.0)
    assert "waited for MISSION_COUNT through 6 attempts, 1.5 s apart" in download.error

    params = ParamDownload((1, 1), timeout=1.5, retries=5, item_timeout=0.5, item_retries=3)
    sent = params.start(0.0)
    for now in times:
        sent += params.on_timer(now)
        if params.finished:
            break
    assert params.failed and len(sent) == 6 and params.list_requests == 6 and now == pytest.approx(9.0)
    # a list whose parameter 2 never arrives: asked for by index item_retries + 1 times, then given up
    params = ParamDownload((1, 1), timeout=1.5, retries=5, item_timeout=0.5, item_retries=3)
    params.start(0.0)
    for index in (0, 1, 3):
        value = mavlink.MAVLink_param_value_message(f"P{index}".encode(), 1.0, 9, 4, index)
        params.on_message(value, 0.1)
    asked = []
    for now in times:
        asked += params.on_timer(now)
        if params.finished:
            break
    assert params.failed and [m.param_index for m in asked] == [2] * 4
    assert params.error == "parameter 2 did not arrive after 4 requests by index (3 of 4 received)"
    assert now < 0.1 + 0.5 * 5 + 1e-9 and math.isfinite(params.give_up_at)
