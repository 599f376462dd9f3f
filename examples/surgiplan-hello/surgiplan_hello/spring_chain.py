"""The ``spring_chain`` deformable model (an example deformable-model plugin).

``nodes`` nodes evenly spaced from ``start`` to ``end``, each of mass
``node_mass``, joined to their neighbours by linear springs of stiffness
``stiffness`` acting on the displacement vector (a discrete string under
tension), under ``gravity``. The equilibrium for prescribed nodes is the
solution of a linear system, exact: with both ends held, node i of n sags
by (m g / 2k) i (n - 1 - i), the discrete parabola the ``simulate`` stage
compares with (``sag_error``).

A model supplies its rest nodes and elements and ``solve`` (what planners
use); ``run_stage`` makes it usable as a pipeline's ``simulate`` stage.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, PositiveFloat
from surgiplan import (
    Constraints,
    DeformableModel,
    EquilibriumState,
    ResourceEstimate,
    SimulateStatus,
    StageResult,
    Vec3,
)
from surgiplan.models import StrictModel


class SpringChainSettings(StrictModel):
    start: Vec3
    end: Vec3
    nodes: int = Field(default=21, ge=3)
    #: N/m, between neighbours
    stiffness: PositiveFloat = 100.0
    #: kg per node
    node_mass: PositiveFloat = 0.001
    #: m/s^2
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    #: simulate stage: which nodes are held at rest ("ends": the first and the last)
    anchored: str = Field(default="ends", pattern="^(ends|first)$")


class SpringChain(DeformableModel):
    Settings = SpringChainSettings

    @classmethod
    def estimate_resources(cls, settings):
        n = settings.nodes  # a tridiagonal system: a few arrays of 3n values
        return [ResourceEstimate(n * 3 * 8 * 20, f"a chain of {n:,} nodes", "nodes")]

    def __init__(self, settings: SpringChainSettings) -> None:
        # heavy libraries are imported where they are used: loading the plugin (surgiplan plugins, validate)
        # does not pay for scipy.sparse
        import scipy.sparse as sp

        super().__init__(settings)
        s = settings
        t = np.linspace(0.0, 1.0, s.nodes)[:, None]
        self._rest = np.asarray(s.start) + t * (np.asarray(s.end) - np.asarray(s.start))
        self._elements = np.column_stack([np.arange(s.nodes - 1), np.arange(1, s.nodes)])
        # the graph Laplacian times k, one block per coordinate
        n = s.nodes
        main = np.full(n, 2.0)
        main[[0, -1]] = 1.0
        self._laplacian = sp.diags([main, -np.ones(n - 1), -np.ones(n - 1)], [0, 1, -1], format="csr") * s.stiffness

    @property
    def rest_nodes(self) -> np.ndarray:
        return self._rest

    @property
    def elements(self) -> np.ndarray:
        return self._elements

    def solve(self, constraints: Constraints, initial: EquilibriumState | None = None) -> EquilibriumState:
        from scipy.sparse.linalg import spsolve

        n = len(self._rest)
        held = np.asarray(constraints.prescribed_nodes, dtype=np.int64)
        free = np.setdiff1d(np.arange(n), held)
        load = np.tile(self.settings.node_mass * np.asarray(self.settings.gravity), (n, 1))
        if constraints.external_forces is not None:
            load = load + constraints.external_forces
        u = np.zeros((n, 3))
        u[held] = np.asarray(constraints.prescribed_positions, float) - self._rest[held]
        if not held.size:
            return EquilibriumState(
                self._rest.copy(),
                np.nan,
                np.zeros(n - 1),
                False,
                False,
                0,
                np.inf,
                "nothing holds the chain: no equilibrium",
            )
        k_ff = self._laplacian[free][:, free]
        k_fh = self._laplacian[free][:, held]
        for axis in range(3):
            u[free, axis] = spsolve(k_ff.tocsc(), load[free, axis] - k_fh @ u[held, axis])
        stretch = np.diff(u, axis=0)
        elastic = 0.5 * self.settings.stiffness * float(np.sum(stretch**2))
        energy = elastic - float(np.sum(load * u))
        residual = float(np.abs((self._laplacian @ u - load)[free]).max()) if free.size else 0.0
        tension = self.settings.stiffness * np.linalg.norm(stretch, axis=1)  # N per spring
        return EquilibriumState(
            self._rest + u, energy, tension, True, True, 1, residual, data={"elastic_energy": elastic}
        )

    def run_stage(self, context) -> StageResult:
        n = len(self._rest)
        held = np.array([0, n - 1]) if self.settings.anchored == "ends" else np.array([0])
        state = self.solve(Constraints(held, self._rest[held]))
        sag = self._rest[:, 2] - state.positions[:, 2]
        metrics = {"energy_J": state.energy, "max_sag_m": float(sag.max()), "residual": state.residual}
        if self.settings.anchored == "ends":
            i = np.arange(n)
            g = -self.settings.gravity[2]
            closed = self.settings.node_mass * g / (2 * self.settings.stiffness) * i * (n - 1 - i)
            metrics["sag_error_m"] = float(np.abs(sag - closed).max())
        return StageResult("simulate", context.name, "spring_chain", SimulateStatus.CONVERGED, metrics=metrics)
