"""``optmis``: the optMIS offline planner, all-pairs certified optimal paths.

A. Rao, M. Valenzuela and J. W. Rozenblit, "Safety-assured offline-online
path planning with reduced storage requirements in simulated surgical
training", Spring Simulation Conference (SpringSim), 2020 (paper 001), §3.1,
after Napalkova et al.'s optMIS. Where each part lives:

* :mod:`.search_space` — §3.1: the Delaunay search space of the free space
  for the tip sphere, every vertex and edge certified;
* :mod:`.paths` — shortest paths from a source (one Dijkstra call),
  tautened, turns wrapped, smoothed by certified splines;
* :mod:`.repository` — all N(N-1)/2 pairs on the pipeline's executor,
  resumable, with the unreachable pairs listed;
* :mod:`.offline` — the settings and the resumable offline run both
  paper-001 stages share;
* :mod:`.planner` — the :class:`OptMIS` plugin: build, stored lookups,
  queries between arbitrary points.

The online half of paper 001 (segmented pathmap, A*) is
:mod:`surgiplan.plugins.planners.segmented_astar`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from surgiplan.hookspecs import PluginSpec, hookimpl
from surgiplan.lazy import lazy_exports

if TYPE_CHECKING:
    from .offline import OptMISSettings
    from .planner import OptMIS

__getattr__, __dir__ = lazy_exports(
    __name__,
    {"OptMISSettings": ".offline", "OptMIS": ".planner"},
)

__all__ = ["OptMIS", "OptMISSettings"]


@hookimpl
def surgiplan_register_planners():
    return [
        PluginSpec(
            "optmis",
            "surgiplan.plugins.planners.optmis.planner:OptMIS",
            "optMIS offline planner: all-pairs certified optimal paths (Rao et al.)",
        )
    ]
