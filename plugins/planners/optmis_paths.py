"""optMIS shortest paths from one source to many targets (paper 001 §3.1).

One Dijkstra call (``scipy.sparse.csgraph.dijkstra``) from a point of
interest gives the shortest-path tree to every vertex of the search space,
hence the paths to all targets at once. Then, beyond the paper:

* *tautening* (``taut``): the graph's paths zig-zag along tetrahedron edges
  (about 6 % longer than the shortest path in the workspace on the hand-eye
  scene). Each tree vertex gets an any-angle parent, an ancestor it is
  certified to reach in a straight motion, in the manner of Theta* (Nash et
  al. 2007), by pointer jumping (:func:`taut_parents`). This keeps a *tree*,
  so paths from one source still share their common stretches exactly (what
  the segmented pathmap compresses).
* *knots*: every straight piece of a path is divided into equal intervals of
  at most ``knot_spacing``; the natural spline through these knots follows
  the straight pieces and rounds the turns (:mod:`.spline_paths`), and a piece
  shared by several paths gets the same knots in all of them.

Lengths in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import dijkstra

from .prm_roadmap import certify_edges
from .spline_paths import CHORD, GLOBAL, WINDOW, smooth_paths


@dataclass
class PathOptions:
    """How paths are drawn (all lengths in m)."""

    taut: bool = True
    #: longest straight motion tautening may create (m); inf: no limit
    max_jump: float = float("inf")
    knot_spacing: float = 0.006
    resolution: float = 0.002
    smoothing: bool = True
    window: int = 2
    margin: float = 0.0


def tree_vertices(predecessors: np.ndarray, source: int, targets: np.ndarray) -> np.ndarray:
    """Vertices on the tree paths from ``source`` to ``targets`` (walked up all at once)."""
    on_path = np.zeros(len(predecessors), dtype=bool)
    on_path[source] = True
    frontier = np.asarray(targets, dtype=np.int64)
    on_path[frontier] = True
    while frontier.size:
        frontier = predecessors[frontier]
        frontier = frontier[frontier >= 0]
        frontier = np.unique(frontier[~on_path[frontier]])
        on_path[frontier] = True
    return np.flatnonzero(on_path)


def taut_parents(space, vertices: np.ndarray, clearance: np.ndarray, predecessors: np.ndarray, source: int,
                 members: np.ndarray, margin: float, max_jump: float = np.inf) -> tuple[np.ndarray, int]:
    """Any-angle parents of the tree ``members`` by pointer jumping; the result is still a tree.

    In every round each vertex still moving tries its current grandparent:
    if the straight motion to it is certified it jumps there (and tries
    again next round), otherwise it keeps its parent for good. A vertex in
    open space reaches the source in log2(depth) rounds; behind a corner it
    stops at an ancestor it can see. Each round is one batched check
    (``clearance`` (m) of the vertices certifies many motions for free, by
    two covering balls). Returns the parents and the number of motion checks.

    This is Theta*'s idea (Nash et al. 2007: take the parent's parent when it
    is visible) applied to a finished Dijkstra tree, with rounds instead of a
    vertex-by-vertex order so that the work is a few large vectorised calls.
    """
    parent = predecessors.copy()
    parent[source] = source
    slack = clearance - margin
    active = members[members != source]
    checks = 0
    while active.size:
        grand = parent[parent[active]]
        moving = grand != parent[active]
        active, grand = active[moving], grand[moving]
        short = np.linalg.norm(vertices[active] - vertices[grand], axis=1) <= max_jump
        active, grand = active[short], grand[short]
        if not active.size:
            break
        ok, _ = certify_edges(space, vertices[active], vertices[grand], slack[active], slack[grand], margin)
        checks += len(active)
        parent[active[ok]] = grand[ok]
        active = active[ok]
    return parent, checks


def chain(parent: np.ndarray, source: int, target: int) -> np.ndarray:
    """Vertex indices from ``source`` to ``target`` following ``parent`` pointers."""
    out = [target]
    while out[-1] != source:
        out.append(int(parent[out[-1]]))
    return np.asarray(out[::-1], dtype=np.int64)


def knots_of(points: np.ndarray, knot_spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Each straight piece of the polyline ``points`` cut into equal intervals of at most ``knot_spacing``.

    Returns the knots and, per knot, whether it is a corner of the polyline
    (its start, end or a turn).
    """
    if len(points) < 2:
        return points.copy(), np.ones(len(points), dtype=bool)
    steps = np.diff(points, axis=0)
    count = np.maximum(1, np.ceil(np.linalg.norm(steps, axis=1) / knot_spacing - 1e-9).astype(np.int64))
    owner = np.repeat(np.arange(len(steps)), count)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    t = (np.arange(len(owner)) - start[owner]) / count[owner]
    knots = np.concatenate([points[owner] + t[:, None] * steps[owner], points[-1:]])
    corner = np.zeros(len(knots), dtype=bool)
    corner[np.concatenate([start, [len(knots) - 1]])] = True
    return knots, corner


def paths_from_source(space, graph, vertices: np.ndarray, clearance: np.ndarray, source: int, targets: np.ndarray,
                      options: PathOptions) -> dict:
    """optMIS paths from vertex ``source`` to each vertex in ``targets``; unreachable ones are listed.

    Returns a mapping of arrays: ``targets`` (the reachable ones, in order),
    ``reachable`` (per given target), ``unreachable``, ``points`` (all paths' samples, concatenated),
    ``path_start`` (offsets into points, one more than paths), ``corner``
    (per sample: a corner of the taut path, where segments may be anchored),
    ``graph_length`` (Dijkstra's length), ``taut_length`` and ``length`` (m),
    ``kinds`` (per path: intervals drawn by the global spline, a window
    spline, the chord) and ``checks`` (certified motion checks for tautening).
    """
    targets = np.asarray(targets, dtype=np.int64)
    distance, predecessors = dijkstra(graph, indices=int(source), return_predecessors=True)
    reachable = np.isfinite(distance[targets])
    unreachable = targets[~reachable]
    targets = targets[reachable]
    checks = 0
    if targets.size and options.taut:
        members = tree_vertices(predecessors, source, targets)
        parent, checks = taut_parents(
            space, vertices, clearance, predecessors, source, members, options.margin, options.max_jump
        )
    else:
        parent = predecessors.copy()
        parent[source] = source
    polylines = [vertices[chain(parent, source, t)] for t in targets]
    knots, corners = [], []
    for polyline in polylines:
        k, c = knots_of(polyline, options.knot_spacing)
        knots.append(k)
        corners.append(c)
    smoothed = smooth_paths(space, knots, options.resolution, options.margin, options.window, options.smoothing)
    points, corner_flags, sizes, kinds = [], [], [], []
    for path, corner in zip(smoothed, corners, strict=True):
        flags = np.zeros(len(path.points), dtype=bool)
        flags[path.knot_index[corner]] = True
        points.append(path.points)
        corner_flags.append(flags)
        sizes.append(len(path.points))
        kinds.append([np.count_nonzero(path.kinds == kind) for kind in (GLOBAL, WINDOW, CHORD)])
    return {
        "targets": targets,
        "reachable": reachable,
        "unreachable": unreachable,
        "points": np.concatenate(points) if points else np.zeros((0, 3)),
        "path_start": np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        "corner": np.concatenate(corner_flags) if corner_flags else np.zeros(0, dtype=bool),
        "graph_length": distance[targets],
        "taut_length": np.array([np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in polylines]),
        "length": np.array([p.length for p in smoothed]),
        "kinds": np.asarray(kinds, dtype=np.int64).reshape(-1, 3),
        "checks": int(checks),
    }
