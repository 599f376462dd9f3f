"""optmis + segmented_astar on the hand-eye block world (paper 001 §6), side by side with the paper and OMPL.

Paper 001: 80 points of interest, about 1,300 paths, about 7 hours offline;
1.46 MB of paths compressed to 419 KB (m = 3.45) with 3-point segments; 44 ms
per online path. On configs/scenes/hand_eye.yaml (80 points, w_tip = 0.4 mm):

1. Offline: the all-pairs repository (search space, 3,160 paths) on the local
   executor with 2 workers, from scratch, median of ``--repeat`` runs
   (target <= 60 s).
2. Pathmap: m = length(P)/|S| for n_s = 3 (target >= 3.45) and the largest
   reconstruction error (<= w_tip), for the paper's encoding (every point of
   the paths) and the thinned one (Douglas-Peucker within w_tip / 4 with
   certified chords, then common segments within 3 w_tip / 4: every stored
   point within w_tip of its rebuilt path); paper 001 Table 1 for n_s = 2..5
   as ``optmis_table1.csv`` / ``.png`` (paper's method, ours, ours thinned,
   and the paper's figures).
3. Online: segmented A* per query, median over >= 1000 random pairs of points
   of interest and over 1000 random pairs of free points (linked to the
   pathmap; pairs in line of sight get the straight motion, and their share
   and both medians are reported apart; target <= 1 ms); side by side: the optMIS search in the search space for
   arbitrary points (the paper's offline-only planner took 67.6 s) and OMPL's
   RRT-Connect through the bridge (target <= 1 ms; paper 44 ms).
4. Path quality: the stored optMIS path against two independent references:
   an edge visibility graph (shortest paths among polyhedra bend on their
   edges: every obstacle edge sampled every 2 mm, the samples offset so that
   legs along a face clear the tip, all certified straight motions between
   them and the points of interest, Dijkstra; built without any optMIS code),
   for all pairs; and OMPL's RRT* given generous time on a sample of pairs;
   and the exact straight line for pairs in line of sight (target: within 3 %
   on average).
5. The compression/quality trade-off: the same search space, paths drawn
   taut and refined (default), taut only, with tautening jumps of at most
   20 mm and 10 mm, and as the search space's own paths (the paper's): mean
   length against the visibility-graph reference and m for n_s = 3.
6. A replanning instance like paper 001 Fig. 6 (``optmis_replanning.png``).

Writes ``benchmarks/results/optmis.json`` (+ the CSV and PNGs). Timings on a
shared machine are noisy: medians, and the machine's load is recorded.

    python benchmarks/bench_optmis.py [--quick] [--repeat N]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, median_time, package_version, save, table
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from surgiplan import LocalExecutor, PlanningProblem, load_scene
from surgiplan.plugins.planners.optmis.offline import OptMISSettings, run_offline
from surgiplan.plugins.planners.optmis.paths import PathOptions
from surgiplan.plugins.planners.optmis.planner import search_between
from surgiplan.plugins.planners.optmis.repository import build_repository
from surgiplan.plugins.planners.segmented_astar.pathmap import build_pathmap, reconstruction_error
from surgiplan.plugins.planners.segmented_astar.report import PAPER_M, table1, write_report
from surgiplan.plugins.planners.segmented_astar.search import SegmentedAStar, SegmentedAStarSettings
from surgiplan.spaces import R3Space

ROOT = Path(__file__).resolve().parent.parent
TIP_RADIUS = 0.0002  # w_tip = 0.4 mm (paper 001 §6)
PAPER_OFFLINE_S = 7 * 3600
PAPER_ONLINE_MS = 44.0
PAPER_OFFLINE_ONLY_S = 67.6
THINNING = 0.0001  # the thinned pathmap encoding: Douglas-Peucker within w_tip / 4, common segments within 3 w_tip / 4


def length(points) -> float:
    return float(np.linalg.norm(np.diff(np.asarray(points), axis=0), axis=1).sum())


# ----------------------------------------------------------------------------- 1. offline


def offline(scene, space, repeat: int):
    times, result = [], None
    for _ in range(repeat):
        with LocalExecutor(workers=2) as executor:
            started = time.perf_counter()
            result = run_offline(PlanningProblem(scene, space, executor), OptMISSettings())
            times.append(time.perf_counter() - started)
        print(f"  offline build {times[-1]:.1f} s", file=sys.stderr, flush=True)
    return result, times


# ----------------------------------------------------------------------------- 4. references


def visibility_reference(space, pois: np.ndarray, spacing: float = 0.002) -> np.ndarray:
    """All-pairs shortest lengths (m) in the edge visibility graph of the obstacles (independent of optMIS)."""
    scene = space.scene
    clear = space.tip_radius + 1e-6
    nodes = []
    for obstacle in scene.obstacles:
        mesh = obstacle.to_trimesh()
        sharp = mesh.face_adjacency_angles > np.radians(1.0)
        edges = mesh.face_adjacency_edges[sharp]
        n1 = mesh.face_normals[mesh.face_adjacency[sharp, 0]]
        n2 = mesh.face_normals[mesh.face_adjacency[sharp, 1]]
        bisector = n1 + n2
        bisector /= np.linalg.norm(bisector, axis=1)[:, None]
        # far enough along the bisector that a leg along either face keeps the tip clear
        offset = clear / np.sum(bisector * n1, axis=1)
        a, b = mesh.vertices[edges[:, 0]], mesh.vertices[edges[:, 1]]
        count = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / spacing).astype(int))
        for k in range(len(a)):
            t = np.linspace(0.0, 1.0, count[k] + 1)[:, None]
            nodes.append(a[k] + t * (b[k] - a[k]) + bisector[k] * offset[k])
        nodes.append(mesh.vertices + mesh.vertex_normals * clear * np.sqrt(3.0))
    nodes = np.concatenate(nodes)
    nodes = nodes[scene.in_bounds(nodes) & (space.clearance(nodes) > 0)]
    nodes = np.unique(np.round(nodes, 9), axis=0)
    vertices = np.concatenate([pois, nodes])
    n = len(vertices)
    i, j = np.triu_indices(n, 1)
    ok = np.zeros(len(i), dtype=bool)
    chunk = 400_000
    for s in range(0, len(i), chunk):
        ok[s : s + chunk] = space.motion_is_clear(vertices[i[s : s + chunk]], vertices[j[s : s + chunk]])
    i, j = i[ok], j[ok]
    w = np.linalg.norm(vertices[i] - vertices[j], axis=1)
    graph = coo_matrix((np.concatenate([w, w]), (np.concatenate([i, j]), np.concatenate([j, i]))), (n, n)).tocsr()
    print(f"  visibility graph: {n} vertices, {len(i)} certified motions", file=sys.stderr, flush=True)
    return dijkstra(graph, indices=np.arange(len(pois)))[:, : len(pois)]


def rrt_star_reference(scene, space, pairs, pois, seconds: float):
    from surgiplan.plugins.planners.ompl_bridge.bridge import OmplPlanner, OmplSettings

    planner = OmplPlanner(OmplSettings(planner="RRTstar", time_limit=seconds, seed=1, simplify=True))
    session = planner.build(PlanningProblem(scene, space))
    out = []
    for i, j in pairs:
        result = planner.query(session, pois[i], pois[j])
        out.append(length(result.path) if result.solved else np.nan)
    return np.array(out)


# ----------------------------------------------------------------------------- 3. online


def online(scene, space, repository, graph, pairs_count: int, rng):
    planner = SegmentedAStar(SegmentedAStarSettings())
    started = time.perf_counter()
    pathmap = build_pathmap(repository, space, n_s=3)
    artifact = SegmentedAStar._artifact(pathmap, space, [])
    setup_s = time.perf_counter() - started
    pois = repository.pois
    reachable = repository.pairs[rng.integers(0, repository.n_paths, pairs_count)]
    flip = rng.random(pairs_count) < 0.5
    reachable[flip] = reachable[flip][:, ::-1]
    rows = {}
    # warm up, then time every query (the planner's full query: checks, links, A*, path assembly)
    for i, j in reachable[:20]:
        planner.query(artifact, pois[i], pois[j])
    times, astar, expanded = [], [], []
    for i, j in reachable:
        t0 = time.perf_counter()
        result = planner.query(artifact, pois[i], pois[j])
        times.append(time.perf_counter() - t0)
        astar.append(result.metrics["astar_s"])
        expanded.append(result.metrics["expanded_junctions"])
        assert result.solved
    rows["poi"] = (np.array(times), np.array(astar), np.array(expanded))
    # arbitrary free points
    free = rng.uniform(scene.bounds_min, scene.bounds_max, (20 * pairs_count, 3))
    free = free[space.clearance(free) > 0][: 2 * pairs_count]
    for a, b in zip(free[:40:2], free[1:40:2], strict=True):  # warm up
        planner.query(artifact, a, b)
    times, solved, in_sight = [], 0, []
    for a, b in zip(free[::2], free[1::2], strict=True):
        t0 = time.perf_counter()
        result = planner.query(artifact, a, b)
        times.append(time.perf_counter() - t0)
        solved += result.solved
        in_sight.append(result.metrics.get("start_link") == "direct")
    rows["free"] = (np.array(times), solved, len(times), np.array(in_sight))
    # the offline-only optMIS search for arbitrary points, and OMPL RRT-Connect, on a few of them
    settings = OptMISSettings()
    few = list(zip(free[: 2 * 20 : 2], free[1 : 2 * 20 : 2], strict=True))
    t_search = []
    for a, b in few:
        t0 = time.perf_counter()
        search_between(space, graph, a, b, settings)
        t_search.append(time.perf_counter() - t0)
    rows["search"] = np.array(t_search)
    from surgiplan.plugins.planners.ompl_bridge.bridge import OmplPlanner, OmplSettings

    ompl = OmplPlanner(OmplSettings(planner="RRTConnect", time_limit=5.0, seed=1, simplify=True))
    session = ompl.build(PlanningProblem(scene, space))
    t_ompl = []
    for a, b in few:
        t0 = time.perf_counter()
        ompl.query(session, a, b)
        t_ompl.append(time.perf_counter() - t0)
    rows["ompl"] = np.array(t_ompl)
    return rows, artifact, planner, setup_s


# ----------------------------------------------------------------------------- 5. trade-off


def tradeoff(space, graph, repository, reference, quick: bool):
    variants = {
        "taut + refined (default)": None,
        "taut, not refined": PathOptions(refine=False),
        "taut, jumps <= 20 mm": PathOptions(max_jump=0.02),
        "taut, jumps <= 10 mm": PathOptions(max_jump=0.01),
        "search-space paths (paper)": PathOptions(taut=False),
    }
    if quick:
        variants = {k: v for k, v in variants.items() if v is None or not v.taut}
    base = OptMISSettings().path_options()
    rows = []
    for name, options in variants.items():
        if options is None:
            repo = repository
        else:
            options.knot_spacing, options.resolution, options.turn_radius = (
                base.knot_spacing,
                base.resolution,
                base.turn_radius,
            )
            options.floor = base.floor
            with LocalExecutor(workers=2) as executor:
                repo = build_repository(space, graph, repository.names, repository.pois, options, executor=executor)
        pathmap = build_pathmap(repo, space, n_s=3)
        ratio = repo.length / reference[repo.pairs[:, 0], repo.pairs[:, 1]]
        rows.append(
            {
                "paths": name,
                "mean_length_mm": round(float(repo.length.mean()) * 1e3, 2),
                "vs_reference_mean": f"{100 * (ratio.mean() - 1):+.2f}%",
                "vs_reference_median": f"{100 * (np.median(ratio) - 1):+.2f}%",
                "m (n_s=3)": round(pathmap.stats["m"], 2),
                "m_bytes": round(pathmap.stats["m_bytes"], 2),
                "common_share": f"{100 * pathmap.stats['common_instance_share']:.1f}%",
            }
        )
        print(f"  trade-off: {name} done", file=sys.stderr, flush=True)
    return rows


# ----------------------------------------------------------------------------- main


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="1 offline run, 200 queries, 4 RRT* pairs, short sweep")
    parser.add_argument("--repeat", type=int, default=None, help="offline builds to time (default 3, quick 1)")
    args = parser.parse_args()
    repeat = args.repeat or (1 if args.quick else 3)
    queries = 200 if args.quick else 1000
    rrt_pairs, rrt_seconds = (4, 3.0) if args.quick else (12, 20.0)
    load = os.getloadavg()
    rng = np.random.default_rng(2024)
    scene = load_scene(ROOT / "configs/scenes/hand_eye.yaml")
    space = R3Space(scene, TIP_RADIUS)
    out: list[dict] = []

    # 1. offline
    result, times = offline(scene, space, repeat)
    repository, graph = result.repository, result.graph
    summary = repository.summary()
    offline_s = statistics.median(times)
    out.append(
        {
            "measure": "offline all-pairs repository (s, local, 2 workers)",
            "value": round(offline_s, 1),
            "target": "<= 60",
            "paper": f"~{PAPER_OFFLINE_S} (7 h, ~1300 paths)",
            "notes": f"{repository.n_paths} paths, {summary['unreachable_pairs']} unreachable pairs; runs: "
            f"{', '.join(f'{t:.1f}' for t in times)}; search space {summary['search_space_s']:.1f} s "
            f"({summary['search_vertices']} vertices, {summary['search_edges']} edges)",
        }
    )

    # 2. pathmap and Table 1
    pathmap = build_pathmap(repository, space, n_s=3)
    error = reconstruction_error(repository, pathmap)
    out.append(
        {
            "measure": "m for n_s = 3 (points in P / points in S)",
            "value": round(pathmap.stats["m"], 3),
            "target": ">= 3.45",
            "paper": PAPER_M,
            "notes": f"bytes: {pathmap.stats['raw_file_bytes'] / 1e3:.0f} KB -> "
            f"{pathmap.stats['pathmap_file_bytes'] / 1e3:.0f} KB (m_bytes "
            f"{pathmap.stats['m_bytes']:.2f}); common share "
            f"{100 * pathmap.stats['common_instance_share']:.1f}% (paper 50.54%)",
        }
    )
    out.append(
        {
            "measure": "largest reconstruction error (mm)",
            "value": round(float(error.max()) * 1e3, 4),
            "target": "<= w_tip = 0.4",
            "paper": "w_tip tolerance",
            "notes": "",
        }
    )
    started = time.perf_counter()
    thinned = build_pathmap(repository, space, n_s=3, thinning=THINNING)
    thinned_s = time.perf_counter() - started
    thinned_error = reconstruction_error(repository, thinned)
    out.append(
        {
            "measure": f"m for n_s = 3, thinned encoding ({THINNING * 1e3:g} mm; taut paths)",
            "value": round(thinned.stats["m"], 3),
            "target": ">= 3.45 (stretch)",
            "paper": PAPER_M,
            "notes": f"bytes: {thinned.stats['raw_file_bytes'] / 1e3:.0f} KB -> "
            f"{thinned.stats['pathmap_file_bytes'] / 1e3:.0f} KB (m_bytes {thinned.stats['m_bytes']:.2f});"
            f" {len(repository.points)} points -> {thinned.stats['thinned_points']} after thinning -> "
            f"{thinned.stats['pathmap_points']} stored (sharing alone m_sharing "
            f"{thinned.stats['m_sharing']:.2f}); largest two-sided deviation from the stored paths "
            f"{thinned_error.max() * 1e3:.3f} mm (<= w_tip 0.4); built in {thinned_s:.1f} s",
        }
    )
    with tempfile.TemporaryDirectory() as tmp:
        rows = table1(repository, space, sizes=(2, 3, 4, 5), directory=Path(tmp), thinning=THINNING)
        files = write_report(
            Path(tmp), rows, f"hand-eye: {repository.n_paths} paths between 80 points of interest, w_tip = 0.4 mm"
        )
        for f in files:
            (RESULTS / f"optmis_{f.name}").write_bytes(f.read_bytes())
    print(
        table(
            rows,
            [
                "method",
                "n_s",
                "common_kb",
                "unique_kb",
                "links_kb",
                "pathmap_kb",
                "raw_kb",
                "m",
                "m_bytes",
                "common_share",
                "max_error_mm",
                "paper_pathmap_kb",
            ],
        )
    )

    # 3. online
    online_rows, artifact, planner, setup_s = online(scene, space, repository, graph, queries, rng)
    poi_times, astar, expanded = online_rows["poi"]
    free_times, solved, tried, in_sight = online_rows["free"]
    out.append(
        {
            "measure": f"online query between points of interest (ms, median of {len(poi_times)})",
            "value": round(float(np.median(poi_times)) * 1e3, 3),
            "target": "<= 1",
            "paper": PAPER_ONLINE_MS,
            "notes": f"A* alone {np.median(astar) * 1e3:.3f} ms; p90 {np.percentile(poi_times, 90) * 1e3:.2f} ms;"
            f" {np.median(expanded):.0f} junctions expanded (median); pathmap graph built in "
            f"{setup_s:.1f} s",
        }
    )
    blocked = free_times[~in_sight]
    out.append(
        {
            "measure": f"online query between free points (ms, median of {tried})",
            "value": round(float(np.median(free_times)) * 1e3, 3),
            "target": "<= 1",
            "paper": "fails (not in graph)",
            "notes": f"{solved}/{tried} solved; links certified; p90 {np.percentile(free_times, 90) * 1e3:.2f} ms; "
            f"{in_sight.sum()} pairs in line of sight (the straight motion, no linking) "
            f"{np.median(free_times[in_sight]) * 1e3:.3f} ms, the other {len(blocked)} "
            f"{np.median(blocked) * 1e3:.3f} ms (p90 {np.percentile(blocked, 90) * 1e3:.2f} ms)",
        }
    )
    out.append(
        {
            "measure": "optMIS search between free points (ms, median of 20)",
            "value": round(float(np.median(online_rows["search"])) * 1e3, 1),
            "target": "",
            "paper": f"{PAPER_OFFLINE_ONLY_S * 1e3:.0f} (offline-only optMIS)",
            "notes": "link, Dijkstra, tautening, refinement, smoothing in the stored search space",
        }
    )
    out.append(
        {
            "measure": "OMPL RRT-Connect between free points (ms, median of 20)",
            "value": round(float(np.median(online_rows["ompl"])) * 1e3, 1),
            "target": "",
            "paper": "",
            "notes": "through the bridge, certified motions, simplified",
        }
    )

    # 4. quality
    started = time.perf_counter()
    reference = visibility_reference(space, repository.pois)
    reference_s = time.perf_counter() - started
    i, j = repository.pairs[:, 0], repository.pairs[:, 1]
    ratio = repository.length / reference[i, j]
    visible = space.motion_is_clear(repository.pois[i], repository.pois[j])
    straight = np.linalg.norm(repository.pois[j] - repository.pois[i], axis=1)
    out.append(
        {
            "measure": "optMIS length vs edge-visibility reference (mean, all pairs)",
            "value": f"{100 * (ratio.mean() - 1):+.2f}%",
            "target": "within 3%",
            "paper": "",
            "notes": f"median {100 * (np.median(ratio) - 1):+.2f}%, "
            f"95th pct {100 * (np.percentile(ratio, 95) - 1):+.2f}%, max {100 * (ratio.max() - 1):+.2f}%, "
            f"{np.count_nonzero(ratio > 1.03)} pairs above +3%, {np.count_nonzero(ratio < 0.99)} pairs "
            f"1% or more shorter than the reference; reference built in {reference_s:.0f} s",
        }
    )
    out.append(
        {
            "measure": f"optMIS length vs straight line, pairs in line of sight ({visible.sum()})",
            "value": f"{100 * (np.mean(repository.length[visible] / straight[visible]) - 1):+.3f}%",
            "target": "0 (exact)",
            "paper": "",
            "notes": "",
        }
    )
    blocked = np.flatnonzero(~visible)
    sample = rng.choice(blocked, min(rrt_pairs, len(blocked)), replace=False)
    rrt = rrt_star_reference(scene, space, repository.pairs[sample], repository.pois, rrt_seconds)
    found = np.isfinite(rrt)
    rrt_ratio = repository.length[sample][found] / rrt[found]
    rrt_vs_reference = rrt[found] / reference[tuple(repository.pairs[sample][found].T)]
    out.append(
        {
            "measure": f"optMIS length vs OMPL RRT* ({rrt_seconds:g} s each, {found.sum()} blocked pairs)",
            "value": f"{100 * (rrt_ratio.mean() - 1):+.2f}%",
            "target": "within 3%",
            "paper": "",
            "notes": f"RRT* vs visibility reference, same pairs: {100 * (rrt_vs_reference.mean() - 1):+.2f}%",
        }
    )
    some = np.arange(0, repository.n_paths, 7)
    online_length = np.array(
        [length(planner.query(artifact, *repository.pois[repository.pairs[k]]).path) for k in some]
    )
    rebuilt = np.array([length(artifact.pathmap.path(k)) for k in some])
    vs_rebuilt, vs_stored = online_length / rebuilt, online_length / repository.length[some]
    out.append(
        {
            "measure": f"online A* path vs the path rebuilt from the pathmap ({len(some)} pairs)",
            "value": f"{100 * (vs_rebuilt.mean() - 1):+.3f}%",
            "target": "<= 0 (the pathmap holds it)",
            "paper": "",
            "notes": f"max {100 * (vs_rebuilt.max() - 1):+.3f}%; vs the stored optMIS path: mean "
            f"{100 * (vs_stored.mean() - 1):+.3f}%, max {100 * (vs_stored.max() - 1):+.3f}% "
            "(rebuilt points move by up to w_tip)",
        }
    )

    # 5. trade-off
    sweep = tradeoff(space, graph, repository, reference, args.quick)
    print(table(sweep, list(sweep[0])))

    # 6. Fig. 6: A = p66 -> B = p41, after 60 % of the way a new goal C = p73 (the planner draws it)
    from surgiplan.plugins.planners.segmented_astar.search import ReplanSettings

    figure = RESULTS / "optmis_replanning.png"
    fig6 = SegmentedAStar(SegmentedAStarSettings(replan=ReplanSettings(goal="p73", at=0.6, figure=str(figure))))
    names = repository.names
    a, b = (repository.pois[names.index(n)] for n in ("p66", "p41"))
    replan = fig6.query(artifact, a, b).metrics["replan"]
    current, goal_c = np.array(replan["position_m"]), np.array(replan["new_goal_m"])
    replan_ms, _ = median_time(lambda: fig6.replan(artifact, current, goal_c), repeat=21)
    out.append(
        {
            "measure": "replanning query, Fig. 6 instance (ms, median of 21)",
            "value": round(replan_ms * 1e3, 3),
            "target": "",
            "paper": "almost real-time",
            "notes": f"A-B {replan['first_length_m'] * 1e3:.1f} mm, R-C {replan['new_length_m'] * 1e3:.1f} mm; "
            "benchmarks/results/optmis_replanning.png",
        }
    )

    print(table(out, ["measure", "value", "target", "paper", "notes"]))
    notes = (
        f"hand-eye scene, 80 points of interest, w_tip 0.4 mm; machine load average at start "
        f"{load[0]:.1f}/{load[1]:.1f}/{load[2]:.1f} on {os.cpu_count()} cores (timings on a shared machine); "
        f"{'quick run' if args.quick else 'full run'}"
    )
    peers = {
        "OMPL": {
            "version": package_version("ompl"),
            "configuration": "RRT-Connect (5 s, seeded, simplified) for arbitrary points; RRT* with generous time "
            "as a path-length reference, through surgiplan's OMPL bridge",
        }
    }
    path = save("optmis", out + [{"measure": "trade-off", **r} for r in sweep], notes, peers=peers)
    print(
        f"\nwritten: {path}, {RESULTS / 'optmis_table1.csv'}, {RESULTS / 'optmis_table1.png'}, "
        f"{RESULTS / 'optmis_replanning.png'}"
    )


if __name__ == "__main__":
    main()
