"""End to end: `surgiplan run` on the shipped configs, outputs checked independently."""

from __future__ import annotations

import json
import textwrap

import matplotlib.image
import numpy as np
import pytest
import trimesh
from conftest import CONFIGS, ROOT
from helpers import coal_scene_segment_distance


@pytest.mark.ompl
def test_shipped_ompl_pipeline_writes_result_png_and_glb(cli, tmp_path, block_world):
    pytest.importorskip("ompl")
    out = tmp_path / "out"
    code, stdout, stderr = cli("run", CONFIGS / "block_world_ompl.yaml", "--out", out)
    assert code == 0, stderr
    assert "surgiplan run: block-world-ompl" in stdout  # the summary table

    result = json.loads((out / "result.json").read_text())
    assert result["units"].startswith("SI")
    assert [s["name"] for s in result["stages"]] == ["prm-expert", "rrtconnect-margin-2mm"]
    for stage in result["stages"]:
        assert stage["status"] == "solved"
        path = np.array(stage["path"])
        assert path.shape[1] == 3 and np.all(block_world.in_bounds(path))
        np.testing.assert_allclose(path[0], block_world.points["entry"], atol=1e-12)
        np.testing.assert_allclose(path[-1], block_world.points["target"], atol=1e-12)
        # re-measured with coal: every segment is clear, and the reported minimum is the true one
        clearance = coal_scene_segment_distance(block_world, path[:-1], path[1:])
        assert clearance.min() > 0
        assert stage["metrics"]["min_clearance_m"] == pytest.approx(clearance.min(), abs=1e-7)
        length = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
        assert stage["metrics"]["length_m"] == pytest.approx(length, rel=1e-9)
        assert stage["metrics"]["clipped_segments"] == 0
        assert stage["metrics"]["build_s"] >= 0 and stage["metrics"]["query_s"] > 0
    margin_stage = result["stages"][1]
    assert margin_stage["metrics"]["min_clearance_m"] >= 0.002 - 1e-9

    for name in ("prm-expert.png", "rrtconnect-margin-2mm.png", "overview.png"):
        image = matplotlib.image.imread(out / name)
        assert image.shape[0] > 300 and image.shape[1] > 600
        assert image[..., :3].std() > 0.05, f"{name} is blank"
    scene = trimesh.load(out / "scene.glb")
    names = set(scene.graph.nodes_geometry)
    assert {f"obstacle:{o}" for o in ("A1", "A2", "B1", "B2", "C1", "C2")} <= names
    assert {"path:prm-expert", "path:rrtconnect-margin-2mm"} <= names
    box = scene.geometry["obstacle:A1"].bounds
    np.testing.assert_allclose(box, [[0.035, 0.0, 0.0], [0.045, 0.047, 0.04]], atol=1e-12)
    assert not any(p.name.endswith(".tmp") for p in out.iterdir()), "no temporary files left"


def artifact_pipeline(tmp_path, seed=3):
    path = tmp_path / "artifact.yaml"
    path.write_text(
        textwrap.dedent(f"""\
        name: artifact-probe
        length_unit: mm
        scene: {ROOT}/configs/scenes/block_world.yaml
        pipeline:
          - stage: plan
            plugin: via_point
            settings: {{via_points: 300, seed: {seed}}}
            start: [60, 30, 20]
            goal: [95, 30, 20]
            artifact: {tmp_path}/viapoints.npz
        output: {{dir: {tmp_path}/out, figures: false, gltf: false}}
        """)
    )
    return path


def test_artifact_is_built_once_then_loaded_and_answers_the_same(with_example_plugin, cli, tmp_path):
    def run(seed=3):
        code, _, err = cli("run", artifact_pipeline(tmp_path, seed), "--quiet")
        assert code == 0, err
        return json.loads((tmp_path / "out" / "result.json").read_text())["stages"][0]

    first = run()
    assert first["metrics"]["artifact"] == "built"
    second = run()
    assert second["metrics"]["artifact"] == "loaded"
    assert second["path"] == first["path"]
    third = run(seed=4)  # other settings: the stored file no longer matches
    assert third["metrics"]["artifact"] == "built"


def test_corrupt_artifact_is_a_clear_error(with_example_plugin, cli, tmp_path):
    (tmp_path / "viapoints.npz").write_bytes(b"PK\x03\x04 half a zip file")
    code, _, err = cli("run", artifact_pipeline(tmp_path), "--quiet")
    assert code == 2
    assert "viapoints.npz is corrupt" in err and "delete it to rebuild" in err and "Traceback" not in err


def test_planner_failures_are_a_status_not_a_crash(with_example_plugin, cli, tmp_path):
    # from low on the left of block pair A to low on its right: the only way is the narrow gap,
    # entered and left at steep angles, which no single via point can see from both ends
    path = tmp_path / "nopath.yaml"
    path.write_text(
        textwrap.dedent(f"""\
        name: nopath
        length_unit: mm
        scene: {ROOT}/configs/scenes/block_world.yaml
        pipeline:
          - {{stage: plan, plugin: via_point, settings: {{via_points: 300}}, start: [20, 20, 20], goal: [60, 30, 20]}}
        output: {{dir: {tmp_path}/out}}
        """)
    )
    code, _, err = cli("run", path, "--quiet")
    assert code == 1
    assert "no_path" in err
    stage = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][0]
    assert stage["status"] == "no_path" and stage["path"] == []


def test_result_json_is_written_atomically(monkeypatch, tmp_path, with_example_plugin, cli):
    """A run interrupted while writing result.json leaves the previous one intact, and no temp file."""
    import surgiplan.storage as storage

    pipeline = artifact_pipeline(tmp_path)
    code, _, err = cli("run", pipeline, "--quiet")
    assert code == 0, err
    before = (tmp_path / "out" / "result.json").read_text()

    def interrupted(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(storage.os, "fsync", interrupted)
    code, _, err = cli("run", pipeline, "--quiet")
    assert code == 130 and "interrupted" in err
    assert (tmp_path / "out" / "result.json").read_text() == before
    assert not [p.name for p in (tmp_path / "out").iterdir() if p.name.endswith(".tmp")]


def test_readme_commands_exist():
    readme = (ROOT / "README.md").read_text()
    assert "make run" in readme and "make test" in readme
    makefile = (ROOT / "Makefile").read_text()
    assert "run:" in makefile and "test:" in makefile
    ci = (ROOT / ".ci" / "run").read_text()
    assert "make test" in ci
