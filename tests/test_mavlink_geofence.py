"""The simulated vehicle enforces its geofence as PX4 does: feasibility, breaches and GF_ACTION, returns to rally.

Flights here are stepped directly on the simulated vehicle (no link, no thread: exactly reproducible and
fast), the lists stored as its mission protocol stores them; the protocol itself (MISSION_ACK, STATUSTEXT)
is exercised over UDP at the end and by MAVSDK and MAVProxy in tests/interop. Every outcome is measured on
the simulator's own states (its position at every 10 ms step), not on what it says.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from surgiplan.plugins.devices.mavlink.gcs import GroundStation
from surgiplan.plugins.devices.mavlink.link import Endpoint, VehicleError, mavlink
from surgiplan.plugins.devices.mavlink.mission import FENCE, RALLY, MissionItem
from surgiplan.plugins.devices.mavlink.sim.geofence import CHECK_INTERVAL
from surgiplan.plugins.devices.mavlink.sim.model import braking_distance
from surgiplan.plugins.devices.mavlink.sim.settings import Airframe, SimSettings
from surgiplan.plugins.devices.mavlink.sim.vehicle import SimulatedVehicle
from surgiplan.plugins.devices.mavlink.zones import Zone, fence_items, rally_items

#: a pillar's zone 8 m north of home: a circle of 1 m about (8, 0)
PILLAR = Zone.circle((8.0, 0.0), 1.0)


def vehicle_with(zones=(PILLAR,), rally=(), **settings) -> SimulatedVehicle:
    """A simulated vehicle (not running: the test steps it) holding ``zones`` and ``rally`` points (NED)."""
    v = SimulatedVehicle(SimSettings(**settings))
    for kind, items in ((FENCE, fence_items(list(zones), v.projection)),):
        v.receiver.stored[kind] = items
        v._mission_accepted(items, kind)
    if rally:
        points = np.asarray(rally, float)
        items = rally_items(points[:, :2], v.projection, -points[:, 2])
        v.receiver.stored[RALLY] = items
        v._mission_accepted(items, RALLY)
    return v


def step(v: SimulatedVehicle, seconds: float, until=None) -> np.ndarray:
    """Advance ``seconds`` of vehicle time (or until ``until(v)``); the true positions (NED) at every step."""
    out = []
    for _ in range(round(seconds / v.settings.step)):
        v._physics(v.settings.step)
        out.append(v.model.p.copy())
        if until is not None and until(v):
            break
    return np.array(out)


def take_off(v: SimulatedVehicle, height: float = 2.0) -> None:
    assert v._arm("test") == mavlink.MAV_RESULT_ACCEPTED
    v._takeoff_request = height
    assert v._set_mode("takeoff", force=True)
    step(v, 20, until=lambda v: v.mode == "hold")
    assert -v.model.p[2] == pytest.approx(height, abs=0.05)


def goto(v: SimulatedVehicle, north: float, east: float, speed: float) -> np.ndarray:
    """A manual goto (DO_REPOSITION) to (north, east) at the current height, until it arrives or the geofence
    acts, and 8 s more; the positions flown."""
    v.mode = "hold"
    v._fly_to(np.array([north, east, v.model.p[2]]), speed)
    flown = step(v, 60, until=lambda v: bool(v.fence_breaches) or v.guidance is None)
    return np.vstack([flown, step(v, 8.0, until=lambda v: not v.armed)])


def distance_to_pillar(positions: np.ndarray) -> np.ndarray:
    return np.hypot(positions[:, 0] - 8.0, positions[:, 1])


@pytest.mark.parametrize("speed", [0.5, 1.5, 3.0])
def test_with_prediction_the_vehicle_holds_before_the_fence(speed):
    v = vehicle_with(geofence_predict=1)
    take_off(v)
    flown = goto(v, 16.0, 0.0, speed)  # straight through the pillar
    breach = v.fence_breaches[0]
    assert len(v.fence_breaches) == 1 and breach["kind"] == "fence" and breach["action"] == "hold"
    assert v.mode == "hold" and np.linalg.norm(v.model.v) < 0.02
    # it never entered the zone: it braked within its braking distance, which the check looked ahead by
    assert distance_to_pillar(flown).min() >= 1.0
    # the overshoot after the breach is the documented braking distance (the position loop's, ~0.30 s x v)
    after = flown[np.argmin(np.abs(np.arange(len(flown)) * 0.01 - (breach["t"] - (v.t - len(flown) * 0.01)))) :]
    overshoot = after[:, 0].max() - breach["position"][0]
    predicted = braking_distance(Airframe(), np.linalg.norm(breach["velocity"]))
    if speed <= 2.0:  # the loop's own overshoot: as integrated
        assert overshoot == pytest.approx(predicted, abs=0.02)
    else:  # braking at the thrust limit (the 1D estimate spends it all along the motion): within it
        assert overshoot <= predicted
    # and it settles back where the breach was predicted (its velocity integral slows the last cm), at most
    # the look-ahead (and one check's travel) before the fence
    ahead = CHECK_INTERVAL * speed + braking_distance(Airframe(), speed)
    assert v.model.p[0] == pytest.approx(breach["position"][0], abs=0.05)
    assert 0 < 7.0 - v.model.p[0] <= ahead + CHECK_INTERVAL * speed + 0.05
    # what it said, and SYS_STATUS: present, enabled, not healthy while breached
    assert any(text == "Geofence breached (fence): holding" for _, text in v.events)


def test_without_prediction_the_vehicle_holds_beyond_the_fence_by_its_braking_distance():
    v = vehicle_with(geofence_predict=0)
    take_off(v)
    flown = goto(v, 16.0, 0.0, 1.5)
    entered = 1.0 - distance_to_pillar(flown).min()
    # PX4 without GF_PREDICT: the breach is seen at the next check after the crossing, then it brakes
    assert 0 < entered <= CHECK_INTERVAL * 1.5 + braking_distance(Airframe(), 1.5) + 0.01
    # it holds at the fence (settling back and forth across it, each crossing a breach again, as PX4's)
    assert v.mode == "hold" and abs(distance_to_pillar(v.model.p[None])[0] - 1.0) < 0.1
    assert v.fence_breaches[0]["test_point"] == v.fence_breaches[0]["position"]  # no look-ahead


@pytest.mark.parametrize("action", [1, 3, 4, 5], ids=["warning", "return", "terminate", "land"])
def test_each_gf_action_does_what_px4_does(action):
    v = vehicle_with(geofence_action=action, rally=[(6.0, -4.0, 0.0)], rtl_return_altitude=3.0)
    take_off(v)
    flown = goto(v, 16.0, 0.0, 1.5)
    words = {1: "warning", 3: "returning", 4: "terminating", 5: "landing"}[action]
    assert v.fence_breaches[0]["action"] == {1: "warning", 3: "return", 4: "terminate", 5: "land"}[action]
    assert any(text == f"Geofence breached (fence): {words}" for _, text in v.events)
    if action == 1:  # a warning only: it flies on, through the zone, to where it was sent
        assert distance_to_pillar(flown).min() < 0.1 and v.model.p[0] == pytest.approx(16.0, abs=0.05)
        return
    step(v, 60, until=lambda v: not v.model.airborne and not v.armed)
    assert not v.armed and not v.model.airborne and v.model.p[2] == pytest.approx(0.0)
    where = v.model.p[:2]
    if action == 3:  # to the nearest of home (7 m away) and the rally point (6, -4) (4.1 m): the rally point
        assert np.linalg.norm(where - [6.0, -4.0]) < 0.35 and "return to rally point 0" in [t for _, t in v.events]
    elif action == 5:  # land where it is
        assert np.linalg.norm(where - v.fence_breaches[0]["position"][:2]) < 0.6
    else:  # motors off: it falls from 2 m (0.64 s) on ahead of where it was, at 1.5 m/s less drag
        assert "Flight termination (geofence)" in [t for _, t in v.events]
        assert where[0] - v.fence_breaches[0]["position"][0] == pytest.approx(1.5 * math.sqrt(2 * 2 / 9.81), abs=0.1)


@pytest.mark.parametrize(("rtl_type", "home", "rally", "lands_at"), [
    (0, (0, 0), [(10, 0)], (0, 0)),  # RTL_TYPE 0: the nearest of home and the rally points: home
    (1, (0, 0), [(10, 0), (-9, 0)], (10, 0)),  # RTL_TYPE 1: the nearest rally point, even with home nearer
    (1, (0, 0), [], (0, 0)),  # RTL_TYPE 1 without rally points: home
])  # fmt: skip
def test_return_goes_to_the_rally_point_rtl_type_chooses(rtl_type, home, rally, lands_at):
    v = vehicle_with(zones=(), rally=[(n, e, 0.0) for n, e in rally], rtl_type=rtl_type, rtl_return_altitude=3.0)
    take_off(v)
    goto(v, 3.0, 1.0, 2.0)
    assert v._set_mode("return", force=True)
    flown = step(v, 60, until=lambda v: not v.armed)
    assert not v.armed and np.linalg.norm(v.model.p[:2] - lands_at) < 0.35
    assert -flown[:, 2].min() == pytest.approx(3.0, abs=0.1)  # the climb to RTL_RETURN_ALT above it


def test_the_ceiling_is_gf_max_ver_dist_above_home():
    v = vehicle_with(zones=(), geofence_max_vertical=3.0, geofence_predict=1)
    take_off(v, 2.0)
    v.mode = "hold"
    v._fly_to(np.array([0.0, 0.0, -6.0]), 1.0)
    flown = step(v, 20, until=lambda v: v.fence_breaches and np.linalg.norm(v.model.v) < 0.02)
    assert v.fence_breaches[0]["kind"] == "max altitude" and -flown[:, 2].max() < 3.0


def test_sys_status_says_present_enabled_and_healthy_until_breached():
    def bits(v):
        m = v._msg_sys_status()
        b = mavlink.MAV_SYS_STATUS_GEOFENCE
        return [bool(x & b) for x in (m.onboard_control_sensors_present, m.onboard_control_sensors_enabled,
                                      m.onboard_control_sensors_health)]  # fmt: skip

    assert bits(vehicle_with(zones=())) == [False, False, True]  # no fence: healthy (MAVProxy reads it so)
    assert bits(vehicle_with(geofence_action=0)) == [True, False, True]
    v = vehicle_with(geofence_predict=1)
    assert bits(v) == [True, True, True]
    take_off(v)
    v.mode = "hold"
    v._fly_to(np.array([16.0, 0.0, v.model.p[2]]), 1.5)
    step(v, 30, until=lambda v: bool(v.fence_breaches))
    assert bits(v) == [True, True, False]


def test_a_fence_that_leaves_home_outside_is_dropped_as_px4_drops_it():
    v = vehicle_with(zones=(PILLAR, Zone.circle((0.0, 0.0), 2.0), Zone.polygon([[1, 1], [5, 1], [5, 5]], True)))
    # home (0, 0) is inside the second circle and outside the inclusion triangle: both dropped, the pillar kept
    assert [z.radius for z in v.zones] == [1.0]
    assert sum(text == "Geofence invalid, doesn't contain Home position" for _, text in v.events) == 2


def waypoint(v: SimulatedVehicle, north: float, east: float, height: float = 2.0, command=None) -> MissionItem:
    lat, lon = v.projection.reproject(north, east)
    return MissionItem(command or mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, float(lat),
                       float(lon), height)  # fmt: skip


def test_missions_that_leave_the_fence_are_refused_over_the_link():
    """PX4's feasibility check, over UDP with the device's own ground station: MISSION_ACK DENIED and PX4's
    STATUSTEXT; a mission a later fence makes infeasible is refused when started."""
    with SimulatedVehicle(SimSettings(speed=10.0)).start() as v:
        link = Endpoint(f"udpout:127.0.0.1:{v.port}", system_id=255, component_id=190)
        try:
            gcs = GroundStation(link, mission_timeout=0.5, item_timeout=0.2)
            gcs.connect(10)
            gcs.upload(fence_items([PILLAR], v.projection), mission_type=FENCE)
            takeoff = waypoint(v, 0, 0, 2.0, mavlink.MAV_CMD_NAV_TAKEOFF)
            into = [takeoff, waypoint(v, 4, 0), waypoint(v, 8.5, 0.3), waypoint(v, 12, 0)]
            with pytest.raises(VehicleError, match=r"MAV_MISSION_DENIED"):
                gcs.upload(into)
            gcs.pump(0.3)
            assert "Geofence violation for waypoint 3" in gcs.vehicle.statustext
            across = [takeoff, waypoint(v, 4, 0), waypoint(v, 12, 0)]
            with pytest.raises(VehicleError, match=r"MAV_MISSION_DENIED"):
                gcs.upload(across)
            gcs.pump(0.3)
            assert "Geofence breach on path to waypoint 3" in gcs.vehicle.statustext
            around = [takeoff, waypoint(v, 4, 0), waypoint(v, 8, 2.5), waypoint(v, 12, 0)]
            gcs.upload(around)
            assert len(v.mission) == 4
            # a fence uploaded afterwards across the mission: refused at its start, with PX4's words
            gcs.upload(fence_items([Zone.circle((8.0, 2.5), 0.5)], v.projection), mission_type=FENCE)
            gcs.step = "mission start"
            with pytest.raises(VehicleError, match=r"MISSION_START with MAV_RESULT_DENIED"):
                gcs.command(mavlink.MAV_CMD_MISSION_START, [0, 0])
            assert gcs.vehicle.statustext[-1] == "Geofence violation for waypoint 3"
        finally:
            link.close()
    assert not v.armed


def test_the_documented_braking_distance():
    """0.30 s x v up to 2 m/s (the position loop's overshoot with the default gains), v^2 / 8 at 5 m/s
    (the thrust authority, 4 m/s^2, then limits the braking)."""
    airframe = Airframe()
    for speed in (0.5, 1.0, 1.5, 2.0):
        assert braking_distance(airframe, speed) == pytest.approx(0.30 * speed, rel=0.02)
    assert braking_distance(airframe, 5.0) == pytest.approx(5.0**2 / 8, rel=0.02)
    # the integrated loop, against the closed form without the velocity integral: v e^-t sin t peaks at pi/4
    free = airframe.model_copy(update={"velocity_integral": 0.0})
    assert braking_distance(free, 1.0) == pytest.approx(math.exp(-math.pi / 4) * math.sin(math.pi / 4), abs=0.01)
