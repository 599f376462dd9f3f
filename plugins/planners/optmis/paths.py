"""optMIS shortest paths from sources to many targets (paper 001 §3.1).

One Dijkstra call (``scipy.sparse.csgraph.dijkstra``) from a point of
interest gives the shortest-path tree to every vertex of the search space,
hence the paths to all targets at once. Then, beyond the paper:

* *tautening* (``taut``): the graph's paths zig-zag along tetrahedron edges
  (about 6-7 % longer than the shortest path on the hand-eye scene). Each
  tree vertex gets an any-angle parent, an ancestor it is certified to reach
  in a straight motion, in the manner of Theta* (Nash et al. 2007), by
  pointer jumping (:func:`taut_parents`). This keeps a *tree*, so paths from
  one source still share their common stretches exactly (what the segmented
  pathmap compresses); ``max_jump`` bounds the jumps, trading length for
  more sharing.
* *turn refinement* (``refine``): a turn stays where the zig-zag path
  happened to round the obstacle; :func:`refine_corners` slides it along the
  obstacle's edge to where the path is shortest and in as close as the legs
  allow (shortest paths among polyhedra bend on their edges).
* *knots*: every straight piece is cut into equal intervals of at most
  ``knot_spacing``, with a knot ``turn_radius`` either side of each turn;
  the natural spline through them follows the straight pieces and rounds the
  turns locally (:mod:`.spline_paths`).

Several sources are processed together (:func:`paths_from_sources`) so that
they share each batched certified check.

Lengths in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import dijkstra
from surgiplan.paths import CHORD, GLOBAL, WINDOW, certify_edges, smooth_paths


@dataclass
class PathOptions:
    """How paths are drawn (all lengths in m)."""

    taut: bool = True
    #: longest straight motion tautening may create (m); inf: no limit
    max_jump: float = float("inf")
    #: slide the corners of taut paths to where the paths are shortest ...
    refine: bool = True
    #: ... passing them this close (m) beyond the margin
    floor: float = 0.00001
    #: the spline rounds each turn within about this distance (m) of it
    turn_radius: float = 0.001
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


def taut_parents(
    space,
    vertices: np.ndarray,
    clearance: np.ndarray,
    predecessors: np.ndarray,
    source,
    members: np.ndarray,
    margin: float,
    max_jump: float = np.inf,
) -> tuple[np.ndarray, int]:
    """Any-angle parents of the tree(s) ``members`` by pointer jumping; the result is still a tree.

    ``source``: the root vertex, or an array of roots (a forest: see :func:`paths_from_sources`).

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
    active = members[~np.isin(members, source)]
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


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=1), 1e-15)[:, None]


def edge_directions(space, points: np.ndarray) -> np.ndarray:
    """The direction of the obstacle edge each point is near (unit vectors), or zero where there is none.

    Near an edge the clearance is the distance to a line: constant along the
    line, and curved (curvature 1/distance) around it. So in the plane
    orthogonal to the clearance gradient, the direction of least curvature is
    the edge, if the other direction is strongly curved; beside a flat face
    both are flat, near a corner both are curved: no edge. Finite
    differences, one batched clearance call.
    """
    n = len(points)
    clearance = space.clearance(points)
    h = 1e-6
    grad_offsets = np.concatenate([np.eye(3), -np.eye(3)]) * h
    values = space.clearance((points[:, None, :] + grad_offsets[None]).reshape(-1, 3)).reshape(n, 6)
    normal = _unit((values[:, :3] - values[:, 3:]) / (2 * h))
    # an orthonormal basis (u, v) of the tangent plane
    helper = np.where(np.abs(normal[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    u = _unit(np.cross(normal, helper))
    v = np.cross(normal, u)
    w = _unit(u + v)
    step = np.maximum(0.2 * np.abs(clearance), 2e-6)[:, None, None]
    directions = np.stack([u, v, w], axis=1)  # (n, 3, 3)
    probes = np.concatenate([points[:, None] + step * directions, points[:, None] - step * directions], axis=1)
    c = space.clearance(probes.reshape(-1, 3)).reshape(n, 6)
    curvature = (c[:, :3] + c[:, 3:] - 2 * clearance[:, None]) / step[:, :, 0] ** 2
    kuu, kvv, kww = curvature[:, 0], curvature[:, 1], curvature[:, 2]
    kuv = kww - 0.5 * (kuu + kvv)
    hessian = np.stack([np.stack([kuu, kuv], -1), np.stack([kuv, kvv], -1)], -2)
    eigenvalues, eigenvectors = np.linalg.eigh(hessian)
    scale = 1.0 / np.maximum(np.abs(clearance), 1e-9)
    edge = (eigenvalues[:, 1] > 0.3 * scale) & (np.abs(eigenvalues[:, 0]) < 0.05 * scale)
    along = eigenvectors[:, 0, 0][:, None] * u + eigenvectors[:, 1, 0][:, None] * v
    return np.where(edge[:, None], _unit(along), 0.0)


def refine_corners(
    space, polylines: list[np.ndarray], margin: float, floor: float, iterations: int = 12
) -> tuple[list[np.ndarray], int]:
    """Slide the corners of taut paths along the obstacle edges to where the paths are shortest.

    Tautening keeps each turn at the vertex where the zig-zag graph path
    happened to round the obstacle's edge; the shortest path turns at the
    point of that edge that makes it shortest (in 3D, shortest paths among
    polyhedra bend on edges). Every interior corner near an edge
    (:func:`edge_directions`) moves along the edge to the point that
    minimises |a - x| + |x - c| (in closed form: unfold the two legs into one
    plane), even and odd corners in turn, and is pushed back out to ``floor``
    (m) of clearance if it came closer (a curved edge); finally it moves in
    towards the edge as far as both its legs keep ``floor`` of clearance, so
    that the path wraps the edge as closely as a polyline can.
    Afterwards every motion of a path is certified (keeping ``margin``) and
    inside the bounds; a path that fails is tried halfway between its old and
    new corners, then kept as it was. Returns the paths and the number of
    motion checks.
    """
    sizes = np.array([len(p) for p in polylines])
    if not len(polylines) or sizes.max() < 3:
        return polylines, 0
    points = np.concatenate(polylines)
    start = np.concatenate([[0], np.cumsum(sizes)])
    interior = np.ones(len(points), dtype=bool)
    interior[start[:-1]] = False
    interior[start[1:] - 1] = False
    moving = np.flatnonzero(interior)
    edge = edge_directions(space, points[moving])
    moving, edge = moving[np.any(edge != 0, axis=1)], edge[np.any(edge != 0, axis=1)]
    x = points.copy()
    # even and odd corners in turn, so that each moves with its neighbours fixed (Gauss-Seidel)
    parity = (moving - start[np.searchsorted(start, moving, side="right") - 1]) % 2
    for k in range(iterations if len(moving) else 0):
        now = parity == k % 2
        corner, direction = moving[now], edge[now]
        here, before, after = x[corner], x[corner - 1], x[corner + 1]
        # the shortest way from a over the edge's line to c, unfolded into a plane:
        # s* = z_a + (z_c - z_a) r_a / (r_a + r_c), z along the edge and r the distance from it
        za = np.sum((before - here) * direction, axis=1)
        zc = np.sum((after - here) * direction, axis=1)
        ra = np.linalg.norm(before - here - za[:, None] * direction, axis=1)
        rc = np.linalg.norm(after - here - zc[:, None] * direction, axis=1)
        slide = za + (zc - za) * ra / np.maximum(ra + rc, 1e-15)
        candidate = here + slide[:, None] * direction
        low = space.clearance(candidate) < floor
        if np.any(low):  # a curved edge: back out to the floor along the clearance gradient
            offsets = np.concatenate([np.eye(3), -np.eye(3)]) * 1e-6
            values = space.clearance((candidate[low][:, None] + offsets[None]).reshape(-1, 3)).reshape(-1, 6)
            normal = _unit(values[:, :3] - values[:, 3:])
            candidate[low] += (floor - space.clearance(candidate[low]))[:, None] * normal
        x[corner] = candidate
    levels = np.array([1.0, 0.9, 0.75, 0.5, 0.25, 0.0])
    for k in range(2 if len(moving) else 0):
        # then in, towards the edge, as far as both legs keep the floor: the path wraps the edge as
        # closely as a polyline can (a few push levels, all tried in one batched check)
        corner = moving[parity == k]
        if not corner.size:
            continue
        here = x[corner]
        offsets = np.concatenate([np.eye(3), -np.eye(3)]) * 1e-6
        values = space.clearance((here[:, None] + offsets[None]).reshape(-1, 3)).reshape(-1, 6)
        normal = _unit(values[:, :3] - values[:, 3:])
        push = np.maximum(space.clearance(here) - floor, 0.0)
        trial = here[None] - (levels[:, None, None] * push[None, :, None]) * normal[None]  # (levels, corners, 3)
        before = np.broadcast_to(x[corner - 1], trial.shape).reshape(-1, 3)
        after = np.broadcast_to(x[corner + 1], trial.shape).reshape(-1, 3)
        flat = trial.reshape(-1, 3)
        ok = space.motion_is_clear(np.concatenate([before, flat]), np.concatenate([flat, after]), floor)
        ok = ok.reshape(2, len(levels), len(corner)).all(axis=0)
        ok[-1] = True  # not moving at all is always allowed
        x[corner] = trial[np.argmax(ok, axis=0), np.arange(len(corner))]
    checks = 0
    accepted = np.zeros(len(polylines), dtype=bool)
    result = [p.copy() for p in polylines]
    owner = np.repeat(np.arange(len(polylines)), np.maximum(sizes - 1, 0))
    first = np.concatenate([start[k] + np.arange(sizes[k] - 1) for k in range(len(sizes))])
    for trial in (x, 0.5 * (x + points)):
        todo = ~accepted[owner]
        if not np.any(todo):
            break
        a, b = trial[first[todo]], trial[first[todo] + 1]
        ok = space.motion_is_clear(a, b, margin) & space.scene.in_bounds(a) & space.scene.in_bounds(b)
        checks += int(np.count_nonzero(todo))
        bad = np.bincount(owner[todo], weights=~ok, minlength=len(polylines))
        tried = np.bincount(owner[todo], minlength=len(polylines)) > 0
        for k in np.flatnonzero((bad == 0) & tried & ~accepted):
            candidate = trial[start[k] : start[k + 1]]
            if _length(candidate) < _length(polylines[k]):
                result[k] = candidate.copy()
            accepted[k] = True
    return result, checks


def _length(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def chain(parent: np.ndarray, source: int, target: int) -> np.ndarray:
    """Vertex indices from ``source`` to ``target`` following ``parent`` pointers."""
    out = [target]
    while out[-1] != source:
        out.append(int(parent[out[-1]]))
    return np.asarray(out[::-1], dtype=np.int64)


def knots_of(points: np.ndarray, knot_spacing: float, turn_radius: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Knots for the spline through the polyline ``points``, and which of them are its corners.

    Each straight piece gets a knot at ``turn_radius`` from each of its ends
    that is a turn (so the spline rounds a turn within about that distance and
    stays straight elsewhere), and the rest of the piece is cut into equal
    intervals of at most ``knot_spacing``. A piece shared by several paths
    gets the same knots in all of them, except within ``turn_radius`` of turns
    where they part.
    """
    if len(points) < 2:
        return points.copy(), np.ones(len(points), dtype=bool)
    knots, corner = [], []
    last = len(points) - 2
    for i in range(len(points) - 1):
        a, b = points[i], points[i + 1]
        length = float(np.linalg.norm(b - a))
        lead = turn_radius if (i > 0 and length > 4 * turn_radius) else 0.0
        tail = turn_radius if (i < last and length > 4 * turn_radius) else 0.0
        inner = length - lead - tail
        count = max(1, int(np.ceil(inner / knot_spacing - 1e-9)))
        t = np.concatenate(
            [
                [0.0],
                ([lead / length] if lead else []),
                (lead + inner * np.arange(1, count) / count) / length,
                ([1.0 - tail / length] if tail else []),
            ]
        )
        knots.append(a + t[:, None] * (b - a))
        flags = np.zeros(len(t), dtype=bool)
        flags[0] = True
        corner.append(flags)
    knots.append(points[-1:])
    corner.append(np.ones(1, dtype=bool))
    return np.concatenate(knots), np.concatenate(corner)


def paths_from_sources(
    space, graph, vertices: np.ndarray, clearance: np.ndarray, sources, targets, options: PathOptions
) -> list[dict]:
    """optMIS paths from each vertex in ``sources`` to each vertex of its ``targets`` array.

    The sources are processed together: one Dijkstra call for all of them,
    and the tautening, refinement and smoothing of all their paths in shared
    batched checks (each check has a fixed cost, which several sources then
    share). The trees are kept apart by giving tree t the vertex indices
    ``t * V + v``. Returns, per source, what :func:`paths_from_source` returns.
    """
    sources = np.atleast_1d(np.asarray(sources, dtype=np.int64))
    count, n = len(sources), len(vertices)
    distance, predecessors = dijkstra(graph, indices=sources, return_predecessors=True)
    distance, predecessors = np.atleast_2d(distance), np.atleast_2d(predecessors)
    offset = np.arange(count, dtype=np.int64) * n
    roots = sources + offset
    flat = np.where(predecessors >= 0, predecessors + offset[:, None], -9999).reshape(-1)
    per_source = []
    members = []
    for t in range(count):
        wanted = np.asarray(targets[t], dtype=np.int64)
        reachable = np.isfinite(distance[t, wanted])
        per_source.append((wanted, reachable))
        if reachable.any() and options.taut:
            members.append(tree_vertices(predecessors[t], int(sources[t]), wanted[reachable]) + offset[t])
    checks = 0
    tiled_vertices = np.tile(vertices, (count, 1)) if count > 1 else vertices
    tiled_clearance = np.tile(clearance, count) if count > 1 else clearance
    if members:
        parent, checks = taut_parents(
            space,
            tiled_vertices,
            tiled_clearance,
            flat,
            roots,
            np.concatenate(members),
            options.margin,
            options.max_jump,
        )
    else:
        parent = flat.copy()
        parent[roots] = roots
    owner, polylines = [], []
    for t, (wanted, reachable) in enumerate(per_source):
        for target in wanted[reachable]:
            polylines.append(tiled_vertices[chain(parent, int(roots[t]), int(target + offset[t]))])
            owner.append(t)
    if polylines and options.taut and options.refine:
        polylines, refine_checks = refine_corners(space, polylines, options.margin, options.margin + options.floor)
        checks += refine_checks
    knots, corners = [], []
    for polyline in polylines:
        k, c = knots_of(polyline, options.knot_spacing, options.turn_radius)
        knots.append(k)
        corners.append(c)
    smoothed = smooth_paths(space, knots, options.resolution, options.margin, options.window, options.smoothing)
    owner = np.asarray(owner, dtype=np.int64)
    out = []
    for t, (wanted, reachable) in enumerate(per_source):
        mine = np.flatnonzero(owner == t)
        points, corner_flags, sizes, kinds = [], [], [], []
        for k in mine:
            path = smoothed[k]
            flags = np.zeros(len(path.points), dtype=bool)
            flags[path.knot_index[corners[k]]] = True
            points.append(path.points)
            corner_flags.append(flags)
            sizes.append(len(path.points))
            kinds.append([np.count_nonzero(path.kinds == kind) for kind in (GLOBAL, WINDOW, CHORD)])
        out.append(
            {
                "targets": wanted[reachable],
                "reachable": reachable,
                "unreachable": wanted[~reachable],
                "points": np.concatenate(points) if points else np.zeros((0, 3)),
                "path_start": np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
                "corner": np.concatenate(corner_flags) if corner_flags else np.zeros(0, dtype=bool),
                "graph_length": distance[t, wanted[reachable]],
                "taut_length": np.array([_length(polylines[k]) for k in mine]),
                "length": np.array([smoothed[k].length for k in mine]),
                "kinds": np.asarray(kinds, dtype=np.int64).reshape(-1, 3),
                "checks": int(checks) if t == 0 else 0,
            }
        )
    return out


def paths_from_source(
    space, graph, vertices: np.ndarray, clearance: np.ndarray, source: int, targets: np.ndarray, options: PathOptions
) -> dict:
    """optMIS paths from vertex ``source`` to each vertex in ``targets``; unreachable ones are listed.

    Returns a mapping of arrays: ``targets`` (the reachable ones, in order),
    ``reachable`` (per given target), ``unreachable``, ``points`` (all
    paths' samples, concatenated), ``path_start`` (offsets into points, one
    more than paths), ``corner`` (per sample: a corner of the taut path, where
    segments may be anchored), ``graph_length`` (Dijkstra's length),
    ``taut_length`` and ``length`` (m), ``kinds`` (per path: intervals drawn
    by the global spline, a window spline, the chord) and ``checks``
    (certified motion checks for tautening and refinement).
    """
    return paths_from_sources(space, graph, vertices, clearance, [source], [targets], options)[0]
