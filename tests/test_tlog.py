"""The flight's telemetry log (``<stage>.tlog``) read by pymavlink and its tools, and replayed into the flight's
metrics.

Independent measures: pymavlink's log reader and its command-line tools (``mavlogdump.py``,
``mavflightmodes.py``), the device's own flight log (flight.csv), its link counters, and coal's distances for
the clearance of the replayed flight.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import coal_scene_segment_distance
from surgiplan import load_scene
from surgiplan.plugins.devices.mavlink.conventions import LocalFrame
from surgiplan.plugins.devices.mavlink.link import mavutil
from surgiplan.plugins.devices.mavlink.tlog import RECORDING_STARTED, RECORDING_STOPPED, flight_samples
from test_mavlink_vehicle import HALL, ORIGIN, RADIUS, external, fly, roadmap, simulated  # noqa: F401 (fixture)

BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def flight(tmp_path_factory, roadmap):  # noqa: F811 (the session fixture imported above)
    tmp = tmp_path_factory.mktemp("tlog")
    with simulated() as vehicle:
        outcome, _, stage, table = fly(tmp, roadmap, external(vehicle))
    assert stage["status"] == "completed", stage["message"]
    return outcome.output_dir, stage, table


def _tool(name: str, *args) -> str:
    result = subprocess.run(
        [sys.executable, str(BIN / name), *args], capture_output=True, text=True, timeout=120, check=False
    )
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_every_packet_each_way_is_in_the_log_as_pymavlink_reads_it(flight):
    out, stage, _ = flight
    assert "flight.tlog" in stage["files"]
    assert not list(out.glob(".*partial"))  # renamed into place when the link closed
    log = mavutil.mavlink_connection(str(out / "flight.tlog"), dialect="common")
    kinds = []
    times = []
    while (message := log.recv_match()) is not None:
        kinds.append((message.get_srcSystem(), message.get_type()))
        times.append(message._timestamp)
    log.close()
    metrics = stage["metrics"]
    notes = 2  # the ground station's marks of the flight's samples (in the log only)
    assert len(kinds) == metrics["messages_sent"] + metrics["messages_received"] + notes
    assert ("BAD_DATA" not in {k for _, k in kinds}) and np.all(np.diff(times) >= 0)
    vehicle = {s for s, k in kinds if k == "LOCAL_POSITION_NED"}
    commands = {s for s, k in kinds if k == "COMMAND_LONG"}  # arm, mode changes: the ground station's
    assert len(vehicle) == 1 and len(commands) == 1 and commands != vehicle  # both ends' packets
    assert sum(k == "LOCAL_POSITION_NED" for _, k in kinds) >= metrics["samples"]


def test_pymavlinks_tools_see_the_flight(flight):
    out, _, _ = flight
    path = str(out / "flight.tlog")
    heartbeats = _tool("mavlogdump.py", "--types", "HEARTBEAT", path).splitlines()
    assert len(heartbeats) > 5 and all("HEARTBEAT" in line for line in heartbeats)
    notes = _tool("mavlogdump.py", "--types", "STATUSTEXT", path)
    assert RECORDING_STARTED in notes and RECORDING_STOPPED in notes and "Armed" in notes
    modes = _tool("mavflightmodes.py", path)
    assert "MISSION" in modes  # PX4's auto mission mode, decoded from the vehicle's HEARTBEATs


def test_a_replay_reproduces_the_flights_samples_and_metrics(flight):
    out, stage, table = flight
    samples = flight_samples(out / "flight.tlog")
    t = np.array([s[0] for s in samples])
    frame = LocalFrame(ORIGIN)
    flown = frame.from_ned(np.array([s[1] for s in samples]))
    velocity = frame.vector_from_ned(np.array([s[2] for s in samples]))
    # the samples the stage computed its metrics from, exactly (float32 on the wire both times)
    assert t == pytest.approx(table[:, 0], abs=1e-9)
    assert flown == pytest.approx(table[:, 1:4], abs=1e-6)
    metrics = stage["metrics"]
    assert metrics["flight_time_s"] == pytest.approx(t[-1] - t[0], abs=1e-9)
    assert metrics["flown_length_m"] == pytest.approx(np.linalg.norm(np.diff(flown, axis=0), axis=1).sum(), rel=1e-6)
    assert metrics["max_speed_mps"] == pytest.approx(np.linalg.norm(velocity, axis=1).max(), rel=1e-6)
    clearance = coal_scene_segment_distance(load_scene(HALL), flown[:-1], flown[1:], RADIUS)
    assert metrics["flight_min_clearance_m"] == pytest.approx(clearance.min(), abs=1e-5)
