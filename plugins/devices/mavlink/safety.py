"""What the vehicle enforces on its own: the scene's geofence and the rally points, uploaded before the mission.

:func:`upload_safety` takes the fence of :mod:`.scene_fence` (scene
coordinates) and the rally points, and makes them the vehicle's:

1. the parameters PX4 enforces them by: GF_ACTION (``fence.action``),
   GF_PREDICT (``fence.predict``), GF_MAX_VER_DIST (the scene's top above
   home: the fence's ceiling), each set and read back;
2. the zones, mapped into the vehicle's local frame and its EKF origin's
   latitude/longitude, uploaded as ``MAV_MISSION_TYPE_FENCE`` items and
   downloaded back and compared (a difference stops the flight before
   arming, as for the mission);
3. the rally points (MAV_CMD_NAV_RALLY_POINT, altitude above home) likewise
   as ``MAV_MISSION_TYPE_RALLY``; an empty list clears what the vehicle held.

A vehicle that answers the fence upload with MAV_MISSION_NO_SPACE is
reported with the number of items the scene needs.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from .conventions import LocalFrame, MapProjection
from .link import VehicleError, mavlink
from .mission import FENCE, RALLY, compare_missions
from .scene_fence import GF_ACTIONS, FenceSettings, SceneFence
from .zones import Zone, fence_items, rally_items

INT32, REAL32 = mavlink.MAV_PARAM_TYPE_INT32, mavlink.MAV_PARAM_TYPE_REAL32


def fence_parameters(fence: SceneFence, settings: FenceSettings, home_z: float) -> dict[str, tuple[float, int]]:
    """The PX4 parameters the fence is enforced by: name -> (value, MAV_PARAM_TYPE)."""
    wanted = {"GF_ACTION": (GF_ACTIONS[settings.action], INT32)}
    if settings.predict:
        wanted["GF_PREDICT"] = (1, INT32)
    ceiling = 0.0 if fence.ceiling is None else float(np.floor((fence.ceiling - home_z) * 100) / 100)
    wanted["GF_MAX_VER_DIST"] = (max(ceiling, 0.0), REAL32)
    return wanted


def to_vehicle(zone: Zone, frame: LocalFrame) -> Zone:
    """A zone in scene x, y mapped to the vehicle's local north, east."""

    def transform(xy: np.ndarray) -> np.ndarray:
        xyz = np.column_stack([xy, np.full(len(xy), frame.origin[2])])
        return frame.to_ned(xyz)[:, :2]

    return zone.mapped(transform)


def _transfer(gcs, items, mission_type: int, what: str, legacy: bool) -> dict[str, Any]:
    """Upload a list, download it back, compare; the statistics (``what``: fence or rally; ``legacy``: as the
    deprecated MISSION_ITEM, for a vehicle without MISSION_INT)."""
    gcs.step = f"{what} upload"
    started = time.monotonic()
    try:
        stats, transfers = gcs.upload(items, mission_type=mission_type, legacy=legacy)
    except VehicleError as exc:
        if "NO_SPACE" in exc.detail:
            raise VehicleError(
                f"{exc.detail}: the {what} has {len(items)} items, more than the vehicle stores", step=exc.step
            ) from None
        raise
    uploaded = time.monotonic() - started
    gcs.step = f"{what} verify"
    held = gcs.download(mission_type, legacy=legacy)
    difference = compare_missions(items, held, legacy)
    if difference is not None:
        raise VehicleError(f"the {what} downloaded back differs from the one uploaded: {difference}", step=gcs.step)
    return {
        f"{what}_verified": True,
        f"{what}_upload_s": uploaded,
        f"{what}_download_s": time.monotonic() - started - uploaded,
        f"{what}_upload_transfers": transfers,
        f"{what}_upload_requests": stats.requests,
        f"{what}_upload_retransmissions": stats.retransmissions,
    }


def upload_safety(
    gcs,
    frame: LocalFrame,
    projection: MapProjection,
    home_z: float,
    fence: SceneFence | None,
    settings: FenceSettings,
    rally: np.ndarray,
    params_set: dict,
    legacy: bool = False,
) -> dict[str, Any]:
    """Set the fence's parameters, upload the fence and the rally points (scene coordinates), each verified by
    download; the metrics. ``params_set`` records the parameters set; ``home_z``: home's scene z; ``legacy``:
    as MISSION_ITEM."""
    metrics: dict[str, Any] = {"fence": fence is not None}
    if fence is not None:
        gcs.step = "setting fence parameters"
        for name, (value, kind) in fence_parameters(fence, settings, home_z).items():
            params_set[name] = gcs.set_param(name, value, kind)
        zones = [to_vehicle(zone, frame) for zone in fence.zones]
        items = fence_items(zones, projection)
        metrics.update(fence.describe())
        said = len(gcs.vehicle.fence_events)
        metrics.update(_transfer(gcs, items, FENCE, "fence", legacy))
        dropped = [text for _, text in gcs.vehicle.fence_events[said:] if "invalid" in text.lower()]
        if dropped:  # PX4 keeps the list but drops such zones from its geofence: the download cannot tell
            raise VehicleError(f"the vehicle dropped zones of the fence: {'; '.join(dropped)}", step="fence verify")
        metrics["geofence_action"] = settings.action
        metrics["geofence_predict"] = settings.predict
    rally = np.asarray(rally, float).reshape(-1, 3)
    if fence is not None or len(rally):
        ned = frame.to_ned(rally) if len(rally) else np.zeros((0, 3))
        items = rally_items(ned[:, :2], projection, rally[:, 2] - home_z)
        metrics["rally_points"] = len(items)
        metrics.update(_transfer(gcs, items, RALLY, "rally", legacy))
    return metrics
