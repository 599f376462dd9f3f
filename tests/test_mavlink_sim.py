"""The simulated vehicle as a MAVLink peer: commands, refusals, global missions, its command line."""

from __future__ import annotations

import contextlib
import hashlib
import math
import time
from types import SimpleNamespace

import numpy as np
import pytest
from surgiplan.plugins.devices.mavlink.conventions import EARTH_RADIUS, LocalFrame, MapProjection
from surgiplan.plugins.devices.mavlink.device import MavlinkVehicleSettings
from surgiplan.plugins.devices.mavlink.flight import SETPOINTS_BEFORE_SWITCH, Flight, Route
from surgiplan.plugins.devices.mavlink.gcs import GroundStation
from surgiplan.plugins.devices.mavlink.link import Endpoint, VehicleError, mavlink, signing_key
from surgiplan.plugins.devices.mavlink.mission import MissionItem
from surgiplan.plugins.devices.mavlink.profile import TimedPath
from surgiplan.plugins.devices.mavlink.sim.model import PointMassMultirotor
from surgiplan.plugins.devices.mavlink.sim.offboard import OffboardSetpoints, Setpoint
from surgiplan.plugins.devices.mavlink.sim.settings import SimSettings
from surgiplan.plugins.devices.mavlink.sim.vehicle import SimulatedVehicle, main
from surgiplan.plugins.devices.mavlink.stream import SetpointStream
from surgiplan.progress import NullProgress


@contextlib.contextmanager
def station(**settings):
    """A simulated vehicle in a thread and a ground station connected to it."""
    vehicle = SimulatedVehicle(SimSettings(**{"speed": 10.0, "heartbeat_rate": 4.0, **settings})).start()
    link = Endpoint(f"udpout:127.0.0.1:{vehicle.port}", system_id=255, component_id=190)
    try:
        gcs = GroundStation(link, heartbeat_period=0.25, missed_heartbeats=20, command_timeout=0.5)
        gcs.connect(10)
        gcs.step = "test"
        yield gcs, vehicle
    finally:
        link.close()
        vehicle.stop()


def test_vehicle_identifies_as_a_px4_quadrotor_and_reports_its_origin():
    with station(origin=(46.5, 6.6, 372.0)) as (gcs, _):
        assert gcs.vehicle.autopilot == mavlink.MAV_AUTOPILOT_PX4
        assert gcs.vehicle.vehicle_type == mavlink.MAV_TYPE_QUADROTOR
        assert gcs.vehicle.mode == "position" and not gcs.vehicle.armed
        origin = gcs.request_message("GPS_GLOBAL_ORIGIN", mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, 5)
        assert (origin.latitude, origin.longitude, origin.altitude) == (465000000, 66000000, 372000)


def test_refusals_come_with_their_result_and_the_vehicles_reason():
    with station(refuse_arming="battery too low") as (gcs, vehicle):
        gcs.step = "arming"
        # PX4's commander: a refused arming or mode change is MAV_RESULT_TEMPORARILY_REJECTED, the reason a STATUSTEXT
        rejected = r"MAV_RESULT_TEMPORARILY_REJECTED.*vehicle says: "
        with pytest.raises(VehicleError, match=r"arming: .*" + rejected + "Arming denied: battery"):
            gcs.arm()
        gcs.step = "mode change"
        with pytest.raises(VehicleError, match=rejected + "Offboard denied: no setpoints"):
            gcs.set_mode("offboard")
        with pytest.raises(VehicleError, match=rejected + "Mission denied: no mission"):
            gcs.set_mode("mission")
        with pytest.raises(VehicleError, match=r"MAV_CMD_DO_FLIGHTTERMINATION with MAV_RESULT_UNSUPPORTED"):
            gcs.command(mavlink.MAV_CMD_DO_FLIGHTTERMINATION, [1])
        assert not vehicle.armed and vehicle.mode == "position"


def test_commands_are_acknowledged_once_even_when_repeated():
    with station() as (gcs, vehicle):
        gcs.set_mode("hold")
        assert vehicle.mode == "hold"
        for _ in range(2):  # arming an armed vehicle is accepted and changes nothing
            gcs.arm()
        assert vehicle.armed and [text for _, text in vehicle.events].count("Armed by external command") == 1


def test_global_mission_items_land_on_the_local_points_they_were_made_from():
    """mission_frame: global_relative_alt (the default): the device converts with the vehicle's own origin and
    home, and the vehicle, as PX4, projects latitude/longitude about its EKF origin."""
    origin = (47.397742, 8.545594, 488.0)
    home = (1.5, -2.0, -0.4)  # the vehicle stands 0.4 m above the EKF origin's height
    with station(origin=origin, home=home) as (gcs, vehicle):
        got = gcs.request_message("GPS_GLOBAL_ORIGIN", mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, 5)
        position = gcs.request_message("HOME_POSITION", mavlink.MAVLINK_MSG_ID_HOME_POSITION, 5)
        geo = (MapProjection(got.latitude * 1e-7, got.longitude * 1e-7), float(position.z), got.altitude * 1e-3)
        frame = LocalFrame((2.0, 6.0, 0.0))
        scene = np.array([[3.5, 4.0, 0.4], [3.5, 4.0, 1.9], [40.0, 30.0, 1.9], [-20.0, 90.0, 2.5], [-20.0, 90.0, 0.4]])
        route = Route(scene, 1, 3, takeoff=True, land=True)
        flight = Flight(gcs, MavlinkVehicleSettings(), frame, route, NullProgress(), geo)
        items, first, last = flight.mission_items()
        assert {i.frame for i in items[1:]} == {mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT}  # the current frame, 3
        assert (first, last) == (1, 3)
        gcs.upload(items)
        local = np.array([vehicle._item_position(item) for item in vehicle.mission[1:]])
    expected = frame.to_ned(scene[1:])
    # 1e-7 degrees of latitude are 1.1 cm; altitudes are floats
    assert np.abs(local[:, :2] - expected[:, :2]).max() < 0.012
    assert local[:-1, 2] == pytest.approx(expected[:-1, 2], abs=1e-5)
    # independently: the great-circle distance between two waypoints is their local distance
    lat = np.radians([vehicle.mission[2].x, vehicle.mission[3].x])
    lon = np.radians([vehicle.mission[2].y, vehicle.mission[3].y])
    h = np.sin((lat[1] - lat[0]) / 2) ** 2 + np.cos(lat[0]) * np.cos(lat[1]) * np.sin((lon[1] - lon[0]) / 2) ** 2
    arc = 2 * EARTH_RADIUS * math.asin(math.sqrt(h))
    assert arc == pytest.approx(np.linalg.norm(expected[2, :2] - expected[1, :2]), abs=0.02)


def test_signing_key_reaches_the_simulated_vehicle_from_the_device_settings():
    settings = MavlinkVehicleSettings.model_validate({"signing": {"key": "shared secret"}})
    from surgiplan.plugins.devices.mavlink.device import MavlinkVehicle

    sim = MavlinkVehicle(settings)._sim_settings()
    assert sim.signing_key == "shared secret"
    assert signing_key(sim.signing_key) == hashlib.sha256(b"shared secret").digest()


def test_command_line_reports_bad_settings(capsys):
    assert main(["udpin:127.0.0.1:0", "--settings", '{"speed": -1}']) == 2
    assert "speed" in capsys.readouterr().err
    assert main(["udpin:127.0.0.1:0", "--packet-loss", "1.5"]) == 2
    assert "packet_loss" in capsys.readouterr().err
    with pytest.raises(SystemExit) as done:
        main(["--help"])
    assert done.value.code == 0 and "PX4-like quadrotor" in capsys.readouterr().out


def test_mission_completes_in_gusts_even_with_a_tight_acceptance_radius():
    """Gusts can keep a hovering vehicle outside a 2 cm radius for ever; it settles and goes on."""
    with station(speed=20.0, wind={"mean": [0.3, 0.6, 0.0], "gust": 1.0}, seed=4) as (gcs, vehicle):
        lat, lon = vehicle.projection.reproject(5.0, 0.0)
        items = [
            MissionItem(mavlink.MAV_CMD_NAV_TAKEOFF, x=math.nan, y=math.nan, z=1.5),
            MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, x=float(lat), y=float(lon), z=1.5, param2=0.02),
            MissionItem(mavlink.MAV_CMD_NAV_LAND, x=float(lat), y=float(lon)),
        ]
        gcs.upload(items)
        gcs.set_mode("hold")
        gcs.arm()
        gcs.set_mode("mission")
        start = gcs.vehicle.vehicle_time
        while vehicle.armed and gcs.vehicle.vehicle_time - start < 120:
            gcs.pump(0.05)
        assert not vehicle.armed  # landed and disarmed by itself
        assert [seq for seq, _ in gcs.vehicle.reached] == [0, 1, 2]
        truth = np.array(vehicle.trajectory)[:, 1:4]
        assert truth[-1][2] == 0.0 and np.linalg.norm(truth[-1][:2] - [5.0, 0.0]) < 0.6  # gusts of 1 m/s


# ----------------------------------------------------------------------------- offboard on the vehicle's clock


def _setpoint(t: float, x: float) -> Setpoint:
    return Setpoint(t, np.array([x, 0.0, -1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.5, 0.0, 0.0]))


def test_setpoint_in_force_is_the_latest_stamped_at_or_before_the_vehicle_time():
    setpoints = OffboardSetpoints(timeout=1.0)
    assert setpoints.lockstep_limit() == math.inf and setpoints.in_force(0.0) is None
    # arriving out of order and ahead of the vehicle's clock (t = 10.0)
    for stamp in (10.1, 10.05, 10.15):
        setpoints.receive(_setpoint(stamp, stamp), t=10.0, now=0.0)
    assert setpoints.lockstep_limit() == pytest.approx(10.15)  # the physics may advance to the newest stamp
    assert setpoints.in_force(10.0).time == pytest.approx(10.05)  # the first holds until the clock gets on
    assert setpoints.in_force(10.12).time == pytest.approx(10.1)
    # the reference: constant-acceleration kinematics from the stamp, 20 ms on
    p, v, _ = setpoints.reference(10.12)
    h = 10.12 - 10.1
    assert p == pytest.approx([10.1 + h + 0.25 * h * h, 0, -1]) and v == pytest.approx([1 + 0.5 * h, 0, 0])
    # a late setpoint (older than the one in force) changes nothing; a repeated stamp replaces its content
    setpoints.receive(_setpoint(10.05, 99.0), t=10.12, now=0.1)
    assert setpoints.in_force(10.12).position[0] == pytest.approx(10.1)
    setpoints.receive(_setpoint(10.15, 42.0), t=10.12, now=0.1)
    assert setpoints.in_force(10.2).position[0] == 42.0
    # a stamp that is not on the vehicle's clock (a ground station sending its own uptime) applies on
    # receipt, as PX4 takes every setpoint, and releases the lockstep
    setpoints.receive(_setpoint(3600.0, 7.0), t=10.2, now=0.2)
    assert setpoints.unstamped == 1 and setpoints.lockstep_limit() == math.inf
    assert setpoints.in_force(10.2).time == pytest.approx(10.2) and setpoints.in_force(10.2).position[0] == 7.0
    # offboard loss: judged on the wall clock in lockstep (the vehicle's clock stops with the stream)
    assert setpoints.fresh(0.5) and not setpoints.stale(10.2, 1.1) and setpoints.stale(10.2, 1.3)


class _Station:
    """What SetpointStream needs of a GroundStation: the vehicle's clock and a send that records."""

    def __init__(self) -> None:
        self.vehicle = SimpleNamespace(vehicle_time=0.0)
        self.sent: list = []
        self.position_target = GroundStation.position_target.__get__(self)
        self.target = (1, 1)

    def send(self, messages) -> None:
        self.sent.extend(messages)


def test_stream_sends_every_grid_time_once_in_order_whatever_the_pumps():
    """Reports arrive one, several or none per pump (scheduling); the stream still sends each 50 ms grid
    time of the vehicle's clock exactly once, in order, 0.1 s ahead, each the timed path at its stamp."""
    profile = TimedPath.along(np.array([[0.0, 0, -1], [4.0, 0, -1], [4.0, 3, -1]]), 2.0, 1.0, 0.05)
    station = _Station()
    stream = SetpointStream(station, profile, hold=[0.0, 0.0, -1.0])
    station.vehicle.vehicle_time = 12.35
    stream([], now=0.0)
    start = stream.begin()
    assert start == pytest.approx(12.55)  # a grid time two leads on
    rng = np.random.default_rng(0)
    wall = 0.0
    for _ in range(400):
        station.vehicle.vehicle_time += 0.05 * rng.integers(0, 3)  # 0, 1 or 2 reports since the last pump
        wall += 0.01
        stream([], now=wall)
    stamps = np.array([m.time_boot_ms for m in station.sent])
    assert stamps[0] == 12450 and stamps[-1] == round(station.vehicle.vehicle_time * 1000) + 100
    steps = np.diff(stamps)
    assert set(steps) <= {0, 50} and np.all(stamps % 50 == 0)  # the grid, in order (0: a keep-alive repeat)
    fresh = np.concatenate([[True], steps > 0])
    assert len(np.unique(stamps)) == fresh.sum() == (stamps[-1] - stamps[0]) // 50 + 1  # none skipped
    # each setpoint is the timed path at its stamp (the hold before the start), as float32 on the wire
    t = stamps / 1000
    position = np.array([[m.x, m.y, m.z] for m in station.sent])
    velocity = np.array([[m.vx, m.vy, m.vz] for m in station.sent])
    flying = t >= start - 1e-9
    p, v, _ = profile.sample(t[flying] - start)
    assert position[flying] == pytest.approx(p, abs=1e-5) and velocity[flying] == pytest.approx(v, abs=1e-5)
    assert np.all(position[~flying] == [0.0, 0.0, -1.0]) and np.all(velocity[~flying] == 0.0)
    # keep-alives: only after 50 ms of wall clock without anything new
    before = len(station.sent)
    stream([], now=wall + 0.01)
    assert len(station.sent) == before
    stream([], now=wall + 0.06)
    assert len(station.sent) == before + 1 and station.sent[-1].time_boot_ms == stamps[-1]


def test_setpoints_flow_for_half_a_second_of_their_own_before_the_switch():
    """The flight switches to offboard once its setpoints have flowed SETPOINTS_BEFORE_SWITCH of vehicle
    time, counted from the stream's first setpoint: reports that queued while nobody pumped (here 0.55 s
    of them, arriving in one burst before the stream's first tick) count for nothing. Waiting on the
    vehicle's clock from a report read before the pump, the flight used to switch with one setpoint sent,
    and on a lossy link the vehicle refused offboard ('no setpoints')."""
    profile = TimedPath.along(np.array([[0.0, 0, 0], [0, 0, -1.5]]), 1.0, 1.0, 0.05, vertical_speed=0.5)
    station = _Station()
    stream = SetpointStream(station, profile, hold=[0.0, 0.0, 0.0])
    station.vehicle.vehicle_time = 4.65  # a burst of reports from 4.1 s on, pumped at once
    assert stream.flowing() == 0.0
    stream([], now=0.0)
    assert stream.sent == 1 and stream.flowing() == 0.0
    ticks = 0
    while stream.flowing() < SETPOINTS_BEFORE_SWITCH:
        station.vehicle.vehicle_time += 0.05
        stream([], now=0.0)
        ticks += 1
    assert ticks == 10 and stream.sent == 11  # one grid setpoint per report, 0.5 s of them
    assert [m.time_boot_ms for m in station.sent] == list(range(4750, 5300, 50))


def test_stream_samples_the_profile_the_same_whenever_it_starts():
    """The setpoints are the timed path at its own time since the start, counted in whole grid periods:
    bit for bit the same payloads whatever vehicle time the profile starts at. (Computed as the difference
    of two absolute times, 7.7 s + 0.5 s - 7.7 s is 0.49999999999999956 s: the climb's acceleration phase,
    which ends at exactly 0.5 s, was sampled on its wrong side at some start times and the vehicle
    extrapolated a = 1 m/s^2 over the next 50 ms, a different flight: the flaky test below.)"""
    profile = TimedPath.along(np.array([[0.0, 0, 0], [0, 0, -1.5], [4, 0, -1.5]]), 2.0, 1.0, 0.05, vertical_speed=0.5)
    assert profile.knot_time[1] == pytest.approx(3.0318549, abs=1e-6) and profile.accelerate[0] == 0.5
    payloads = []
    for report in (7.45, 7.25, 123.45, 3.05):  # 7.45 s: the profile starts at 7.7 s
        station = _Station()
        stream = SetpointStream(station, profile, hold=[0.0, 0.0, 0.0])
        station.vehicle.vehicle_time = report
        start = stream.begin()
        for _ in range(80):
            station.vehicle.vehicle_time += 0.05
            stream([], now=0.0)
        sent = [m for m in station.sent if m.time_boot_ms >= round(start * 1000)]
        payloads.append([(m.time_boot_ms - round(start * 1000), m.x, m.y, m.z, m.vz, m.afz) for m in sent])
    assert all(p == payloads[0] for p in payloads[1:])
    # the end of the climb's acceleration (0.5 s) is the cruise's first setpoint: a = 0 from there on
    at = dict((row[0], row) for row in payloads[0])
    assert at[450][5] == pytest.approx(-1.0) and at[500][5] == 0.0 and at[500][4] == pytest.approx(-0.5)


def _offboard_flight(stall: float, **sim):
    """A short offboard flight (take-off, an L through a corner, landing) at 20x real time, the ground
    station stalling up to ``stall`` s (wall) at random in each pump; returns the simulator's states
    (vehicle time from the profile's start, NED position) and the flight log."""
    rng = np.random.default_rng()

    def stalls(messages, now) -> None:
        if stall and rng.random() < 0.5:
            time.sleep(rng.uniform(0, stall))

    settings = MavlinkVehicleSettings(mode="offboard", cruise_speed=2.0, land=False)
    with station(speed=20.0, wind={"mean": [0.3, -0.2, 0.0], "gust": 0.4}, seed=5, **sim) as (gcs, vehicle):
        gcs.set_message_interval(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, settings.telemetry_rate)
        gcs.wait_for(lambda: gcs.vehicle.position is not None, 5, "no position")
        gcs.tickers.append(stalls)
        route = Route(np.array([[0.0, 0, 0], [0, 0, 1.5], [4, 0, 1.5], [4, 3, 1.5]]), 1, 3, takeoff=True, land=False)
        flight = Flight(gcs, settings, LocalFrame((0.0, 0.0, 0.0), heading=0.0), route, NullProgress())
        log = flight.fly_offboard()
        gcs.tickers.remove(stalls)
        unstamped = vehicle.offboard.unstamped
    states = np.array(vehicle.trajectory)
    states[:, 0] -= log.profile_start
    # from the profile's start to its end (the vehicle then holds until the test stops it)
    return states[(states[:, 0] > -1e-9) & (states[:, 0] <= log.profile.duration + 1e-9)], log, unstamped


def test_offboard_flight_is_the_same_however_the_ground_station_is_scheduled():
    """The lockstep: the same seed flies the same flight, to rounding, whether the ground station answers
    at once or stalls at random for up to 30 ms (0.6 s of vehicle time), and that flight is the airframe
    tracking the timed path itself (an offline simulation of the model against the exact profile)."""
    calm, log, unstamped = _offboard_flight(stall=0.0)
    stalled, _, _ = _offboard_flight(stall=0.03)
    assert log.status == "completed" and unstamped == 0
    # the same to rounding (the flights start at different vehicle times, so their clocks' floats differ)
    assert calm.shape == stalled.shape and np.abs(calm - stalled).max() < 1e-9
    # independently: the airframe model (from rest on its pad, in the same gusts: the simulator seeds its
    # airframe with seed + 1, and gusts advance only in the air) fed the setpoint in force at each instant:
    # the timed path sampled at the last 50 ms grid time, extrapolated at constant acceleration
    sim = SimSettings(wind={"mean": [0.3, -0.2, 0.0], "gust": 0.4}, seed=5)
    model = PointMassMultirotor(sim.airframe, sim.home, sim.wind, seed=sim.seed + 1)
    steps = round(calm[-1, 0] / sim.step)
    k = np.arange(steps)
    h = (k % 5) * sim.step  # 5 steps of 10 ms per grid time
    p, v, a = log.profile.sample((k // 5) * 50 / 1000)  # the grid time since the start, exactly as the stream
    reference = (p + v * h[:, None] + 0.5 * a * h[:, None] ** 2, v + a * h[:, None], a)
    replay = [model.p.copy()]
    for i in k:
        model.step(sim.step, (reference[0][i], reference[1][i], reference[2][i]), armed=True)
        replay.append(model.p.copy())
    replay = np.array(replay)[np.round(calm[:, 0] / sim.step).astype(int)]
    assert np.abs(calm[:, 1:4] - replay).max() < 1e-6  # setpoints travel as float32
    # against the timed path itself the gusts (0.4 m/s, with a position loop of 1 s) show, and stay bounded
    tracking = np.linalg.norm(calm[:, 1:4] - log.profile.sample(calm[:, 0])[0], axis=1)
    assert 0.05 < tracking.max() < 0.3


@pytest.mark.parametrize("lockstep", [True, False])
def test_offboard_loss_holds_the_vehicle_where_the_stream_stopped(lockstep):
    """PX4's offboard loss (COM_OF_LOSS_T) on the simulated vehicle: in lockstep its clock stops at the last
    stamp with the stream, so the loss is judged on the wall clock (``offboard_timeout`` wall s) and costs
    no flight time; without lockstep the clock runs on, and the loss comes ``offboard_timeout`` s of
    vehicle time after the last setpoint. Either way it then holds in the air."""
    sim = {"speed": 20.0, "lockstep": lockstep, "offboard_timeout": 1.0}
    with station(**sim) as (gcs, vehicle):
        gcs.set_message_interval(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 20)
        gcs.wait_for(lambda: gcs.vehicle.position is not None, 5, "no position")
        profile = TimedPath.along(np.array([[0.0, 0, 0], [0, 0, -1.5], [6, 0, -1.5]]), 1.0, 1.0, 0.05, 0.5)
        stream = SetpointStream(gcs, profile, hold=[0.0, 0.0, 0.0])
        gcs.tickers.append(stream)
        gcs.wait_for(lambda: vehicle.offboard.received > 0, 5, "no setpoint")
        gcs.set_mode("offboard")
        gcs.arm()
        start = stream.begin()
        gcs.wait_for(lambda: gcs.vehicle.vehicle_time >= start + 4.0, 20, "no flight")
        gcs.tickers.remove(stream)  # the ground station falls silent mid-leg
        silent = time.monotonic()
        gcs.wait_for(lambda: gcs.vehicle.mode == "hold", 10, "no offboard loss")
        waited = time.monotonic() - silent
        last = vehicle.offboard.newest
        (lost,) = [t for t, text in vehicle.events if text == "offboard setpoints lost: holding"]
        gcs.wait_for(lambda: gcs.vehicle.vehicle_time >= lost + 6.0, 10, "no hold")
        held = np.array(vehicle.trajectory)
    assert vehicle.offboard.unstamped == 0
    if lockstep:
        assert lost == pytest.approx(last, abs=1e-9)  # the clock waited at the newest stamp
        assert waited >= 1.0 - 0.05  # for offboard_timeout of wall clock
    else:
        assert lost == pytest.approx(last + 1.0, abs=0.02)  # offboard_timeout of vehicle time later
    # holding in the air: it brakes to a stop near where it was (a position loop of 1 s) and stays there
    at_loss = held[np.searchsorted(held[:, 0], lost), 1:4]
    after = held[held[:, 0] >= lost + 4.0]
    assert np.all(after[:, 3] < -1.0) and np.ptp(after[:, 1:4], axis=0).max() < 0.1
    assert np.linalg.norm(after[-1, 1:4] - at_loss) < 0.5  # braked, not flown on along the leg to x = 6 m
    assert np.linalg.norm(after[-1, 4:7]) < 0.05


@pytest.mark.timeout(60)
def test_offboard_flight_in_lockstep_survives_a_lossy_link():
    """With 20 % of the messages lost each way, a position report the ground station stamps its setpoints
    from can be lost while the vehicle waits in lockstep for the next setpoint: the waiting vehicle says
    where it is again every 0.1 s of wall clock, so the flight goes on (it used to wait for ever)."""
    _, log, _ = _offboard_flight(stall=0.0, packet_loss=0.2)
    assert log.status == "completed"


def test_a_simulated_vehicle_that_does_not_start_is_a_connect_error_with_what_it_said(monkeypatch):
    """The process exits at once: the error says so with its last words on stderr, and nothing is left open."""
    from surgiplan.plugins.devices.mavlink import local_simulator

    # /bin/sh cannot run the simulator module: it exits, saying why on stderr
    monkeypatch.setattr(local_simulator, "sys", SimpleNamespace(executable="/bin/sh"))
    simulator = local_simulator.LocalSimulator(SimSettings(), "subprocess", timeout=10)
    with pytest.raises(VehicleError, match=r"connect: the simulated vehicle did not start \((?!no output).+\)"):
        simulator.start()
    assert simulator.process is None and simulator._stderr is None
