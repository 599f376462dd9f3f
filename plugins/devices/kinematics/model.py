"""Kinematic models of the devices: Pinocchio models loaded from the shipped URDF files.

A :class:`KinematicModel` is a serial chain (one degree of freedom per joint)
placed in the scene by its *base placement*: the pose of the URDF's root link
in the scene frame (the fulcrum pose for the CAST gimbal, the arm's mounting
pose for gripper6). The placement is folded into the Pinocchio model itself
(the root joints' and root frames' placements), so ``data.oMf`` is in scene
coordinates and no caller ever transforms by hand.

Inverse kinematics (:class:`DifferentialIK`) solves, per iteration, the
differential-IK quadratic program of Kanoun, Lamiraux & Wieber (2011, "Kinematic
control of redundant manipulators: generalizing the task-priority framework to
inequality tasks", IEEE T-RO 27(4)) with OSQP:

    min_dq  1/2 |W (J dq - e)|^2 + 1/2 lambda |dq|^2
    s.t.    max(q_min - q, -v_max h) <= dq <= min(q_max - q, v_max h)

``e`` is the task error (tip position, or tip position and orientation as a
rotation vector, world-aligned), ``J`` the frame Jacobian in the
LOCAL_WORLD_ALIGNED convention, ``W`` weighs rotation against translation
(metres per radian), the box keeps every iterate inside the joint limits and
moves each joint at most ``v_max h`` per iteration (the velocity limits over a
step time ``h``). The damping ``lambda = lambda_0 + |W e|^2`` is the
Levenberg-Marquardt choice of Sugihara (2011, "Solvability-unconcerned inverse
kinematics by the Levenberg-Marquardt method", IEEE T-RO 27(5)): large far
from the target (robust), vanishing at it (quadratic convergence, no bias).
Joints the task does not see (the gimbal's roll for a tip position) keep the
value of the initial guess, because only the step is damped.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import osqp
import pinocchio as pin
import scipy.sparse as sp
from scipy.spatial.transform import Rotation
from surgiplan.errors import ConfigError
from surgiplan.geometry.transforms import Pose


def urdf_path(package: str, name: str) -> Path:
    """Path of the URDF file ``urdf/<name>.urdf`` shipped with a device package (e.g.
    ``surgiplan.plugins.devices.cast_gimbal``).

    The files are package data (see pyproject.toml), found through importlib.resources, so
    installed wheels and editable installs alike have them.
    """
    return Path(str(resources.files(package).joinpath("urdf", f"{name}.urdf")))


class KinematicModel:
    """A Pinocchio model of a serial device, its root placed at ``base`` in the scene.

    Attributes (SI: rad for revolute joints, m for prismatic ones):
    ``joint_names``, ``lower``, ``upper`` (position limits), ``velocity_limit``,
    ``prismatic`` (bool per joint), ``nq``.
    """

    def __init__(self, urdf: str | Path, tip_frame: str, base: Pose | None = None) -> None:
        urdf = Path(urdf)
        if not urdf.is_file():
            raise ConfigError(f"URDF file not found: {urdf}")
        try:
            model = pin.buildModelFromUrdf(str(urdf))
        except (RuntimeError, ValueError) as exc:
            raise ConfigError(f"cannot load URDF {urdf}: {exc}") from None
        if model.nq != model.nv:
            raise ConfigError(
                f"{urdf}: only revolute and prismatic joints are supported (nq {model.nq} != nv {model.nv})"
            )
        frames = [f.name for f in model.frames]
        if tip_frame not in frames:
            raise ConfigError(f"{urdf}: no frame named '{tip_frame}'; frames are {frames}")
        self.base = base or Pose()
        if not self.base.is_identity:
            placement = pin.SE3(self.base.rotation, self.base.translation)
            for j in range(1, model.njoints):
                if model.parents[j] == 0:
                    model.jointPlacements[j] = placement * model.jointPlacements[j]
            for frame in model.frames:
                if frame.parentJoint == 0 and frame.name != "universe":
                    frame.placement = placement * frame.placement
        self.model = model
        self.data = model.createData()
        self.urdf = urdf
        self.tip_frame = tip_frame
        self.tip_id = model.getFrameId(tip_frame)
        self.nq = model.nq
        self.joint_names = [model.names[j] for j in range(1, model.njoints)]
        self.lower = np.array(model.lowerPositionLimit, dtype=float)
        self.upper = np.array(model.upperPositionLimit, dtype=float)
        self.velocity_limit = np.array(model.velocityLimit, dtype=float)
        self.prismatic = np.array(
            [model.joints[j].shortname().startswith("JointModelP") for j in range(1, model.njoints)]
        )

    # ------------------------------------------------------------------ forward kinematics
    def placement(self, q, frame: str | None = None) -> pin.SE3:
        """World placement of ``frame`` (default: the tip frame) for one configuration."""
        fid = self.tip_id if frame is None else self.model.getFrameId(frame)
        pin.forwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        return pin.updateFramePlacement(self.model, self.data, fid).copy()

    def tip_positions(self, q) -> np.ndarray:
        """Tip-frame origins (n, 3) in metres for configurations (n, nq)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        out = np.empty((len(q), 3))
        for i, qi in enumerate(q):  # one Pinocchio call per configuration
            pin.forwardKinematics(self.model, self.data, qi)
            out[i] = pin.updateFramePlacement(self.model, self.data, self.tip_id).translation
        return out

    def tip_poses(self, q) -> np.ndarray:
        """Tip-frame poses (n, 7) as (x, y, z, qx, qy, qz, qw) for configurations (n, nq)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        position = np.empty((len(q), 3))
        rotation = np.empty((len(q), 3, 3))
        for i, qi in enumerate(q):
            pin.forwardKinematics(self.model, self.data, qi)
            m = pin.updateFramePlacement(self.model, self.data, self.tip_id)
            position[i] = m.translation
            rotation[i] = m.rotation
        quaternion = Rotation.from_matrix(rotation).as_quat()
        quaternion = np.where(quaternion[:, 3:4] < 0, -quaternion, quaternion)
        return np.concatenate([position, quaternion], axis=1)

    def joint_origins(self, q) -> np.ndarray:
        """World positions (n, njoints, 3) of every joint origin (for link capsules)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        out = np.empty((len(q), self.model.njoints - 1, 3))
        for i, qi in enumerate(q):
            pin.forwardKinematics(self.model, self.data, qi)
            for j in range(1, self.model.njoints):
                out[i, j - 1] = self.data.oMi[j].translation
        return out

    def jacobian(self, q) -> tuple[pin.SE3, np.ndarray]:
        """Tip placement and its 6 x nq Jacobian (LOCAL_WORLD_ALIGNED: linear rows 0-2, angular 3-5)."""
        q = np.asarray(q, dtype=float)
        jac = pin.computeFrameJacobian(self.model, self.data, q, self.tip_id, pin.LOCAL_WORLD_ALIGNED)
        # computeFrameJacobian ran the forward kinematics: read the placement from data
        placement = pin.updateFramePlacement(self.model, self.data, self.tip_id)
        return placement, jac

    def within_limits(self, q, tolerance: float = 1e-9) -> np.ndarray:
        q = np.atleast_2d(q)
        return np.all((q >= self.lower - tolerance) & (q <= self.upper + tolerance), axis=1)

    def neutral(self) -> np.ndarray:
        """Mid-range configuration (limits' midpoints)."""
        return 0.5 * (self.lower + self.upper)


@dataclass
class IKResult:
    """Joint solutions (n, nq) with per-target residuals and convergence flags.

    ``position_error``: metres; ``rotation_error``: radians (0 for position targets).
    """

    q: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray


class DifferentialIK:
    """Iterated differential IK as OSQP quadratic programs (see the module docstring).

    ``tolerance`` (m) and ``rotation_tolerance`` (rad) end an iteration;
    ``step_time`` (s) bounds each joint's step by its velocity limit;
    ``rotation_weight`` (m/rad) weighs orientation errors against positions;
    ``restarts``: extra initial guesses (deterministic, drawn in the joint
    limits) for the first target of a sequence when the given guess does not
    converge or its branch cannot follow the whole sequence; ``branches``: how
    many distinct solutions of the first target are followed at most;
    ``max_joint_step`` (rad or m): a larger change between neighbouring targets
    counts as a failure (the solution jumped to another branch).
    """

    def __init__(
        self,
        model: KinematicModel,
        *,
        tolerance: float = 1e-7,
        rotation_tolerance: float = 1e-6,
        max_iterations: int = 100,
        step_time: float = 0.2,
        rotation_weight: float = 0.1,
        damping: float = 1e-10,
        restarts: int = 16,
        branches: int = 6,
        max_joint_step: float | None = None,
    ) -> None:
        self.model = model
        self.tolerance = tolerance
        self.rotation_tolerance = rotation_tolerance
        self.max_iterations = max_iterations
        self.step = model.velocity_limit * step_time
        self.rotation_weight = rotation_weight
        self.damping = damping
        self.restarts = restarts
        self.branches = branches
        self.max_joint_step = max_joint_step
        #: indices where the last sequence's attempts failed by a joint jump (a branch change)
        self.jumps: list[int] = []
        n = model.nq
        # P's sparsity (dense upper triangle) and A = I are fixed; values change per iteration
        self._triu = np.triu_indices(n)
        pattern = sp.csc_matrix(np.triu(np.ones((n, n))))
        self._order = _csc_order(pattern, n)
        self._solver = osqp.OSQP()
        self._solver.setup(
            pattern,
            np.zeros(n),
            sp.identity(n, format="csc"),
            -np.ones(n),
            np.ones(n),
            verbose=False,
            eps_abs=1e-9,
            eps_rel=1e-9,
            polishing=False,
            max_iter=4000,
        )

    # ------------------------------------------------------------------ one target
    def _error(self, placement: pin.SE3, target: pin.SE3 | np.ndarray, orientation: bool) -> np.ndarray:
        if not orientation:
            return np.asarray(target) - placement.translation
        linear = target.translation - placement.translation
        angular = pin.log3(target.rotation @ placement.rotation.T)
        return np.concatenate([linear, angular])

    def _solve_one(self, target, q0: np.ndarray, orientation: bool) -> tuple[np.ndarray, float, float, int]:
        model = self.model
        rows = slice(0, 6) if orientation else slice(0, 3)
        weights = np.array([1.0, 1.0, 1.0, self.rotation_weight, self.rotation_weight, self.rotation_weight])[rows]
        q = np.clip(np.asarray(q0, dtype=float), model.lower, model.upper)
        iteration = 0
        while True:
            placement, jac = model.jacobian(q)
            error = self._error(placement, target, orientation)
            position_error = float(np.linalg.norm(error[:3]))
            rotation_error = float(np.linalg.norm(error[3:])) if orientation else 0.0
            if (position_error <= self.tolerance and rotation_error <= self.rotation_tolerance) or (
                iteration >= self.max_iterations
            ):
                return q, position_error, rotation_error, iteration
            step = self.qp_step(q, jac[rows] * weights[:, None], error * weights)
            if step is None:
                return q, position_error, rotation_error, iteration
            q = np.clip(q + step, model.lower, model.upper)
            iteration += 1

    def qp_step(self, q: np.ndarray, jacobian: np.ndarray, error: np.ndarray) -> np.ndarray | None:
        """One differential-IK step: the QP of the module docstring for the weighted task Jacobian
        (k x nq) and error (k,) at ``q``; None if OSQP fails."""
        model = self.model
        damping = self.damping + float(error @ error)
        hessian = jacobian.T @ jacobian + damping * np.eye(model.nq)
        gradient = -(jacobian.T @ error)
        lower = np.maximum(model.lower - q, -self.step)
        upper = np.minimum(model.upper - q, self.step)
        # the unconstrained minimiser solves the (convex) QP whenever it lies in the box;
        # OSQP is needed only when a joint or step bound is active
        step = np.linalg.solve(hessian, -gradient)
        if np.all(step >= lower) and np.all(step <= upper):
            return step
        self._solver.update(Px=hessian[self._triu][self._order], q=gradient, l=lower, u=upper)
        result = self._solver.solve(raise_error=False)
        if result.x is None or not np.all(np.isfinite(result.x)):
            return None
        return np.asarray(result.x)

    def _restart_guesses(self, q0: np.ndarray) -> list[np.ndarray]:
        rng = np.random.default_rng(0)  # deterministic: the same targets give the same solutions
        guesses = [q0, self.model.neutral()]
        guesses += list(rng.uniform(self.model.lower, self.model.upper, size=(self.restarts, self.model.nq)))
        return guesses

    def _follow(self, targets: list, first: tuple, orientation: bool) -> tuple[IKResult, int]:
        """Warm-start along the targets from a solution of the first; stop at the first failure.

        A failure is a target not reached, or (with ``max_joint_step``) a joint jumping by more than
        that between neighbouring targets (the solution slid onto another branch). Returns the
        result (targets after the failure: not converged, infinite error) and how many succeeded.
        """
        n, nq = len(targets), self.model.nq
        q_out = np.empty((n, nq))
        position_error = np.full(n, np.inf)
        rotation_error = np.full(n, np.inf)
        iterations = np.zeros(n, dtype=int)
        q_out[0], position_error[0], rotation_error[0], iterations[0] = first
        done = 1
        for i in range(1, n):
            solution = self._solve_one(targets[i], q_out[i - 1], orientation)
            q_out[i], position_error[i], rotation_error[i], iterations[i] = solution
            jump = self.max_joint_step is not None and np.max(np.abs(q_out[i] - q_out[i - 1])) > self.max_joint_step
            if not self._ok(solution) or jump:
                if jump:
                    self.jumps.append(i)
                break
            done += 1
        if done + 1 < n:
            q_out[done + 1 :] = q_out[done]  # unsolved; q_out[done] is the failed attempt, for diagnosis
        converged = np.arange(n) < done
        return IKResult(q_out, position_error, rotation_error, converged, iterations), done

    def _sequence(self, targets: list, q0, orientation: bool) -> IKResult:
        """Solutions along the targets, on the branch nearest ``q0`` that reaches all of them.

        The first target is solved from ``q0`` (the device's configuration); if that fails, or the
        sequence from it fails later (a joint limit or a singularity on that branch), solutions of
        the first target from other starts are followed in turn, nearest first, up to ``branches``
        distinct ones. The result says where the best attempt failed when none reaches every target.
        """
        q0 = np.clip(np.asarray(q0, dtype=float), self.model.lower, self.model.upper)
        self.jumps = []
        first = self._solve_one(targets[0], q0, orientation)
        candidates = [first] if self._ok(first) else []
        tried: list[np.ndarray] = []
        restarted = False
        best: tuple[IKResult, int] | None = None
        while len(tried) < self.branches:
            if not candidates:
                if restarted:
                    break
                restarted = True
                solutions = [self._solve_one(targets[0], g, orientation) for g in self._restart_guesses(q0)[1:]]
                candidates = sorted(
                    (c for c in solutions if self._ok(c)), key=lambda c: float(np.linalg.norm(c[0] - q0))
                )
                continue
            candidate = candidates.pop(0)
            if any(np.max(np.abs(candidate[0] - t)) < 1e-3 for t in tried):
                continue  # the same branch again
            tried.append(candidate[0])
            attempt = self._follow(targets, candidate, orientation)
            if attempt[1] == len(targets):
                return attempt[0]
            if best is None or attempt[1] > best[1]:
                best = attempt
        if best is None:  # not even the first target: report it from the given start
            n, nq = len(targets), self.model.nq
            q_out = np.broadcast_to(first[0], (n, nq)).copy()
            position_error = np.full(n, np.inf)
            rotation_error = np.full(n, np.inf)
            position_error[0], rotation_error[0] = first[1], first[2]
            return IKResult(q_out, position_error, rotation_error, np.zeros(n, dtype=bool), np.zeros(n, dtype=int))
        return best[0]

    def at_limit(self, q: np.ndarray, tolerance: float = 1e-6) -> list[str]:
        """Names of the joints of ``q`` at (within ``tolerance`` of) a position limit."""
        model = self.model
        hit = (q <= model.lower + tolerance) | (q >= model.upper - tolerance)
        return [name for name, h in zip(model.joint_names, hit, strict=True) if h]

    def _ok(self, solution) -> bool:
        return solution[1] <= self.tolerance * 10 and solution[2] <= self.rotation_tolerance * 10

    # ------------------------------------------------------------------ public
    def solve_positions(self, targets, q0) -> IKResult:
        """Joint solutions for tip positions (n, 3) in metres, each warm-started from the previous one."""
        targets = np.atleast_2d(np.asarray(targets, dtype=float))
        return self._sequence(list(targets), q0, orientation=False)

    def solve_poses(self, targets, q0) -> IKResult:
        """Joint solutions for tip poses (n, 7) = (x, y, z, qx, qy, qz, qw), warm-started along the sequence."""
        targets = np.atleast_2d(np.asarray(targets, dtype=float))
        rotations = Rotation.from_quat(targets[:, 3:]).as_matrix()
        placements = [pin.SE3(r, p) for r, p in zip(rotations, targets[:, :3], strict=True)]
        return self._sequence(placements, q0, orientation=True)


def _csc_order(pattern: sp.csc_matrix, n: int) -> np.ndarray:
    """Permutation from ``np.triu_indices`` order to the CSC order of the upper triangle's values."""
    rows, cols = np.triu_indices(n)
    position = {(int(r), int(c)): k for k, (r, c) in enumerate(zip(rows, cols, strict=True))}
    order = []
    for col in range(n):
        for ptr in range(pattern.indptr[col], pattern.indptr[col + 1]):
            order.append(position[(int(pattern.indices[ptr]), col)])
    return np.array(order)
