"""The offline phase: equilibrium samples and roadmap per candidate grasp (paper 002 §IV-A to §IV-C).

For each initial grasp, configurations are sampled (uniform or user-guided),
ordered into warm-started chains and solved by the executor's workers with
``run_tasks`` (checkpointed: an interrupted build resumes where it
stopped; a task's key hashes everything its equilibria depend on, so a
changed setting never reuses stale states). Then each state is checked
(gripper against obstacles, certified by the ``se3`` space; flap against
obstacles; instrument against tissue) and its visibility of A measured, and
the roadmap joins each valid state to its k nearest by DISP.

Node 0 of a grasp's roadmap is the start (the flap held at the grasp at
rest); nodes 1..N are the samples.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from surgiplan.executors import TaskStore, run_tasks
from surgiplan.storage import to_jsonable

from .equilibria import assess_chunk, sample_chain
from .roadmap import knn_edges
from .sampling import sample_configurations, tour_order
from .setup import Setup


@dataclass
class GraspRoadmap:
    """One grasp's states (node 0: the start) and roadmap."""

    grasp: np.ndarray  # (7,)
    q: np.ndarray  # (N + 1, 7)
    positions: np.ndarray  # (N + 1, n, 3) float32
    energy: np.ndarray  # (N + 1,) J
    max_stress: np.ndarray  # (N + 1,) Pa
    ok: np.ndarray  # (N + 1,) valid and collision-free
    reason: list[str]  # why not ok ('' when ok)
    visible: np.ndarray  # (N + 1,) fraction of A visible
    edges: np.ndarray  # (E, 2)
    disp: np.ndarray  # (E,) DISP of each edge, m
    length: np.ndarray  # (E,) the roadmap distance d
    relief: dict[str, np.ndarray] = field(default_factory=dict)
    timing: dict[str, float] = field(default_factory=dict)

    @property
    def samples(self) -> int:
        return len(self.q) - 1

    def arrays(self) -> dict[str, Any]:
        out = {
            "grasp": self.grasp,
            "q": self.q,
            "positions": self.positions,
            "energy": self.energy,
            "max_stress": self.max_stress,
            "ok": self.ok,
            "visible": self.visible,
            "edges": self.edges,
            "disp": self.disp,
            "length": self.length,
        }
        out.update({f"relief_{k}": v for k, v in self.relief.items()})
        return out


def _digest(value: Any) -> str:
    return hashlib.sha256(json.dumps(to_jsonable(value), sort_keys=True).encode()).hexdigest()[:16]


def generate(setup: Setup) -> list[GraspRoadmap]:
    """Sample, solve, check and connect the states of every candidate grasp."""
    settings, problem = setup.settings, setup.problem
    space = problem.space
    started = time.perf_counter()
    configurations = []
    for grasp in setup.grasps:
        # the seed follows the grasp itself, so a grasp gets the same samples in any list of candidates
        offset = int(_digest(np.round(grasp, 12))[:8], 16)
        q = sample_configurations(settings.sampling, grasp, space, seed_offset=offset, goal=problem.goal)
        configurations.append(q[tour_order(space, grasp, q)])
    sampling_s = time.perf_counter() - started

    # equilibria: one task per chunk of consecutive samples of one grasp
    relief = settings.relief.model_dump()
    tasks: dict[str, dict[str, Any]] = {}
    chunks: list[tuple[int, slice]] = []
    for k, q in enumerate(configurations):
        shared = {**setup.chain_args(k), "collision": None, "relief": relief}
        identity = _digest(
            {
                "model": [f"{setup.model_class.__module__}.{setup.model_class.__qualname__}", setup.model_settings],
                "anchored": setup.frames[k].anchored,
                "grasped": setup.frames[k].grasped,
                "q0": setup.frames[k].q0,
                "relief": relief,
            }
        )
        size = settings.sampling.chunk
        for c, first in enumerate(range(0, len(q), size)):
            part = slice(first, first + size)
            key = f"grasp{k}-chunk{c:04d}-{identity}-{_digest(q[part])}"
            tasks[key] = {**shared, "configurations": q[part]}
            chunks.append((k, part))
    # keys are content hashes, so stages planning on the same model and grasps share one store
    # (scenario 2 plans twice on the same equilibria, for two metrics)
    store = TaskStore(problem.workdir.parent / "retraction-equilibria") if problem.workdir is not None else None
    started = time.perf_counter()
    results = run_tasks(
        problem.executor,
        sample_chain,
        tasks,
        store=store,
        progress=problem.progress,
        description=f"retraction: equilibria of {sum(len(q) for q in configurations)} samples "
        f"({len(setup.grasps)} grasp{'s' if len(setup.grasps) > 1 else ''})",
    )
    equilibria_s = time.perf_counter() - started

    # the start states: the flap held at each grasp at rest
    model = setup.model
    starts = [model.solve(frame.constraints(frame.q0)) for frame in setup.frames]

    roadmaps = []
    for k, q in enumerate(configurations):
        parts = [results[key] for key, (g, _) in zip(tasks, chunks, strict=True) if g == k]
        start = starts[k]
        start_reason = "" if start.converged and start.valid else f"the start state is not valid: {start.message}"
        roadmaps.append(
            GraspRoadmap(
                grasp=setup.grasps[k],
                q=np.concatenate([setup.grasps[k][None], *[p["q"] for p in parts]]),
                positions=np.concatenate(
                    [np.asarray(start.positions, np.float32)[None], *[p["positions"] for p in parts]]
                ),
                energy=np.concatenate([[start.energy], *[p["energy"] for p in parts]]),
                max_stress=np.concatenate([[float(np.max(start.stress))], *[p["max_stress"] for p in parts]]),
                ok=np.concatenate([[not start_reason], *[p["ok"] for p in parts]]),
                reason=[start_reason, *[r for p in parts for r in p["reason"]]],
                visible=np.zeros(len(q) + 1),
                edges=np.empty((0, 2), dtype=np.int64),
                disp=np.empty(0),
                length=np.empty(0),
                relief={
                    name: np.concatenate([p[name] for p in parts])
                    for name in ("relief_iterations", "relief_angle", "grasp_stress_before", "grasp_stress_after")
                },
                timing={
                    "fem_s": float(sum(p["fem_s"] for p in parts)),
                    "validation_s": float(sum(p["validation_s"] for p in parts)),
                },
            )
        )
        roadmaps[-1].relief = {k.removeprefix("relief_"): v for k, v in roadmaps[-1].relief.items()}

    started = time.perf_counter()
    assess(setup, roadmaps, [(key, g, part) for key, (g, part) in zip(tasks, chunks, strict=True)], store)
    assess_s = time.perf_counter() - started
    started = time.perf_counter()
    for roadmap in roadmaps:
        connect(setup, roadmap)
    roadmap_s = time.perf_counter() - started
    for roadmap in roadmaps:
        roadmap.timing.update(
            {
                "sampling_s": sampling_s / len(roadmaps),
                "equilibria_s": equilibria_s / len(roadmaps),
                "assess_s": assess_s / len(roadmaps),
                "roadmap_s": roadmap_s / len(roadmaps),
            }
        )
    return roadmaps


def assess(setup: Setup, roadmaps: list[GraspRoadmap], chunks: list[tuple[str, int, slice]], store) -> None:
    """Gripper clearance (here, certified by the space), flap and instrument collisions and visibility
    (workers, checkpointed next to the equilibria: a second stage on the same states and scene reuses them).

    ``chunks``: (equilibrium task key, grasp, slice of its samples) as solved.
    """
    problem, settings = setup.problem, setup.settings
    geometry = _digest(
        {
            "scene": problem.scene.spec(),
            "space": problem.space.spec(),
            "visibility": settings.visibility.model_dump(mode="json"),
            "margin": settings.margin,
            "instrument": settings.instrument_tissue_check,
        }
    )
    for roadmap in roadmaps:
        free = problem.space.is_valid(roadmap.q, settings.margin)
        for i in np.flatnonzero(roadmap.ok & ~free):
            roadmap.reason[i] = "the gripper touches an obstacle"
        roadmap.ok &= free
    tasks, where = {}, {}
    for key, k, part in chunks:
        nodes = slice(part.start + 1, part.stop + 1)  # node 0 is the start
        roadmap = roadmaps[k]
        job_key = f"{key}-assess-{geometry}-{_digest(roadmap.ok[nodes])}"
        tasks[job_key] = {
            "collision": setup.collisions[k],
            "visibility": setup.visibility,
            "triangles": setup.triangles,
            "positions": roadmap.positions[nodes],
            "q": roadmap.q[nodes],
            "ok": roadmap.ok[nodes],
        }
        where[job_key] = (k, nodes)
    for k, roadmap in enumerate(roadmaps):  # the start states, here
        job = {**next(iter(tasks.values())), "collision": setup.collisions[k]} if tasks else None
        if job is not None:
            job.update(positions=roadmap.positions[:1], q=roadmap.q[:1], ok=roadmap.ok[:1])
            _record(roadmap, slice(0, 1), assess_chunk(job))
    results = run_tasks(
        problem.executor,
        assess_chunk,
        tasks,
        store=store,
        progress=problem.progress,
        description="retraction: collisions and visibility",
    )
    for job_key, result in results.items():
        k, nodes = where[job_key]
        _record(roadmaps[k], nodes, result)


def _record(roadmap: GraspRoadmap, nodes: slice, result: dict[str, Any]) -> None:
    for offset, reason in enumerate(result["reason"]):
        if reason:
            roadmap.reason[nodes.start + offset] = reason
    roadmap.ok[nodes] &= np.array([not r for r in result["reason"]], dtype=bool)
    roadmap.visible[nodes] = np.nan_to_num(np.asarray(result["visible"], dtype=float), nan=0.0)
    roadmap.timing["collision_s"] = roadmap.timing.get("collision_s", 0.0) + float(result["collision_s"])
    roadmap.timing["visibility_s"] = roadmap.timing.get("visibility_s", 0.0) + float(result["visibility_s"])


def connect(setup: Setup, roadmap: GraspRoadmap) -> None:
    """Edges between valid states: k nearest by DISP, lengths d = w_D DISP + w_C d_SE3."""
    options = setup.settings.roadmap
    nodes = np.flatnonzero(roadmap.ok)
    surface = roadmap.positions[nodes][:, setup.surface_nodes]
    pairs, disp = knn_edges(surface, options.k, options.max_distance)
    edges = nodes[pairs] if len(pairs) else np.empty((0, 2), dtype=np.int64)
    length = options.disp_weight * disp
    if options.configuration_weight > 0 and len(edges):
        length = length + options.configuration_weight * setup.problem.space.distance(
            roadmap.q[edges[:, 0]], roadmap.q[edges[:, 1]]
        )
    roadmap.edges, roadmap.disp, roadmap.length = edges, disp, length
