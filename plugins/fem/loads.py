"""External loads of the ``stvk`` model: lumped-mass gravity, dead loads, base-plane contact.

Patil & Alterovitz §V ("Assembling external forces"): gravity acts through
a lumped mass matrix (each linear tetrahedron gives a quarter of its mass
rho V to each of its nodes; for quadratic tetrahedra the work-equivalent
nodal loads ``rho g int N_a dV`` are used instead, which are exact for a
uniform field: a quadratic element's vertices then carry -1/20 and its
mid-edge nodes 1/5 of its weight, see :func:`work_equivalent_masses`),
and the tissue rests on an underlying base, a plane, held by a penalty: a
node that sinks a depth d below the plane is pushed back by ``k d`` along
the plane's normal. Dead loads (forces of fixed
direction and size, N) may be added per node.

All of these derive from a potential measured from the rest state X (x =
X + u), which :meth:`ExternalLoads.evaluate` returns with its gradient:

    V_ext(x) = - sum_nodes (m g + f) . u  +  sum_nodes k/2 min(n . (x - p), 0)^2.

The first sum is the work-of-external-forces term of the paper's total
energy Π (§IV-D) with the sign of a potential (lifting tissue against
gravity raises Π); the second is the contact penalty's stored energy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class BasePlane:
    """The plane through ``point`` with unit ``normal`` (m); nodes below it are pushed out.

    ``stiffness`` in N/m per node.
    """

    point: np.ndarray
    normal: np.ndarray
    stiffness: float

    def __post_init__(self) -> None:
        self.point = np.asarray(self.point, dtype=float).reshape(3)
        normal = np.asarray(self.normal, dtype=float).reshape(3)
        length = np.linalg.norm(normal)
        if not length > 0:
            raise ValueError("the base plane's normal must not be zero")
        self.normal = normal / length
        if not self.stiffness > 0:
            raise ValueError("the base plane's stiffness must be positive")

    def depth(self, x: np.ndarray) -> np.ndarray:
        """Signed height (n,) of points above the plane (m); negative below."""
        return (x - self.point) @ self.normal


@dataclass
class LoadEvaluation:
    energy: float  # J
    gradient: np.ndarray | None  # (3n,) N
    contact_nodes: np.ndarray  # nodes below the base plane
    contact_blocks: np.ndarray  # (k, 3, 3) their penalty tangents, N/m
    work: float  # J, (m g + f) . u: work done by gravity and dead loads
    contact_energy: float  # J


class ExternalLoads:
    """Gravity on lumped masses (kg, (n,)), dead loads (n, 3) N and an optional base plane."""

    def __init__(
        self,
        rest: np.ndarray,
        masses: np.ndarray,
        gravity=(0.0, 0.0, -9.8),
        forces: np.ndarray | None = None,
        base: BasePlane | None = None,
    ) -> None:
        self.rest = np.asarray(rest, dtype=float)
        self.masses = np.asarray(masses, dtype=float)
        self.gravity = np.asarray(gravity, dtype=float).reshape(3)
        self.base = base
        self.body_forces = self.masses[:, None] * self.gravity  # N per node
        self._rest_depth: np.ndarray | None = None  # heights of the rest nodes above the base plane
        self.set_forces(forces)

    def set_forces(self, forces: np.ndarray | None) -> None:
        """Dead loads (n, 3) in N, added to gravity; ``None`` for none."""
        total = self.body_forces.copy()
        if forces is not None:
            total += np.asarray(forces, dtype=float).reshape(total.shape)
        self.total_forces = total
        self._flat = total.ravel()

    def evaluate(self, x: np.ndarray, gradient: bool = True, displacement: bool = False) -> LoadEvaluation:
        """Potential, gradient and contact of the loads at positions x (n, 3), or displacements u (``displacement``)."""
        u = np.asarray(x, dtype=float).reshape(self.rest.shape)
        if not displacement:
            u = u - self.rest
        work = float(np.dot(self._flat, u.ravel()))
        grad = -self._flat.copy() if gradient else None
        nodes = np.empty(0, dtype=np.int64)
        blocks = np.empty((0, 3, 3))
        contact = 0.0
        if self.base is not None:
            if self._rest_depth is None:
                self._rest_depth = self.base.depth(self.rest)
            depth = self._rest_depth + u @ self.base.normal
            nodes = np.flatnonzero(depth < 0)
            if len(nodes):
                k = self.base.stiffness
                d = depth[nodes]
                contact = 0.5 * k * float(np.dot(d, d))
                if gradient:
                    grad.reshape(-1, 3)[nodes] += (k * d)[:, None] * self.base.normal
                blocks = np.broadcast_to(k * np.outer(self.base.normal, self.base.normal), (len(nodes), 3, 3))
        return LoadEvaluation(contact - work, grad, nodes, blocks, work, contact)


def lumped_masses(n_nodes: int, tets: np.ndarray, volumes: np.ndarray, density: np.ndarray) -> np.ndarray:
    """Node masses (n,) in kg: a quarter of each tetrahedron's mass rho V to each of its nodes."""
    share = np.repeat(0.25 * np.asarray(density) * np.asarray(volumes), 4)
    return np.bincount(np.asarray(tets).ravel(), weights=share, minlength=n_nodes)


def work_equivalent_masses(n_nodes: int, tets: np.ndarray, point_weights, shape_values, density) -> np.ndarray:
    """Node masses (n,) in kg whose weights are the work-equivalent gravity loads ``rho g int N_a dV``.

    ``point_weights`` (p, m) quadrature weights times Jacobians (m^3),
    ``shape_values`` (p, k) the shape functions at the quadrature points.
    For linear tetrahedra this is :func:`lumped_masses`; for quadratic ones
    the vertices get negative shares (-1/20 of an element's mass each).
    """
    share = np.einsum("pm,pk->mk", np.asarray(point_weights), np.asarray(shape_values)) * np.asarray(density)[:, None]
    return np.bincount(np.asarray(tets).ravel(), weights=share.ravel(), minlength=n_nodes)
