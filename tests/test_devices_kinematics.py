"""Device kinematics: Pinocchio models from the shipped URDFs, checked against independent methods."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from devices_support import ARM_BASE, FULCRUM, gimbal_space, urdf_forward_kinematics
from scipy.spatial.transform import Rotation
from surgiplan.geometry.transforms import Pose
from surgiplan.plugins.devices.kinematics.model import DifferentialIK, KinematicModel, urdf_path
from surgiplan.spaces import CastGimbalSettings


def gimbal_model(fulcrum=FULCRUM) -> KinematicModel:
    return KinematicModel(
        urdf_path("surgiplan.plugins.devices.cast_gimbal", "cast_gimbal"),
        "tip",
        Pose.from_xyz_rpy(fulcrum["xyz"], fulcrum["rpy"]),
    )


def arm_model() -> KinematicModel:
    return KinematicModel(
        urdf_path("surgiplan.plugins.devices.gripper6", "gripper6"),
        "jaws",
        Pose.from_xyz_rpy(ARM_BASE["xyz"], ARM_BASE["rpy"]),
    )


@pytest.mark.parametrize(
    "fulcrum",
    [FULCRUM, {"xyz": [0.075, -0.06, 0.12], "rpy": [0.1, -0.2, 1.3]}, {"xyz": [0, 0, 0], "rpy": [0, 0, 0]}],
)
def test_gimbal_urdf_forward_kinematics_is_the_gimbal_space_convention(block_world, rng, fulcrum):
    space = gimbal_space(block_world, fulcrum)
    model = gimbal_model(fulcrum)
    q = rng.uniform(model.lower, model.upper, size=(300, 4))
    np.testing.assert_allclose(model.tip_positions(q), space.tip(q), atol=1e-12)
    # positive pitch tips the shaft below the fulcrum frame's horizontal plane
    down = model.tip_positions([[0.0, 0.5, 0.1, 0.0]])[0] - space.fulcrum
    assert down @ space.frame[:, 2] < 0


def test_gimbal_urdf_limits_are_the_trainer_defaults_of_the_space():
    model = gimbal_model()
    defaults = CastGimbalSettings(fulcrum={})
    expected_low = [defaults.yaw.min, defaults.pitch.min, defaults.insertion.min, defaults.roll.min]
    expected_high = [defaults.yaw.max, defaults.pitch.max, defaults.insertion.max, defaults.roll.max]
    assert model.joint_names == ["yaw", "pitch", "insertion", "roll"]
    np.testing.assert_allclose(model.lower, expected_low, atol=1e-9)
    np.testing.assert_allclose(model.upper, expected_high, atol=1e-9)
    assert list(model.prismatic) == [False, False, True, False]


def test_gimbal_qp_inverse_kinematics_matches_the_closed_form(block_world, rng):
    space = gimbal_space(block_world)
    model = gimbal_model()
    q = rng.uniform(model.lower, model.upper, size=(60, 4))
    q[:, 3] = 0.0
    tips = space.tip(q)
    result = DifferentialIK(model).solve_positions(tips, model.neutral())
    assert result.converged.all()
    assert result.position_error.max() < 1e-7
    closed = space.inverse(tips)
    # angles to within what 0.1 um at the tip allows at that insertion
    tolerance = 2e-7 / closed[:, 2]
    np.testing.assert_allclose(result.q[:, 2], closed[:, 2], atol=2e-7)
    assert np.all(np.abs(result.q[:, 0] - closed[:, 0]) < tolerance / np.maximum(np.cos(closed[:, 1]), 1e-3))
    assert np.all(np.abs(result.q[:, 1] - closed[:, 1]) < tolerance)
    # roll is not seen by a tip target: it keeps the initial guess
    np.testing.assert_allclose(result.q[:, 3], model.neutral()[3])


def test_inverse_kinematics_stays_within_the_joint_limits_for_unreachable_targets(block_world):
    model = gimbal_model()
    far = np.array([[0.15, 0.05, 0.13 - 0.40]])  # 400 mm below the fulcrum: insertion max is 300 mm
    result = DifferentialIK(model).solve_positions(far, model.neutral())
    assert not result.converged[0]
    assert model.within_limits(result.q).all()
    assert result.q[0, 2] == pytest.approx(model.upper[2])
    assert result.position_error[0] == pytest.approx(0.10, abs=1e-6)


def test_arm_forward_kinematics_matches_the_urdf_composed_by_hand(rng):
    model = arm_model()
    q = rng.uniform(model.lower, model.upper, size=(50, 6))
    poses = model.tip_poses(q)
    for qi, pose in zip(q, poses, strict=True):
        position, rotation = urdf_forward_kinematics(
            urdf_path("surgiplan.plugins.devices.gripper6", "gripper6"), "jaws", qi, ARM_BASE["xyz"], ARM_BASE["rpy"]
        )
        np.testing.assert_allclose(pose[:3], position, atol=1e-12)
        np.testing.assert_allclose(Rotation.from_quat(pose[3:]).as_matrix(), rotation, atol=1e-12)


def test_arm_wrist_is_spherical():
    """Joints 4-6 only rotate the jaws about the wrist centre, 0.10 m behind the jaws."""
    model = arm_model()
    q = np.zeros((20, 6))
    q[:, 3:] = np.random.default_rng(3).uniform(-1.5, 1.5, size=(20, 3))
    poses = model.tip_poses(q)
    approach = Rotation.from_quat(poses[:, 3:]).as_matrix()[:, :, 2]
    centres = poses[:, :3] - 0.10 * approach
    np.testing.assert_allclose(centres, centres[0][None].repeat(20, 0), atol=1e-12)


def test_jacobian_matches_finite_differences(rng):
    model = arm_model()
    q = rng.uniform(model.lower, model.upper, size=6)
    _placement, jac = model.jacobian(q)
    h = 1e-7
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = h
        plus = model.placement(q + dq)
        minus = model.placement(q - dq)
        linear = (plus.translation - minus.translation) / (2 * h)
        angular = pin.log3(plus.rotation @ minus.rotation.T) / (2 * h)
        np.testing.assert_allclose(jac[:3, j], linear, atol=1e-6)
        np.testing.assert_allclose(jac[3:, j], angular, atol=1e-6)


def test_arm_pose_inverse_kinematics_reaches_random_reachable_poses():
    """FK(IK(pose)) = pose for poses made by FK of random joint vectors, from the neutral guess."""
    model = arm_model()
    rng = np.random.default_rng(7)
    q_true = rng.uniform(model.lower * 0.9, model.upper * 0.9, size=(25, 6))
    targets = model.tip_poses(q_true)
    ik = DifferentialIK(model)
    reached = 0
    for target in targets:  # each from scratch: the first target of a sequence gets restarts
        result = ik.solve_poses(target[None], model.neutral())
        if result.converged[0]:
            reached += 1
            pose = model.tip_poses(result.q)[0]
            assert np.linalg.norm(pose[:3] - target[:3]) < 1e-6
            angle = 2 * np.arccos(min(1.0, abs(float(pose[3:] @ target[3:]))))
            assert angle < 1e-5
            assert model.within_limits(result.q).all()
    assert reached == len(targets)


def test_warm_started_pose_sequence_is_continuous():
    model = arm_model()
    q_path = np.linspace([0.2, 0.3, 0.8, 0.1, 0.9, -0.2], [-0.4, 0.5, 0.4, -0.3, 1.2, 0.6], 80)
    targets = model.tip_poses(q_path)
    result = DifferentialIK(model).solve_poses(targets, q_path[0])
    assert result.converged.all()
    # the solution follows the same branch: neighbouring targets give neighbouring joints
    np.testing.assert_allclose(result.q, q_path, atol=1e-5)


def test_qp_step_with_active_joint_and_velocity_bounds_matches_bounded_least_squares(rng):
    """The OSQP step against scipy's bounded least squares (an independent solver of the same problem):
    min |J dq - e|^2 + lambda |dq|^2 subject to the joint limits and the per-step velocity bound."""
    from scipy.optimize import lsq_linear

    model = arm_model()
    ik = DifferentialIK(model, step_time=0.05)  # 0.075 rad per step for joints 1-3: bounds bind
    active = 0
    for _ in range(40):
        q = rng.uniform(model.lower, model.upper)
        q[1] = model.upper[1] - 0.01  # near a limit
        _, jac = model.jacobian(q)
        error = rng.normal(0.0, 0.05, size=6) * np.array([1, 1, 1, 0.1, 0.1, 0.1])
        weighted = jac * np.array([1, 1, 1, 0.1, 0.1, 0.1])[:, None]
        step = ik.qp_step(q, weighted, error)
        damping = ik.damping + float(error @ error)
        lower = np.maximum(model.lower - q, -ik.step)
        upper = np.minimum(model.upper - q, ik.step)
        a = np.vstack([weighted, np.sqrt(damping) * np.eye(6)])
        b = np.concatenate([error, np.zeros(6)])
        reference = lsq_linear(a, b, bounds=(lower, upper), tol=1e-12, lsmr_tol="auto").x
        assert np.all(step >= lower - 1e-7) and np.all(step <= upper + 1e-7)
        np.testing.assert_allclose(step, reference, atol=2e-6)
        active += bool(np.any(np.isclose(step, lower, atol=1e-6) | np.isclose(step, upper, atol=1e-6)))
    assert active >= 20  # most cases exercised OSQP with a bound active


def test_urdf_files_ship_as_package_data_and_load_through_importlib_resources():
    """Installed wheels have the URDFs: setuptools lists their directory as a data package of its own
    (tests/test_packaging.py builds and installs the wheel), and the loader finds them through
    importlib.resources rather than a path relative to the source tree."""
    import fnmatch
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    config = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    for name in ("cast_gimbal", "gripper6"):
        package = f"surgiplan.plugins.devices.{name}"
        assert package in config["packages"] and f"{package}.urdf" in config["packages"]
        patterns = config["package-data"][f"{package}.urdf"]
        shipped = sorted(p.name for p in (root / "plugins" / "devices" / name / "urdf").iterdir())
        assert shipped == [f"{name}.urdf"]
        assert all(any(fnmatch.fnmatch(file, p) for p in patterns) for file in shipped)
        path = urdf_path(package, name)
        assert path.is_file() and path.parent.name == "urdf"
        assert pin.buildModelFromUrdf(str(path)).nq in (4, 6)
