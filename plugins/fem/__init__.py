"""``stvk``: nonlinear St. Venant-Kirchhoff tetrahedral FEM, the deformable-model plugin.

S. Patil and R. Alterovitz, "Automated tissue retraction for robot-assisted
surgical procedures" (paper 002; published as "Toward automated tissue
retraction in robot-assisted surgery", IEEE ICRA 2010), §IV-D and §V, compute static equilibria of a tissue
flap with a nonlinear StVK finite element model; the ``retraction`` planner
calls this model for every sampled gripper pose. Modules:

* :mod:`.mesh` — tetrahedral meshes (linear or quadratic): structured boxes, meshio files, TetGen;
* :mod:`.shape` — reference tetrahedra: shape functions and quadrature rules;
* :mod:`.material` — per-element E, nu, rho, volume penalty; region and image maps;
* :mod:`.stvk` — the element kernel: energy, forces, tangent (vectorised numpy);
* :mod:`.kernels` — its compiled (numba) parts: the Newton solve's energy and forces, the element
  tangents summed over the quadrature points and assembled as they are computed;
* :mod:`.loads` — lumped-mass gravity, dead loads, base-plane contact;
* :mod:`.assembly` — the sparse tangent by precomputed index arrays;
* :mod:`.linear` — its sparse direct solvers: PARDISO (oneMKL, analysis once per mesh; Cholesky, LDLᵀ with
  inertia), SuperLU;
* :mod:`.newton` — Newton's method with predictor, line search, stopping rules;
* :mod:`.intersection` — self-intersection of the deformed surface;
* :mod:`.model` — :class:`StVKModel`, the public API (what planners use; it imports no stage code);
* :mod:`.stage` — the ``simulate`` stage (one equilibrium or quasi-static steps, ``.vtu``/``.pvd``)
  and :class:`StVK`, the registered plugin: the model plus its stage;
* :mod:`.tasks` — equilibria in worker processes (``run_tasks``);
* :mod:`.output` — ``.vtu`` files.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from surgiplan.hookspecs import PluginSpec, hookimpl
from surgiplan.lazy import lazy_exports

if TYPE_CHECKING:
    from .mesh import TetMesh, box_mesh, read_tet_mesh
    from .model import AxisConstraints, StVKModel
    from .settings import StVKSettings
    from .stage import StVK

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "TetMesh": ".mesh",
        "box_mesh": ".mesh",
        "read_tet_mesh": ".mesh",
        "AxisConstraints": ".model",
        "StVKModel": ".model",
        "StVKSettings": ".settings",
        "StVK": ".stage",
    },
)

__all__ = ["AxisConstraints", "StVK", "StVKModel", "StVKSettings", "TetMesh", "box_mesh", "read_tet_mesh"]


@hookimpl
def surgiplan_register_deformable_models():
    return [
        PluginSpec(
            "stvk",
            "surgiplan.plugins.fem.stage:StVK",
            "nonlinear St. Venant-Kirchhoff tetrahedral FEM: static equilibria of grasped tissue (paper 002 §V)",
        )
    ]
