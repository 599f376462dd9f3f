"""``ompl``: OMPL's PRM, PRM*, RRT-Connect and RRT* on surgiplan's scene and spaces (:mod:`.bridge`).

The reference planners the methods of papers 000 and 001 are benchmarked
against (I. A. Şucan, M. Moll and L. E. Kavraki, "The Open Motion Planning
Library", IEEE Robotics & Automation Magazine 19(4), 2012). Needs the
optional extra ``pip install 'surgiplan[ompl]'``; without it the plugin is
listed as unavailable with that hint.
"""

from __future__ import annotations

import importlib.util
from typing import TYPE_CHECKING

from surgiplan.hookspecs import PluginSpec, hookimpl
from surgiplan.lazy import lazy_exports

if TYPE_CHECKING:
    from .bridge import OmplPlanner, OmplSettings

__getattr__, __dir__ = lazy_exports(
    __name__,
    {"OmplPlanner": ".bridge", "OmplSettings": ".bridge"},
)

__all__ = ["OmplPlanner", "OmplSettings"]


@hookimpl
def surgiplan_register_planners():
    if importlib.util.find_spec("ompl") is None:
        return [
            PluginSpec(
                "ompl",
                "surgiplan.plugins.planners.ompl_bridge.bridge:OmplPlanner",
                "OMPL planners (PRM, PRM*, RRT-Connect, RRT*)",
                unavailable="OMPL is not installed: pip install 'surgiplan[ompl]'",
            )
        ]
    return [
        PluginSpec(
            "ompl",
            "surgiplan.plugins.planners.ompl_bridge.bridge:OmplPlanner",
            "OMPL planners (PRM, PRM*, RRT-Connect, RRT*) on surgiplan's checks",
        )
    ]
