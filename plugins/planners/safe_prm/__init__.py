"""``safe_prm``: the proficiency-based safe PRM with path repair.

S. Jain, M. Hong and J. W. Rozenblit, "Proficiency based planner for safe
path planning and applications in surgical training", Spring Simulation
Conference, Modeling and Simulation in Medicine (SpringSim-MSM), 2019
(paper 000). Where each part of the paper lives:

* :mod:`.roadmap` — §3.2-3.3, Algorithms 1 and 3: the roadmap pair R and
  R_safe from one set of milestones (K-S neighbours, union-find), every
  edge certified;
* :mod:`.search` — Algorithms 2-3: the shortest path in R (or R_safe);
* :mod:`.repair` — Algorithm 4, PathRepair; what it cannot span is a
  critical region;
* :mod:`.query` — a query: links, §5's projection of a start or goal in the
  risk region, search, repair;
* :mod:`.proficiency` — §3.1: d_thresh from a level, a length or a trainee's
  recorded attempts;
* :mod:`.smoothing` — §5's admitted roughness: a QP inside the certified
  clearance corridor (OSQP);
* :mod:`.planner` — the :class:`SafePRM` plugin: settings, build, query,
  critical regions.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from surgiplan.hookspecs import PluginSpec, hookimpl
from surgiplan.lazy import lazy_exports

if TYPE_CHECKING:
    from .planner import SafePRM, SafePRMSettings, critical_regions

__getattr__, __dir__ = lazy_exports(
    __name__,
    {"SafePRM": ".planner", "SafePRMSettings": ".planner", "critical_regions": ".planner"},
)

__all__ = ["SafePRM", "SafePRMSettings", "critical_regions"]


@hookimpl
def surgiplan_register_planners():
    return [
        PluginSpec(
            "safe_prm",
            "surgiplan.plugins.planners.safe_prm.planner:SafePRM",
            "proficiency-based safe PRM with path repair (Jain, Hong & Rozenblit 2019)",
        )
    ]
