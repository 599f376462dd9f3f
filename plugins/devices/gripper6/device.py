"""``gripper6``: a 6R arm with a spherical wrist and a gripper, six CiA 402 axes over CAN.

The model is ``urdf/gripper6.urdf``, placed in the scene by the ``base``
setting (the arm's mounting pose). It executes

* a path in the ``se3`` space, from any plan stage that plans in it (OMPL, the
  ``retraction`` planner, a third-party planner) or handed to
  :meth:`execute` directly: poses (x, y, z, qx, qy, qz, qw) of the planned
  body's frame. That frame is the JAWS frame (z out of the jaws, x along the
  flange's -z) unless ``tool_frame`` says where the planned frame sits in the
  jaws frame (a planner that grasps with another convention needs only this
  setting, no code);
* a path in ``r3``: jaws positions, held at the fixed ``orientation`` setting
  (default: jaws pointing down).

The path is resampled (``path_resolution`` in position, ``angle_resolution``
in orientation, slerp between poses) and mapped to joints by the QP inverse
kinematics, warm-started along the path from the current configuration; a
pose out of reach, or an IK solution that jumps between branches, refuses the
path before any motion.

Executed clearance, re-measured on the scene from the measured joints:
``executed_min_clearance_m`` is the executed tip path's (the jaws origin, as a
sphere of the r3 plan's tip radius, or a point for se3 plans; exact between
samples); ``executed_body_min_clearance_m`` the planned body's (the se3
space's parts, certified to 1e-5 m between samples) or, for r3 paths, a
sphere of ``tool_radius`` at the jaws; with ``link_radius`` > 0
``arm_min_clearance_m`` the arm's links (capsules between joint origins, at
the samples).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, PositiveFloat
from scipy.spatial.transform import Rotation
from surgiplan.devices import Trajectory
from surgiplan.geometry.transforms import canonical_quaternion, quaternion_angle, slerp
from surgiplan.models import PoseModel
from surgiplan.plugins.devices.canopen.certify import Certificate, certify
from surgiplan.plugins.devices.canopen.device import Cia402Device, JointPath
from surgiplan.plugins.devices.canopen.refusal import Refusal
from surgiplan.plugins.devices.canopen.settings import Cia402DeviceSettings
from surgiplan.plugins.devices.canopen.sim.drives import DriveSimulator
from surgiplan.plugins.devices.kinematics.model import DifferentialIK, KinematicModel, urdf_path
from surgiplan.units import Angle, Length


class Gripper6Settings(Cia402DeviceSettings):
    """The arm: where it is mounted, the jaws' orientation for r3 paths, its size for clearance."""

    #: the arm's base pose in the scene
    base: PoseModel = Field(default_factory=PoseModel)
    #: where the planned se3 frame sits in the jaws frame (identity: the plan's poses are the jaws')
    tool_frame: PoseModel = Field(default_factory=PoseModel)
    #: jaws orientation (roll, pitch, yaw) for r3 paths; default: jaws pointing down
    orientation: tuple[Angle, Angle, Angle] = (np.pi, 0.0, 0.0)
    #: jaws as a sphere of this radius (m) for the clearance of r3 paths
    tool_radius: Length = 0.004
    #: radius (m) of the arm's links for their clearance; 0: links are not measured
    link_radius: Length = 0.0
    #: orientation resampling step (rad)
    angle_resolution: PositiveFloat = 0.02
    #: largest joint change between neighbouring resampled poses (rad) before the IK is deemed to jump
    max_joint_step: PositiveFloat = 0.3
    #: acceleration limits default: 5 rad/s^2 for joints 1-3, 10 rad/s^2 for the wrist
    acceleration_limits: list[float] | None = Field(default=None)


class Gripper6Device(Cia402Device):
    Settings = Gripper6Settings
    default_acceleration = (5.0, 5.0, 5.0, 10.0, 10.0, 10.0)
    urdf_name = "gripper6"
    tip_frame = "jaws"
    clearance_label = "executed jaws body clearance"
    #: on the virtual bus: surgiplan's simulated CiA 402 drives (their EDS files ship in ``eds/``)
    simulated_drives = DriveSimulator

    def build_model(self, base=None) -> KinematicModel:
        return KinematicModel(
            urdf_path(__package__, self.urdf_name), self.tip_frame, base or self.settings.base.to_pose()
        )

    def _tool(self) -> tuple[Rotation, np.ndarray]:
        pose = self.settings.tool_frame.to_pose()
        return Rotation.from_matrix(pose.rotation), np.asarray(pose.translation, dtype=float)

    def jaws_from_planned(self, poses: np.ndarray) -> np.ndarray:
        """Jaws poses (n, 7) for planned-frame poses (n, 7): jaws = planned * tool_frame^-1."""
        tool_rotation, tool_translation = self._tool()
        planned = Rotation.from_quat(poses[:, 3:7])
        jaws = planned * tool_rotation.inv()
        position = poses[:, :3] - jaws.apply(tool_translation)
        return np.concatenate([position, canonical_quaternion(jaws.as_quat())], axis=1)

    def planned_from_jaws(self, poses: np.ndarray) -> np.ndarray:
        """Planned-frame poses (n, 7) for jaws poses (n, 7): planned = jaws * tool_frame."""
        tool_rotation, tool_translation = self._tool()
        jaws = Rotation.from_quat(poses[:, 3:7])
        position = poses[:, :3] + jaws.apply(tool_translation)
        return np.concatenate([position, canonical_quaternion((jaws * tool_rotation).as_quat())], axis=1)

    def _poses(self, trajectory: Trajectory) -> np.ndarray:
        path = np.atleast_2d(np.asarray(trajectory.path, dtype=float))
        kind = trajectory.space.kind
        if kind == "se3":
            return self.jaws_from_planned(np.concatenate([path[:, :3], canonical_quaternion(path[:, 3:7])], axis=1))
        if kind == "r3":
            quaternion = canonical_quaternion(Rotation.from_euler("xyz", self.settings.orientation).as_quat())
            return np.concatenate([path, np.broadcast_to(quaternion, (len(path), 4))], axis=1)
        raise Refusal(f"gripper6 executes paths in the se3 or r3 space, not '{kind}'")

    def _resample(self, poses: np.ndarray) -> np.ndarray:
        """Poses at most ``path_resolution`` m and ``angle_resolution`` rad apart (slerp in between)."""
        if len(poses) < 2:
            return poses
        a, b = poses[:-1], poses[1:]
        steps = np.maximum(
            np.linalg.norm(b[:, :3] - a[:, :3], axis=1) / self.settings.path_resolution,
            quaternion_angle(a[:, 3:], b[:, 3:]) / self.settings.angle_resolution,
        )
        counts = np.maximum(1, np.ceil(steps).astype(int))
        owner = np.repeat(np.arange(len(a)), counts)
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        t = (np.arange(len(owner)) - start[owner]) / counts[owner]
        position = a[owner, :3] + t[:, None] * (b[owner, :3] - a[owner, :3])
        rotation = slerp(a[owner, 3:], b[owner, 3:], t)
        return np.concatenate([np.concatenate([position, rotation], axis=1), poses[-1:]])

    def joint_path(self, trajectory: Trajectory, current: np.ndarray) -> JointPath:
        poses = self._poses(trajectory)
        dense = self._resample(poses)
        ik = DifferentialIK(
            self.model,
            tolerance=self.settings.ik.tolerance,
            rotation_tolerance=self.settings.ik.rotation_tolerance,
            max_iterations=self.settings.ik.max_iterations,
            max_joint_step=self.settings.max_joint_step,
        )
        result = ik.solve_poses(dense, current)
        bad = np.flatnonzero(~result.converged)
        if len(bad):
            i = int(bad[0])
            where = (
                f"the jaws pose at {np.round(dense[i, :3], 5).tolist()} m "
                f"(quaternion {np.round(dense[i, 3:], 4).tolist()}, resampled pose {i} of {len(dense)})"
            )
            if i in ik.jumps:
                raise Refusal(
                    f"the inverse kinematics jumps by more than {self.settings.max_joint_step:g} rad at {where}: "
                    "a singularity or a branch change on every branch tried"
                )
            limits = ik.at_limit(result.q[i])
            why = f"; joints at their limits: {', '.join(limits)}" if limits else ""
            raise Refusal(
                f"{where} is out of the arm's reach on every inverse kinematics branch tried: residual "
                f"{result.position_error[i] * 1000:.3g} mm, {np.degrees(result.rotation_error[i]):.3g} deg{why}"
            )
        return JointPath(
            result.q,
            {
                "waypoints": len(poses),
                "ik_waypoints": len(dense),
                "ik_max_residual_m": float(result.position_error.max()),
                "ik_max_rotation_residual_rad": float(result.rotation_error.max()),
                "ik_iterations_mean": float(result.iterations.mean()),
            },
        )

    def _body_clearance(self, q: np.ndarray, trajectory: Trajectory) -> tuple[float, np.ndarray]:
        """Lowest clearance (m) of the planned body along joint samples q, and at each sample."""
        poses = self.model.tip_poses(q)
        space = trajectory.space
        if space.kind == "se3":
            planned = self.planned_from_jaws(poses)
            at_samples = space.clearance(planned)
            if len(planned) >= 2:
                return float(np.min(space.segment_clearance(planned[:-1], planned[1:]))), at_samples
            return float(at_samples.min()), at_samples
        radius = float(self.settings.tool_radius)
        at_samples = space.scene.clearance(poses[:, :3], radius)
        if len(poses) >= 2:
            return float(np.min(space.scene.motion_clearance(poses[:-1, :3], poses[1:, :3], radius))), at_samples
        return float(at_samples.min()), at_samples

    def _reach_per_joint(self, beyond_jaws: float, to_jaws: bool) -> np.ndarray:
        """Per joint j, a bound (m) on the distance from joint j's origin (on its axis) to any point moved by
        it: the chain's link lengths from j on (configuration-independent), to the last joint or on to the jaws
        and ``beyond_jaws`` further. A revolute joint turning by dq moves such a point at most R_j |dq|."""
        q0 = self.model.neutral()[None]
        origins = self.model.joint_origins(q0)[0]
        links = np.linalg.norm(np.diff(origins, axis=0), axis=1)
        tail = float(np.linalg.norm(self.model.tip_positions(q0)[0] - origins[-1])) + beyond_jaws if to_jaws else 0.0
        reach = np.array([links[j:].sum() + tail for j in range(len(origins))])
        return np.where(self.model.prismatic, 1.0, reach)

    def _body_at(self, q: np.ndarray, trajectory: Trajectory) -> np.ndarray:
        """The jaws body's clearance (m) at each joint sample (exact)."""
        poses = self.model.tip_poses(q)
        space = trajectory.space
        if space.kind == "se3":
            return space.clearance(self.planned_from_jaws(poses))
        return space.scene.clearance(poses[:, :3], float(self.settings.tool_radius))

    def _links_at(self, q: np.ndarray, trajectory: Trajectory) -> np.ndarray:
        origins = self.model.joint_origins(q)
        a = origins[:, :-1].reshape(-1, 3)
        b = origins[:, 1:].reshape(-1, 3)
        distance = trajectory.space.scene.segment_distance(a, b)[0] - float(self.settings.link_radius)
        return distance.reshape(len(q), -1).min(axis=1)

    def certify_motion(self, q: np.ndarray, trajectory: Trajectory, margin: float) -> list[Certificate]:
        """The jaws (the se3 plan's body, or a sphere of ``tool_radius``) and, with ``link_radius``, the links,
        along the joint-space polyline the drives interpolate (certified between the samples)."""
        space = trajectory.space
        if space.kind == "se3":
            extent = float(np.linalg.norm(self.settings.tool_frame.to_pose().translation)) + space.reach
        else:
            extent = 0.0  # a sphere about the jaws origin: only its centre's motion matters
        jaws_reach = self._reach_per_joint(extent, to_jaws=True)

        def jaws_speed(a, b):
            return np.abs(b - a) @ jaws_reach

        out = [certify("jaws", lambda c: self._body_at(c, trajectory), jaws_speed, q, margin)]
        if space.kind == "r3" and space.tip_radius > self.settings.tool_radius:
            radius = float(space.tip_radius)
            tip = self._reach_per_joint(0.0, to_jaws=True)
            out.append(
                certify(
                    "tip",
                    lambda c: space.scene.clearance(self.model.tip_positions(c), radius),
                    lambda a, b: np.abs(b - a) @ tip,
                    q,
                    margin,
                )
            )
        if self.settings.link_radius > 0:
            link_reach = self._reach_per_joint(0.0, to_jaws=False)
            out.append(
                certify(
                    "links", lambda c: self._links_at(c, trajectory), lambda a, b: np.abs(b - a) @ link_reach, q, margin
                )
            )
        return out

    def approach_is_clear(self, q_from, q_to, trajectory: Trajectory) -> bool:
        # sampled every 0.01 rad of the largest joint: not certified (the arm's motion is not a space's)
        count = max(2, int(np.ceil(np.max(np.abs(q_to - q_from)) / 0.01)) + 1)
        q = q_from + np.linspace(0.0, 1.0, count)[:, None] * (q_to - q_from)
        return self._body_clearance(q, trajectory)[0] > 0.0

    def executed_geometry(self, q: np.ndarray, trajectory: Trajectory):
        """The planned body (the se3 plan's jaws) at the executed joints; else the tool sphere at the tip."""
        if trajectory.space.kind == "se3":
            return trajectory.space, self.planned_from_jaws(self.model.tip_poses(q))
        return None, None

    def clearance_along(self, q: np.ndarray, trajectory: Trajectory) -> tuple[dict[str, float], np.ndarray]:
        scene = trajectory.space.scene
        tips = self.model.tip_positions(q)
        radius = trajectory.space.tip_radius if trajectory.space.kind == "r3" else 0.0
        if len(tips) >= 2:
            tip_lowest = float(np.min(scene.motion_clearance(tips[:-1], tips[1:], radius)))
        else:
            tip_lowest = float(scene.clearance(tips, radius).min())
        body_lowest, at_samples = self._body_clearance(q, trajectory)
        out = {
            "executed_min_clearance_m": tip_lowest,
            "executed_body_min_clearance_m": body_lowest,
            "tip_radius_m": float(radius),
        }
        if self.settings.link_radius > 0:
            origins = self.model.joint_origins(q)  # (n, 6, 3): the links run between joint origins
            a = origins[:, :-1].reshape(-1, 3)
            b = origins[:, 1:].reshape(-1, 3)
            distance = scene.segment_distance(a, b)[0] - float(self.settings.link_radius)
            out["arm_min_clearance_m"] = float(distance.min())
        return out, at_samples
