"""Reference tetrahedra of the ``stvk`` model: shape functions and quadrature, linear and quadratic.

The reference tetrahedron has vertices (0, 0, 0), (1, 0, 0), (0, 1, 0),
(0, 0, 1); with barycentric coordinates ``L0 = 1 - xi - eta - zeta``,
``L1 = xi``, ``L2 = eta``, ``L3 = zeta``:

* **linear** (4 nodes): ``N_i = L_i``; one quadrature point, the centroid,
  integrates every polynomial of degree 1 exactly (the deformation
  gradient is constant, so the StVK energy is integrated exactly);
* **quadratic** (10 nodes, VTK/meshio ``tetra10`` order: the four vertices,
  then the mid-edge nodes of edges 0-1, 1-2, 0-2, 0-3, 1-3, 2-3):
  ``N_i = L_i (2 L_i - 1)`` at the vertices, ``N_ij = 4 L_i L_j`` at the
  edges; the symmetric four-point rule of degree 2 (Hammer, Marlowe &
  Stroud 1956; the rule of Abaqus' C3D10). Its 4 x 6 strain samples
  exceed the 30 - 6 non-rigid degrees of freedom of an element, so no
  spurious zero-energy mode exists.

Quadratic tetrahedra represent bending (a linear variation of strain
through the thickness) exactly, which linear tetrahedra cannot: they do not
lock (Zienkiewicz & Taylor, *The Finite Element Method*, vol. 1, §8-9).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: local vertices (i, j) of the mid-edge nodes 4..9 of a quadratic tetrahedron (VTK order)
EDGES = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])
#: EDGE_NODE[i, j]: the local mid-edge node between vertices i and j (-1 on the diagonal)
EDGE_NODE = np.full((4, 4), -1)
EDGE_NODE[EDGES[:, 0], EDGES[:, 1]] = EDGE_NODE[EDGES[:, 1], EDGES[:, 0]] = np.arange(4, 10)
#: local node order of a quadratic tetrahedron with vertices 1 and 2 swapped (fixes its orientation)
SWAP_1_2 = {4: np.array([0, 2, 1, 3]), 10: np.array([0, 2, 1, 3, 6, 5, 4, 7, 9, 8])}

# the gradients of the barycentric coordinates with respect to (xi, eta, zeta)
_DL = np.array([[-1.0, -1.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])

_A, _B = 0.5854101966249685, 0.1381966011250105  # (5 + 3 sqrt 5) / 20, (5 - sqrt 5) / 20


@dataclass(frozen=True)
class ReferenceElement:
    """Shape functions of one element type and its quadrature rule (reference coordinates)."""

    nodes: int
    #: (p, 4) barycentric coordinates of the quadrature points
    points: np.ndarray
    #: (p,) weights; they add up to the reference volume 1/6
    weights: np.ndarray

    def values(self, barycentric: np.ndarray) -> np.ndarray:
        """N (p, nodes) at points given by barycentric coordinates (p, 4)."""
        lam = np.atleast_2d(np.asarray(barycentric, dtype=float))
        if self.nodes == 4:
            return lam.copy()
        vertex = lam * (2.0 * lam - 1.0)
        edge = 4.0 * lam[:, EDGES[:, 0]] * lam[:, EDGES[:, 1]]
        return np.concatenate([vertex, edge], axis=1)

    def derivatives(self, barycentric: np.ndarray) -> np.ndarray:
        """dN/d(xi, eta, zeta) (p, nodes, 3) at points given by barycentric coordinates (p, 4)."""
        lam = np.atleast_2d(np.asarray(barycentric, dtype=float))
        if self.nodes == 4:
            return np.broadcast_to(_DL, (len(lam), 4, 3)).copy()
        vertex = (4.0 * lam - 1.0)[:, :, None] * _DL[None]
        i, j = EDGES[:, 0], EDGES[:, 1]
        edge = 4.0 * (lam[:, j, None] * _DL[None, i] + lam[:, i, None] * _DL[None, j])
        return np.concatenate([vertex, edge], axis=1)


LINEAR = ReferenceElement(4, np.full((1, 4), 0.25), np.array([1.0 / 6.0]))
QUADRATIC = ReferenceElement(
    10,
    np.array([[_A, _B, _B, _B], [_B, _A, _B, _B], [_B, _B, _A, _B], [_B, _B, _B, _A]]),
    np.full(4, 1.0 / 24.0),
)
#: the vertices in barycentric coordinates (where a quadratic element's Jacobian is also checked)
VERTICES = np.eye(4)


def reference_element(nodes_per_element: int) -> ReferenceElement:
    """The reference element with 4 (linear) or 10 (quadratic) nodes."""
    if nodes_per_element == 4:
        return LINEAR
    if nodes_per_element == 10:
        return QUADRATIC
    raise ValueError(f"tetrahedra have 4 or 10 nodes, not {nodes_per_element}")


def physical_gradients(rest: np.ndarray, derivatives: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shape-function gradients in rest coordinates and the Jacobian determinants, at one point.

    ``rest`` (m, nodes, 3) element node positions (m), ``derivatives``
    (nodes, 3) dN/dxi at the point. Returns ``grad`` (m, nodes, 3) in 1/m
    (dN/dX = dN/dxi J^-1 with J = dX/dxi) and ``det J`` (m,) in m^3.
    """
    jacobian = np.einsum("mai,aj->mij", rest, derivatives)
    det = np.linalg.det(jacobian)
    return derivatives @ np.linalg.inv(jacobian), det
