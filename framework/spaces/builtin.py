"""Registers the built-in configuration spaces (through the ``surgiplan`` entry points)."""

from __future__ import annotations

from ..hookspecs import PluginSpec, hookimpl
from .gimbal import CastGimbalSpace
from .r3 import R3Space
from .se3 import SE3Space


@hookimpl
def surgiplan_register_spaces():
    return [
        PluginSpec("r3", R3Space, "instrument tip as a sphere moving in the workspace"),
        PluginSpec(
            "cast_gimbal", CastGimbalSpace, "laparoscopic shaft about a fixed fulcrum (yaw, pitch, insertion, roll)"
        ),
        PluginSpec("se3", SE3Space, "rigid body (e.g. gripper) position and orientation"),
    ]
