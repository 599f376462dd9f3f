"""Trainee guidance: per-sample latency of the guide stage against a recommended path from a 5,000-milestone roadmap.

The issue's targets: median under 1 ms and p99 under 5 ms per sample. Measured
on the block world, for the recommended path of a beginner planned by
safe_prm with 5,000 milestones:

* **r3**: the tip (a point) followed from recorded tip positions: the
  closest point on the recommended polyline (densified at 0.25 mm) and the
  tip's clearance;
* **cast_gimbal**: the instrument's configuration (the gimbal's joints): the
  tip through the space's kinematics and the *whole shaft's* clearance.

Two figures per case:

* ``analysis``: :meth:`Guide.measure` alone, over every sample of synthetic
  beginner attempts (5 seeds), what the stage adds per sample;
* ``delay``: the whole ``guide`` stage with the synthetic trainee paced in real
  time (100 samples/s): from the source producing a sample to the end of its
  analysis, through the source thread and queue, what a trainee watching
  feels (one 20 s attempt per case).

The load average at the start is recorded (the machine is shared).

    python benchmarks/bench_guide.py [--quick]    (--quick: 1 seed, writes nothing)
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import save, table
from surgiplan import load_pipeline, load_scene, run_pipeline
from surgiplan.clearance import critical_regions, intervals
from surgiplan.guidance import GuidanceSettings, Guide, PoseSample, TraineeModel, synthetic_attempt
from surgiplan.planning import PlanningProblem
from surgiplan.plugins.planners.safe_prm import SafePRM, SafePRMSettings
from surgiplan.spaces import CastGimbalSpace, R3Space

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "configs" / "scenes" / "block_world.yaml"
FULCRUM = {"xyz": [0.150, 0.050, 0.130], "rpy": [0.0, np.pi / 2, 0.0]}


def recommended(space, start, goal):
    settings = SafePRMSettings(proficiency="beginner", milestones=5000, k=15, seed=1)
    planner = SafePRM(settings)
    artifact = planner.build(PlanningProblem(space.scene, space))
    result = planner.query(artifact, start, goal)
    assert result.solved, result.message
    # as the plan stage measures them (the planner no longer reports its critical regions itself)
    regions = intervals(critical_regions(space, result.path, settings.d_thresh))
    return result.path, regions, settings.d_thresh


def analysis_latency(space, path, regions, threshold, seeds) -> list[float]:
    latencies = []
    for seed in seeds:
        guide = Guide(space, path, space.scene, threshold, regions, GuidanceSettings(), unit="mm")
        times, tips = synthetic_attempt(guide.tips, TraineeModel(level="beginner", seed=seed))
        for t, tip in zip(times, tips, strict=True):
            if space.kind == "cast_gimbal":
                try:
                    sample = PoseSample(float(t), q=space.configuration(tip))
                except Exception:
                    continue
            else:
                sample = PoseSample(float(t), tip=tip)
            m, _ = guide.measure(sample)
            latencies.append(m.latency)
    return latencies


def stage_delay(space_yaml: dict, start, seconds: float) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        data = {
            "name": "bench-guide",
            "length_unit": "mm",
            "scene": str(SCENE),
            "pipeline": [
                {
                    "stage": "plan",
                    "name": "plan",
                    "plugin": "safe_prm",
                    "space": space_yaml,
                    "start": start,
                    "goal": "target",
                    "settings": {"proficiency": "beginner", "milestones": 5000, "seed": 1},
                },
                {
                    "stage": "guide",
                    "name": "attempt",
                    "plugin": "synthetic_trainee",
                    "path_from": "plan",
                    "settings": {"level": "beginner", "seed": 3, "pace": 1, "speed": 190 / seconds},
                },
            ],
            "output": {"dir": tmp, "figures": False, "gltf": False},
            "record": str(Path(tmp) / "record.sqlite"),
        }
        path = Path(tmp) / "p.yaml"
        path.write_text(yaml.safe_dump(data))
        outcome = run_pipeline(load_pipeline(path))
        return outcome.results[1].metrics


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    load = os.getloadavg()
    scene = load_scene(SCENE)
    seeds = [1] if args.quick else [1, 2, 3, 4, 5]
    rows = []
    cases = [
        ("r3 (tip)", R3Space(scene), scene.points["entry"], {"kind": "r3"}, "entry"),
        (
            "cast_gimbal (whole shaft)",
            CastGimbalSpace.from_settings(CastGimbalSpace.Settings.model_validate({"fulcrum": FULCRUM}), scene),
            None,
            {"kind": "cast_gimbal", "fulcrum": {"xyz": [150, 50, 130], "rpy": [0, "90 deg", 0]}},
            [60, 50, 20],
        ),
    ]
    for name, space, start, space_yaml, start_yaml in cases:
        if start is None:
            start = space.configuration(np.array([0.060, 0.050, 0.020]))
        else:
            start = space.configuration(start)
        goal = space.configuration(scene.points["target"])
        path, regions, threshold = recommended(space, start, goal)
        latency = np.asarray(analysis_latency(space, path, regions, threshold, seeds)) * 1e3
        started = time.perf_counter()
        staged = stage_delay(space_yaml, start_yaml, 10.0 if args.quick else 20.0)
        rows.append(
            {
                "case": name,
                "recommended_waypoints": len(path),
                "samples": len(latency),
                "analysis_median_ms": round(float(np.median(latency)), 4),
                "analysis_p99_ms": round(float(np.percentile(latency, 99)), 4),
                "analysis_max_ms": round(float(latency.max()), 3),
                "paced_samples": staged["samples"],
                "paced_delay_median_ms": round(staged["delay_median_ms"], 4),
                "paced_delay_p99_ms": round(staged["delay_p99_ms"], 4),
                "paced_analysis_median_ms": round(staged["latency_median_ms"], 4),
                "paced_analysis_p99_ms": round(staged["latency_p99_ms"], 4),
                "stage_s": round(time.perf_counter() - started, 2),
            }
        )
        print(table(rows[-1:], list(rows[-1])), flush=True)
    print(table(rows, list(rows[0])))
    if not args.quick:
        notes = (
            f"load average at the start {load[0]:.2f}/{load[1]:.2f}/{load[2]:.2f} (1/5/15 min; 2 cores, shared); "
            "targets: median < 1 ms, p99 < 5 ms per sample"
        )
        print("wrote", save("guide", rows, notes))


if __name__ == "__main__":
    main()
