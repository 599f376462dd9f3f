"""Validation costs what its checks need (issue #38): a pipeline's start and goal are checked by numpy's closed
forms without the compiled kernels (numba is not imported), with the same clearances as the compiled kernels and
as coal; a turned obstacle's rotation is written out (scipy's, to 1e-15) without importing scipy."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import coal_scene_point_distance
from surgiplan.geometry.transforms import rpy_to_matrix

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from scale_scene import write_pipeline  # noqa: E402


def _validate_and_list_modules(pipeline: Path) -> tuple[str, set[str]]:
    probe = (
        "import contextlib, io, json, sys\n"
        "from surgiplan.cli import main\n"
        "out = io.StringIO()\n"
        "with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):\n"
        f"    main(['validate', {str(pipeline)!r}])\n"
        "print(json.dumps([out.getvalue(), sorted(sys.modules)]))\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300, check=True)
    said, modules = json.loads(done.stdout.strip().splitlines()[-1])
    return said, set(modules)


@pytest.mark.parametrize("pipeline", ["small", "many boxes"])
def test_validating_a_pipeline_does_not_import_numba(pipeline, tmp_path):
    if pipeline == "small":
        path = ROOT / "configs" / "block_world_proficiency.yaml"
    else:  # 100 boxes: a scene the planner queries through the tree (at least bvh.MIN_OBSTACLES)
        path = write_pipeline(tmp_path, 100, 1_000)
    said, modules = _validate_and_list_modules(path)
    assert ": ok: pipeline" in said, said
    assert not {m.split(".")[0] for m in modules} & {"numba", "llvmlite"}
    assert "surgiplan.geometry.compiled" not in modules and "surgiplan.geometry.bvh" not in modules
    assert "scipy.spatial" not in modules  # the boxes' rotations are written out


def test_few_point_answers_equal_the_compiled_kernels_and_coal(tmp_path):
    from surgiplan import load_scene

    path = write_pipeline(tmp_path, 300, 1_000).parent / "scene.yaml"
    light, full = load_scene(path), load_scene(path)
    full._prepare()
    assert full._tree is not None  # the compiled tree answers the full scene
    rng = np.random.default_rng(3)
    points = np.vstack([list(light.points.values()), rng.uniform(light.bounds_min, light.bounds_max, (60, 3))])
    d_light, i_light = light.signed_distance(points)
    assert not getattr(light, "_packed_ready", False)  # answered by numpy: nothing compiled was prepared
    d_full, i_full = full.signed_distance(points)
    assert np.max(np.abs(d_light - d_full)) < 1e-12
    assert np.array_equal(i_light, i_full)
    reference = coal_scene_point_distance(light, points)
    outside = reference > 0
    assert outside.sum() > 50
    assert np.max(np.abs(d_light[outside] - reference[outside])) < 1e-9
    # segments too, with a cutoff: the same certified verdicts
    a, b = points[:-1], points[1:]
    for cutoff in (np.inf, 0.002):
        s_light = light.segment_distance(a, b, cutoff)[0]
        s_full = full.segment_distance(a, b, cutoff)[0]
        assert np.array_equal(s_light < cutoff, s_full < cutoff)
        near = s_full < cutoff
        assert np.max(np.abs(s_light[near] - s_full[near])) < 1e-12
    # a large batch prepares the compiled kernels, and from then on they answer
    light.signed_distance(rng.uniform(light.bounds_min, light.bounds_max, (light.FEW + 1, 3)))
    assert light._packed_ready and light._tree is not None


def test_rpy_matrix_is_scipys():
    from scipy.spatial.transform import Rotation

    rpy = np.random.default_rng(0).uniform(-4, 4, (500, 3))
    assert np.max(np.abs(rpy_to_matrix(rpy) - Rotation.from_euler("xyz", rpy).as_matrix())) < 1e-15
    assert rpy_to_matrix(rpy.reshape(5, 100, 3)).shape == (5, 100, 3, 3)
    assert np.array_equal(rpy_to_matrix([0.0, 0.0, 0.0]), np.eye(3))
    yaw = rpy_to_matrix([0.0, 0.0, np.pi / 2])
    assert np.allclose(yaw @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
