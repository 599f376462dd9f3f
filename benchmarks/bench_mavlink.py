"""mavlink_vehicle: the hall flights as shipped, mission upload under packet loss, tracking in wind, speed.

Everything over real MAVLink 2 on 127.0.0.1 UDP:

0. hall: configs/hall_flight.yaml exactly as shipped (its simulated vehicle the separate program it is
   by default, at 4x real time, a breeze with gusts): per flight, the tracking error against the planned
   path and the flown clearance in the door (the critical region, 0.35 m planned) and outside it (the
   0.5 m threshold). The README's hall table is this section's output (results/mavlink.md).
1. upload: missions of 20 and 100 waypoints (MAV_FRAME_GLOBAL_RELATIVE_ALT, MISSION_ITEM_INT), packets
   dropped at 0-40 % in each direction; median upload time over seeds, the vehicle's re-requests and
   the ground station's retransmissions; beside it the time the mission protocol's own timeouts
   predict (the reference): with q = (1 - p)^2 the chance that a request and its item both arrive, a
   lost round trip costs the vehicle's item timeout (0.25 s), and a lost MISSION_COUNT (or first
   request) the ground station's 1.5 s, so E[T] ~ N (1/q - 1) 0.25 s + (1 - q) 1.5 s + N * (one round
   trip). Each upload is then downloaded back and compared (what the device does before it flies).
2. tracking: the hall path flown as a mission and as an offboard stream, in a 0.5 m/s breeze with gusts
   of 0-0.9 m/s (3 seeds each), the vehicle in a thread at 20x real time: tracking error against the
   planned path, and the flown clearance inside the door and outside it, re-measured on the scene.
3. speed: simulated seconds per wall second the simulator sustains while flying a mission (asked for
   1000x), with PX4's default telemetry streams and with the streams the device leaves on.
1b. links and fence (mavlink_links.py): the parameters, the hall's fence, rally points and mission through
   30 % loss each way (attempts, time, the bound the retries put on it); the shipped fence rehearsal
   (hall_faults_fence.yaml: setpoints through a pillar, the vehicle's geofence holds it).
4. lockstep: the hall's offboard flight repeated with one seed while the ground station stalls at
   random (0-20 ms in half its pumps, i.e. up to 0.4 s of vehicle time at 20x), with the vehicle in
   lockstep (it never steps past the newest setpoint's stamp) beside the reference it replaces
   (``lockstep_horizon: 0.2``: up to 0.2 s past it, extrapolating): the spread of
   setpoint_error_max_m over the repeats (0 means reproducible), and the wall time per flight
   (what the lockstep's round trips cost).

Each section records the load average (1, 5, 15 min) when it starts: the machine is shared.

    python benchmarks/bench_mavlink.py [--quick] [--only hall,upload,links,fence,tracking,speed,lockstep]

A full run writes results/mavlink.json and results/mavlink.md (the tables the README copies; a test
checks that the README quotes them as written).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import package_version, save, table
from mavlink_links import bench_fence, bench_links
from mavlink_table import markdown
from surgiplan import load_pipeline, run_pipeline
from surgiplan.plugins.devices.mavlink.gcs import GroundStation
from surgiplan.plugins.devices.mavlink.link import Endpoint, VehicleError, mavlink
from surgiplan.plugins.devices.mavlink.mission import MissionItem, compare_missions
from surgiplan.plugins.devices.mavlink.sim.settings import SimSettings
from surgiplan.plugins.devices.mavlink.sim.vehicle import SimulatedVehicle

ROOT = Path(__file__).resolve().parent.parent
ITEM_TIMEOUT, COUNT_TIMEOUT = 0.25, 1.5


#: the simulator's EKF origin (its default): waypoints are latitude/longitude about it
ORIGIN = SimSettings().origin
EARTH = 6371000.0


def load() -> list[float]:
    """The load average (1, 5, 15 min) now: the machine is shared; recorded with every section."""
    return [round(x, 2) for x in os.getloadavg()]


def waypoint(north: float, east: float, up: float, command=mavlink.MAV_CMD_NAV_WAYPOINT, **params) -> MissionItem:
    """A mission item ``north``, ``east`` m from the EKF origin, ``up`` m above home (the current frame 3)."""
    lat = ORIGIN[0] + np.degrees(north / EARTH)
    lon = ORIGIN[1] + np.degrees(east / (EARTH * np.cos(np.radians(ORIGIN[0]))))
    return MissionItem(command, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, float(lat), float(lon), up, **params)


def mission(n: int) -> list[MissionItem]:
    return [waypoint(0.5 * i, 0.0, 1.5, param2=0.1) for i in range(n)]


def predicted_upload(n: int, loss: float, round_trip: float) -> float:
    q = (1 - loss) ** 2
    return n * (1 / q - 1) * ITEM_TIMEOUT + (1 - q) * COUNT_TIMEOUT + n * round_trip


def upload_once(n: int, loss: float, seed: int) -> dict:
    vehicle = SimulatedVehicle(SimSettings(packet_loss=loss, seed=seed, heartbeat_rate=5.0)).start()
    link = Endpoint(f"udpout:127.0.0.1:{vehicle.port}", system_id=255, component_id=190)
    try:
        station = GroundStation(link, missed_heartbeats=50, heartbeat_period=0.2)
        station.connect(30)
        station.step = "mission upload"
        items = mission(n)
        started = time.perf_counter()
        try:
            stats, transfers = station.upload(items)
        except VehicleError:  # every transfer cancelled: counted, not hidden
            return {"upload_s": time.perf_counter() - started, "failed": True, "transfers": station.upload_attempts}
        elapsed = time.perf_counter() - started
        intact = len(vehicle.mission) == n and all(a.same_as(b) for a, b in zip(vehicle.mission, items, strict=True))
        started = time.perf_counter()
        try:
            verified = compare_missions(items, station.download()) is None
        except VehicleError:
            verified = False
        return {
            "download_s": time.perf_counter() - started,
            "verified": verified,
            "upload_s": elapsed,
            "failed": False,
            "transfers": transfers,
            "requests_per_item": stats.requests / n,
            "vehicle_rerequests": vehicle.receiver.stats.rerequests,
            "gcs_retransmissions": stats.retransmissions,
            "intact": intact,
        }
    finally:
        link.close()
        vehicle.stop()


def bench_upload(sizes, losses, seeds) -> list[dict]:
    rows = []
    started_at = load()
    base = statistics.median(upload_once(sizes[0], 0.0, s)["upload_s"] for s in range(3))
    round_trip = base / sizes[0]
    for n in sizes:
        for loss in losses:
            runs = [upload_once(n, loss, seed) for seed in range(seeds)]
            done = [r for r in runs if not r["failed"]] or [{"requests_per_item": None}]

            def median(key, done=done):
                values = [r[key] for r in done if r.get(key) is not None]
                return round(statistics.median(values), 3) if values else None

            rows.append(
                {
                    "benchmark": "upload",
                    "items": n,
                    "loss": loss,
                    "upload_s_median": median("upload_s"),
                    "upload_s_max": round(max(r["upload_s"] for r in runs), 3),
                    "predicted_s": round(predicted_upload(n, loss, round_trip), 3),
                    "requests_per_item": median("requests_per_item"),
                    "vehicle_rerequests": median("vehicle_rerequests"),
                    "gcs_retransmissions": median("gcs_retransmissions"),
                    "transfers_max": max(r["transfers"] for r in runs),
                    "uploaded": f"{sum(not r['failed'] for r in runs)}/{len(runs)}",
                    "all_intact": all(r.get("intact", False) for r in runs if not r["failed"]),
                    "download_s_median": median("download_s"),
                    "verified": f"{sum(r.get('verified', False) for r in runs)}/{len(runs)}",
                    "load_average_at_start": started_at,
                }
            )
            print(table(rows[-1:], list(rows[-1])), flush=True)
    return rows


HALL = """
name: bench-hall
length_unit: m
scene: {scene}
pipeline:
{plan}  - stage: execute
    name: flight
    plugin: mavlink_vehicle
    settings: {settings}
output: {{dir: {out}, figures: false, gltf: false}}
"""


def hall_plan(artifact: Path) -> str:
    text = (ROOT / "configs" / "hall_flight.yaml").read_text()
    stage = text[text.index("  - stage: plan") : text.index("  - stage: execute")]
    return stage.replace("out/hall-flight/roadmap.npz", str(artifact))


def fly(tmp: Path, artifact: Path, mode: str, gust: float, seed: int, **sim_settings) -> dict:
    sim = SimSettings(speed=20.0, seed=seed, wind={"mean": [0.3, 0.4, 0.0], "gust": gust}, **sim_settings)
    vehicle = SimulatedVehicle(sim).start()
    try:
        settings = {
            "connection": f"udpout:127.0.0.1:{vehicle.port}",
            "mode": mode,
            "frame": {"local_origin": [2, 6, 0]},
            "cruise_speed": 1.5,
            "figure": False,
            # these flights measure tracking: in strong gusts they leave the scene's fence, which only warns here
            "fence": {"action": "warning"},
        }
        path = tmp / f"{mode}-{gust}-{seed}.yaml"
        text = HALL.format(
            scene=ROOT / "configs" / "scenes" / "hall.yaml",
            plan=hall_plan(artifact),
            settings=json.dumps(settings),
            out=tmp / f"out-{mode}-{gust}-{seed}",
        )
        path.write_text(text)
        outcome = run_pipeline(load_pipeline(path))
        stage = json.loads((outcome.output_dir / "result.json").read_text())["stages"][1]
        return stage["metrics"] | {"status": stage["status"], "message": stage.get("message")}
    finally:
        vehicle.stop()


def bench_tracking(gusts, seeds) -> list[dict]:
    rows = []
    started_at = load()
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        artifact = tmp / "roadmap.npz"
        for gust in gusts:
            for mode in ("mission", "offboard"):
                runs = [fly(tmp, artifact, mode, gust, seed) for seed in range(seeds)]
                ok = [r for r in runs if r["status"] == "completed"]

                def med(key, ok=ok):
                    values = [r[key] for r in ok if r.get(key) is not None]
                    return round(statistics.median(values), 4) if values else None

                rows.append(
                    {
                        "benchmark": "tracking",
                        "mode": mode,
                        "gust_mps": gust,
                        "completed": f"{len(ok)}/{len(runs)}",
                        "tracking_error_max_m": med("tracking_error_max_m"),
                        "tracking_error_rms_m": med("tracking_error_rms_m"),
                        "setpoint_error_max_m": med("setpoint_error_max_m"),
                        "door_min_clearance_m": med("flown_min_clearance_in_critical_m"),
                        "outside_min_clearance_m": med("flown_min_clearance_outside_critical_m"),
                        "below_threshold_outside_m": med("flown_length_below_threshold_outside_critical_m"),
                        "path_time_s": med("path_time_s"),
                        "load_average_at_start": started_at,
                    }
                )
                print(table(rows[-1:], list(rows[-1])), flush=True)
    return rows


@contextlib.contextmanager
def stalling_ground_station(stall: float, seed: int):
    """Every GroundStation pump stalls, half of the time, for up to ``stall`` s (a loaded machine)."""
    original = GroundStation.pump
    rng = random.Random(seed)

    def pump(self, timeout: float = 0.0):
        if stall and rng.random() < 0.5:
            time.sleep(rng.uniform(0.0, stall))
        return original(self, timeout)

    GroundStation.pump = pump
    try:
        yield
    finally:
        GroundStation.pump = original


def bench_lockstep(stall: float, repeats: int) -> list[dict]:
    rows = []
    started_at = load()
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        artifact = tmp / "roadmap.npz"
        fly(tmp, artifact, "offboard", 0.3, 1)  # builds the roadmap, outside the timings
        for horizon in (0.0, 0.2):
            errors, walls, completed = [], [], 0
            for repeat in range(repeats):
                started = time.perf_counter()
                with stalling_ground_station(stall, repeat):
                    metrics = fly(tmp, artifact, "offboard", 0.3, 1, lockstep_horizon=horizon)
                walls.append(time.perf_counter() - started)
                completed += metrics["status"] == "completed"
                errors.append(metrics["setpoint_error_max_m"])
            rows.append(
                {
                    "benchmark": "lockstep",
                    "lockstep_horizon_s": horizon,
                    "stall_s": stall,
                    "completed": f"{completed}/{repeats}",
                    "setpoint_error_max_m_min": round(min(errors), 4),
                    "setpoint_error_max_m_max": round(max(errors), 4),
                    "spread_m": round(max(errors) - min(errors), 6),
                    "wall_s_median": round(statistics.median(walls), 2),
                    "load_average_at_start": started_at,
                }
            )
            print(table(rows[-1:], list(rows[-1])), flush=True)
    return rows


def bench_speed(seconds: float, repeats: int = 3) -> list[dict]:
    """Simulated seconds per wall second while flying a 60-waypoint mission, asked for 1000x: with PX4's default
    telemetry (ATTITUDE at 15 Hz, ... of vehicle time) and with the streams the device leaves on; the median of
    ``repeats`` runs each, alternating."""
    rows = []
    for streams in ("PX4 defaults", "as the device sets them"):
        started_at = load()
        factors = [speed_once(streams, seconds) for _ in range(repeats)]
        rows.append(
            {
                "benchmark": "speed",
                "streams": streams,
                "asked": 1000.0,
                "sustained_x_real_time": round(statistics.median(factors), 1),
                "runs": [round(f, 1) for f in factors],
                "physics_step_s": SimSettings().step,
                "load_average_at_start": started_at,
            }
        )
        print(table(rows[-1:], list(rows[-1])), flush=True)
    return rows


def speed_once(streams: str, seconds: float) -> float:
    from surgiplan.plugins.devices.mavlink.device import UNUSED_STREAMS

    vehicle = SimulatedVehicle(SimSettings(speed=1000.0, wind={"mean": [0.3, 0.4, 0.0], "gust": 0.3})).start()
    link = Endpoint(f"udpout:127.0.0.1:{vehicle.port}", system_id=255, component_id=190)
    try:
        station = GroundStation(link, missed_heartbeats=1000)
        station.connect(30)
        station.step = "setup"
        if streams != "PX4 defaults":
            station.set_message_interval(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 20.0)
            for message_id in UNUSED_STREAMS:
                station.stop_message(message_id)
        items = [waypoint(0.0, 0.0, 1.5, mavlink.MAV_CMD_NAV_TAKEOFF)]
        circle = np.linspace(0, 12 * np.pi, 60)
        items += [waypoint(10.0 * np.cos(k), 10.0 * np.sin(k), 1.5) for k in circle]
        station.upload(items)
        station.set_mode("mission")
        station.arm()
        start_sim, start_wall = vehicle.t, time.perf_counter()
        while time.perf_counter() - start_wall < seconds:
            station.pump(0.05)
        return (vehicle.t - start_sim) / (time.perf_counter() - start_wall)
    finally:
        link.close()
        vehicle.stop()


def bench_hall(tmp: Path) -> list[dict]:
    """configs/hall_flight.yaml as shipped: both flights, the README's table."""
    started_at = load()
    pipeline = load_pipeline(ROOT / "configs" / "hall_flight.yaml", output_dir=tmp / "hall-flight")
    pipeline.stages[0].artifact = tmp / "hall-roadmap.npz"
    started = time.perf_counter()
    outcome = run_pipeline(pipeline)
    wall = time.perf_counter() - started
    stages = json.loads((outcome.output_dir / "result.json").read_text())["stages"]
    wind = pipeline.stages[1].settings.sim.wind
    breeze = float(np.hypot(*wind.mean[:2]))
    plan = stages[0]
    rows = []
    for stage in stages[1:]:
        m = stage["metrics"]
        rows.append(
            {
                "benchmark": "hall",
                "flight": m["mode"],
                "status": stage["status"],
                "tracking_error_max_m": round(m["tracking_error_max_m"], 3),
                "tracking_error_rms_m": round(m["tracking_error_rms_m"], 3),
                "door_min_clearance_m": round(m["flown_min_clearance_in_critical_m"], 3),
                "planned_door_clearance_m": round(plan["metrics"]["min_clearance_m"], 3),
                "outside_min_clearance_m": round(m["flown_min_clearance_outside_critical_m"], 3),
                "threshold_m": m["clearance_threshold_m"],
                "fence_items": m["fence_items"],
                "fence_verified": m["fence_verified"],
                "fence_breaches": sum("Geofence breached" in e["message"] for e in m["fence_events"]),
                "breeze_mps": round(breeze, 2),
                "gust_mps": wind.gust,
                "pipeline_wall_s": round(wall, 1),
                "load_average_at_start": started_at,
            }
        )
    print(table(rows, list(rows[0])), flush=True)
    return rows


SECTIONS = ("hall", "upload", "links", "fence", "tracking", "speed", "lockstep")  # the tables' order


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, for checking the script")
    parser.add_argument("--only", help=f"comma-separated sections of {', '.join(SECTIONS)} (saved only with --save)")
    parser.add_argument(
        "--save", action="store_true", help="with --only: replace those sections in results/mavlink.json, keep the rest"
    )
    parser.add_argument(
        "--markdown", action="store_true", help="only rewrite results/mavlink.md from results/mavlink.json"
    )
    args = parser.parse_args()
    if args.markdown:
        from common import RESULTS
        from surgiplan.storage import write_text_atomic

        rows = json.loads((RESULTS / "mavlink.json").read_text())["rows"]
        write_text_atomic(RESULTS / "mavlink.md", markdown(rows))
        print(markdown(rows))
        return
    only = set(args.only.split(",")) if args.only else set(SECTIONS)
    unknown = only - set(SECTIONS)
    if unknown:
        parser.error(f"unknown section(s) {', '.join(sorted(unknown))}; choose from {', '.join(SECTIONS)}")
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as folder:
        if "hall" in only:
            rows += bench_hall(Path(folder))
    if args.quick:
        if "upload" in only:
            rows += bench_upload([20], [0.0, 0.2], 2)
        if "links" in only:
            rows += bench_links([0.0, 0.3], 1)
        if "fence" in only:
            rows += bench_fence()
        if "tracking" in only:
            rows += bench_tracking([0.3], 1)
        if "speed" in only:
            rows += bench_speed(2.0)
        if "lockstep" in only:
            rows += bench_lockstep(0.02, 2)
    else:
        if "upload" in only:
            rows += bench_upload([20, 100], [0.0, 0.1, 0.2, 0.3, 0.4], 5)
        if "links" in only:
            rows += bench_links([0.0, 0.3], 5)
        if "fence" in only:
            rows += bench_fence()
        if "tracking" in only:
            rows += bench_tracking([0.0, 0.3, 0.6, 0.9], 3)
        if "speed" in only:
            rows += bench_speed(10.0)
        if "lockstep" in only:
            rows += bench_lockstep(0.02, 5)
    notes = (
        "MAVLink 2 over 127.0.0.1 UDP; hall: the shipped pipeline, its simulated vehicle a subprocess at 4x; "
        "otherwise the simulated vehicle in a thread of this process; upload times are wall "
        "clock (protocol timeouts: vehicle 0.25 s per item, 20 retries; ground station 1.5 s, 5 retries, "
        "3 transfers), each upload downloaded back (0.5 s per item) and compared; "
        "predicted_s is the mission protocol's expectation from its timeouts; tracking flights at 20x real time; "
        "lockstep: one seed flown repeatedly with a ground station stalling at random (spread 0: reproducible); "
        "links: the ground station's default timeouts, the vehicle's link dropping that share each way; "
        "load_average_at_start: os.getloadavg() when each section began (a shared machine)"
    )
    print("\n" + markdown(rows))
    if args.quick or (args.only and not args.save):
        return  # a check of the script, or a part not asked to be saved
    from common import RESULTS

    if args.only:
        # replace this run's sections in the saved results, keep the others (their load averages say when)
        kept = [r for r in json.loads((RESULTS / "mavlink.json").read_text())["rows"] if r["benchmark"] not in only]
        order = {name: i for i, name in enumerate(SECTIONS)}
        rows = sorted(kept + rows, key=lambda r: order.get(r["benchmark"], len(order)))

    peers = {"pymavlink": {"version": package_version("pymavlink"), "role": "the MAVLink 2 codec both sides use"}}
    print(f"\nwritten {save('mavlink', rows, notes, peers=peers)}")
    from surgiplan.storage import write_text_atomic

    write_text_atomic(RESULTS / "mavlink.md", markdown(rows))
    print(f"written {RESULTS / 'mavlink.md'}")


if __name__ == "__main__":
    main()
