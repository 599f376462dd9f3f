"""The many-obstacle scene of issue 38: a box trainer filled with small boxes, as a voxelised scan turns into.

``write_scene(path, boxes)`` writes a scene file (mm) of ``boxes`` small axis-aligned boxes (1-3 mm sides, a
tenth of them turned about z) scattered over a 200 x 150 x 60 mm trainer, none within 6 mm of the two named
points ``entry`` and ``target``, reproducibly (one seed); ``write_pipeline`` a safe-PRM pipeline on it. Used by
``bench_scale.py`` and the tests (at small sizes)::

    python benchmarks/scale_scene.py out/scale 10000 5000   # out/scale/scene.yaml and pipeline.yaml
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

BOUNDS_MM = (np.zeros(3), np.array([200.0, 150.0, 60.0]))
ENTRY_MM = np.array([10.0, 75.0, 30.0])
TARGET_MM = np.array([190.0, 75.0, 30.0])
KEEP_OUT_MM = 6.0


def box_rows(boxes: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """``boxes`` (centre mm, size mm, yaw rad) rows, reproducible from ``seed``."""
    rng = np.random.default_rng(seed)
    lo, hi = BOUNDS_MM
    rows: list[tuple[np.ndarray, np.ndarray, float]] = []
    while len(rows) < boxes:
        want = boxes - len(rows)
        centres = rng.uniform(lo + 2, hi - 2, (2 * want + 8, 3))
        sizes = rng.uniform(1.0, 3.0, (len(centres), 3))
        yaws = np.where(rng.random(len(centres)) < 0.1, rng.uniform(0, np.pi / 2, len(centres)), 0.0)
        far = (
            np.minimum(np.linalg.norm(centres - ENTRY_MM, axis=1), np.linalg.norm(centres - TARGET_MM, axis=1))
            > KEEP_OUT_MM + 3.0
        )
        for c, s, y in zip(centres[far], sizes[far], yaws[far], strict=True):
            if len(rows) == boxes:
                break
            rows.append((c, s, float(y)))
    return rows


def scene_text(boxes: int, seed: int = 0) -> str:
    """The scene file's YAML (flow style, one obstacle a line, as a generator would write it)."""
    lo, hi = BOUNDS_MM
    lines = [
        f"# {boxes} small boxes in a 200 x 150 x 60 mm trainer (benchmarks/scale_scene.py, seed {seed})",
        f"name: scale-{boxes}",
        "length_unit: mm",
        f"bounds: {{min: [{lo[0]:g}, {lo[1]:g}, {lo[2]:g}], max: [{hi[0]:g}, {hi[1]:g}, {hi[2]:g}]}}",
        "points:",
        f"  entry: [{ENTRY_MM[0]:g}, {ENTRY_MM[1]:g}, {ENTRY_MM[2]:g}]",
        f"  target: [{TARGET_MM[0]:g}, {TARGET_MM[1]:g}, {TARGET_MM[2]:g}]",
        "obstacles:",
    ]
    for i, (c, s, yaw) in enumerate(box_rows(boxes, seed)):
        pose = f", pose: {{xyz: [{c[0]:.3f}, {c[1]:.3f}, {c[2]:.3f}], rpy: [0, 0, {yaw:.4f}]}}"
        lines.append(f"  - {{name: b{i}, box: {{size: [{s[0]:.3f}, {s[1]:.3f}, {s[2]:.3f}]}}{pose}}}")
    return "\n".join(lines) + "\n"


def pipeline_text(scene_file: str, milestones: int, out_dir: str, seed: int = 1) -> str:
    """A safe-PRM pipeline (intermediate proficiency) from ``entry`` to ``target`` on ``scene_file``."""
    return (
        "name: scale\n"
        "length_unit: mm\n"
        f"scene: {scene_file}\n"
        "pipeline:\n"
        "  - stage: plan\n"
        "    name: cross\n"
        "    plugin: safe_prm\n"
        f"    settings: {{proficiency: 1 mm, milestones: {milestones}, k: 15, seed: {seed}}}\n"
        "    start: entry\n"
        "    goal: target\n"
        f"output: {{dir: {out_dir}}}\n"
    )


def write_scene(path: Path, boxes: int, seed: int = 0) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(scene_text(boxes, seed))
    return path


def write_pipeline(directory: Path, boxes: int, milestones: int, seed: int = 0) -> Path:
    """``scene.yaml`` and ``pipeline.yaml`` in ``directory`` (outputs into ``directory/out``)."""
    write_scene(directory / "scene.yaml", boxes, seed)
    path = directory / "pipeline.yaml"
    path.write_text(pipeline_text("scene.yaml", milestones, str(directory / "out")))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory", type=Path)
    parser.add_argument("boxes", type=int)
    parser.add_argument("milestones", type=int)
    args = parser.parse_args()
    print(write_pipeline(args.directory, args.boxes, args.milestones))


if __name__ == "__main__":
    main()
