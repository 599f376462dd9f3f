"""Grasps: which nodes the gripper holds, where they go for a gripper configuration, and candidates.

Paper 002 §IV-A ("Manipulation constraints"): the flap is anchored at a
subset of nodes (held at rest), and every node inside the bounding box of
the gripper jaws at the initial grasp ``q0`` is fixed to the gripper. For a
sampled configuration ``q`` the grasped nodes move rigidly,

    x = T(q) T(q0)^-1 X      (X their rest positions),

and the equilibrium under these constraints is the state M(q).
Configurations are SE(3) poses ``(x, y, z, qx, qy, qz, qw)`` in metres with
scalar-last unit quaternions (the ``se3`` space's layout).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from surgiplan.deformable import Constraints
from surgiplan.errors import PlanningInputError
from surgiplan.geometry.transforms import canonical_quaternion

from .settings import GraspCandidatesModel, JawsModel, RegionModel


def pose_matrices(q) -> np.ndarray:
    """4 x 4 transforms (..., 4, 4) of configurations (..., 7)."""
    q = np.asarray(q, dtype=float)
    out = np.zeros((*q.shape[:-1], 4, 4))
    out[..., :3, :3] = Rotation.from_quat(q[..., 3:].reshape(-1, 4)).as_matrix().reshape(*q.shape[:-1], 3, 3)
    out[..., :3, 3] = q[..., :3]
    out[..., 3, 3] = 1.0
    return out


def configuration(position, rotation) -> np.ndarray:
    """A configuration (7,) from a position (3,) and a rotation matrix (3, 3)."""
    quaternion = canonical_quaternion(Rotation.from_matrix(np.asarray(rotation, float)).as_quat())
    return np.concatenate([np.asarray(position, float), quaternion])


def nodes_in_regions(nodes: np.ndarray, regions: list[RegionModel], tolerance: float = 1e-9) -> np.ndarray:
    """Sorted indices of the nodes (n, 3) inside any of the axis-aligned boxes."""
    inside = np.zeros(len(nodes), dtype=bool)
    for region in regions:
        lo = np.asarray(region.min) - tolerance
        hi = np.asarray(region.max) + tolerance
        inside |= np.all((nodes >= lo) & (nodes <= hi), axis=1)
    return np.flatnonzero(inside)


def nodes_in_jaws(nodes: np.ndarray, jaws: JawsModel, q0: np.ndarray, tolerance: float = 1e-9) -> np.ndarray:
    """Indices of the rest nodes inside the jaws' box with the gripper at ``q0``."""
    transform = pose_matrices(q0)
    local = (nodes - transform[:3, 3]) @ transform[:3, :3] - np.asarray(jaws.offset)
    half = 0.5 * np.asarray(jaws.size)
    return np.flatnonzero(np.all(np.abs(local) <= half + tolerance, axis=1))


@dataclass
class GraspFrame:
    """Everything that turns a gripper configuration into constraints (picklable, SI).

    ``rest`` (n, 3) rest nodes; ``anchored`` and ``grasped`` node indices
    (disjoint: a grasped node that is also anchored follows the gripper);
    ``q0`` the initial grasp.
    """

    rest: np.ndarray
    anchored: np.ndarray
    grasped: np.ndarray
    q0: np.ndarray

    def grasped_positions(self, q) -> np.ndarray:
        """Positions (g, 3) of the grasped nodes with the gripper at ``q``."""
        relative = pose_matrices(q) @ np.linalg.inv(pose_matrices(self.q0))
        return self.rest[self.grasped] @ relative[:3, :3].T + relative[:3, 3]

    def constraints(self, q) -> Constraints:
        nodes = np.concatenate([self.anchored, self.grasped])
        positions = np.concatenate([self.rest[self.anchored], self.grasped_positions(q)])
        return Constraints(nodes, positions)

    def rest_constraints(self) -> Constraints:
        """Only the anchors: the flap at rest under its own weight (the lowest energy any grasp can reach)."""
        return Constraints(self.anchored, self.rest[self.anchored])


def grasp_frame(rest: np.ndarray, anchored_regions: list[RegionModel], jaws: JawsModel, q0, what: str) -> GraspFrame:
    """The grasp at ``q0``: anchored nodes from the regions, grasped nodes in the jaws (errors name ``what``)."""
    anchored = nodes_in_regions(rest, anchored_regions)
    if len(anchored) == 0:
        raise PlanningInputError("the anchored regions contain no node of the flap", location="settings.anchored")
    grasped = nodes_in_jaws(rest, jaws, q0)
    if len(grasped) == 0:
        raise PlanningInputError(
            f"{what}: the gripper jaws hold no node of the flap there (jaws {np.round(np.asarray(jaws.size) * 1e3, 3)}"
            f" mm at ({', '.join(f'{1e3 * c:.4g}' for c in q0[:3])}) mm)",
            location="settings.jaws",
        )
    anchored = np.setdiff1d(anchored, grasped)
    return GraspFrame(np.asarray(rest, float), anchored, grasped, np.asarray(q0, float))


def candidate_grasps(start: np.ndarray, candidates: GraspCandidatesModel) -> np.ndarray:
    """The stage's start followed by the candidate grasps (k, 7), duplicates of earlier ones dropped."""
    grasps = [np.asarray(start, float)]
    for edge in candidates.edges:
        if edge.rpy is not None:
            quaternion = canonical_quaternion(Rotation.from_euler("xyz", edge.rpy).as_quat())
        else:
            quaternion = grasps[0][3:]
        a, b = np.asarray(edge.start), np.asarray(edge.end)
        fractions = np.linspace(0.0, 1.0, edge.count) if edge.count > 1 else np.array([0.5])
        grasps.extend(np.concatenate([a + f * (b - a), quaternion]) for f in fractions)
    for pose in candidates.poses:
        if pose.quaternion is not None:
            quaternion = canonical_quaternion(np.asarray(pose.quaternion, float))
        else:
            quaternion = canonical_quaternion(Rotation.from_euler("xyz", pose.rpy or (0, 0, 0)).as_quat())
        grasps.append(np.concatenate([np.asarray(pose.xyz, float), quaternion]))
    unique: list[np.ndarray] = []
    for q in grasps:
        if not any(np.allclose(q, u, atol=1e-9) for u in unique):
            unique.append(q)
    return np.array(unique)
