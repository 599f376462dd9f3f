"""Built-in deformable-model plugins: ``stvk``, nonlinear St. Venant-Kirchhoff tetrahedral FEM.

Patil & Alterovitz (paper 002, §V) compute static equilibria of a tissue
flap with a nonlinear StVK finite element model; the ``retraction`` planner
calls this model for every sampled gripper pose. Modules:

* :mod:`.mesh` — tetrahedral meshes (linear or quadratic): structured boxes, meshio files, TetGen;
* :mod:`.shape` — reference tetrahedra: shape functions and quadrature rules;
* :mod:`.material` — per-element E, nu, rho, volume penalty; region and image maps;
* :mod:`.stvk` — the element kernel: energy, forces, tangent (vectorised);
* :mod:`.loads` — lumped-mass gravity, dead loads, base-plane contact;
* :mod:`.assembly` — the sparse tangent by precomputed index arrays, SuperLU;
* :mod:`.newton` — Newton's method with predictor, line search, stopping rules;
* :mod:`.intersection` — self-intersection of the deformed surface;
* :mod:`.model` — :class:`StVKModel`, the public API;
* :mod:`.stage` — the ``simulate`` stage: one equilibrium or quasi-static steps, ``.vtu``/``.pvd``;
* :mod:`.tasks` — equilibria in worker processes (``run_tasks``);
* :mod:`.output` — ``.vtu`` files.
"""

from __future__ import annotations

from surgiplan.hookspecs import PluginSpec, hookimpl

from .mesh import TetMesh, box_mesh, read_tet_mesh
from .model import AxisConstraints, StVKModel
from .settings import StVKSettings

__all__ = ["AxisConstraints", "StVKModel", "StVKSettings", "TetMesh", "box_mesh", "read_tet_mesh"]


@hookimpl
def surgiplan_register_deformable_models():
    return [
        PluginSpec(
            "stvk",
            StVKModel,
            "nonlinear St. Venant-Kirchhoff tetrahedral FEM: static equilibria of grasped tissue (paper 002 §V)",
        )
    ]
