"""Scene queries: surgiplan's vectorised exact distances against coal called per query.

Both sides compute the same exact numbers (checked here again); the point is
throughput, because planners make these queries by the hundred thousand.
Median of 5 runs on the block world scene (6 boxes) and on a mixed scene
(box, sphere, cylinder, capsule, mesh).

    python benchmarks/bench_scene.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from common import median_time, package_version, save, table
from helpers import coal_scene_point_distance, coal_scene_segment_distance
from surgiplan import load_scene
from surgiplan.geometry.mesh import mesh_from_arrays
from surgiplan.geometry.shapes import Box, Capsule, Cylinder, Mesh, Sphere
from surgiplan.geometry.transforms import Pose
from surgiplan.scene import Scene
from surgiplan.spaces import CastGimbalSettings, CastGimbalSpace

ROOT = Path(__file__).resolve().parent.parent


def mixed_scene() -> Scene:
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.01)
    return Scene(
        [0, 0, 0],
        [0.15, 0.10, 0.08],
        [
            Box("block", Pose.from_xyz_rpy([0.04, 0.05, 0.02], [0, 0, 0.3]), size=(0.01, 0.05, 0.04)),
            Sphere("ball", Pose.from_xyz_rpy([0.09, 0.03, 0.03]), radius=0.012),
            Cylinder("post", Pose.from_xyz_rpy([0.11, 0.07, 0.04], [0.4, 0.2, 0]), radius=0.008, length=0.06),
            Capsule("vessel", Pose.from_xyz_rpy([0.07, 0.08, 0.06], [0, 1.2, 0.5]), radius=0.004, length=0.08),
            Mesh("organ", Pose.from_xyz_rpy([0.12, 0.02, 0.06]), mesh=mesh_from_arrays(ball.vertices, ball.faces)),
        ],
    )


def main() -> None:
    rng = np.random.default_rng(0)
    rows = []
    scenes = {
        "block world (6 boxes)": load_scene(ROOT / "configs/scenes/block_world.yaml"),
        "mixed (5 shapes)": mixed_scene(),
    }
    for label, scene in scenes.items():
        n_points, n_segments, n_coal = 100_000, 20_000, 2_000
        points = rng.uniform(scene.bounds_min, scene.bounds_max, (n_points, 3))
        a = rng.uniform(scene.bounds_min, scene.bounds_max, (n_segments, 3))
        b = a + rng.normal(0, 0.01, (n_segments, 3))  # PRM-like edges of ~1.6 cm

        t_ours, _ = median_time(lambda: scene.signed_distance(points))
        t_coal, _ = median_time(lambda: coal_scene_point_distance(scene, points[:n_coal]), repeat=3)
        ours = scene.signed_distance(points[:n_coal])[0]
        ref = coal_scene_point_distance(scene, points[:n_coal])
        # coal's mesh distances are unsigned: compare where both say "outside"
        err = float(np.max(np.abs(ours - ref)[(ref > 0) & (ours > 0)]))
        rows.append(
            {
                "scene": label,
                "query": "point signed distance",
                "surgiplan_us_per_query": round(t_ours / n_points * 1e6, 3),
                "coal_loop_us_per_query": round(t_coal / n_coal * 1e6, 3),
                "speedup": round((t_coal / n_coal) / (t_ours / n_points), 1),
                "max_abs_diff_m": f"{err:.1e}",
            }
        )

        t_ours, _ = median_time(lambda: scene.segment_distance(a, b))
        t_coal, _ = median_time(lambda: coal_scene_segment_distance(scene, a[:n_coal], b[:n_coal]), repeat=3)
        ours = scene.segment_distance(a[:n_coal], b[:n_coal])[0]
        ref = coal_scene_segment_distance(scene, a[:n_coal], b[:n_coal])
        err = float(np.max(np.abs(ours - ref)[(ref > 1e-9) & (ours > 1e-9)]))
        rows.append(
            {
                "scene": label,
                "query": "motion clearance (exact)",
                "surgiplan_us_per_query": round(t_ours / n_segments * 1e6, 3),
                "coal_loop_us_per_query": round(t_coal / n_coal * 1e6, 3),
                "speedup": round((t_coal / n_coal) / (t_ours / n_segments), 1),
                "max_abs_diff_m": f"{err:.1e}",
            }
        )

        t_ours, _ = median_time(lambda: scene.is_motion_clear(a, b, 0.0, 0.004))
        rows.append(
            {
                "scene": label,
                "query": "motion clear with 4 mm margin (certified)",
                "surgiplan_us_per_query": round(t_ours / n_segments * 1e6, 3),
            }
        )

    scene = scenes["block world (6 boxes)"]
    space = CastGimbalSpace(
        scene,
        CastGimbalSettings.model_validate(
            {"fulcrum": {"xyz": [0.075, -0.06, 0.12], "rpy": [0, 0, np.pi / 2]}, "shaft_radius": 0.0025}
        ),
    )
    q = space.inverse(rng.uniform(scene.bounds_min, scene.bounds_max, (4000, 3)))
    q = q[space.is_valid(q)]
    q1 = q[:-1]
    q2 = space.interpolate(q1, q[1:], np.full(len(q1), 0.1))
    t_ours, _ = median_time(lambda: space.motion_is_clear(q1, q2, 0.004), repeat=3)
    rows.append(
        {
            "scene": "block world",
            "query": "gimbal shaft motion, 4 mm margin (certified, covering balls)",
            "surgiplan_us_per_query": round(t_ours / len(q1) * 1e6, 2),
        }
    )

    columns = ["scene", "query", "surgiplan_us_per_query", "coal_loop_us_per_query", "speedup", "max_abs_diff_m"]
    print(table(rows, columns))
    peers = {"coal": {"version": package_version("coal"), "configuration": "called once per query from Python"}}
    notes = "median of 5 (coal: 3) runs; coal called once per query from Python"
    print(f"\nwritten: {save('scene', rows, notes, peers=peers)}")


if __name__ == "__main__":
    main()
