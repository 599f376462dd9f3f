"""The ``retraction`` planner: optimal tissue-retraction plans and grasp selection on FEM states (paper 002).

S. Patil and R. Alterovitz, "Automated tissue retraction for robot-assisted
surgical procedures" (paper 002; published as "Toward automated tissue
retraction in robot-assisted surgery", IEEE ICRA 2010), §IV, plan how a gripper lifts a tissue flap until an area of
interest beneath it is visible, on a roadmap of static FEM equilibria,
minimising the maximum deformation energy, the maximum stress or the
control effort, and choose the best initial grasp. Modules:

* :mod:`.settings` — the planner's settings (pydantic, SI);
* :mod:`.grasp` — anchored and grasped nodes, constraints of a gripper pose, candidate grasps;
* :mod:`.sampling` — uniform and user-guided sampling in SE(3), warm-start ordering;
* :mod:`.equilibria` — worker tasks: samples (with the rotation's local optimisation), edges, trajectories;
* :mod:`.geometry` — flap against obstacles, instrument against tissue (coal);
* :mod:`.visibility` — the visible fraction of the area of interest (ray casting);
* :mod:`.roadmap` — exact k nearest neighbours by DISP;
* :mod:`.search` — bottleneck and additive optimal paths, lazy search;
* :mod:`.generation` — the build: samples, checks and roadmap per grasp;
* :mod:`.lazy` — the query: lazy search per grasp, grasp selection, the C¹ trajectory;
* :mod:`.trajectory` — cubic splines in position and rotation;
* :mod:`.outputs` — the states file and the figures;
* :mod:`.planner` — :class:`RetractionPlanner`.

The tissue is any deformable-model plugin, found by its registered name
(``deformable: {plugin: stvk, ...}``) and used only through
:class:`surgiplan.DeformableModel`: this package imports no FEM code.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from surgiplan.hookspecs import PluginSpec, hookimpl
from surgiplan.lazy import lazy_exports

if TYPE_CHECKING:
    from .planner import RetractionPlanner
    from .settings import RetractionSettings

__getattr__, __dir__ = lazy_exports(
    __name__,
    {"RetractionPlanner": ".planner", "RetractionSettings": ".settings"},
)

__all__ = ["RetractionPlanner", "RetractionSettings"]


@hookimpl
def surgiplan_register_planners():
    return [
        PluginSpec(
            "retraction",
            "surgiplan.plugins.planners.retraction.planner:RetractionPlanner",
            "tissue retraction on FEM equilibria: min-max energy/stress or control effort, best grasp (paper 002)",
        )
    ]
