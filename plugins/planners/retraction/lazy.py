"""The online phase: lazy optimal search per grasp, grasp selection, C¹ trajectory (paper 002 §IV-C to §IV-E).

Every grasp's lazy search runs in rounds: each unfinished search proposes
its best path, and all their unvalidated edges are validated together (the
gripper's motion certified by the ``se3`` space in this process; the FEM
states along each edge by the executor's workers), so the workers stay busy
although each search is serial. The best grasp is the one whose plan is
cheapest (Objective 2). Its path becomes a C¹ trajectory (cubic splines in
position and rotation), re-simulated at a fine DISP step; a piece of the
spline that fails falls back to the validated straight motion, and a piece
that fails even so invalidates its edge and the search resumes.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .equilibria import disp, edge_chain, path_chain
from .generation import GraspRoadmap
from .grasp import pose_matrices
from .search import BOTTLENECK, LazyState, Path
from .setup import Setup
from .trajectory import SE3Spline, parameters, piece_parameters


@dataclass
class GraspOutcome:
    index: int
    lazy: LazyState | None
    goals: np.ndarray
    message: str = ""
    invalid_reasons: dict[str, int] = field(default_factory=dict)

    @property
    def path(self) -> Path | None:
        return self.lazy.path if self.lazy is not None else None


@dataclass
class Trajectory:
    """The executed plan: dense configurations and the FEM state at each (SI)."""

    q: np.ndarray  # (M, 7)
    positions: np.ndarray  # (M, n, 3) float32
    energy: np.ndarray  # (M,) J
    max_stress: np.ndarray  # (M,) Pa
    stress: np.ndarray  # (M, elements) float32, Pa
    waypoints: np.ndarray  # (k,) indices into q of the path's roadmap states
    spline_pieces: int
    linear_pieces: int
    visible: np.ndarray  # (p,) A's points visible at the end
    effort: float  # control effort along the dense states, J m


@dataclass
class Outcome:
    grasps: list[GraspOutcome]
    best: int | None
    trajectory: Trajectory | None
    message: str
    timing: dict[str, float]
    validated_edges: int = 0

    def annotations(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.best is not None and self.grasps[self.best].path is not None:
            out["roadmap_path_nodes"] = self.grasps[self.best].path.nodes.tolist()
        return out


class LazyPlanner:
    """Lazy search over every grasp's roadmap, then the trajectory of the best."""

    def __init__(self, setup: Setup, roadmaps: list[GraspRoadmap]) -> None:
        self.setup = setup
        self.roadmaps = roadmaps
        self.settings = setup.settings
        self.metric = self.settings.metric
        self.timing = {"collision_s": 0.0, "validation_s": 0.0, "fem_s": 0.0, "search_s": 0.0, "smoothing_s": 0.0}
        # Π of the flap held by its anchors only: no grasped state has less (a constrained minimum),
        # so the control effort's Π - Π_ref is never negative
        rest = setup.model.solve(setup.frames[0].rest_constraints())
        self.reference_energy = float(rest.energy) if rest.converged else float(np.nanmin(roadmaps[0].energy))
        self.edge_results: dict[tuple[int, int], tuple[bool, float, str]] = {}

    # ------------------------------------------------------------------ weights
    def node_values(self, roadmap: GraspRoadmap) -> np.ndarray:
        if self.metric == "max_stress":
            return roadmap.max_stress
        if self.metric == "max_energy":
            return roadmap.energy
        return np.maximum(roadmap.energy - self.reference_energy, 0.0)

    def estimates(self, roadmap: GraspRoadmap) -> np.ndarray:
        """Edge weights before validation: never above the true ones (lazy search stays exact)."""
        value = self.node_values(roadmap)
        a, b = roadmap.edges[:, 0], roadmap.edges[:, 1]
        if self.metric in BOTTLENECK:
            return np.maximum(value[a], value[b])
        return roadmap.length * 0.5 * (value[a] + value[b])

    # ------------------------------------------------------------------ the search
    def start_searches(self) -> list[GraspOutcome]:
        threshold = self.settings.visibility.threshold
        outcomes = []
        for k, roadmap in enumerate(self.roadmaps):
            goals = np.flatnonzero(roadmap.ok & (roadmap.visible >= threshold - 1e-12))
            if not roadmap.ok[0]:
                outcomes.append(GraspOutcome(k, None, goals, roadmap.reason[0] or "the start state is not valid"))
                continue
            if len(goals) == 0:
                valid = int(roadmap.ok[1:].sum())
                best = float(roadmap.visible[roadmap.ok].max()) if roadmap.ok.any() else 0.0
                outcomes.append(
                    GraspOutcome(
                        k,
                        None,
                        goals,
                        f"no goal state: none of the {valid} valid states of {roadmap.samples} samples exposes "
                        f"{threshold:.0%} of the area of interest (the best exposes {best:.1%}); sample more "
                        "or elsewhere, or lower visibility.threshold",
                    )
                )
                continue
            lazy = LazyState(
                self.metric, len(roadmap.q), roadmap.edges, roadmap.length, self.estimates(roadmap), 0, goals
            )
            outcomes.append(GraspOutcome(k, lazy, goals))
        return outcomes

    def search(self, outcomes: list[GraspOutcome]) -> None:
        """Rounds of lazy search until every grasp's best path is validated (or none is left)."""
        progress = self.setup.problem.progress
        with progress.task("retraction: lazy search (edges validated)", total=None) as task:
            while True:
                batch: list[tuple[int, int]] = []
                for outcome in outcomes:
                    if outcome.lazy is None or outcome.lazy.done:
                        continue
                    started = time.perf_counter()
                    todo = outcome.lazy.step()
                    self.timing["search_s"] += time.perf_counter() - started
                    batch.extend((outcome.index, int(e)) for e in todo)
                if not batch:
                    break
                results = self.validate(batch)
                for outcome in outcomes:
                    mine = [(e, r) for (k, e), r in zip(batch, results, strict=True) if k == outcome.index]
                    if not mine:
                        continue
                    ids = np.array([e for e, _ in mine])
                    valid = np.array([r[0] for _, r in mine])
                    weights = np.array([r[1] for _, r in mine]) if self.metric in BOTTLENECK else None
                    for _, r in mine:
                        if not r[0]:
                            kind = r[2].split(":")[0].split(" (")[0]
                            outcome.invalid_reasons[kind] = outcome.invalid_reasons.get(kind, 0) + 1
                    outcome.lazy.update(ids, valid, weights)
                task.advance(len(batch))
        for outcome in outcomes:
            if outcome.lazy is not None and outcome.lazy.path is None and not outcome.message:
                removed = int((~outcome.lazy.alive).sum())
                outcome.message = (
                    f"no path: the {len(outcome.goals)} goal states are not connected to the grasp "
                    f"({removed} edges found invalid: "
                    + (", ".join(f"{v} {k}" for k, v in sorted(outcome.invalid_reasons.items())) or "none")
                    + "); sample more, or raise roadmap.k"
                )

    def validate(self, batch: list[tuple[int, int]]) -> list[tuple[bool, float, str]]:
        """Validate edges (grasp, edge id): certified gripper motion here, FEM along them in the workers."""
        space = self.setup.problem.space
        options = self.settings.roadmap
        out: list[tuple[bool, float, str] | None] = [None] * len(batch)
        pending = []
        for i, (k, e) in enumerate(batch):
            if (k, e) in self.edge_results:
                out[i] = self.edge_results[(k, e)]
            else:
                pending.append(i)
        if not pending:
            return out  # type: ignore[return-value]
        started = time.perf_counter()
        a = np.array([self.roadmaps[batch[i][0]].edges[batch[i][1], 0] for i in pending])
        b = np.array([self.roadmaps[batch[i][0]].edges[batch[i][1], 1] for i in pending])
        qa = np.array([self.roadmaps[batch[i][0]].q[n] for i, n in zip(pending, a, strict=True)])
        qb = np.array([self.roadmaps[batch[i][0]].q[n] for i, n in zip(pending, b, strict=True)])
        clear = space.motion_is_clear(qa, qb, self.settings.margin)
        self.timing["collision_s"] += time.perf_counter() - started

        jobs, members = [], []
        by_grasp: dict[int, list[int]] = {}
        for j, i in enumerate(pending):
            if not clear[j]:
                out[i] = (False, np.inf, "the gripper's motion touches an obstacle")
                continue
            by_grasp.setdefault(batch[i][0], []).append(j)
        workers = max(1, int(getattr(self.setup.problem.executor, "workers", 2) or 2))
        for k, js in by_grasp.items():
            roadmap = self.roadmaps[k]
            steps_of = {j: max(1, math.ceil(roadmap.disp[batch[pending[j]][1]] / options.step)) for j in js}
            for group in _balanced(js, steps_of, min(len(js), workers)):
                edges = []
                for j in group:
                    steps = steps_of[j]
                    edges.append(
                        {
                            "q": self._linear(qa[j], qb[j], steps),
                            "start": roadmap.positions[a[j]],
                            "end": roadmap.positions[b[j]],
                        }
                    )
                jobs.append(
                    {
                        **self.setup.chain_args(k),
                        "edges": edges,
                        "surface_nodes": self.setup.surface_nodes,
                        "branch_tolerance": options.branch_tolerance,
                    }
                )
                members.append([pending[j] for j in group])
        for index, result in self.setup.problem.executor.imap_unordered(edge_chain, jobs):
            for slot, i in enumerate(members[index]):
                weight = result["max_energy" if self.metric == "max_energy" else "max_stress"][slot]
                out[i] = (bool(result["valid"][slot]), float(weight), result["reason"][slot])
            for name in ("fem_s", "validation_s", "collision_s"):
                self.timing[name] += float(result[name])
        for i in pending:
            self.edge_results[batch[i]] = out[i]
        return out  # type: ignore[return-value]

    # ------------------------------------------------------------------ the plan
    def plan(self) -> Outcome:
        outcomes = self.start_searches()
        for _ in range(20):  # a trajectory piece that fails invalidates its edge: search again
            self.search(outcomes)
            solved = [o for o in outcomes if o.path is not None]
            if not solved:
                reasons = "; ".join(f"grasp {o.index}: {o.message}" for o in outcomes)
                message = outcomes[0].message if len(outcomes) == 1 else f"no grasp has a plan ({reasons})"
                return Outcome(outcomes, None, None, message, self.timing, len(self.edge_results))
            best = min(solved, key=lambda o: (o.path.value, o.path.length, o.index))
            started = time.perf_counter()
            trajectory, failed = self.trajectory(best)
            self.timing["smoothing_s"] += time.perf_counter() - started
            if trajectory is not None:
                return Outcome(
                    outcomes, best.index, trajectory, self._message(outcomes, best), self.timing, len(self.edge_results)
                )
            if failed < 0:  # the grasp's own state failed when re-solved: drop the grasp
                best.message, best.lazy = "the start state fails when re-simulated", None
                continue
            best.lazy.update(np.array([failed]), np.array([False]), None)
            best.lazy.done = False
        return Outcome(outcomes, None, None, "the trajectory could not be verified", self.timing, 0)

    def _message(self, outcomes: list[GraspOutcome], best: GraspOutcome) -> str:
        path = best.path
        grasp = self.roadmaps[best.index].grasp
        where = ", ".join(f"{1e3 * c:.4g}" for c in grasp[:3])
        if len(outcomes) == 1:
            return f"{len(path.nodes) - 1} roadmap edges from the grasp at ({where}) mm; {self.metric} {path.value:.4g}"
        solved = sum(o.path is not None for o in outcomes)
        return (
            f"best of {len(outcomes)} grasps ({solved} with a plan): grasp {best.index} at ({where}) mm, "
            f"{len(path.nodes) - 1} roadmap edges; {self.metric} {path.value:.4g}"
        )

    def trajectory(self, outcome: GraspOutcome) -> tuple[Trajectory | None, int]:
        """The C¹ trajectory of a grasp's path, re-simulated; or (None, the id of an edge that failed)."""
        roadmap = self.roadmaps[outcome.index]
        path = outcome.path
        nodes, edge_ids = path.nodes, path.edges
        q_path = roadmap.q[nodes]
        smooth = self.settings.smoothing
        counts = np.array([max(1, math.ceil(roadmap.disp[e] / smooth.step)) for e in edge_ids], dtype=int)
        if len(nodes) == 1:  # the grasp itself already exposes A: a trajectory of one state
            (result,) = self._simulate(outcome.index, nodes, [np.empty((0, 7))])
            if any(result["reason"]):
                return None, -1
            return self._assemble(roadmap, nodes, [np.empty((0, 7))], [result], []), -1
        if smooth.enabled and len(nodes) >= 3:
            spline = SE3Spline(parameters(roadmap.length[edge_ids]), q_path)
            pieces = [spline(u) for u in piece_parameters(spline.knots, counts)]
            kinds = ["spline"] * len(pieces)
        else:
            pieces = [self._linear(q_path[k], q_path[k + 1], c) for k, c in enumerate(counts)]
            kinds = ["linear"] * len(pieces)
        results = self._simulate(outcome.index, nodes, pieces)
        for k, (q_piece, result) in enumerate(zip(pieces, results, strict=True)):
            if self._piece_ok(roadmap, nodes, k, q_piece, result, q_path):
                continue
            steps = max(1, math.ceil(roadmap.disp[edge_ids[k]] / self.settings.roadmap.step))
            linear = self._linear(q_path[k], q_path[k + 1], steps)
            retry = self._simulate(outcome.index, nodes[k : k + 2], [linear], first=k == 0)[0]
            if not self._piece_ok(roadmap, nodes, k, linear, retry, q_path):
                return None, int(edge_ids[k])
            pieces[k], results[k], kinds[k] = linear, retry, "linear"
        return self._assemble(roadmap, nodes, pieces, results, kinds), -1

    def _assemble(self, roadmap, nodes, pieces, results, kinds) -> Trajectory:
        setup, space = self.setup, self.setup.problem.space
        q = np.concatenate([roadmap.q[nodes[:1]], *pieces])
        positions = np.concatenate([r["positions"] for r in results])
        energy = np.concatenate([r["energy"] for r in results])
        max_stress = np.concatenate([r["max_stress"] for r in results])
        stress = np.concatenate([r["stress"] for r in results])
        waypoints = np.concatenate([[0], np.cumsum([len(p) for p in pieces])])
        surface = setup.surface_nodes
        steps = np.max(np.linalg.norm(np.diff(positions[:, surface], axis=0), axis=2), axis=1)
        options = self.settings.roadmap
        d = options.disp_weight * steps + options.configuration_weight * space.distance(q[:-1], q[1:])
        value = np.maximum(energy - self.reference_energy, 0.0)
        effort = float(np.sum(d * 0.5 * (value[:-1] + value[1:])))
        visible = setup.visibility.visible(positions[-1].astype(float), setup.triangles, pose_matrices(q[-1]))
        return Trajectory(
            q,
            positions,
            energy,
            max_stress,
            stress,
            waypoints,
            kinds.count("spline"),
            kinds.count("linear"),
            visible,
            effort,
        )

    def _linear(self, qa: np.ndarray, qb: np.ndarray, steps: int) -> np.ndarray:
        t = np.arange(1, steps + 1) / steps
        return self.setup.problem.space.interpolate(np.repeat(qa[None], steps, 0), np.repeat(qb[None], steps, 0), t)

    def _simulate(self, k: int, nodes: np.ndarray, pieces: list[np.ndarray], first: bool = True) -> list[dict]:
        """States along each piece (piece j starts from the stored state of nodes[j]); the first piece
        also re-solves the start configuration, so the trajectory's states begin at the grasp."""
        roadmap = self.roadmaps[k]
        jobs = []
        for j, piece in enumerate(pieces):
            q = np.concatenate([roadmap.q[nodes[:1]], piece]) if (j == 0 and first) else piece
            jobs.append({**self.setup.chain_args(k), "q": q, "start": roadmap.positions[nodes[j]]})
        results: list[dict] = [{}] * len(jobs)
        for index, result in self.setup.problem.executor.imap_unordered(path_chain, jobs):
            results[index] = result
            for name in ("fem_s", "validation_s", "collision_s"):
                self.timing[name] += float(result[name])
        return results

    def _piece_ok(self, roadmap, nodes, k, q_piece, result, q_path) -> bool:
        """Every state valid and collision-free, the gripper's motion certified, the end on the stored branch."""
        if any(result["reason"]) or len(result["reason"]) < len(result["positions"]):
            return False
        space = self.setup.problem.space
        polyline = np.concatenate([q_path[k : k + 1], q_piece])
        started = time.perf_counter()
        clear = bool(np.all(space.motion_is_clear(polyline[:-1], polyline[1:], self.settings.margin)))
        self.timing["collision_s"] += time.perf_counter() - started
        if not clear:
            return False
        gap = disp(result["positions"][-1], roadmap.positions[nodes[k + 1]], self.setup.surface_nodes)
        return gap <= self.settings.roadmap.branch_tolerance

    # ------------------------------------------------------------------ report
    def metrics(self, outcome: Outcome) -> dict[str, Any]:
        threshold = self.settings.visibility.threshold
        candidates = []
        for o in outcome.grasps:
            roadmap = self.roadmaps[o.index]
            entry = {
                "grasp": o.index,
                "xyz_m": roadmap.grasp[:3].tolist(),
                "status": "solved" if o.path is not None else "no_path",
                "cost": o.path.value if o.path is not None else None,
                "valid_samples": int(roadmap.ok[1:].sum()),
                "goal_states": len(o.goals),
                "lazy_iterations": o.lazy.iterations if o.lazy is not None else 0,
                "validated_edges": int(o.lazy.validated.sum()) if o.lazy is not None else 0,
                "invalid_edges": int((~o.lazy.alive).sum()) if o.lazy is not None else 0,
            }
            if o.message:
                entry["message"] = o.message
            candidates.append(entry)
        metrics: dict[str, Any] = {
            "metric": self.metric,
            "grasp_candidates": candidates,
            "visibility_threshold": threshold,
            "area_points": len(self.setup.visibility.points),
            "edges_validated": outcome.validated_edges,
            "lazy_collision_s": self.timing["collision_s"],
            "lazy_mesh_validation_s": self.timing["validation_s"],
            "lazy_fem_s": self.timing["fem_s"],
            "lazy_search_s": self.timing["search_s"],
            "smoothing_s": self.timing["smoothing_s"],
            "reference_energy_J": self.reference_energy,
        }
        if outcome.best is not None:
            best = outcome.grasps[outcome.best]
            t = outcome.trajectory
            metrics.update(
                {
                    "cost": best.path.value,
                    "grasp": outcome.best,
                    "grasp_xyz_m": self.roadmaps[outcome.best].grasp[:3].tolist(),
                    "grasp_quaternion": self.roadmaps[outcome.best].grasp[3:].tolist(),
                    "roadmap_waypoints": len(best.path.nodes),
                    "trajectory_states": len(t.q),
                    "spline_pieces": t.spline_pieces,
                    "linear_pieces": t.linear_pieces,
                    "max_energy_J": float(np.max(t.energy)),
                    "max_stress_Pa": float(np.max(t.max_stress)),
                    "control_effort_Jm": t.effort,
                    "visible_fraction": float(np.mean(t.visible)),
                    "goal_reached": bool(np.mean(t.visible) >= threshold - 1e-12),
                }
            )
        return metrics


def _balanced(items: list[int], load: dict[int, int], groups: int) -> list[list[int]]:
    """Items split into ``groups`` of nearly equal total load (longest first, each to the lightest group)."""
    out: list[list[int]] = [[] for _ in range(groups)]
    totals = [0] * groups
    for item in sorted(items, key=lambda i: -load[i]):
        lightest = totals.index(min(totals))
        out[lightest].append(item)
        totals[lightest] += load[item]
    return [g for g in out if g]
