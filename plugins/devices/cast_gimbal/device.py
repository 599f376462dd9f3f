"""``cast_gimbal``: the CAST laparoscopic gimbal, four CiA 402 axes over CAN.

Kinematics exactly as :class:`surgiplan.spaces.CastGimbalSpace`
(q = yaw, pitch, insertion, roll about a fulcrum; ``urdf/cast_gimbal.urdf``,
the fulcrum pose as the URDF base placement). It executes

* a path in the ``cast_gimbal`` space (configurations): the fulcrum comes
  from the space unless the device's ``fulcrum`` setting is given, and a
  mismatch between the two is refused;
* a path in ``r3`` (tip positions): the device's ``fulcrum`` setting is
  required; the tip path is resampled every ``path_resolution`` along its
  straight segments and mapped to joints by the QP inverse kinematics (roll
  kept at its current value). The closed form
  (:meth:`CastGimbalSpace.inverse`) cross-checks every solution
  (``ik_closed_form_deviation_m``).

Executed clearance, re-measured on the scene from the measured joints:
``executed_min_clearance_m`` is the executed tip path's (a sphere of the
shaft radius, or of the r3 plan's tip radius, swept exactly along straight
lines between the samples); ``executed_shaft_min_clearance_m`` the whole
shaft's (a capsule of ``shaft_radius`` through the fulcrum to the tip, as the
gimbal space plans it; certified to 1e-5 m between samples,
:meth:`Space.segment_clearance`).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field
from surgiplan.devices import Trajectory
from surgiplan.geometry.transforms import Pose
from surgiplan.models import PoseModel
from surgiplan.plugins.devices.canopen.certify import Certificate, certify
from surgiplan.plugins.devices.canopen.device import Cia402Device, JointPath
from surgiplan.plugins.devices.canopen.refusal import Refusal
from surgiplan.plugins.devices.canopen.settings import Cia402DeviceSettings
from surgiplan.plugins.devices.canopen.sim.drives import DriveSimulator
from surgiplan.plugins.devices.kinematics.model import DifferentialIK, KinematicModel, urdf_path
from surgiplan.spaces import CastGimbalSettings, CastGimbalSpace
from surgiplan.units import Length


class CastGimbalDeviceSettings(Cia402DeviceSettings):
    """The gimbal device: where its fulcrum is, and its shaft (see :class:`Cia402DeviceSettings`)."""

    #: fulcrum pose in the scene; None: taken from the plan's cast_gimbal space
    fulcrum: PoseModel | None = None
    #: instrument shaft radius (m) for the executed clearance; None: the space's, else 2.5 mm
    shaft_radius: Length | None = None
    #: acceleration limits default: yaw, pitch 4 rad/s^2, insertion 0.5 m/s^2, roll 10 rad/s^2
    acceleration_limits: list[float] | None = Field(default=None)


class CastGimbalDevice(Cia402Device):
    Settings = CastGimbalDeviceSettings
    default_acceleration = (4.0, 4.0, 0.5, 10.0)
    #: the motors (yaw, pitch, insertion, roll): 0.1 N·m rated motors; yaw and pitch through a 10:1 capstan (1 N·m
    #: rated, 3 N·m peak at the joint), insertion by a capstan of 1 cm radius (10 N rated), roll 5:1; inertias,
    #: viscous and Coulomb friction at the joint (a haptic gimbal's order of magnitude)
    default_motors: ClassVar[dict[str, tuple]] = {
        "rated_torque": (0.1, 0.1, 0.1, 0.05),
        "peak_torque": (3000, 3000, 3000, 3000),
        "gear_ratio": (10.0, 10.0, 100.0, 5.0),
        "inertia": (0.004, 0.004, 0.25, 2e-4),
        "viscous_friction": (0.01, 0.01, 0.5, 1e-3),
        "coulomb_friction": (0.005, 0.005, 0.1, 5e-4),
    }
    urdf_name = "cast_gimbal"
    tip_frame = "tip"
    clearance_label = "executed shaft clearance"
    #: on the virtual bus: surgiplan's simulated CiA 402 drives (their EDS files ship in ``eds/``)
    simulated_drives = DriveSimulator

    def __init__(self, settings: CastGimbalDeviceSettings) -> None:
        super().__init__(settings)
        self.fulcrum: Pose | None = settings.fulcrum.to_pose() if settings.fulcrum is not None else None
        self.space: CastGimbalSpace | None = None

    def build_model(self, base: Pose | None = None) -> KinematicModel:
        return KinematicModel(urdf_path(__package__, self.urdf_name), self.tip_frame, base or self.fulcrum)

    # ------------------------------------------------------------------ the fulcrum and the space
    def _space_for(self, trajectory: Trajectory) -> CastGimbalSpace:
        """The gimbal space of this execution: the plan's, or one built from the device settings."""
        space = trajectory.space
        scene = self.context.scene if self.context is not None else space.scene
        if space.kind == "cast_gimbal":
            if self.fulcrum is not None:
                same = np.allclose(space.fulcrum, self.fulcrum.translation, atol=1e-9) and np.allclose(
                    space.frame, self.fulcrum.rotation, atol=1e-9
                )
                if not same:
                    raise Refusal(
                        f"the plan's cast_gimbal space has its fulcrum at {np.round(space.fulcrum, 6).tolist()} m, "
                        f"the device's fulcrum setting at {np.round(self.fulcrum.translation, 6).tolist()} m "
                        "(or another orientation); remove the device's fulcrum setting or make them equal"
                    )
            if self.settings.shaft_radius is not None and self.settings.shaft_radius != space.shaft_radius:
                settings = space.settings.model_copy(update={"shaft_radius": self.settings.shaft_radius})
                return CastGimbalSpace(scene, settings)
            return CastGimbalSpace(scene, space.settings)
        if self.fulcrum is None:
            raise Refusal(
                f"a path in the '{space.kind}' space needs the device's fulcrum setting "
                "(fulcrum: {xyz: [...], rpy: [...]}) to place the gimbal"
            )
        model = self.model
        shaft = self.settings.shaft_radius if self.settings.shaft_radius is not None else 0.0025
        settings = CastGimbalSettings(
            fulcrum=self.settings.fulcrum,
            yaw={"min": model.lower[0], "max": model.upper[0]},
            pitch={"min": model.lower[1], "max": model.upper[1]},
            insertion={"min": model.lower[2], "max": model.upper[2]},
            roll={"min": model.lower[3], "max": model.upper[3]},
            shaft_radius=shaft,
        )
        return CastGimbalSpace(scene, settings)

    # ------------------------------------------------------------------ path to joints
    def joint_path(self, trajectory: Trajectory, current: np.ndarray) -> JointPath:
        space = self._space_for(trajectory)
        self.space = space
        if self.fulcrum is None or not np.allclose(self.model.base.translation, space.fulcrum, atol=1e-12):
            # place the Pinocchio model at the plan's fulcrum
            self.model = self.build_model(Pose(space.frame, space.fulcrum))
        path = np.atleast_2d(np.asarray(trajectory.path, dtype=float))
        kind = trajectory.space.kind
        resolution = float(self.settings.path_resolution)
        if kind == "cast_gimbal":
            return JointPath(space.densify(path, resolution), {"waypoints": len(path)})
        if kind != "r3":
            raise Refusal(f"cast_gimbal executes paths in the cast_gimbal or r3 space, not '{kind}'")
        tips = _resample(path, resolution)
        ik = DifferentialIK(
            self.model,
            tolerance=self.settings.ik.tolerance,
            max_iterations=self.settings.ik.max_iterations,
        )
        result = ik.solve_positions(tips, current)
        bad = np.flatnonzero(~result.converged)
        if len(bad):
            i = int(bad[0])
            closed = space.inverse(tips[i : i + 1])[0]
            why = "outside the joint limits" if not space.within_limits(closed[None])[0] else "not reached"
            raise Refusal(
                f"tip point {np.round(tips[i], 5).tolist()} m is out of the gimbal's reach ({why}: "
                f"insertion {closed[2] * 1000:.1f} mm, yaw {np.degrees(closed[0]):.1f} deg, pitch "
                f"{np.degrees(closed[1]):.1f} deg; residual {result.position_error[i] * 1000:.3g} mm)"
            )
        closed = space.inverse(tips)
        deviation = np.abs(result.q[:, 2] - closed[:, 2]) + closed[:, 2] * np.hypot(
            result.q[:, 0] - closed[:, 0], result.q[:, 1] - closed[:, 1]
        )
        return JointPath(
            result.q,
            {
                "waypoints": len(path),
                "ik_waypoints": len(tips),
                "ik_max_residual_m": float(result.position_error.max()),
                "ik_closed_form_deviation_m": float(deviation.max()),
                "ik_iterations_mean": float(result.iterations.mean()),
            },
        )

    def certify_motion(self, q: np.ndarray, trajectory: Trajectory, margin: float) -> list[Certificate]:
        """The whole shaft (a capsule from the fulcrum to the tip, the tip's end included) along the joint-space
        polyline the drives interpolate; for an r3 plan whose tip sphere is wider than the shaft, the tip too."""
        space = self.space
        out = [certify("shaft", space.clearance, space.motion_speed_bound, q, margin)]
        plan = trajectory.space
        if plan.kind == "r3" and plan.tip_radius > space.shaft_radius:
            radius = float(plan.tip_radius)
            scene = plan.scene
            out.append(
                certify("tip", lambda c: scene.clearance(space.tip(c), radius), space.motion_speed_bound, q, margin)
            )
        return out

    def approach_is_clear(self, q_from, q_to, trajectory: Trajectory) -> bool:
        return bool(self.space.motion_is_clear(q_from[None], q_to[None], 0.0)[0])

    def executed_geometry(self, q: np.ndarray, trajectory: Trajectory):
        """The whole shaft: the measured joints in the gimbal space (the shaft radius is the device's)."""
        return self.space, q

    def clearance_along(self, q: np.ndarray, trajectory: Trajectory) -> tuple[dict[str, float], np.ndarray]:
        space = self.space
        scene = trajectory.space.scene
        # the tip path: a sphere of the plan's tip radius (r3) or of the shaft radius (the shaft's end)
        radius = trajectory.space.tip_radius if trajectory.space.kind == "r3" else space.shaft_radius
        tips = space.tip(q)
        shaft = space.clearance(q)
        if len(q) >= 2:
            tip_lowest = float(np.min(scene.motion_clearance(tips[:-1], tips[1:], radius)))
            shaft_lowest = float(np.min(space.segment_clearance(q[:-1], q[1:])))
        else:
            tip_lowest = float(scene.clearance(tips, radius).min())
            shaft_lowest = float(shaft.min())
        metrics = {
            "executed_min_clearance_m": tip_lowest,
            "executed_shaft_min_clearance_m": shaft_lowest,
            "tip_radius_m": float(radius),
            "shaft_radius_m": space.shaft_radius,
        }
        return metrics, shaft


def _resample(points: np.ndarray, spacing: float) -> np.ndarray:
    """Points along a polyline (n, 3) at most ``spacing`` apart, keeping every vertex."""
    if len(points) < 2:
        return points.copy()
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    counts = np.maximum(1, np.ceil(steps / spacing).astype(int))
    owner = np.repeat(np.arange(len(steps)), counts)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    fraction = (np.arange(len(owner)) - start[owner]) / counts[owner]
    inner = points[owner] + fraction[:, None] * (points[owner + 1] - points[owner])
    return np.concatenate([inner, points[-1:]])
