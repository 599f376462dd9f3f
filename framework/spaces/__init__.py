"""Configuration spaces: R3 (tip), the CAST gimbal (shaft about a fulcrum), SE3 (rigid body)."""

from .base import Space, certify_by_covering
from .gimbal import CastGimbalSettings, CastGimbalSpace
from .r3 import R3Settings, R3Space
from .se3 import SE3Settings, SE3Space

__all__ = [
    "CastGimbalSettings",
    "CastGimbalSpace",
    "R3Settings",
    "R3Space",
    "SE3Settings",
    "SE3Space",
    "Space",
    "certify_by_covering",
]
