"""Scale: scenes of 10 to 10,000 small boxes, roadmaps of 1,000 to 100,000 milestones (issue 38).

For each case a fresh process validates the pipeline (``load_pipeline``, what ``surgiplan validate`` does), runs
it (``run_pipeline``: roadmap build, query, figure, scene.glb, report.html) and reports each phase's time and its
peak memory (``getrusage``); the growth exponent of each phase is the slope of a log-log fit over the obstacle
counts (5,000 milestones) and over the milestone counts (10,000 boxes). Then, on the 10,000-box scene:

* the whole ``surgiplan run`` of 5,000 milestones as a user starts it (a process, imports included);
* report.html in headless Chromium (SwiftShader, no GPU): its size, time to the first frame, and frame times
  while the camera turns (``surgiplan.frameTimes``);
* the broad phase against coal's ``DynamicAABBTreeCollisionManager`` (the same exact distances, asserted) and
  against the all-obstacle brute force it replaces (``geometry.compiled.nearest``).

The largest cases are capped by time (``--budget``, seconds a case may take): a case after one that took longer
is skipped and recorded as such.

    python benchmarks/bench_scale.py            # results: benchmarks/results/scale.json
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))

from common import package_version, save  # noqa: E402
from scale_scene import write_pipeline  # noqa: E402

OBSTACLES = (10, 100, 1_000, 10_000)
MILESTONES = (1_000, 5_000, 20_000, 100_000)
BASE_MILESTONES, BASE_OBSTACLES = 5_000, 10_000
TARGETS = {"validate_s": 2.0, "build_s": 5.0, "query_s": 0.5, "run_s": 30.0, "output_s": 5.0, "report_MB": 20.0}


# ----------------------------------------------------------------------------- one case, in its own process


def _timed(module, name: str, times: dict[str, float], label: str) -> None:
    """Wrap ``module.name`` so that its calls add their wall time to ``times[label]``."""
    original = getattr(module, name)

    def wrapper(*args, **kwargs):
        started = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            times[label] = times.get(label, 0.0) + time.perf_counter() - started

    setattr(module, name, wrapper)


def case(pipeline_file: Path) -> dict:
    """Validate and run one pipeline in this process: each phase's wall time and the peak memory."""
    import surgiplan.outputs.figures as figures
    import surgiplan.outputs.gltf as gltf
    import surgiplan.outputs.report as report
    import surgiplan.runner as runner
    import surgiplan.stages.plan as plan
    from surgiplan.pipeline import load_pipeline

    outputs: dict[str, float] = {}
    for module, name, label in (
        (figures, "plan_figure", "figure_s"),
        (gltf, "write_scene_glb", "glb_s"),
        (report, "write_run_report", "report_s"),
    ):
        _timed(module, name, outputs, label)
        for user in (runner, plan):  # where it was imported by name (modules importing lazily find the wrapper)
            if hasattr(user, name):
                setattr(user, name, getattr(module, name))
    from surgiplan.registry import default_registry

    started = time.perf_counter()
    default_registry()  # the plugins imported and registered: what a small pipeline's validation costs too
    imports_s = time.perf_counter() - started
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    started, cpu = time.perf_counter(), time.process_time()
    pipe = load_pipeline(pipeline_file)
    validate_s, validate_cpu_s = time.perf_counter() - started, time.process_time() - cpu
    started = time.perf_counter()
    outcome = runner.run_pipeline(pipe)
    run_s = time.perf_counter() - started
    metrics = outcome.results[0].metrics
    out = outcome.output_dir
    return {
        "status": outcome.results[0].status,
        "imports_s": imports_s,
        "validate_s": validate_s,
        "validate_cpu_s": validate_cpu_s,  # the process's CPU time: less sensitive to a loaded machine
        "build_s": metrics["build_s"],
        "query_s": metrics["answer_s"],
        "search_s": metrics["search_s"],
        "run_s": run_s,
        **outputs,
        "report_MB": (Path(out) / "report.html").stat().st_size / 1e6,
        "glb_MB": (Path(out) / "scene.glb").stat().st_size / 1e6,
        "edges": metrics["edges"],
        "peak_MB_before_validate": rss_before / 1024,
        "peak_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def run_case(tmp: Path, obstacles: int, milestones: int) -> dict:
    directory = tmp / f"o{obstacles}-m{milestones}"
    path = write_pipeline(directory, obstacles, milestones)
    done = subprocess.run(
        [sys.executable, __file__, "--case", str(path)], capture_output=True, text=True, timeout=3600, check=False
    )
    if done.returncode != 0:
        raise SystemExit(f"case {obstacles} obstacles, {milestones} milestones failed:\n{done.stderr[-3000:]}")
    row = {"obstacles": obstacles, "milestones": milestones, **json.loads(done.stdout.strip().splitlines()[-1])}
    print({k: round(v, 3) if isinstance(v, float) else v for k, v in row.items()}, flush=True)
    return row


# ----------------------------------------------------------------------------- the whole command, the browser


def whole_run(tmp: Path) -> dict:
    """``surgiplan run`` of the 10,000-box, 5,000-milestone pipeline as a process: wall time and peak memory."""
    path = write_pipeline(tmp / "whole", BASE_OBSTACLES, BASE_MILESTONES)
    started = time.perf_counter()
    child = subprocess.Popen(
        [sys.executable, "-m", "surgiplan.cli", "run", str(path), "--quiet"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - started
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        raise SystemExit(f"surgiplan run failed: {child.stderr.read().decode()[-2000:]}")
    cpu = usage.ru_utime + usage.ru_stime  # the process's CPU time (and its waited-for children's)
    return {"wall_s": wall, "cpu_s": cpu, "peak_MB": usage.ru_maxrss / 1024, "out": str(tmp / "whole" / "out")}


def browser_frames(out: Path, loads: int = 3, frames: int = 30) -> dict:
    from browser_support import Browser

    browser = Browser()
    try:
        url = (out / "report.html").resolve().as_uri()
        first, times, counts = [], [], {}
        for _ in range(loads + 1):  # the first load warms the browser's caches
            page = browser.page(url, timeout=300_000)
            first.append(page.evaluate("surgiplan.loadMs") / 1000)
            times.append(page.evaluate(f"surgiplan.frameTimes({frames})"))
            counts = page.evaluate("surgiplan.counts")
            page.close()
    finally:
        browser.close()
    every = [t for run in times[1:] for t in run]
    return {
        "first_frame_s": statistics.median(first[1:]),
        "frame_ms_median": statistics.median(every),
        "frame_ms_p90": float(np.percentile(every, 90)),
        "frames": len(every),
        "obstacles_drawn": counts.get("obstacles"),
    }


# ----------------------------------------------------------------------------- the broad phase against its peers


def broad_phase_peers(tmp: Path) -> dict:
    import coal
    from helpers import coal_scene_point_distance
    from surgiplan import load_scene
    from surgiplan.geometry import compiled

    scene = load_scene(write_pipeline(tmp / "peers", BASE_OBSTACLES, 1_000).parent / "scene.yaml")
    scene._prepare()
    rng = np.random.default_rng(5)
    points = rng.uniform(scene.bounds_min, scene.bounds_max, (2_000, 3))
    a = rng.uniform(scene.bounds_min, scene.bounds_max, (20_000, 3))
    b = a + rng.normal(0, 0.004, a.shape)

    def timed(fn, repeat=3):
        runs = []
        for _ in range(repeat):
            started = time.perf_counter()
            value = fn()
            runs.append(time.perf_counter() - started)
        return statistics.median(runs), value

    ours_point_s, (ours, _) = timed(lambda: scene.signed_distance(points))
    ours_segment_s, _ = timed(lambda: scene.segment_distance(a, b, 0.001))
    manager = coal.DynamicAABBTreeCollisionManager()
    objects = []
    for o in scene.obstacles:
        objects.append(coal.CollisionObject(o.coal_geometry(), o.coal_transform()))
        manager.registerObject(objects[-1])
    manager.setup()
    probe = coal.CollisionObject(coal.Sphere(1e-12), coal.Transform3s())
    callback = coal.DistanceCallBackDefault()

    def coal_points():
        out = np.empty(len(points))
        for i, p in enumerate(points):
            probe.setTranslation(p)
            probe.computeAABB()
            callback.data.result.clear()
            callback.data.done = False
            manager.distance(probe, callback)
            out[i] = callback.data.result.min_distance + 1e-12
        return out

    coal_s, managed = timed(coal_points)
    # the independent answer: coal's pairwise distance to every box (the tests' reference), on a sample
    sample = points[:100]
    reference = coal_scene_point_distance(scene, sample)
    outside = reference > 0
    agreement = float(np.max(np.abs(ours[:100][outside] - reference[outside])))
    assert agreement < 1e-8, f"coal's pairwise distances and ours disagree by {agreement} m"
    # coal's manager, as called here, may answer a farther box than the nearest: recorded, not hidden
    manager_diff = np.abs(managed - ours)[ours > 0]
    brute = 200
    brute_s, (brute_d, _) = timed(lambda: compiled.distances(scene._packed, a[:brute], b[:brute], 0.001), repeat=1)
    tree_d = scene.segment_distance(a[:brute], b[:brute], 0.001)[0]
    assert np.array_equal(brute_d < 0.001, tree_d < 0.001)
    return {
        "obstacles": len(scene.obstacles),
        "tree_point_us": 1e6 * ours_point_s / len(points),
        "coal_manager_point_us": 1e6 * coal_s / len(points),
        "coal_pairwise_max_abs_diff_m": agreement,
        "coal_manager_max_abs_diff_m": float(manager_diff.max()),
        "coal_manager_points_differing": int(np.count_nonzero(manager_diff > 1e-9)),
        "points": len(points),
        "tree_segment_us": 1e6 * ours_segment_s / len(a),
        "brute_force_segment_us": 1e6 * brute_s / brute,
    }


# ----------------------------------------------------------------------------- the fit, the whole benchmark


def exponent(xs, ys) -> float | None:
    """The slope of log y against log x (the growth exponent), over the cases with a positive time."""
    pairs = [(x, y) for x, y in zip(xs, ys, strict=True) if y and y > 0]
    if len(pairs) < 2:
        return None
    x, y = np.log([p[0] for p in pairs]), np.log([p[1] for p in pairs])
    return float(np.polyfit(x, y, 1)[0])


PHASES = ("validate_s", "build_s", "query_s", "figure_s", "glb_s", "report_s", "run_s", "peak_MB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--budget", type=float, default=240.0, help="skip larger cases after one this slow (s)")
    args = parser.parse_args()
    if args.case is not None:
        print(json.dumps(case(args.case)))
        return
    rows, skipped = [], []
    with tempfile.TemporaryDirectory(prefix="bench-scale-") as name:
        tmp = Path(name)
        for obstacles in OBSTACLES:
            rows.append({"series": "obstacles", **run_case(tmp, obstacles, BASE_MILESTONES)})
        for milestones in MILESTONES:
            slow = rows[-1]["run_s"] + rows[-1]["validate_s"] > args.budget
            if slow and milestones > BASE_MILESTONES:
                skipped.append(milestones)
                continue
            if milestones == BASE_MILESTONES:
                rows.append({**rows[OBSTACLES.index(BASE_OBSTACLES)], "series": "milestones"})
                continue
            rows.append({"series": "milestones", **run_case(tmp, BASE_OBSTACLES, milestones)})
        whole = whole_run(tmp)
        browser = browser_frames(Path(whole["out"]))
        peers = broad_phase_peers(tmp)
    fits = {}
    for series, key in (("obstacles", "obstacles"), ("milestones", "milestones")):
        chosen = [r for r in rows if r["series"] == series]
        fits[series] = {p: exponent([r[key] for r in chosen], [r.get(p) for r in chosen]) for p in PHASES}
    summary = {
        "series": "summary",
        "whole_run": {k: v for k, v in whole.items() if k != "out"},
        "browser": browser,
        "broad_phase": peers,
        "exponents": fits,
        "skipped_milestones": skipped,
        "budget_s": args.budget,
        "targets": TARGETS,
    }
    print(json.dumps(summary, indent=2))
    save(
        "scale",
        [*rows, summary],
        notes=f"each case in a fresh process; cases after one slower than {args.budget:g} s skipped; "
        f"browser: headless chromium (SwiftShader, no GPU), frame times of {browser['frames']} frames",
        peers={
            "coal": {
                "version": package_version("coal"),
                "configuration": "DynamicAABBTreeCollisionManager, "
                "DistanceCallBackDefault, a sphere of 1e-12 m as the probe",
            },
            "Chromium": {"version": _chromium_version(), "configuration": "headless, SwiftShader (no GPU)"},
        },
    )


def _chromium_version() -> str | None:
    from bench_report import chromium_version

    return chromium_version()


if __name__ == "__main__":
    main()
