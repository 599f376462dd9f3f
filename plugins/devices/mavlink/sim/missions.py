"""The simulated vehicle's mission manager: PX4's rules for what it stores and how it sends it back.

PX4 (``src/modules/mavlink/mavlink_mission.cpp``) keeps three lists: the
mission, the geofence and the rally points (MAV_MISSION_TYPE_MISSION, _FENCE,
_RALLY), each uploaded, downloaded and cleared with the mission protocol
(:class:`~surgiplan.plugins.devices.mavlink.mission_vehicle.MissionReceiver` and
:class:`~surgiplan.plugins.devices.mavlink.mission_vehicle.MissionSender` do the
protocol). What this module adds is PX4's judgement of each item:

* frames: MAV_FRAME_GLOBAL (0) and MAV_FRAME_GLOBAL_RELATIVE_ALT (3) in
  either message, their deprecated ``_INT`` twins (5, 6) only in
  MISSION_ITEM_INT, MAV_FRAME_MISSION (2) for items without a position;
  anything else (local frames, terrain altitude) is
  MAV_MISSION_UNSUPPORTED_FRAME;
* commands: those PX4 parses for the frame (MAV_MISSION_UNSUPPORTED
  otherwise); fence and rally commands in a mission are MAV_MISSION_ERROR, a
  fence polygon vertex with fewer than 3 vertices too;
* the simulator flies NAV_WAYPOINT, NAV_TAKEOFF, NAV_LAND, NAV_LOITER_TIME,
  NAV_LOITER_UNLIM, NAV_RETURN_TO_LAUNCH and DO_CHANGE_SPEED; the camera,
  gimbal and region-of-interest items PX4 accepts are accepted and skipped
  (a vehicle without that payload); the flight-changing items PX4 has and
  the simulator does not (DO_JUMP, NAV_DELAY, LOITER_TO_ALT, VTOL, DO_SET_HOME,
  DO_LAND_START, CONDITION_*) are refused with MAV_MISSION_UNSUPPORTED and a
  STATUSTEXT that says so, rather than accepted and then flown wrongly;
* download: what PX4's storage keeps, formatted as PX4 formats it: a global
  item's frame is 5 or 6 (absolute or relative altitude) in MISSION_ITEM_INT
  and 0 or 3 in MISSION_ITEM, whatever frame it was uploaded in; of its
  parameters only those PX4 stores (waypoint: hold time, acceptance radius,
  yaw wrapped to [0, 360) deg; take-off: yaw; ...); latitude and longitude
  as uploaded (1e-7 deg in MISSION_ITEM_INT, a float32 in MISSION_ITEM).

Fence and rally lists are stored and sent back as PX4 keeps them; what the
vehicle does with them (the feasibility check of missions, the breach check
and GF_ACTION, returns to rally points) is :mod:`.geofence`'s.
"""

from __future__ import annotations

import math

from surgiplan.plugins.devices.mavlink.link import enum_name, mavlink
from surgiplan.plugins.devices.mavlink.mission import FENCE, MISSION, RALLY, MissionItem

C = mavlink
GLOBAL = {C.MAV_FRAME_GLOBAL, C.MAV_FRAME_GLOBAL_RELATIVE_ALT}
GLOBAL_INT_ONLY = {C.MAV_FRAME_GLOBAL_INT, C.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
RELATIVE = {C.MAV_FRAME_GLOBAL_RELATIVE_ALT, C.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}

FENCE_COMMANDS = {
    C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
    C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
    C.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
    C.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
    C.MAV_CMD_NAV_FENCE_RETURN_POINT,
}
RALLY_COMMANDS = {C.MAV_CMD_NAV_RALLY_POINT}
#: what PX4 parses in a global frame
PX4_GLOBAL_COMMANDS = {
    C.MAV_CMD_NAV_WAYPOINT,
    C.MAV_CMD_NAV_LOITER_UNLIM,
    C.MAV_CMD_NAV_LOITER_TIME,
    C.MAV_CMD_NAV_LAND,
    C.MAV_CMD_NAV_TAKEOFF,
    C.MAV_CMD_NAV_LOITER_TO_ALT,
    C.MAV_CMD_NAV_ROI,
    C.MAV_CMD_DO_SET_ROI,
    C.MAV_CMD_DO_SET_ROI_LOCATION,
    C.MAV_CMD_NAV_VTOL_TAKEOFF,
    C.MAV_CMD_NAV_VTOL_LAND,
    C.MAV_CMD_CONDITION_GATE,
    C.MAV_CMD_COMPONENT_ARM_DISARM,
    C.MAV_CMD_DO_AUTOTUNE_ENABLE,
    *FENCE_COMMANDS,
    *RALLY_COMMANDS,
}
#: what PX4 parses in MAV_FRAME_MISSION
PX4_MISSION_FRAME_COMMANDS = {
    C.MAV_CMD_DO_JUMP,
    C.MAV_CMD_NAV_ROI,
    C.MAV_CMD_DO_SET_ROI,
    C.MAV_CMD_DO_WINCH,
    C.MAV_CMD_DO_GRIPPER,
    C.MAV_CMD_DO_CHANGE_SPEED,
    C.MAV_CMD_DO_SET_HOME,
    C.MAV_CMD_DO_LAND_START,
    C.MAV_CMD_DO_TRIGGER_CONTROL,
    C.MAV_CMD_DO_DIGICAM_CONTROL,
    C.MAV_CMD_DO_MOUNT_CONFIGURE,
    C.MAV_CMD_DO_MOUNT_CONTROL,
    C.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
    C.MAV_CMD_SET_CAMERA_FOCUS,
    C.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
    C.MAV_CMD_IMAGE_START_CAPTURE,
    C.MAV_CMD_IMAGE_STOP_CAPTURE,
    C.MAV_CMD_VIDEO_START_CAPTURE,
    C.MAV_CMD_VIDEO_STOP_CAPTURE,
    C.MAV_CMD_DO_CONTROL_VIDEO,
    C.MAV_CMD_DO_SET_CAM_TRIGG_DIST,
    C.MAV_CMD_OBLIQUE_SURVEY,
    C.MAV_CMD_DO_SET_CAM_TRIGG_INTERVAL,
    C.MAV_CMD_SET_CAMERA_MODE,
    C.MAV_CMD_SET_CAMERA_SOURCE,
    C.MAV_CMD_DO_VTOL_TRANSITION,
    C.MAV_CMD_NAV_DELAY,
    C.MAV_CMD_NAV_RETURN_TO_LAUNCH,
    C.MAV_CMD_DO_SET_ROI_WPNEXT_OFFSET,
    C.MAV_CMD_DO_SET_ROI_NONE,
    C.MAV_CMD_CONDITION_DELAY,
    C.MAV_CMD_CONDITION_DISTANCE,
    C.MAV_CMD_DO_SET_ACTUATOR,
    C.MAV_CMD_DO_AUTOTUNE_ENABLE,
    C.MAV_CMD_COMPONENT_ARM_DISARM,
}
#: the items the simulator flies
FLOWN = {
    C.MAV_CMD_NAV_WAYPOINT,
    C.MAV_CMD_NAV_TAKEOFF,
    C.MAV_CMD_NAV_LAND,
    C.MAV_CMD_NAV_RETURN_TO_LAUNCH,
    C.MAV_CMD_NAV_LOITER_TIME,
    C.MAV_CMD_NAV_LOITER_UNLIM,
    C.MAV_CMD_DO_CHANGE_SPEED,
}
#: accepted and skipped: payload items (camera, gimbal, region of interest) of a vehicle without that payload
SKIPPED = {
    C.MAV_CMD_NAV_ROI,
    C.MAV_CMD_DO_SET_ROI,
    C.MAV_CMD_DO_SET_ROI_LOCATION,
    C.MAV_CMD_DO_SET_ROI_WPNEXT_OFFSET,
    C.MAV_CMD_DO_SET_ROI_NONE,
    C.MAV_CMD_DO_TRIGGER_CONTROL,
    C.MAV_CMD_DO_DIGICAM_CONTROL,
    C.MAV_CMD_DO_MOUNT_CONFIGURE,
    C.MAV_CMD_DO_MOUNT_CONTROL,
    C.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
    C.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
    C.MAV_CMD_SET_CAMERA_FOCUS,
    C.MAV_CMD_IMAGE_START_CAPTURE,
    C.MAV_CMD_IMAGE_STOP_CAPTURE,
    C.MAV_CMD_VIDEO_START_CAPTURE,
    C.MAV_CMD_VIDEO_STOP_CAPTURE,
    C.MAV_CMD_DO_CONTROL_VIDEO,
    C.MAV_CMD_DO_SET_CAM_TRIGG_DIST,
    C.MAV_CMD_DO_SET_CAM_TRIGG_INTERVAL,
    C.MAV_CMD_SET_CAMERA_MODE,
    C.MAV_CMD_SET_CAMERA_SOURCE,
}
ROI = {C.MAV_CMD_NAV_ROI, C.MAV_CMD_DO_SET_ROI}


def px4_check(item: MissionItem, mission_type: int, int_form: bool) -> tuple[int | None, str]:
    """PX4's verdict on an uploaded item: (None, "") to store it, or the MAV_MISSION_RESULT and why."""
    frame, command = item.frame, item.command
    name = enum_name("MAV_CMD", command)
    if frame in GLOBAL or (int_form and frame in GLOBAL_INT_ONLY):
        if command not in PX4_GLOBAL_COMMANDS:
            return C.MAV_MISSION_UNSUPPORTED, f"{name} is not a position item"
        if command in ROI and int(item.param1) not in (C.MAV_ROI_LOCATION, C.MAV_ROI_NONE):
            return C.MAV_MISSION_INVALID_PARAM1, f"{name}: ROI mode {item.param1:g}"
    elif frame == C.MAV_FRAME_MISSION:
        if command not in PX4_MISSION_FRAME_COMMANDS:
            return C.MAV_MISSION_UNSUPPORTED, f"{name} needs a position"
        if command in ROI and int(item.param1) not in (C.MAV_ROI_NONE, C.MAV_ROI_WPNEXT, C.MAV_ROI_WPINDEX):
            return C.MAV_MISSION_INVALID_PARAM1, f"{name}: ROI mode {item.param1:g}"
    else:
        why = "only in MISSION_ITEM_INT" if frame in GLOBAL_INT_ONLY else "global frames only"
        return C.MAV_MISSION_UNSUPPORTED_FRAME, f"frame {enum_name('MAV_FRAME', frame)}: {why}"
    if mission_type == MISSION:
        if command in FENCE_COMMANDS or command in RALLY_COMMANDS:
            return C.MAV_MISSION_ERROR, f"{name} in a mission"
        if command not in FLOWN and command not in SKIPPED:
            return C.MAV_MISSION_UNSUPPORTED, f"{name} is not simulated"
        if command in (C.MAV_CMD_NAV_WAYPOINT, C.MAV_CMD_NAV_TAKEOFF) and math.isnan(item.z):
            return C.MAV_MISSION_INVALID_PARAM7, f"{name} without an altitude"
    elif mission_type == FENCE:
        if command not in FENCE_COMMANDS:
            return C.MAV_MISSION_UNSUPPORTED, f"{name} in a geofence"
        vertex = command in (C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION)
        if vertex and round(item.param1) < 3:
            return C.MAV_MISSION_ERROR, "fence polygon with fewer than 3 vertices"
    elif mission_type == RALLY and command not in RALLY_COMMANDS:
        return C.MAV_MISSION_UNSUPPORTED, f"{name} in the rally points"
    return None, ""


def _yaw(degrees: float) -> float:
    """PX4 stores a yaw as radians wrapped to [0, 2 pi) and sends back degrees."""
    if not math.isfinite(degrees):
        return degrees
    return math.degrees(math.radians(degrees) % (2 * math.pi))


def px4_stored(item: MissionItem, int_form: bool) -> MissionItem:
    """The item as PX4 sends it back (download): see the module's docstring."""
    if item.frame == C.MAV_FRAME_MISSION:
        return item
    relative = item.frame in RELATIVE
    if int_form:
        frame = C.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT if relative else C.MAV_FRAME_GLOBAL_INT
    else:
        frame = C.MAV_FRAME_GLOBAL_RELATIVE_ALT if relative else C.MAV_FRAME_GLOBAL
    p = [0.0, 0.0, 0.0, 0.0]
    command = item.command
    if command == C.MAV_CMD_NAV_WAYPOINT:
        p = [item.param1, item.param2, 0.0, _yaw(item.param4)]
    elif command == C.MAV_CMD_NAV_LOITER_UNLIM:
        p = [0.0, 0.0, item.param3, _yaw(item.param4)]
    elif command == C.MAV_CMD_NAV_LOITER_TIME:
        p = [item.param1, float(item.param2 > 0), item.param3, float(item.param4 > 0)]
    elif command == C.MAV_CMD_NAV_LAND:
        p = [0.0, item.param2, 0.0, _yaw(item.param4)]
    elif command == C.MAV_CMD_NAV_TAKEOFF:
        p = [0.0, 0.0, 0.0, _yaw(item.param4)]
    elif command in (C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION):
        p = [float(round(item.param1)), 0.0, 0.0, 0.0]
    elif command in (C.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, C.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION):
        p = [item.param1, 0.0, 0.0, 0.0]
    return MissionItem(command, frame, item.x, item.y, item.z, *p, autocontinue=item.autocontinue)
