"""The stvk simulate stage from pipeline files, bad input, and equilibria in worker processes."""

from __future__ import annotations

import json
import pickle
from xml.etree import ElementTree

import meshio
import numpy as np
import pytest
from conftest import CONFIGS, write
from fem_support import model
from surgiplan.executors import LocalExecutor, TaskStore, run_tasks
from surgiplan.plugins.fem.tasks import grasp_sequence_task
from surgiplan.registry import default_registry

CANTILEVER = """
name: small-cantilever
length_unit: mm
scene:
  bounds: {{min: [-10, -10, -60], max: [110, 20, 20]}}
pipeline:
  - stage: simulate
    name: beam
    plugin: stvk
    settings:
      mesh: {{box: {{size: [100, 10, 10], divisions: [10, 1, 1]}}}}
      material: {{youngs_modulus: 1.0e6, poisson_ratio: 0.3}}
      gravity: [0, 0, -9.8]
      anchored: [{{region: {{min: [0, 0, 0], max: [0, 10, 10]}}}}]
      loads: [{{region: {{min: [100, 0, 0], max: [100, 10, 10]}}, total_force: [0, 0, -0.02]}}]
      solver: {{max_iterations: {iterations}}}
{extra}
output: {{dir: out}}
"""


def test_the_stage_writes_a_vtu_and_the_metrics(tmp_path, cli):
    path = write(tmp_path / "beam.yaml", CANTILEVER.format(iterations=60, extra=""))
    code, _, err = cli("run", path, "--out", tmp_path / "out")
    assert code == 0, err
    stage = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][0]
    assert stage["status"] == "converged" and stage["files"] == ["beam.vtu", "beam.png"]
    metrics = stage["metrics"]
    for key in ("energy_J", "max_stress_Pa", "max_displacement_m", "newton_iterations", "residual", "converged"):
        assert key in metrics
    # the same equilibrium from Python (SI), independently of the pipeline's mm
    size = (0.1, 0.01, 0.01)
    m = model(
        size,
        (10, 1, 1),
        material={"youngs_modulus": 1e6, "poisson_ratio": 0.3},
        anchored=[{"region": {"min": [0, 0, 0], "max": [0, 0.01, 0.01]}}],
        loads=[{"region": {"min": [0.1, 0, 0], "max": [0.1, 0.01, 0.01]}, "total_force": [0, 0, -0.02]}],
    )
    state = m.solve(m.stage_constraints())
    displacement = np.linalg.norm(state.positions - m.rest_nodes, axis=1)
    assert metrics["max_displacement_m"] == pytest.approx(displacement.max(), rel=1e-6)
    assert metrics["energy_J"] == pytest.approx(state.energy, rel=1e-6)
    assert metrics["max_stress_Pa"] == pytest.approx(state.stress.max(), rel=1e-5)
    assert metrics["converged"] is True and metrics["residual"] < 1e-6 * 0.2  # N
    vtu = meshio.read(tmp_path / "out" / "beam.vtu")
    assert np.allclose(vtu.points, state.positions, atol=1e-9)
    assert np.allclose(vtu.point_data["displacement"], state.positions - m.rest_nodes, atol=1e-9)
    assert np.allclose(vtu.cell_data["max_principal_stress"][0], state.stress, rtol=1e-5)
    # the gripper-free tip load and gravity are carried by the clamp
    clamp = vtu.point_data["reaction_force"].sum(axis=0)
    weight = 1000 * 0.1 * 0.01 * 0.01 * 9.8
    assert clamp == pytest.approx([0, 0, 0.02 + weight], abs=1e-6)


def test_non_convergence_is_a_failed_stage_with_the_reason(tmp_path, cli):
    path = write(tmp_path / "beam.yaml", CANTILEVER.format(iterations=1, extra=""))
    code, _, _ = cli("run", path, "--out", tmp_path / "out")
    assert code == 1
    stage = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][0]
    assert stage["status"] == "failed"
    assert "did not converge in 1 Newton iterations" in stage["message"]
    assert stage["metrics"]["converged"] is False


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ("divisions: [10, 1, 1]}}", "divisions: [10, 1, 1]}, file: nowhere.vtu}"),
        ("max: [0, 10, 10]}}]", "max: [-1, 10, 10]}}]"),
        ("poisson_ratio: 0.3", "poisson_ratio: 0.5"),
        ("total_force: [0, 0, -0.02]", "total_force: [0, 0]"),
    ],
)
def test_bad_settings_are_clear_errors(tmp_path, cli, change, message):
    text = CANTILEVER.format(iterations=60, extra="").replace(change, message)
    code, _, err = cli("run", write(tmp_path / "beam.yaml", text), "--out", tmp_path / "out")
    assert code == 2
    assert "pipeline[0].settings" in err or "settings" in err
    assert "Traceback" not in err


def test_a_region_without_nodes_names_the_setting(tmp_path, cli):
    nowhere = "{region: {min: [200, 0, 0], max: [300, 1, 1]}}"
    text = CANTILEVER.format(iterations=60, extra="").replace("10, 10]}}]", "10, 10]}}, " + nowhere + "]")
    code, _, err = cli("run", write(tmp_path / "beam.yaml", text), "--out", tmp_path / "out")
    assert code == 2
    assert "settings.anchored[1].region" in err and "no node" in err


FLAP_STEPS = """
name: small-flap
length_unit: mm
scene:
  bounds: {min: [-10, -10, -10], max: [40, 40, 30]}
pipeline:
  - stage: simulate
    name: flap
    plugin: stvk
    settings:
      mesh: {box: {size: [30, 30, 2], divisions: [6, 6, 2], pattern: five}}
      anchored: [{region: {min: [0, 0, 0], max: [0, 30, 2]}}]
      grasp: {region: {min: [27.5, 12.5, 0], max: [30, 17.5, 2]}, transform: {xyz: [-3, 0, 9], rpy: [0, -30 deg, 0]}}
      base_plane: {}
      steps: 3
output: {dir: out}
"""


def lifted_and_turned_flap():
    """A 30 x 30 x 2 mm flap anchored along one edge, its far edge grasped, lifted 9 mm and turned 30 degrees."""
    return model(
        (0.03, 0.03, 0.002),
        (6, 6, 2),
        pattern="five",
        anchored=[{"region": {"min": [0, 0, 0], "max": [0, 0.03, 0.002]}}],
        grasp={
            "region": {"min": [0.0275, 0.0125, 0], "max": [0.03, 0.0175, 0.002]},
            "transform": {"xyz": [-0.003, 0, 0.009], "rpy": [0, -np.pi / 6, 0]},
        },
        base_plane={},
    )


def test_steps_apply_the_grasp_quasi_statically_and_write_a_paraview_series(tmp_path, cli):
    code, _, err = cli("run", write(tmp_path / "flap.yaml", FLAP_STEPS), "--out", tmp_path / "out")
    assert code == 0, err
    stage = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][0]
    steps = [f"flap/step_{k:03d}.vtu" for k in range(4)]
    assert stage["status"] == "converged" and stage["files"] == ["flap.vtu", "flap.png", "flap.pvd", *steps]
    metrics = stage["metrics"]
    assert metrics["step_fraction"] == pytest.approx([0, 1 / 3, 2 / 3, 1])
    assert all(metrics["step_converged"]) and metrics["steps_solved"] == 3
    assert np.all(np.diff(metrics["step_energy_J"]) > 0)  # lifting the flap stores energy at every step
    collection = ElementTree.parse(tmp_path / "out" / "flap.pvd").getroot()
    datasets = collection.findall("./Collection/DataSet")
    assert [d.get("file") for d in datasets] == steps
    assert [float(d.get("timestep")) for d in datasets] == pytest.approx([0, 1 / 3, 2 / 3, 1], abs=1e-6)
    # the last step is the one-shot equilibrium (a hyperelastic static answer does not depend on the path
    # here), and each step holds the grasp at its fraction of the rigid motion (slerp about the pivot)
    m = lifted_and_turned_flap()
    one_shot = m.solve(m.stage_constraints())
    final = meshio.read(tmp_path / "out" / "flap.vtu")
    assert np.abs(final.points - one_shot.positions).max() < 1e-6 * 0.03
    jaws = m.grasped_nodes()
    pivot = m.rest_nodes[jaws].mean(axis=0)
    middle = meshio.read(tmp_path / "out" / steps[2]).points[jaws]
    turn = np.array([[np.cos(np.pi / 9), 0, -np.sin(np.pi / 9)], [0, 1, 0], [np.sin(np.pi / 9), 0, np.cos(np.pi / 9)]])
    expected = pivot + np.array([-0.002, 0, 0.006]) + (m.rest_nodes[jaws] - pivot) @ turn.T
    assert np.abs(middle - expected).max() < 1e-12
    assert np.all(meshio.read(tmp_path / "out" / steps[2]).point_data["held"][jaws] == 1)


def test_a_step_that_fails_stops_the_sequence_and_names_the_step(tmp_path, cli):
    # the budget: what step 0 (the flap settling from rest) needs, less than step 1 (a third of the motion)
    flap = lifted_and_turned_flap()
    settled = flap.solve(flap.stage_constraints(0.0))
    budget = settled.iterations
    assert flap.solve(flap.stage_constraints(1 / 3), initial=settled).iterations > budget
    text = FLAP_STEPS.replace("steps: 3", f"steps: 3\n      solver: {{max_iterations: {budget}}}")
    code, _, _ = cli("run", write(tmp_path / "flap.yaml", text), "--out", tmp_path / "out")
    assert code == 1
    stage = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][0]
    assert stage["status"] == "failed"
    assert stage["message"].startswith(
        f"step 1 of 3 (33% of the motion): did not converge in {budget} Newton iterations"
    )
    assert stage["metrics"]["step_converged"] == [True, False]
    assert stage["files"] == ["flap.vtu", "flap.png", "flap.pvd", "flap/step_000.vtu", "flap/step_001.vtu"]


def test_a_closed_surface_meshed_by_tetgen_runs_as_quadratic_elements(tmp_path, cli):
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("tetgen")
    ball = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    ball.apply_translation((0, 0, 10))
    ball.export(tmp_path / "ball.stl")
    text = """
name: ball
length_unit: mm
scene:
  bounds: {min: [-20, -20, -5], max: [20, 20, 30]}
pipeline:
  - stage: simulate
    name: ball
    plugin: stvk
    settings:
      mesh: {file: ball.stl, order: 2}
      material: {youngs_modulus: 2.0e4, poisson_ratio: 0.45}
      anchored: [{region: {min: [-20, -20, 0], max: [20, 20, 0.5]}}]
      grasp: {region: {min: [-20, -20, 19.5], max: [20, 20, 20]}, transform: {xyz: [0, 0, -4]}}
output: {dir: out}
"""
    code, _, err = cli("run", write(tmp_path / "ball.yaml", text), "--out", tmp_path / "out")
    assert code == 0, err
    stage = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][0]
    metrics = stage["metrics"]
    assert stage["status"] == "converged" and metrics["element_order"] == 2 and metrics["valid"]
    # the clamp and the gripper squeeze the ball; together they carry exactly its weight (the mesh fills the
    # polyhedral surface, whose volume trimesh measures independently)
    vtu = meshio.read(tmp_path / "out" / "ball.vtu")
    assert vtu.cells[0].type == "tetra10"
    reactions = vtu.point_data["reaction_force"].sum(axis=0)
    weight = 1000 * 9.8 * ball.volume * 1e-9  # N
    assert reactions == pytest.approx([0, 0, weight], rel=1e-4, abs=1e-5 * weight)
    assert metrics["grasp_force_N"][2] < -0.01  # the gripper pushes down
    png = (tmp_path / "out" / "ball.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_shipped_configs_validate_and_the_plugin_is_registered(cli):
    assert "stvk" in default_registry().names("deformable_model")
    for name in ("flap_simulate.yaml", "cantilever_simulate.yaml", "flap_veins_simulate.yaml"):
        code, _, err = cli("validate", CONFIGS / name)
        assert code == 0, err


def test_models_pickle_and_solve_the_same_in_worker_processes(tmp_path):
    size = (0.03, 0.03, 0.002)
    m = model(
        size,
        (6, 6, 2),
        pattern="five",
        anchored=[{"region": {"min": [0, 0, 0], "max": [0, 0.03, 0.002]}}],
        grasp={"region": {"min": [0.0275, 0.0125, 0], "max": [0.03, 0.0175, 0.002]}},
        base_plane={},
    )
    lifts = np.repeat(np.eye(4)[None], 3, axis=0)
    lifts[:, 2, 3] = [0.002, 0.004, 0.006]
    tasks = {
        f"chunk-{k}": {"settings": m.settings.model_dump(mode="json"), "transforms": lifts[k:], "positions": True}
        for k in range(2)
    }
    with LocalExecutor(2) as executor:
        results = run_tasks(executor, grasp_sequence_task, tasks, store=TaskStore(tmp_path / "store"))
    copy = pickle.loads(pickle.dumps(m))
    state = None
    for k, lift in enumerate(lifts):
        state = copy.solve(copy.grasp_constraints(copy.grasped_nodes(), lift), initial=state)
        assert results["chunk-0"]["converged"][k] and state.converged
        assert np.abs(results["chunk-0"]["positions"][k] - state.positions).max() < 1e-6 * size[0]
        assert results["chunk-0"]["energy"][k] == pytest.approx(state.energy, rel=1e-5)
    assert results["chunk-1"]["energy"][-1] == pytest.approx(state.energy, rel=1e-5)
    assert all(m.startswith("converged in") for m in results["chunk-0"]["messages"])
    assert not results["chunk-0"]["retried"].any()
    # resumed: everything comes from the store
    again = run_tasks(LocalExecutor(1), lambda _: pytest.fail("recomputed"), tasks, store=TaskStore(tmp_path / "store"))
    assert np.array_equal(again["chunk-1"]["energy"], results["chunk-1"]["energy"])


PROBE = (
    "      probes:\n"
    "        - {name: tip_deflection, region: {min: [100, 0, 0], max: [100, 10, 10]}, direction: [0, 0, -2],"
    " reference: %s, source: a reference}\n"
)


def test_a_probe_reports_a_displacement_against_its_reference(tmp_path, cli):
    path = write(tmp_path / "beam.yaml", CANTILEVER.format(iterations=60, extra=PROBE % "12.5"))
    code, _, err = cli("run", path, "--out", tmp_path / "out")
    assert code == 0, err
    metrics = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][0]["metrics"]
    # independently: the mean downward displacement of the tip nodes in the written .vtu (direction normalised)
    vtu = meshio.read(tmp_path / "out" / "beam.vtu")
    rest = vtu.points - vtu.point_data["displacement"]
    tip = np.isclose(rest[:, 0], 0.1)
    measured = -vtu.point_data["displacement"][tip, 2].mean()
    assert tip.sum() == 4 and measured > 0.001
    assert metrics["tip_deflection_m"] == pytest.approx(measured, rel=1e-9)
    assert metrics["tip_deflection_reference_m"] == pytest.approx(0.0125)  # mm in the file, m in the metrics
    assert metrics["tip_deflection_relative_error"] == pytest.approx((measured - 0.0125) / 0.0125, rel=1e-9)
    assert metrics["tip_deflection_source"] == "a reference"


def test_a_probe_that_selects_no_node_is_reported_before_anything_is_written(tmp_path, cli):
    extra = PROBE.replace("min: [100, 0, 0], max: [100, 10, 10]", "min: [200, 0, 0], max: [210, 10, 10]") % "1"
    path = write(tmp_path / "beam.yaml", CANTILEVER.format(iterations=60, extra=extra))
    code, _, err = cli("run", path, "--out", tmp_path / "out")
    assert code == 2
    assert "probes[0].region: the probe's region contains no node of the mesh" in err
    assert "Traceback" not in err
    assert not (tmp_path / "out" / "beam.vtu").exists() and not (tmp_path / "out" / "beam.png").exists()


def test_the_figure_colours_up_to_the_largest_stress():
    from surgiplan.plugins.fem.figure import stress_norm

    stress = np.array([1.0e3, 2.0e4, 3.0e5, 1.889e6, np.inf, np.nan])
    norm = stress_norm(stress / 1e3)
    assert norm.vmin == 0 and norm.vmax == pytest.approx(1889.0)  # to the maximum, not a percentile
    assert norm(1889.0) == pytest.approx(1.0) and norm(1889.0 / 4) == pytest.approx(0.5)  # square-root spaced
