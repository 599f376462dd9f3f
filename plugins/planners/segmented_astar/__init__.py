"""``segmented_astar``: online A* on the segmented pathmap of an optMIS repository.

A. Rao, M. Valenzuela and J. W. Rozenblit, "Safety-assured offline-online
path planning with reduced storage requirements in simulated surgical
training", Spring Simulation Conference (SpringSim), 2020 (paper 001),
§3.2, §4 and §5. Where each part lives:

* :mod:`.pathmap` — §3.2, §4: paths cut into segments of n_s points, common
  segments merged within w_tip, each path a sequence of references;
* :mod:`.graph` — the online graph of the pathmap's points (degree-2 chains
  contracted) and the links of a start or goal off the pathmap;
* :mod:`.search` — §5: A* with the Euclidean heuristic, links, replanning
  (Fig. 6); the :class:`SegmentedAStar` plugin;
* :mod:`.report` — §6, Table 1: storage against n_s, the paper's method and
  ours;
* :mod:`.figures` — Fig. 6, replanning.

The pathmap compresses the repository of :mod:`surgiplan.plugins.planners.optmis`
(the offline half of the same paper), the one import between planner
packages that the import contracts allow.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from surgiplan.hookspecs import PluginSpec, hookimpl
from surgiplan.lazy import lazy_exports

if TYPE_CHECKING:
    from .search import SegmentedAStar

__getattr__, __dir__ = lazy_exports(
    __name__,
    {"SegmentedAStar": ".search"},
)

__all__ = ["SegmentedAStar"]


@hookimpl
def surgiplan_register_planners():
    return [
        PluginSpec(
            "segmented_astar",
            "surgiplan.plugins.planners.segmented_astar.search:SegmentedAStar",
            "online A* on the segmented pathmap of an optMIS repository (Rao, Valenzuela & Rozenblit)",
        )
    ]
