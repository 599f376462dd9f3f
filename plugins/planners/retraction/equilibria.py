"""Equilibrium states of the grasped flap, solved in worker processes (paper 002 §IV-A, §IV-E, §V).

Three picklable task functions for ``run_tasks`` / ``Executor.map``, each a
warm-started chain of static equilibria through the
:class:`~surgiplan.DeformableModel` interface (so any deformable model
plugin can replace ``stvk``):

* :func:`sample_chain` — the roadmap's samples: the equilibrium for each
  sampled gripper configuration, then the local optimisation of the
  gripper's rotation (Fig. 3), then its validity (converged, no inverted
  element, no self-penetration, no collision);
* :func:`edge_chain` — local planning: the FEM states along the SE(3)
  interpolation of roadmap edges, each valid and collision-free, and the
  last one back on the stored sample's equilibrium branch;
* :func:`path_chain` — the states along a trajectory (the smoothed plan).

A worker builds each model once (:func:`deformable_model`) and keeps it.
Times are split as in the paper's Table I: Newton's iterations (``fem_s``),
the model's validity checks (``validation_s``: inverted elements and
self-intersection, what the solve spends outside Newton) and collision
detection (``collision_s``).
"""

from __future__ import annotations

import json
import time
from collections import OrderedDict
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation
from surgiplan.deformable import DeformableModel, EquilibriumState

from .geometry import CollisionModel
from .grasp import GraspFrame, configuration, pose_matrices

_MODELS: OrderedDict[str, DeformableModel] = OrderedDict()
_KEEP = 4


def deformable_model(cls: type[DeformableModel], settings: dict[str, Any]) -> DeformableModel:
    """The model of ``cls`` for these SI settings, built once per process."""
    key = f"{cls.__module__}.{cls.__qualname__}:" + json.dumps(settings, sort_keys=True)
    model = _MODELS.get(key)
    if model is None:
        model = cls(cls.Settings.model_validate(settings))
        _MODELS[key] = model
        if len(_MODELS) > _KEEP:
            _MODELS.popitem(last=False)
    else:
        _MODELS.move_to_end(key)
    return model


def _seconds(state: EquilibriumState) -> tuple[float, float]:
    """(Newton, validity checks) seconds of a solve; all of it is Newton's when the model does not say."""
    total = float(state.data.get("solve_s", 0.0))
    newton = float(state.data.get("newton_s", total))
    return newton, max(total - newton, 0.0)


class _Chain:
    """A model, a grasp and running totals of where the time goes."""

    def __init__(self, args: dict[str, Any]) -> None:
        self.model = deformable_model(args["model_class"], args["model_settings"])
        cls = args["model_class"]
        #: how messages name the model: its plugin name, else its class
        self.model_name = args.get("model_name") or f"{cls.__module__}.{cls.__qualname__}"
        self.frame: GraspFrame = args["frame"]
        self.collision: CollisionModel | None = args["collision"]  # None: the caller checks collisions
        if self.collision is not None:
            self.collision.seconds = 0.0
        self.fem_s = 0.0
        self.validation_s = 0.0

    def solve(self, q: np.ndarray, initial: EquilibriumState | None) -> EquilibriumState:
        started = time.perf_counter()
        try:
            state = self.model.solve(self.frame.constraints(q), initial=initial)
        except (ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            # the interface asks a model to answer a configuration it cannot solve with an invalid state
            # (stvk does); a third-party model that raises instead loses that state, not the whole chain
            positions = initial.positions if initial is not None else self.frame.rest
            state = EquilibriumState(
                np.array(positions, dtype=float),
                np.inf,
                np.full(len(self.model.elements), np.inf),
                False,
                False,
                0,
                np.inf,
                f"the deformable model '{self.model_name}' failed: {type(exc).__name__}: {exc}",
            )
        state.data.setdefault("solve_s", time.perf_counter() - started)
        newton, validation = _seconds(state)
        self.fem_s += newton
        self.validation_s += validation
        return state

    def rest(self) -> EquilibriumState:
        """The flap held at the initial grasp (the chain's first warm start)."""
        return self.solve(self.frame.q0, None)

    def problem(self, state: EquilibriumState, q: np.ndarray) -> str:
        """'' for a valid, collision-free state; else the reason."""
        if not state.converged:
            return "not converged: " + state.message
        if not state.valid:
            return "invalid mesh: " + state.message
        return self.collision.check(state.positions, q) if self.collision is not None else ""

    def totals(self) -> dict[str, float]:
        collision_s = self.collision.seconds if self.collision is not None else 0.0
        return {"fem_s": self.fem_s, "validation_s": self.validation_s, "collision_s": collision_s}


# ----------------------------------------------------------------------------- samples


def _moment(chain: _Chain, state: EquilibriumState, q: np.ndarray) -> np.ndarray | None:
    """dΠ/dω (3,) N m: the moment of the jaws' forces on the tissue about the gripper origin.

    Envelope theorem: at an equilibrium, the derivative of Π with respect to
    the prescribed positions is the reaction (the force the constraint
    applies), so turning the grasped nodes by ω about the gripper origin
    changes Π by ω · Σ (x_i - p) × f_i. ``None`` when the model does not
    report its reactions (:attr:`EquilibriumState.reaction_forces`, one row
    per prescribed node: the anchored nodes, then the grasped ones, as
    :meth:`GraspFrame.constraints` lists them).
    """
    reactions = state.reaction_forces
    grasped = chain.frame.grasped
    if reactions is None or np.shape(reactions) != (len(chain.frame.anchored) + len(grasped), 3):
        return None
    arms = np.asarray(state.positions)[grasped] - q[:3]
    return np.cross(arms, np.asarray(reactions, dtype=float)[len(chain.frame.anchored) :]).sum(axis=0)


def _moment_by_differences(chain: _Chain, state: EquilibriumState, q: np.ndarray, h: float = 0.01) -> np.ndarray:
    """dΠ/dω by forward differences (three solves), for models that do not report reactions."""
    rotation = Rotation.from_quat(q[3:])
    gradient = np.zeros(3)
    for axis in range(3):
        turned = configuration(q[:3], (Rotation.from_rotvec(h * np.eye(3)[axis]) * rotation).as_matrix())
        gradient[axis] = (chain.solve(turned, state).energy - state.energy) / h
    return gradient


def relieve(chain: _Chain, q: np.ndarray, state: EquilibriumState, options: dict[str, Any], alpha: float | None = None):
    """Gradient descent on the gripper's rotation, position fixed, of Π (Fig. 3); Barzilai-Borwein steps.

    ``alpha`` (rad per N m): the first step's length per unit moment, e.g.
    the last Barzilai-Borwein value of the previous sample in the chain (a
    nearby state has a similar rotational stiffness); default: a step of
    ``max_step``. Returns (q, state, iterations, total rotation angle in rad,
    the last step length per unit moment). A step that fails (not converged,
    invalid) or does not lower Π is shrunk. Stops after ``max_iterations``
    trial steps, when a step would turn less than ``tolerance``, or once the
    moment has fallen to ``moment_ratio`` of the sample's (optional, default
    0: never; where Π is about quadratic in the rotation, further steps
    could gain about that ratio squared of what the relief gained, each at
    the price of a solve).
    """
    gradient = _moment(chain, state, q)
    if gradient is None:
        gradient = _moment_by_differences(chain, state, q)
    norm = float(np.linalg.norm(gradient))
    max_step, tolerance = float(options["max_step"]), float(options["tolerance"])
    settled = float(options.get("moment_ratio", 0.0)) * norm  # N m: a moment this small ends the descent
    if not norm > 0:
        return q, state, 0, 0.0, alpha
    if alpha is None or not alpha > 0:
        alpha = max_step / norm
    start_rotation = Rotation.from_quat(q[3:])
    iterations = 0
    for _ in range(int(options["max_iterations"])):
        step = -alpha * gradient
        angle = float(np.linalg.norm(step))
        if angle > max_step:
            step *= max_step / angle
            angle = max_step
        if angle < tolerance:
            break
        iterations += 1
        turned = configuration(q[:3], (Rotation.from_rotvec(step) * Rotation.from_quat(q[3:])).as_matrix())
        new = chain.solve(turned, state)
        if not (new.converged and new.valid) or not new.energy < state.energy:
            alpha *= 0.25
            continue
        new_gradient = _moment(chain, new, turned)
        if new_gradient is None:
            new_gradient = _moment_by_differences(chain, new, turned)
        change = new_gradient - gradient
        curvature = float(step @ change)
        alpha = float(step @ step) / curvature if curvature > 0 else 2.0 * alpha
        q, state, gradient = turned, new, new_gradient
        if float(np.linalg.norm(gradient)) <= settled:
            break
    total = float((Rotation.from_quat(q[3:]) * start_rotation.inv()).magnitude())
    return q, state, iterations, total, alpha


def _near_grasp_stress(chain: _Chain, state: EquilibriumState) -> float:
    """Largest element stress (Pa) among the elements touching grasped nodes."""
    elements = np.asarray(chain.model.elements)
    near = np.isin(elements, chain.frame.grasped).any(axis=1)
    stress = np.asarray(state.stress)
    return float(stress[near].max()) if near.any() and len(stress) == len(elements) else float("nan")


def sample_chain(args: dict[str, Any]) -> dict[str, Any]:
    """Equilibria of sampled configurations ``args["configurations"]`` (s, 7), warm-started in order.

    ``args``: ``model_class``, ``model_settings`` (SI), ``frame`` (GraspFrame),
    ``collision`` (CollisionModel), ``relief`` (dict of ReliefModel's fields),
    ``configurations``. Returns arrays over the s samples: ``q`` (after the
    local optimisation), ``positions`` float32 (s, n, 3), ``energy`` J,
    ``max_stress`` Pa, ``ok`` (valid and collision-free), ``reason``
    (JSON list), ``relief_iterations``, ``relief_angle`` rad,
    ``grasp_stress_before``/``after`` Pa, and the chain's time totals.
    """
    chain = _Chain(args)
    configurations = np.asarray(args["configurations"], dtype=float).reshape(-1, 7)
    relief = args["relief"]
    s = len(configurations)
    n = len(chain.frame.rest)
    out: dict[str, Any] = {
        "q": configurations.copy(),
        "positions": np.zeros((s, n, 3), dtype=np.float32),
        "energy": np.full(s, np.inf),
        "max_stress": np.full(s, np.inf),
        "ok": np.zeros(s, dtype=bool),
        "relief_iterations": np.zeros(s, dtype=np.int64),
        "relief_angle": np.zeros(s),
        "grasp_stress_before": np.full(s, np.nan),
        "grasp_stress_after": np.full(s, np.nan),
    }
    reasons = [""] * s
    previous = chain.rest()
    alpha = None
    for i, q in enumerate(configurations):  # a chain: each solve starts from the one before
        state = chain.solve(q, previous)
        sampled = state
        if state.converged and state.valid and relief["enabled"]:
            out["grasp_stress_before"][i] = _near_grasp_stress(chain, state)
            q, state, iterations, angle, alpha = relieve(chain, q, state, relief, alpha)
            out["relief_iterations"][i] = iterations
            out["relief_angle"][i] = angle
            out["grasp_stress_after"][i] = _near_grasp_stress(chain, state)
        out["q"][i] = q
        out["positions"][i] = state.positions
        reasons[i] = chain.problem(state, q)
        if state.converged and state.valid:
            out["energy"][i] = state.energy
            out["max_stress"][i] = float(np.max(state.stress))
            previous = sampled  # a failed solve never becomes the next one's start
        out["ok"][i] = not reasons[i]
    out["reason"] = reasons
    out.update(chain.totals())
    return out


# ----------------------------------------------------------------------------- edges and paths


def disp(a: np.ndarray, b: np.ndarray, nodes: np.ndarray) -> float:
    """The DISP distance (m): the largest displacement of a surface node between two states."""
    return float(np.max(np.linalg.norm(np.asarray(a)[nodes] - np.asarray(b)[nodes], axis=1)))


def _initial(chain: _Chain, positions: np.ndarray) -> EquilibriumState:
    """A stored state as a warm start (only its positions matter to the solver)."""
    return EquilibriumState(np.asarray(positions, dtype=float), 0.0, np.zeros(0), True, True, 0, 0.0)


def edge_chain(args: dict[str, Any]) -> dict[str, Any]:
    """Validate roadmap edges: FEM states along each edge's SE(3) interpolation (local planning, §IV-C).

    ``args``: as :func:`sample_chain`, plus ``edges``: a list of dicts with
    ``q`` (m, 7) the interpolated configurations after the first endpoint
    (the last is the second endpoint), ``start`` and ``end`` (n, 3) the
    endpoints' stored states; ``surface_nodes``; ``branch_tolerance`` (m).
    Returns per edge: ``valid``, ``reason``, ``max_energy``, ``max_stress``,
    ``energies`` (list), and the time totals.
    """
    chain = _Chain(args)
    surface = np.asarray(args["surface_nodes"])
    tolerance = float(args["branch_tolerance"])
    valid, reasons, max_energy, max_stress, energies = [], [], [], [], []
    for edge in args["edges"]:
        state = _initial(chain, edge["start"])
        reason = ""
        top_energy, top_stress, along = -np.inf, -np.inf, []
        for q in np.asarray(edge["q"], dtype=float):
            state = chain.solve(q, state)
            reason = chain.problem(state, q)
            if reason:
                break
            along.append(float(state.energy))
            top_energy = max(top_energy, float(state.energy))
            top_stress = max(top_stress, float(np.max(state.stress)))
        if not reason:
            gap = disp(state.positions, edge["end"], surface)
            if gap > tolerance:
                reason = (
                    f"the motion reaches another equilibrium than the stored sample (DISP {gap * 1e3:.3g} mm): "
                    "the flap snaps between branches"
                )
        valid.append(not reason)
        reasons.append(reason)
        max_energy.append(top_energy)
        max_stress.append(top_stress)
        energies.append(along)
    return {
        "valid": np.array(valid, dtype=bool),
        "reason": reasons,
        "max_energy": np.array(max_energy),
        "max_stress": np.array(max_stress),
        "energies": energies,
        **chain.totals(),
    }


def path_chain(args: dict[str, Any]) -> dict[str, Any]:
    """States along configurations ``args["q"]`` (m, 7) from the stored state ``args["start"]``.

    Returns ``positions`` float32 (m, n, 3), ``energy``, ``max_stress``,
    ``stress`` float32 (m, elements), ``reason`` (list; '' when valid) and the time totals.
    """
    chain = _Chain(args)
    configurations = np.asarray(args["q"], dtype=float).reshape(-1, 7)
    m = len(configurations)
    n = len(chain.frame.rest)
    elements = len(chain.model.elements)
    out: dict[str, Any] = {
        "positions": np.zeros((m, n, 3), dtype=np.float32),
        "energy": np.full(m, np.inf),
        "max_stress": np.full(m, np.inf),
        "stress": np.zeros((m, elements), dtype=np.float32),
    }
    reasons = []
    state = _initial(chain, args["start"])
    for i, q in enumerate(configurations):
        state = chain.solve(q, state)
        reasons.append(chain.problem(state, q))
        out["positions"][i] = state.positions
        out["energy"][i] = state.energy
        out["max_stress"][i] = float(np.max(state.stress))
        out["stress"][i] = np.asarray(state.stress, dtype=np.float32)
        if reasons[-1]:
            break
    out["reason"] = reasons
    out.update(chain.totals())
    return out


def assess_chunk(args: dict[str, Any]) -> dict[str, Any]:
    """Collision checks and visibility of solved states (§IV-B), for ``Executor.map``.

    ``args``: ``collision`` (CollisionModel), ``visibility`` (Visibility),
    ``triangles`` (t, 3), ``positions`` (s, n, 3), ``q`` (s, 7), ``ok``
    (s,) states worth checking. Returns ``reason`` (list; '' when clear),
    ``visible`` (s,) fraction of A visible (nan where not checked),
    ``collision_s`` and ``visibility_s``.
    """
    collision: CollisionModel = args["collision"]
    collision.seconds = 0.0
    visibility = args["visibility"]
    positions = np.asarray(args["positions"])
    q = np.asarray(args["q"], dtype=float)
    reasons, visible = [], np.full(len(q), np.nan)
    started = 0.0
    for i in range(len(q)):  # one collision query and one ray cast per state
        if not args["ok"][i]:
            reasons.append("")
            continue
        x = positions[i].astype(float)
        reasons.append(collision.check(x, q[i]))
        tick = time.perf_counter()
        visible[i] = visibility.fraction(x, args["triangles"], pose_matrices(q[i]))
        started += time.perf_counter() - tick
    return {"reason": reasons, "visible": visible, "collision_s": collision.seconds, "visibility_s": started}
