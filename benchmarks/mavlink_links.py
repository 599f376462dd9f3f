"""bench_mavlink.py's sections on what the vehicle enforces: every transfer of a flight through a lossy link,
and the fence rehearsal as shipped.

links: what the device exchanges before a hall flight, over 127.0.0.1 UDP to the simulated vehicle
whose link drops that share of the messages in *each* direction (seeded): the whole parameter list
(PARAM_REQUEST_LIST, then by index what was lost), the hall's fence (27 items, derived from the scene as
the device derives it), two rally points and a 21-waypoint mission, each uploaded and downloaded back and
compared. The ground station's defaults throughout (1.5 s and 5 retries per message, 0.5 s per item of a
download or parameter, 3 transfers); per transfer: completed, attempts (whole transfers; requests and
retransmissions), wall time median and worst, and the bound its retries put on it.

fence: configs/hall_faults_fence.yaml as shipped (its simulated vehicle a subprocess at 4x): offboard
setpoints aimed through pillar A1; the vehicle's own geofence (GF_ACTION hold, GF_PREDICT 1) holds it.
The flown minimum clearance against the threshold, where it came to rest, and the braking distance the
prediction looked ahead by.
"""

from __future__ import annotations

import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from surgiplan import load_pipeline, load_scene, run_pipeline
from surgiplan.plugins.devices.mavlink.gcs import GroundStation
from surgiplan.plugins.devices.mavlink.link import Endpoint, VehicleError, mavlink
from surgiplan.plugins.devices.mavlink.mission import FENCE, MISSION, RALLY, MissionItem, compare_missions
from surgiplan.plugins.devices.mavlink.scene_fence import FenceSettings, scene_fence
from surgiplan.plugins.devices.mavlink.sim.model import braking_distance
from surgiplan.plugins.devices.mavlink.sim.settings import Airframe, SimSettings
from surgiplan.plugins.devices.mavlink.sim.vehicle import SimulatedVehicle
from surgiplan.plugins.devices.mavlink.zones import fence_items, rally_items

ROOT = Path(__file__).resolve().parent.parent
#: the ground station's defaults (MavlinkVehicleSettings.timeouts)
COMMAND, RETRIES, ITEM, ATTEMPTS = 1.5, 5, 0.5, 3
#: a route through the hall, as tests/test_mavlink_fence.py flies it: its fence is the scene's 27 items
ROUTE = np.array(
    [[2, 6, 0], [2, 6, 1.5], [5, 8.2, 1.5], [7, 8.2, 1.5], [10.8, 6, 1.5], [13.2, 6, 1.5], [15, 9.3, 1.5],
     [19, 9.3, 1.5], [22, 6, 1.5], [22, 6, 0]], float,
)  # fmt: skip


def load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def lists(projection) -> dict[int, list[MissionItem]]:
    """The hall's fence (in the vehicle's frame: scene x east, y north about the pad), two rally points, and a
    21-item mission (take-off and waypoints along the route)."""
    scene = load_scene(ROOT / "configs" / "scenes" / "hall.yaml")
    fence = scene_fence(scene, ROUTE, 0.25, 0.5, FenceSettings())
    to_ned = lambda xy: np.column_stack([xy[:, 1] - 6.0, xy[:, 0] - 2.0])  # noqa: E731  (north = y, east = x)
    fence_list = fence_items([z.mapped(to_ned) for z in fence.zones], projection)
    rally = rally_items(np.array([[0.0, 20.0], [3.0, 0.0]]), projection, [0.0, 0.0])
    points = to_ned(ROUTE[1:-1][:, :2])  # 20 waypoints along the route (inside its own fence)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    at = np.linspace(0.0, arc[-1], 20)
    dense = np.column_stack([np.interp(at, arc, points[:, 0]), np.interp(at, arc, points[:, 1])])
    lat, lon = projection.reproject(dense[:, 0], dense[:, 1])
    mission = [MissionItem(mavlink.MAV_CMD_NAV_TAKEOFF, 3, float(lat[0]), float(lon[0]), 1.5)]
    mission += [
        MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, 3, float(a), float(o), 1.5, param2=0.1)
        for a, o in zip(lat, lon, strict=True)
    ]
    return {FENCE: fence_list, RALLY: rally, MISSION: mission}


def bounds(count: int, kind: str) -> float:
    """The most time (s) the ground station gives a transfer (its retries, every message once), one attempt."""
    if kind == "params":
        return (
            COMMAND * (RETRIES + 1)
            + ITEM * (max(RETRIES, int(np.ceil(COMMAND * (RETRIES + 1) / ITEM)) - 1) + 1) * count
        )
    if kind == "upload":
        return COMMAND * (RETRIES + 1) * (count + 1) + COMMAND
    item_retries = max(RETRIES, int(np.ceil(COMMAND * (RETRIES + 1) / ITEM)) - 1)
    return COMMAND * (RETRIES + 1) + ITEM * (item_retries + 1) * count + COMMAND


def links_once(loss: float, seed: int) -> list[dict]:
    vehicle = SimulatedVehicle(SimSettings(packet_loss=loss, seed=seed, heartbeat_rate=5.0)).start()
    link = Endpoint(f"udpout:127.0.0.1:{vehicle.port}", system_id=255, component_id=190)
    out = []
    try:
        station = GroundStation(link, missed_heartbeats=50, heartbeat_period=0.2)
        station.connect(30)
        station.step = "parameters"
        started = time.perf_counter()
        try:
            download = station.download_params()
            ok = len(download.values) == download.count
            extra = {"list_requests": download.list_requests, "read_requests": download.read_requests}
        except VehicleError:
            ok, extra = False, {}
        out.append({"transfer": "parameters (26)", "kind": "params", "items": 26, "ok": ok,
                    "s": time.perf_counter() - started, "attempts": 1, **extra})  # fmt: skip
        for kind, items in lists(vehicle.projection).items():
            name = {FENCE: "fence", RALLY: "rally points", MISSION: "mission"}[kind]
            station.step = f"{name} upload"
            started = time.perf_counter()
            try:
                stats, transfers = station.upload(items, mission_type=kind)
                uploaded = True
            except VehicleError:
                uploaded, transfers, stats = False, ATTEMPTS, None
            up = time.perf_counter() - started
            out.append({"transfer": f"{name} ({len(items)}): upload", "kind": "upload", "items": len(items),
                        "ok": uploaded, "s": up, "attempts": transfers,
                        "requests": stats.requests if stats else None,
                        "retransmissions": stats.retransmissions if stats else None})  # fmt: skip
            started = time.perf_counter()
            try:
                back = station.download(kind)
                verified = compare_missions(items, back) is None
            except VehicleError:
                verified = False
            down = time.perf_counter() - started
            out.append({"transfer": f"{name} ({len(items)}): download, compared", "kind": "download",
                        "items": len(items), "ok": verified, "s": down, "attempts": 1})  # fmt: skip
    finally:
        link.close()
        vehicle.stop()
    return out


def bench_links(losses, repeats: int) -> list[dict]:
    rows = []
    started_at = load()
    for loss in losses:
        runs = [links_once(loss, seed) for seed in range(repeats)]
        for k, first in enumerate(runs[0]):
            same = [run[k] for run in runs]
            done = [r for r in same if r["ok"]]

            def median(key, done=done):
                values = [r[key] for r in done if r.get(key) is not None]
                return round(statistics.median(values), 3) if values else None

            rows.append(
                {
                    "benchmark": "links",
                    "loss": loss,
                    "transfer": first["transfer"],
                    "completed": f"{len(done)}/{len(same)}",
                    "s_median": median("s"),
                    "s_max": round(max(r["s"] for r in same), 3),
                    "attempts_max": max(r["attempts"] for r in same),
                    "requests_median": median("requests"),
                    "retransmissions_median": median("retransmissions"),
                    "read_requests_median": median("read_requests"),
                    "bound_s": round(bounds(first["items"], first["kind"]), 1),
                    "load_average_at_start": started_at,
                }
            )
    return rows


def bench_fence() -> list[dict]:
    """The shipped rehearsal: offboard setpoints through pillar A1, the vehicle's geofence holds it."""
    started_at = load()
    with tempfile.TemporaryDirectory() as folder:
        pipeline = load_pipeline(ROOT / "configs" / "hall_faults_fence.yaml", output_dir=Path(folder) / "out")
        pipeline.stages[0].artifact = Path(folder) / "roadmap.npz"
        outcome = run_pipeline(pipeline)
        stage = json.loads((outcome.output_dir / "result.json").read_text())["stages"][1]
    m = stage["metrics"]
    cruise = pipeline.stages[1].settings.cruise_speed
    return [
        {
            "benchmark": "fence",
            "status": stage["status"],
            "obstacle": pipeline.stages[1].settings.rehearsal.setpoints_through,
            "threshold_m": m.get("clearance_threshold_m"),
            "flight_min_clearance_m": round(m["flight_min_clearance_m"], 3),
            "final_clearance_m": round(m["final_clearance_m"], 3),
            "final_fence_distance_m": round(m["final_fence_distance_m"], 3),
            "vehicle_said": next((e["message"] for e in m["fence_events"] if "Geofence" in e["message"]), None),
            "cruise_mps": cruise,
            "braking_distance_m": round(braking_distance(Airframe(), cruise), 3),
            "look_ahead_m": round(braking_distance(Airframe(), cruise) + 0.2 * cruise, 3),
            "fence_items": m["fence_items"],
            "unfenced": sorted(m["fence_unfenced"]),
            "load_average_at_start": started_at,
        }
    ]
