"""bench_devices.py, part 4: inverse kinematics per waypoint, against a closed form and Pinocchio's CLIK.

The gimbal's tip positions (QP, OSQP with joint and velocity limits) against its closed form, and
gripper6's SE(3) poses warm-started along a path (QP) against Pinocchio's documented CLIK loop (damped
pseudo-inverse on log6, no limits). Imported by bench_devices.py, which puts benchmarks/ and tests/ on the
import path (``common``, ``devices_support``).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from common import median_time
from devices_support import ARM_BASE, FULCRUM, GAP_TIPS, gimbal_space
from scipy.spatial.transform import Rotation
from surgiplan.geometry.transforms import Pose
from surgiplan.plugins.devices.kinematics.model import DifferentialIK, KinematicModel, urdf_path


def clik(model: pin.Model, data: pin.Data, frame: int, target: pin.SE3, q: np.ndarray) -> np.ndarray:
    """Pinocchio's documented CLIK (damped pseudo-inverse on log6), for a frame target."""
    eps, it_max, dt, damp = 1e-7, 1000, 1e-1, 1e-12
    for _ in range(it_max):
        pin.forwardKinematics(model, data, q)
        placement = pin.updateFramePlacement(model, data, frame)
        error = pin.log6(placement.actInv(target)).vector
        if np.linalg.norm(error) < eps:
            break
        jac = pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL)
        jac = -pin.Jlog6(placement.actInv(target)) @ jac
        v = -jac.T @ np.linalg.solve(jac @ jac.T + damp * np.eye(6), error)
        q = pin.integrate(model, q, v * dt)
    return q


def inverse_kinematics(scene, waypoints: int) -> list[dict]:
    rows = []
    space = gimbal_space(scene)
    gimbal = KinematicModel(
        urdf_path("surgiplan.plugins.devices.cast_gimbal", "cast_gimbal"),
        "tip",
        Pose.from_xyz_rpy(FULCRUM["xyz"], FULCRUM["rpy"]),
    )
    tips = np.linspace(GAP_TIPS[0], GAP_TIPS[-1], waypoints)
    ik = DifferentialIK(gimbal)
    qp, _ = median_time(lambda: ik.solve_positions(tips, gimbal.neutral()), repeat=5)
    closed, _ = median_time(lambda: space.inverse(tips), repeat=5)
    result = ik.solve_positions(tips, gimbal.neutral())
    deviation = float(np.max(np.abs(result.q[:, :3] - space.inverse(tips)[:, :3])))
    rows.append(
        {
            "ik": "cast_gimbal tip positions: QP (OSQP, limits)",
            "waypoints": waypoints,
            "per_waypoint_us": round(qp / waypoints * 1e6, 1),
            "iterations_mean": round(float(result.iterations.mean()), 2),
            "max_residual_m": float(result.position_error.max()),
            "vs_closed_form_max_joint_difference": deviation,
        }
    )
    rows.append(
        {
            "ik": "cast_gimbal closed form (reference)",
            "waypoints": waypoints,
            "per_waypoint_us": round(closed / waypoints * 1e6, 2),
        }
    )

    arm = KinematicModel(
        urdf_path("surgiplan.plugins.devices.gripper6", "gripper6"),
        "jaws",
        Pose.from_xyz_rpy(ARM_BASE["xyz"], ARM_BASE["rpy"]),
    )
    q_path = np.linspace([0.2, 0.3, 0.8, 0.1, 0.9, -0.2], [-0.4, 0.5, 0.4, -0.3, 1.2, 0.6], waypoints)
    poses = arm.tip_poses(q_path)
    arm_ik = DifferentialIK(arm)
    warm, _ = median_time(lambda: arm_ik.solve_poses(poses, q_path[0]), repeat=3)
    result = arm_ik.solve_poses(poses, q_path[0])
    rows.append(
        {
            "ik": "gripper6 SE(3) poses, warm-started along a path: QP (OSQP, limits)",
            "waypoints": waypoints,
            "per_waypoint_us": round(warm / waypoints * 1e6, 1),
            "iterations_mean": round(float(result.iterations.mean()), 2),
            "max_residual_m": float(result.position_error.max()),
            "max_rotation_residual_rad": float(result.rotation_error.max()),
        }
    )
    model, data, frame = arm.model, arm.model.createData(), arm.tip_id
    targets = [pin.SE3(Rotation.from_quat(p[3:]).as_matrix(), p[:3]) for p in poses]

    def reference():
        q = q_path[0].copy()
        out = []
        for target in targets:
            q = clik(model, data, frame, target, q)
            out.append(q)
        return np.array(out)

    ref_time, _ = median_time(reference, repeat=3)
    ref = reference()
    reached = arm.tip_poses(ref)
    rows.append(
        {
            "ik": "gripper6: Pinocchio's documented CLIK, same warm start (reference, no limits)",
            "waypoints": waypoints,
            "per_waypoint_us": round(ref_time / waypoints * 1e6, 1),
            "max_residual_m": float(np.max(np.linalg.norm(reached[:, :3] - poses[:, :3], axis=1))),
        }
    )
    # a cold solve (first pose of a path, from the neutral configuration, with restarts when needed)
    rng = np.random.default_rng(1)
    cold_targets = arm.tip_poses(rng.uniform(arm.lower * 0.9, arm.upper * 0.9, size=(20, 6)))
    cold, _ = median_time(lambda: [arm_ik.solve_poses(t[None], arm.neutral()) for t in cold_targets], repeat=3)
    rows.append(
        {
            "ik": "gripper6 cold pose from the neutral configuration: QP",
            "waypoints": 20,
            "per_waypoint_us": round(cold / 20 * 1e6, 1),
        }
    )
    return rows
