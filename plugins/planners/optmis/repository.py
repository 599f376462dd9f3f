"""The optMIS path repository P: optimal paths between every pair of points of interest (paper 001 §3.1, §4.1).

For N points of interest the repository holds the N(N-1)/2 paths P_i (paper
001 eq. 2), each an array of 3D points, or reports the pair as unreachable
(paper 001 §6 eliminates points of interest the instrument cannot reach; we
list every such pair instead of dropping it silently).

The work is one task per group of source points of interest (one Dijkstra
call gives a source's paths to all later points of interest) and runs on the
pipeline's executor (a local process pool, or a dask cluster) with a
progress bar. It is *resumable*: each finished group is checkpointed atomically
(:class:`surgiplan.TaskStore`) in ``<output>/.work/optmis-<key>/``, where key
is a hash of everything the paths depend on (scene, tip, points of interest,
search-space and path settings); the search space itself is stored there
too. A run that is interrupted and started again loads what is finished and
computes only the rest; an ``optmis`` and a ``segmented_astar`` stage with
the same settings in one pipeline share the work.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from surgiplan.executors import Executor, InlineExecutor, TaskStore, run_tasks
from surgiplan.progress import NullProgress, Progress
from surgiplan.storage import load_bundle, save_bundle

from .paths import PathOptions, paths_from_sources
from .search_space import SearchGraph, build_search_graph, edge_graph

log = logging.getLogger(__name__)

#: bump when the checkpoint layout or the path computation changes
CHECKPOINT_VERSION = 2


@dataclass
class SearchOptions:
    """How the search space is seeded (lengths in m); see :mod:`.optmis_graph`."""

    grid_spacing: float = 0.006
    surface_spacing: float = 0.003
    surface_gap: float = 0.0001
    neighbours: int = 12
    seed: int = 0


@dataclass
class Repository:
    """All-pairs optMIS paths between the points of interest ``names`` at ``pois`` (N, 3) m.

    Path k joins ``pairs[k] = (i, j)`` with i < j, from i to j; its samples
    are ``points[path_start[k]:path_start[k + 1]]``. ``corner`` flags the
    samples where the taut path turns (and its ends). ``graph_length``,
    ``taut_length`` and ``length`` (m): Dijkstra's length in the search
    space, after tautening, and of the stored (smoothed) path. ``kinds``
    counts each path's knot intervals drawn by the global spline, a window
    spline and the chord. ``unreachable`` (U, 2): pairs with no path.
    """

    names: list[str]
    pois: np.ndarray
    pairs: np.ndarray
    path_start: np.ndarray
    points: np.ndarray
    corner: np.ndarray
    graph_length: np.ndarray
    taut_length: np.ndarray
    length: np.ndarray
    kinds: np.ndarray
    unreachable: np.ndarray
    stats: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.names)
        self._index = np.full(n * n, -1, dtype=np.int64)
        if len(self.pairs):
            self._index[self.pairs[:, 0] * n + self.pairs[:, 1]] = np.arange(len(self.pairs))

    @property
    def n_paths(self) -> int:
        return len(self.pairs)

    def path(self, k: int) -> np.ndarray:
        return self.points[self.path_start[k] : self.path_start[k + 1]]

    def paths(self) -> list[np.ndarray]:
        return [self.path(k) for k in range(self.n_paths)]

    def index(self, i: int, j: int) -> int:
        """Index of the stored path joining points of interest i and j (either order), -1 if none."""
        lo, hi = min(i, j), max(i, j)
        return int(self._index[lo * len(self.names) + hi]) if lo != hi else -1

    def between(self, i: int, j: int) -> np.ndarray | None:
        """The path from point of interest i to j (reversed from storage when i > j), or None if unreachable."""
        if i == j:
            return self.pois[i][None].copy()
        k = self.index(i, j)
        if k < 0:
            return None
        path = self.path(k)
        return path.copy() if i < j else path[::-1].copy()

    def summary(self) -> dict:
        n = len(self.names)
        out = {
            "points_of_interest": n,
            "pairs": n * (n - 1) // 2,
            "paths": int(self.n_paths),
            "unreachable_pairs": len(self.unreachable),
            "repository_points": len(self.points),
        }
        if self.n_paths:
            out.update(
                {
                    "mean_path_length_m": float(self.length.mean()),
                    "graph_over_final_length": float(np.mean(self.graph_length / np.maximum(self.length, 1e-15))),
                    "smoothing_intervals": {
                        "spline": int(self.kinds[:, 0].sum()),
                        "window_spline": int(self.kinds[:, 1].sum()),
                        "chord": int(self.kinds[:, 2].sum()),
                    },
                }
            )
        if len(self.unreachable):
            out["unreachable_examples"] = [
                f"{self.names[i]}-{self.names[j]}" for i, j in self.unreachable[:10].tolist()
            ]
        return {**out, **self.stats}

    # ------------------------------------------------------------------ storage
    def to_arrays(self) -> dict:
        return {
            "poi_names": json.dumps(self.names),
            "pois": self.pois,
            "pairs": self.pairs.astype(np.int32),
            "path_start": self.path_start.astype(np.int64),
            "points": self.points,
            "corner": self.corner,
            "graph_length": self.graph_length,
            "taut_length": self.taut_length,
            "length": self.length,
            "kinds": self.kinds.astype(np.int32),
            "unreachable": self.unreachable.astype(np.int32).reshape(-1, 2),
            "repository_stats": json.dumps(self.stats),
        }

    @classmethod
    def from_arrays(cls, data) -> Repository:
        names = json.loads(str(data["poi_names"]))
        repo = cls(
            names,
            np.asarray(data["pois"], float).reshape(-1, 3),
            np.asarray(data["pairs"], np.int64).reshape(-1, 2),
            np.asarray(data["path_start"], np.int64),
            np.asarray(data["points"], float).reshape(-1, 3),
            np.asarray(data["corner"], bool),
            np.asarray(data["graph_length"], float),
            np.asarray(data["taut_length"], float),
            np.asarray(data["length"], float),
            np.asarray(data["kinds"], np.int64).reshape(-1, 3),
            np.asarray(data["unreachable"], np.int64).reshape(-1, 2),
            json.loads(str(data.get("repository_stats", "{}"))),
        )
        repo.validate()
        return repo

    def validate(self) -> None:
        n, p = len(self.names), len(self.pairs)
        if self.pois.shape != (n, 3):
            raise ValueError("points of interest do not match their names")
        if len(self.path_start) != p + 1 or self.path_start[0] != 0 or self.path_start[-1] != len(self.points):
            raise ValueError("path offsets do not match the points")
        if np.any(np.diff(self.path_start) < 1):
            raise ValueError("empty path")
        if len(self.corner) != len(self.points):
            raise ValueError("corner flags do not match the points")
        for name in ("graph_length", "taut_length", "length", "kinds"):
            if len(getattr(self, name)) != p:
                raise ValueError(f"{name} does not match the paths")
        pairs = np.concatenate([self.pairs, self.unreachable])
        if len(pairs) and (pairs.min() < 0 or pairs.max() >= n or np.any(pairs[:, 0] >= pairs[:, 1])):
            raise ValueError("pair indices out of range")


# ----------------------------------------------------------------------------- the tasks

_GRAPH_CACHE: dict[str, object] = {}


def _cached_graph(digest: str, vertices: np.ndarray, edges: np.ndarray):
    """The CSR graph for ``digest``, built once per worker process (tasks of one build share it)."""
    graph = _GRAPH_CACHE.get(digest)
    if graph is None:
        _GRAPH_CACHE.clear()
        graph = _GRAPH_CACHE[digest] = edge_graph(vertices, edges)
    return graph


def sources_task(item: dict) -> dict:
    """A group of source points of interest: their paths to all later ones (runs on an executor's worker)."""
    graph = _cached_graph(item["digest"], item["vertices"], item["edges"])
    started = time.perf_counter()
    sources = [int(s) for s in item["source_pois"]]
    vertex = np.asarray(item["poi_vertex"], np.int64)
    n = len(vertex)
    results = paths_from_sources(
        item["space"],
        graph,
        item["vertices"],
        item["clearance"],
        vertex[sources],
        [vertex[s + 1 : n] for s in sources],
        PathOptions(**item["options"]),
    )
    pairs, unreachable, sizes = [], [], []
    for s, r in zip(sources, results, strict=True):
        later = np.arange(s + 1, n)  # reported as point-of-interest indices, not vertex indices
        pairs.append(np.stack([np.full(int(r["reachable"].sum()), s), later[r["reachable"]]], axis=1))
        unreachable.append(np.stack([np.full(int((~r["reachable"]).sum()), s), later[~r["reachable"]]], axis=1))
        sizes.append(np.diff(r["path_start"]))

    def cat(key, shape):
        parts = [np.asarray(r[key]) for r in results]
        return np.concatenate(parts) if parts else np.zeros(shape)

    sizes = np.concatenate(sizes) if sizes else np.zeros(0, np.int64)
    return {
        "pairs": np.concatenate(pairs).astype(np.int64).reshape(-1, 2),
        "unreachable": np.concatenate(unreachable).astype(np.int64).reshape(-1, 2),
        "path_start": np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        "points": cat("points", (0, 3)).reshape(-1, 3),
        "corner": cat("corner", (0,)).astype(bool),
        "graph_length": cat("graph_length", (0,)),
        "taut_length": cat("taut_length", (0,)),
        "length": cat("length", (0,)),
        "kinds": cat("kinds", (0, 3)).reshape(-1, 3).astype(np.int64),
        "checks": int(sum(r["checks"] for r in results)),
        "seconds": time.perf_counter() - started,
    }


# ----------------------------------------------------------------------------- the build


def offline_key(space, names: list[str], pois: np.ndarray, search: SearchOptions, paths: PathOptions) -> str:
    """Hash of everything the repository depends on."""
    identity = {
        "version": CHECKPOINT_VERSION,
        "scene": space.scene.spec(),
        "space": space.spec(),
        "points": {name: p.tolist() for name, p in zip(names, pois, strict=True)},
        "search": asdict(search),
        "paths": asdict(paths),
    }
    return hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()


def checkpoint_dir(workdir: Path | None, key: str) -> Path | None:
    """Where the checkpoints of this repository live: shared by every stage of the run with the same key."""
    if workdir is None:
        return None
    return Path(workdir).parent / f"optmis-{key[:16]}"


def _load_graph(path: Path, key: str) -> SearchGraph | None:
    try:
        arrays, meta = load_bundle(path)
        if meta.get("key") != key:
            return None
        return SearchGraph(
            arrays["vertices"], arrays["clearance"], arrays["edges"], arrays["poi_vertex"], float(meta["margin"])
        )
    except (ValueError, KeyError) as exc:
        log.warning("ignoring the damaged search-space checkpoint %s (%s); rebuilding it", path, exc)
        return None


def search_space(
    space,
    names: list[str],
    pois: np.ndarray,
    search: SearchOptions,
    margin: float,
    *,
    store_dir: Path | None = None,
    key: str = "",
    progress: Progress | None = None,
) -> SearchGraph:
    """The search space, loaded from ``store_dir`` when a finished one for ``key`` is there."""
    progress = progress or NullProgress()
    path = store_dir / "search_space.npz" if store_dir is not None else None
    if path is not None and path.is_file():
        graph = _load_graph(path, key)
        if graph is not None:
            return graph
    with progress.task("optMIS search space (Delaunay)", total=1) as task:
        graph = build_search_graph(
            space,
            pois,
            grid_spacing=search.grid_spacing,
            surface_spacing=search.surface_spacing,
            surface_gap=search.surface_gap,
            neighbours=search.neighbours,
            margin=margin,
            seed=search.seed,
            names=names,
        )
        task.advance(1)
    if path is not None:
        save_bundle(
            path,
            {
                "vertices": graph.vertices,
                "clearance": graph.clearance,
                "edges": graph.edges,
                "poi_vertex": graph.poi_vertex,
            },
            {"key": key, "margin": graph.margin},
        )
    return graph


def source_groups(n: int, group: int) -> list[list[int]]:
    """Sources 0..n-2 in groups of about equal work (source i has n - 1 - i paths), at most ``group`` per group."""
    work = np.arange(n - 1, 0, -1)  # paths per source
    if not len(work):
        return []
    target = max(work.sum() / max(1, int(np.ceil((n - 1) / group))), 1)
    groups, current, load = [], [], 0
    for source, paths in enumerate(work):
        current.append(source)
        load += paths
        if load >= target or len(current) == group:
            groups.append(current)
            current, load = [], 0
    if current:
        groups.append(current)
    return groups


def build_repository(
    space,
    graph: SearchGraph,
    names: list[str],
    pois: np.ndarray,
    options: PathOptions,
    *,
    executor: Executor | None = None,
    progress: Progress | None = None,
    store_dir: Path | None = None,
    group: int = 4,
) -> Repository:
    """All-pairs paths, one executor task per group of sources; resumable through ``store_dir``.

    Grouping sources lets their checks share the fixed cost of each batched
    call; groups hold about equal numbers of paths (early sources have more)
    and at most ``group`` sources, so a resumed run loses little.
    """
    executor = executor or InlineExecutor()
    started = time.perf_counter()
    n = len(names)
    common = {
        "space": space,
        "vertices": graph.vertices,
        "clearance": graph.clearance,
        "edges": graph.edges,
        "digest": graph.digest(),
        "options": asdict(options),
        "poi_vertex": graph.poi_vertex,
    }
    tasks = {f"sources-{g[0]:04d}-{g[-1]:04d}": {**common, "source_pois": g} for g in source_groups(n, group)}
    store = TaskStore(store_dir / "paths") if store_dir is not None else None
    resumed = sum(1 for key in tasks if store is not None and key in store)
    results = run_tasks(
        executor,
        sources_task,
        tasks,
        store=store,
        progress=progress,
        description=f"optMIS paths ({n} points of interest, {n * (n - 1) // 2} pairs)",
    )
    parts = [results[key] for key in tasks]

    def cat(key, shape, dtype=float):
        arrays = [np.asarray(r[key], dtype).reshape((-1, *shape[1:])) for r in parts]
        return np.concatenate(arrays) if arrays else np.zeros(shape, dtype)

    offsets = [0]
    for r in parts:
        offsets.extend((offsets[-1] + np.asarray(r["path_start"], np.int64)[1:]).tolist())
    repository = Repository(
        list(names),
        np.asarray(pois, float),
        cat("pairs", (0, 2), np.int64),
        np.asarray(offsets, dtype=np.int64),
        cat("points", (0, 3)),
        cat("corner", (0,), bool),
        cat("graph_length", (0,)),
        cat("taut_length", (0,)),
        cat("length", (0,)),
        cat("kinds", (0, 3), np.int64),
        cat("unreachable", (0, 2), np.int64),
        {
            "tautening_checks": int(sum(int(r["checks"]) for r in parts)),
            "task_seconds": float(sum(float(r["seconds"]) for r in parts)),
            "paths_s": time.perf_counter() - started,
            "tasks": len(tasks),
            "resumed_tasks": resumed,
            "executor": executor.describe(),
        },
    )
    repository.validate()
    return repository
