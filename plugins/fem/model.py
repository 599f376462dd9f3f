"""The ``stvk`` deformable model: nonlinear St. Venant-Kirchhoff FEM with fast static equilibria.

Patil & Alterovitz, "Toward automated tissue retraction in robot-assisted
surgery" (paper 002), §V: a tetrahedral tissue flap, anchored along some
edges and grasped by a gripper, deforms under gravity, base contact and
the gripper's rigid motion; each sampled gripper pose needs the static
equilibrium, its total energy Π, its stresses and whether it is valid.

Use from Python (a planner calls this thousands of times)::

    from surgiplan.plugins.fem import StVKModel, StVKSettings

    model = StVKModel(StVKSettings.model_validate({
        "mesh": {"box": {"size": [0.05, 0.05, 0.0025], "divisions": [20, 20, 2], "pattern": "five"}},
        "anchored": [{"region": {"min": [0, 0, 0], "max": [0, 0.05, 0.0025]}}],
        "base_plane": {},
    }))
    jaws = model.nodes_in_region([0.048, 0.022, 0], [0.05, 0.028, 0.0025])
    state = None
    for pose in gripper_poses:                      # 4 x 4 world transforms (or Pose)
        c = model.grasp_constraints(jaws, pose)     # anchors from the settings + grasped nodes
        state = model.solve(c, initial=state)       # warm start + predictor
        state.positions, state.energy, state.stress, state.valid, state.converged
        state.reaction_forces                       # (k, 3) N, one row per prescribed node of c

* :meth:`StVKModel.grasp_constraints` holds the settings' anchored nodes
  and moves ``nodes`` to ``transform`` applied to their rest positions
  (``x = R X + t``, world frame), with the settings' dead loads.
* :meth:`StVKModel.solve` (the framework's interface) returns an
  :class:`~surgiplan.deformable.EquilibriumState`: positions (n, 3) m;
  energy Π (J): elastic + volume penalty + base contact energy minus the
  work of gravity and dead loads (it grows when tissue is lifted); stress
  (m,) Pa: per element, the largest absolute principal value of the second
  Piola-Kirchhoff stress (paper §IV-D); valid: no inverted element and no
  self-crossing of the boundary surface; converged, iterations, residual
  (N), message; ``reaction_forces`` (k, 3) N, what each constraint of
  ``constraints.prescribed_nodes`` (in that order) applies to the tissue,
  which at an equilibrium is dΠ/d(prescribed position). ``data`` holds
  ``surface_triangles`` (t, 3) (outward, shared by all states),
  ``prescribed_nodes`` (the held nodes, sorted) and ``reaction_field``
  (n, 3) N (zero where nothing is held), ``volume_ratio`` (m,),
  ``min_volume_ratio``, ``inverted_elements``, ``self_intersections``
  (crossing triangle pairs), ``elastic_energy``, ``external_work``,
  ``contact_energy`` (J), ``energy_history`` (Π after each corrector
  step), ``predictor_steps``, ``definite_steps``, ``quasi_newton_steps``,
  ``factorizations``, ``line_search_cuts``, ``tangent_shift``, ``solve_s``.
* A solve never raises on a configuration it cannot handle (a degenerate
  or inverted state, a singular tangent): its state says ``converged``
  or ``valid`` False and why. Only malformed constraints raise.
* Answers depend on the constraints and the start state only (its
  positions and its ``tangent_shift``, see :meth:`StVKModel.solve`). The
  model keeps the factored tangents at the start positions of its last few
  solves (:attr:`StVKModel.START_FACTORS`); a solve from exactly those
  positions (each relief step of a retraction sample, and the next sample,
  start from one state) skips that factorisation and gets the same bits.
  :meth:`StVKModel.clear_caches` frees them.
* :meth:`StVKModel.evaluate_state` gives the same outputs for given
  positions without solving.
* Constraints may hold nodes along some axes only (rollers, symmetry
  planes): :class:`AxisConstraints`.
* :attr:`StVKModel.surface_nodes` and :meth:`StVKModel.disp_distance` (the
  paper's DISP metric, §IV-C) for planners; :meth:`StVKModel.nodes_in_oriented_box`
  selects the nodes between a gripper's jaws (§IV-A).
* Linear or quadratic tetrahedra (``mesh: {..., order: 2}``): the same API.
* A model pickles (for worker processes) without its caches, which are
  rebuilt on the first solve (about 0.2 s for the paper's flap); or rebuild
  it from ``model.settings`` (see :mod:`.tasks`).
"""

from __future__ import annotations

import hashlib
import time
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from surgiplan.deformable import Constraints, DeformableModel, EquilibriumState
from surgiplan.errors import ConfigError
from surgiplan.geometry.transforms import Pose
from surgiplan.resources import ResourceEstimate

from .assembly import TangentPattern
from .intersection import self_intersections
from .loads import BasePlane, ExternalLoads, work_equivalent_masses
from .material import ImageMap, MaterialField
from .mesh import TetMesh, box_mesh, read_tet_mesh, tetrahedralize_surface
from .newton import EquilibriumSolver, NewtonResult, SolverOptions
from .settings import RegionModel, StVKSettings
from .stvk import StVKElements
from .tangent_factor import CachedFactor

AXES = {"x": 0, "y": 1, "z": 2}


@dataclass
class AxisConstraints(Constraints):
    """Constraints whose nodes may be held along some axes only.

    ``prescribed_axes`` (k, 3) bool: which coordinates of each prescribed
    node are held at ``prescribed_positions``; ``None`` holds all three.
    """

    prescribed_axes: np.ndarray | None = None


def rigid_transform(transform) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) from a :class:`Pose`, a 4 x 4 matrix or an (R, t) pair."""
    if isinstance(transform, Pose):
        return np.asarray(transform.rotation, float), np.asarray(transform.translation, float)
    if isinstance(transform, tuple) and len(transform) == 2:
        return np.asarray(transform[0], float).reshape(3, 3), np.asarray(transform[1], float).reshape(3)
    matrix = np.asarray(transform, dtype=float)
    if matrix.shape != (4, 4):
        raise ValueError("a transform is a Pose, a 4 x 4 matrix or a (rotation, translation) pair")
    return matrix[:3, :3], matrix[:3, 3]


def build_mesh(settings: StVKSettings) -> TetMesh:
    """The settings' mesh: a structured box or a file (volume mesh, or a closed surface for TetGen)."""
    mesh = settings.mesh
    if mesh.box is not None:
        box = mesh.box
        built = box_mesh(box.size, box.divisions, box.origin, box.pattern)
    elif Path(mesh.file).suffix.lower() in {".stl", ".obj", ".ply", ".off"}:
        built = tetrahedralize_surface(
            mesh.file, mesh.file_scale, max_volume=mesh.max_tet_volume, location="settings.mesh.file"
        )
    else:
        built = read_tet_mesh(mesh.file, mesh.file_scale, location="settings.mesh.file")
    return built.quadratic() if mesh.order == 2 else built


def build_material(settings: StVKSettings, mesh: TetMesh) -> MaterialField:
    m = settings.material
    field = MaterialField.uniform(
        mesh.n_elements, m.youngs_modulus, m.poisson_ratio, m.density, volume_penalty=m.volume_penalty
    )
    for i, region in enumerate(m.regions):
        where = f"settings.material.regions[{i}]"
        if region.region is not None:
            mask = mesh.elements_in_box(region.region.min, region.region.max)
        else:
            image = region.image
            mask = ImageMap.read(
                image.file, image.min, image.max, image.threshold, image.dark, location=f"{where}.image"
            ).select(mesh.centroids)
        if not mask.any():
            raise ConfigError("the region contains no element centroid", location=where)
        field.override(mask, region.youngs_modulus, region.poisson_ratio, region.density)
    return field


class StVKModel(DeformableModel):
    """Nonlinear St. Venant-Kirchhoff tetrahedral FEM (see the module docstring)."""

    @classmethod
    def estimate_resources(cls, settings):
        """Memory of a box mesh's model and its factorisation (files: their size is known only when read).

        Per tetrahedron ~3 kB (linear) or ~20 kB (quadratic) of kernel arrays; the sparse factor of n
        unknowns about 320 n^(4/3) bytes (3D nested-dissection fill, double precision, with workspace).
        """
        box = settings.mesh.box
        if box is None:
            return []
        nx, ny, nz = box.divisions
        cells = nx * ny * nz
        tets = cells * (5 if box.pattern == "five" else 6)
        order = settings.mesh.order
        nodes = (order * nx + 1) * (order * ny + 1) * (order * nz + 1)
        unknowns = 3 * nodes
        per_tet = 3_000 if order == 1 else 20_000
        return [
            ResourceEstimate(
                tets * per_tet + 320 * unknowns ** (4 / 3),
                f"a mesh of {tets:,} {'linear' if order == 1 else 'quadratic'} tetrahedra ({unknowns:,} unknowns)",
                "mesh",
            )
        ]

    Settings = StVKSettings

    def __init__(
        self, settings: StVKSettings, mesh: TetMesh | None = None, material: MaterialField | None = None
    ) -> None:
        super().__init__(settings)
        self.mesh = mesh if mesh is not None else build_mesh(settings)
        self.material = material if material is not None else build_material(settings, self.mesh)
        if len(self.material.youngs_modulus) != self.mesh.n_elements:
            raise ValueError("the material must give one value per element")
        lam, mu = self.material.lame
        self.kernel = StVKElements(self.mesh.nodes, self.mesh.tets, lam, mu, self.material.penalty_modulus)
        kernel = self.kernel
        self.node_masses = work_equivalent_masses(
            self.mesh.n_nodes,
            self.mesh.tets,
            [p.weight for p in kernel.points],
            kernel.reference.values(kernel.reference.points),
            self.material.density,
        )
        self.edge_length = self.mesh.mean_edge_length
        base = None
        if settings.base_plane is not None:
            plane = settings.base_plane
            stiffness = plane.stiffness or 0.1 * float(self.material.youngs_modulus.mean()) * self.edge_length
            base = BasePlane(np.asarray(plane.point), np.asarray(plane.normal), stiffness)
        self.loads = ExternalLoads(self.mesh.nodes, self.node_masses, settings.gravity, None, base)
        self.options = SolverOptions(
            residual_tol=settings.solver.residual_tol,
            step_tol=settings.solver.step_tol,
            max_iterations=settings.solver.max_iterations,
            tangent=settings.solver.tangent,
        )
        self._solver: EquilibriumSolver | None = None
        #: factored tangents at the start positions of recent solves: a later solve from exactly the same
        #: positions (e.g. each relief step of a sample, and the next sample, start from its state) skips
        #: that factorisation; a hit gives the very bits a miss computes
        self._start_factors: OrderedDict[bytes, CachedFactor] = OrderedDict()

    # ------------------------------------------------------------------ the interface's properties
    @property
    def rest_nodes(self) -> np.ndarray:
        return self.mesh.nodes

    @property
    def elements(self) -> np.ndarray:
        return self.mesh.tets

    @property
    def surface_triangles(self) -> np.ndarray:
        """Boundary triangles (t, 3), counter-clockwise seen from outside (same for every state)."""
        return self.mesh.surface

    @property
    def surface_nodes(self) -> np.ndarray:
        """Indices (sorted) of the nodes on the boundary surface."""
        if getattr(self, "_surface_nodes", None) is None:
            self._surface_nodes = np.unique(self.surface_triangles)
        return self._surface_nodes

    def disp_distance(self, a, b) -> float:
        """DISP distance (m) between two states: the largest displacement of a surface node from a to b.

        Patil & Alterovitz §IV-C use it to choose a roadmap sample's nearest
        neighbours; ``a`` and ``b`` are states or positions (n, 3).
        """
        xa = np.asarray(getattr(a, "positions", a), dtype=float)[self.surface_nodes]
        xb = np.asarray(getattr(b, "positions", b), dtype=float)[self.surface_nodes]
        return float(np.linalg.norm(xa - xb, axis=1).max())

    @property
    def element_volumes(self) -> np.ndarray:
        """Rest volumes (m,) in m^3."""
        return self.kernel.volume

    @property
    def solver(self) -> EquilibriumSolver:
        if self._solver is None:
            pattern = TangentPattern(self.kernel.dofs, 3 * self.mesh.n_nodes, self.settings.solver.linear_solver)
            floor = 1e-9 * float(self.material.youngs_modulus.mean()) * self.edge_length**2
            self._solver = EquilibriumSolver(self.kernel, self.loads, pattern, self.edge_length, floor)
        return self._solver

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_solver"] = None  # index arrays and factor caches: rebuilt on first use
        state["_start_factors"] = OrderedDict()
        return state

    # ------------------------------------------------------------------ node sets
    def nodes_in_region(self, lower, upper) -> np.ndarray:
        """Nodes (sorted indices) whose rest position lies in the axis-aligned box (m)."""
        return self.mesh.nodes_in_box(lower, upper)

    def nodes_in_oriented_box(self, pose, half_extents) -> np.ndarray:
        """Nodes whose rest position lies in a box of ``half_extents`` (m) placed at ``pose`` (a gripper's jaws)."""
        rotation, translation = rigid_transform(pose)
        local = (self.mesh.nodes - translation) @ rotation
        return np.flatnonzero(np.all(np.abs(local) <= np.asarray(half_extents, float) + 1e-12, axis=1))

    def _region_nodes(self, region: RegionModel, location: str) -> np.ndarray:
        nodes = self.nodes_in_region(region.min, region.max)
        if len(nodes) == 0:
            raise ConfigError("the region contains no node of the mesh", location=location)
        return nodes

    def anchored_nodes(self) -> tuple[np.ndarray, np.ndarray]:
        """The settings' anchored nodes (k,) and which of their axes are held (k, 3) bool."""
        held: dict[int, np.ndarray] = {}
        for i, anchor in enumerate(self.settings.anchored):
            axes = np.zeros(3, dtype=bool)
            axes[[AXES[a] for a in anchor.axes]] = True
            for node in self._region_nodes(anchor.region, f"settings.anchored[{i}].region"):
                held[int(node)] = held.get(int(node), np.zeros(3, dtype=bool)) | axes
        nodes = np.array(sorted(held), dtype=np.int64)
        return nodes, np.array([held[n] for n in nodes], dtype=bool).reshape(-1, 3)

    def grasped_nodes(self) -> np.ndarray:
        """The nodes of the settings' ``grasp`` region (empty without one)."""
        if self.settings.grasp is None:
            return np.empty(0, dtype=np.int64)
        return self._region_nodes(self.settings.grasp.region, "settings.grasp.region")

    def load_forces(self) -> np.ndarray:
        """The settings' dead loads as nodal forces (n, 3) in N."""
        forces = np.zeros((self.mesh.n_nodes, 3))
        for i, load in enumerate(self.settings.loads):
            nodes = self._region_nodes(load.region, f"settings.loads[{i}].region")
            forces[nodes] += np.asarray(load.total_force) / len(nodes)
        return forces

    # ------------------------------------------------------------------ constraints
    def grasp_constraints(self, nodes, transform=None, *, anchored: bool = True, loads: bool = True) -> AxisConstraints:
        """Anchors from the settings plus ``nodes`` at ``transform`` of their rest positions.

        ``transform`` maps rest to target positions in the world frame
        (``x = R X + t``): a :class:`Pose`, a 4 x 4 matrix or (R, t); ``None``
        holds the nodes at rest. A grasped node that is also anchored follows
        the grasp. ``loads`` adds the settings' dead loads.
        """
        nodes = np.unique(np.asarray(nodes, dtype=np.int64).ravel())
        targets = self.mesh.nodes[nodes]
        if transform is not None:
            rotation, translation = rigid_transform(transform)
            targets = targets @ rotation.T + translation
        all_nodes, all_targets, all_axes = [nodes], [targets], [np.ones((len(nodes), 3), dtype=bool)]
        if anchored:
            anchor, axes = self.anchored_nodes()
            keep = ~np.isin(anchor, nodes)
            all_nodes.append(anchor[keep])
            all_targets.append(self.mesh.nodes[anchor[keep]])
            all_axes.append(axes[keep])
        return AxisConstraints(
            np.concatenate(all_nodes),
            np.concatenate(all_targets),
            self.load_forces() if loads and self.settings.loads else None,
            np.concatenate(all_axes),
        )

    def stage_constraints(self, fraction: float = 1.0) -> AxisConstraints:
        """Everything the settings prescribe: anchors, the grasp's transform, dead loads.

        ``fraction`` (0 to 1) of the grasp's motion (rotation by slerp about the
        pivot, translation linearly) and of the dead loads, as the ``steps`` of a
        simulate stage apply them.
        """
        settings = self.settings
        grasp = settings.grasp
        if grasp is None:
            constraints = self.grasp_constraints(np.empty(0, dtype=np.int64))
        else:
            nodes = self.grasped_nodes()
            pose = grasp.transform.to_pose()
            rotation = Rotation.from_rotvec(fraction * Rotation.from_matrix(pose.rotation).as_rotvec()).as_matrix()
            pivot = np.asarray(grasp.pivot) if grasp.pivot is not None else self.mesh.nodes[nodes].mean(axis=0)
            translation = pivot + fraction * np.asarray(pose.translation) - rotation @ pivot
            constraints = self.grasp_constraints(nodes, (rotation, translation))
        if constraints.external_forces is not None:
            constraints.external_forces = fraction * constraints.external_forces
        return constraints

    def _prescribed(self, constraints: Constraints) -> tuple[np.ndarray, np.ndarray]:
        n = self.mesh.n_nodes
        nodes = np.asarray(constraints.prescribed_nodes, dtype=np.int64).ravel()
        targets = np.asarray(constraints.prescribed_positions, dtype=float).reshape(-1, 3)
        if len(nodes) != len(targets):
            raise ValueError(f"{len(nodes)} prescribed nodes but {len(targets)} prescribed positions")
        if len(nodes) and (nodes.min() < 0 or nodes.max() >= n):
            raise ValueError(f"prescribed nodes must be in [0, {n})")
        if not np.all(np.isfinite(targets)):
            raise ValueError("prescribed positions must be finite")
        axes = getattr(constraints, "prescribed_axes", None)
        axes = np.ones((len(nodes), 3), dtype=bool) if axes is None else np.asarray(axes, dtype=bool).reshape(-1, 3)
        mask = np.zeros((n, 3), dtype=bool)
        goal = self.mesh.nodes.copy()
        dofs_nodes, dofs_axes = np.nonzero(axes)
        picked = nodes[dofs_nodes]
        values = targets[dofs_nodes, dofs_axes]
        order = np.lexsort((dofs_axes, picked))
        key = picked[order] * 3 + dofs_axes[order]
        duplicate = np.flatnonzero(np.diff(key) == 0)
        if len(duplicate) and np.any(values[order][duplicate] != values[order][duplicate + 1]):
            raise ValueError("a node is prescribed twice at different positions")
        mask[picked, dofs_axes] = True
        goal[picked, dofs_axes] = values
        return mask.ravel(), goal.ravel()

    # ------------------------------------------------------------------ equilibria
    def solve(self, constraints: Constraints, initial: EquilibriumState | None = None) -> EquilibriumState:
        """The static equilibrium under ``constraints``, warm-started from ``initial`` (see the module docstring).

        The answer depends on ``constraints``, ``initial.positions`` and
        ``initial.data["tangent_shift"]`` only, never on what this model
        solved before (see :meth:`clear_caches`). ``tangent_shift`` (set on
        every state this model returns) is the relative diagonal shift the
        solve that found ``initial`` would give its next indefinite tangent:
        a solve continuing from it starts its search for a definite
        tangent there, which saves factorisations along a chain of nearby
        states (absent: the smallest shift).
        A configuration the solver cannot handle (a degenerate or inverted
        state, a singular tangent, non-finite numbers) gives a state with
        ``converged``/``valid`` False and the reason in ``message``; only
        malformed constraints (shapes, indices) raise ``ValueError``.
        """
        started = time.perf_counter()
        prescribed, goal = self._prescribed(constraints)
        self.loads.set_forces(constraints.external_forces)
        x0 = self.mesh.nodes
        shift = None
        if initial is not None:
            start = np.asarray(initial.positions, dtype=float)
            if start.shape == x0.shape and np.all(np.isfinite(start)) and self.kernel.upright(start):
                x0 = start
                shift = self._shift_hint(initial)
        key = self._factor_key(x0, prescribed, shift)
        try:
            result = self.solver.solve(
                x0.ravel(), prescribed, goal, self.options, self._start_factors.get(key), shift=shift
            )
        except (ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            # the checks in the solver should leave nothing to catch here; a state is still better than a crash
            result = NewtonResult(x0.ravel().copy(), False, 0, np.inf, np.nan, np.inf)
            result.message = f"numerical failure of the solver: {type(exc).__name__}: {exc}"
        if result.start_factor is not None:
            self._start_factors[key] = result.start_factor
            self._start_factors.move_to_end(key)
            while len(self._start_factors) > self.START_FACTORS:
                self._start_factors.popitem(last=False)
        state = self._state(result.x.reshape(-1, 3), prescribed, result, constraints)
        state.data["solve_s"] = time.perf_counter() - started
        return state

    #: factorisations kept, keyed by the positions they were computed at (a few MB each)
    START_FACTORS = 3

    def _factor_key(self, x: np.ndarray, prescribed: np.ndarray, shift: float | None = None) -> bytes:
        """What a start factorisation is a function of: positions, held dofs, tangent policy (contact included),
        and the diagonal shift an indefinite tangent there starts from."""
        digest = hashlib.blake2b(np.ascontiguousarray(x, dtype=float).tobytes(), digest_size=20)
        digest.update(np.packbits(prescribed).tobytes())
        digest.update(self.options.tangent.encode())
        digest.update(np.float64(np.nan if shift is None else shift).tobytes())
        return digest.digest()

    @staticmethod
    def _shift_hint(initial: EquilibriumState) -> float | None:
        """The warm start's ``tangent_shift`` (see :meth:`solve`), if it carries a usable one."""
        value = initial.data.get("tangent_shift") if isinstance(initial.data, dict) else None
        if isinstance(value, (int, float)) and np.isfinite(value) and value > 0:
            return float(value)
        return None

    def clear_caches(self) -> None:
        """Drop the kept factorisations (memory only: answers never depend on them)."""
        self._start_factors.clear()

    def evaluate_state(self, positions, constraints: Constraints | None = None) -> EquilibriumState:
        """Energy, stress and validity of given positions (n, 3), without solving.

        ``converged`` says whether the positions are an equilibrium under
        ``constraints`` (residual within the solver's tolerance).
        """
        x = np.asarray(positions, dtype=float).reshape(-1, 3)
        if constraints is None:
            constraints = Constraints(np.empty(0, dtype=np.int64), np.empty((0, 3)))
        prescribed, _ = self._prescribed(constraints)
        self.loads.set_forces(constraints.external_forces)
        energy, grad = self.solver.gradient(x.ravel())
        scale = max(
            float(np.abs(self.loads.total_forces).max(initial=0.0)),
            float(np.abs(grad[prescribed]).max(initial=0.0)) if grad is not None else 0.0,
            self.solver.force_floor,
        )
        residual = float(np.abs(grad[~prescribed]).max(initial=0.0)) if grad is not None else np.inf
        result = NewtonResult(
            x.ravel(), residual <= self.options.residual_tol * scale, 0, residual, scale, energy, "evaluated"
        )
        result.gradient = grad
        return self._state(x, prescribed, result, constraints)

    def _state(
        self, x: np.ndarray, prescribed: np.ndarray, result: NewtonResult, constraints: Constraints
    ) -> EquilibriumState:
        finite = bool(np.all(np.isfinite(x)))
        ratio, stress, elastic = self.kernel.summary(x)  # one compiled pass over the elements
        degenerate = ~(ratio > 0)  # inverted, flat, or not a number
        inverted = int(np.count_nonzero(degenerate))
        crossings = 0
        if self.settings.self_intersection and finite:
            crossings = len(self_intersections(x, self.surface_triangles))
        loads = self.loads.evaluate(x, gradient=False)
        grad = result.gradient
        reactions = np.zeros((self.mesh.n_nodes, 3))
        if grad is not None:
            reactions.ravel()[prescribed] = grad[prescribed]
        if inverted:
            stress = np.full(len(ratio), np.inf)
        message = result.message
        if not finite:
            message += "; positions that are not finite numbers"
        elif inverted:
            message += f"; {inverted} inverted elements"
        if crossings:
            message += f"; the surface crosses itself ({crossings} triangle pairs)"
        nodes = np.asarray(constraints.prescribed_nodes, dtype=np.int64).ravel()
        return EquilibriumState(
            positions=x,
            energy=float(elastic + loads.energy) if inverted == 0 else np.inf,
            stress=stress,
            valid=finite and inverted == 0 and crossings == 0,
            converged=result.converged and finite,
            iterations=result.iterations,
            residual=result.residual,
            message=message.removeprefix("; "),
            data={
                "surface_triangles": self.surface_triangles,
                "prescribed_nodes": np.flatnonzero(prescribed.reshape(-1, 3).any(axis=1)),
                "reaction_field": reactions,
                "volume_ratio": ratio,
                "min_volume_ratio": float(np.nanmin(ratio)) if finite else float("nan"),
                "inverted_elements": inverted,
                "self_intersections": crossings,
                "elastic_energy": float(elastic),
                "external_work": loads.work,
                "contact_energy": loads.contact_energy,
                "residual_scale": result.residual_scale,
                "energy_history": list(result.energy_history),
                "predictor_steps": result.predictor_steps,
                "definite_steps": result.definite_steps,
                "quasi_newton_steps": result.quasi_newton_steps,
                "line_search_cuts": result.line_search_cuts,
                "factorizations": result.factorizations,
                "tangent_shift": result.shift,
                "trace": list(result.trace),
                "newton_s": result.seconds,
                "linear_solver": self.solver.pattern.solver,
            },
            reaction_forces=reactions[nodes] if grad is not None else None,
        )
