"""The retraction planner end to end (paper 002) on a coarse flap, checked independently.

A 50 x 50 x 2.5 mm flap (8 x 8 x 1 cells) anchored along x = 0 is grasped
on its free edge; a bar hangs above it; the area of interest lies beneath
the free edge. The plan's trajectory is re-solved state by state with a
fresh ``stvk`` model, its states checked for inverted elements, its flap
and gripper measured against the bar with coal, and the end state's
visibility re-computed with an independent ray-triangle test.
"""

from __future__ import annotations

import copy
import json

import coal
import numpy as np
import pytest
import yaml
from pipeline_support import retraction_flap, retraction_pipeline
from surgiplan import load_pipeline, run_pipeline
from surgiplan.plugins.fem import StVKModel, StVKSettings
from surgiplan.plugins.planners.retraction.equilibria import _Chain, _moment, _moment_by_differences, relieve
from surgiplan.plugins.planners.retraction.grasp import GraspFrame, configuration
from surgiplan.storage import load_bundle

MM = 1e-3
FLAP = retraction_flap((8, 8, 1))
BASE = retraction_pipeline(
    "retraction-test",
    (8, 8, 1),
    samples=25,
    chunk=13,
    grasps={"edges": [{"start": [50, 12.5, 1.25], "end": [50, 37.5, 1.25], "count": 2}]},
)


def pipeline_file(path, out, change=None):
    data = copy.deepcopy(BASE)
    data["output"] = {"dir": str(out)}
    if change:
        change(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    root = tmp_path_factory.mktemp("retraction")
    file = pipeline_file(root / "p.yaml", root / "out")
    outcome = run_pipeline(load_pipeline(file))
    result = json.loads((root / "out" / "result.json").read_text())["stages"][0]
    arrays, _ = load_bundle(root / "out" / "page-states.npz")
    return {"root": root, "file": file, "outcome": outcome, "result": result, "states": arrays}


def test_plan_is_solved_and_writes_its_files(plan):
    result = plan["result"]
    assert result["status"] == "solved", result.get("message")
    assert set(result["files"]) >= {"page-states.npz", "page-retraction.png", "page-profile.png"}
    for name in result["files"]:
        assert (plan["root"] / "out" / name).stat().st_size > 0
    m = result["metrics"]
    assert m["goal_reached"] and m["visible_fraction"] == 1.0
    assert m["samples"] == 3 * 25 and 0 < m["valid_samples"] <= m["samples"]
    assert m["max_energy_J"] >= m["cost"] * (1 - 1e-9) or m["spline_pieces"] > 0
    assert len(result["path"]) == m["trajectory_states"]


def model():
    return StVKModel(
        StVKSettings.model_validate(
            FLAP | {"mesh": {"box": {"size": [0.05, 0.05, 0.0025], "divisions": [8, 8, 1], "pattern": "five"}}}
        )
    )


def ray_hits(origins, targets, triangles):
    """Möller-Trumbore in numpy: does segment origin -> target cross any triangle (t, 3, 3)?"""
    d = targets - origins
    v0, e1, e2 = triangles[:, 0], triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    p = np.cross(d[:, None, :], e2[None])
    det = np.einsum("tk,rtk->rt", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = origins[:, None, :] - v0[None]
        u = np.einsum("rtk,rtk->rt", s, p) * inv
        qv = np.cross(s, e1[None])
        v = np.einsum("rk,rtk->rt", d, qv) * inv
        t = np.einsum("tk,rtk->rt", e2, qv) * inv
    hit = (np.abs(det) > 1e-18) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9) & (t < 1 - 1e-9)
    return hit.any(axis=1)


def test_every_state_of_the_trajectory_is_an_equilibrium_valid_and_clear(plan):
    states = plan["states"]
    q, positions = states["q"], states["positions"].astype(float)
    fem = model()
    anchored = fem.nodes_in_region([0, 0, 0], [0, 0.05, 0.0025])
    grasp = q[0]
    frame_nodes = np.flatnonzero(np.all(np.abs(fem.rest_nodes - grasp[:3]) <= [0.0035, 0.0035, 0.002], axis=1))
    frame = GraspFrame(fem.rest_nodes, np.setdiff1d(anchored, frame_nodes), frame_nodes, grasp)
    state = None
    bar = coal.Box(0.010, 0.060, 0.004)
    bar_pose = coal.Transform3s(np.eye(3), np.array([0.013, 0.025, 0.022]))
    tets = fem.elements
    for i in range(len(q)):
        state = fem.solve(frame.constraints(q[i]), initial=state)  # an independent chain from the grasp
        assert state.converged
        assert np.max(np.abs(state.positions - positions[i])) < 2e-5  # the stored state is this equilibrium
        x = positions[i]
        edges = x[tets[:, 1:]] - x[tets[:, :1]]
        assert np.all(np.linalg.det(edges) > 0)  # no inverted element
        # the flap's surface against the bar, measured by coal
        tri = states["triangles"]
        bvh = coal.BVHModelOBBRSS()
        bvh.beginModel(len(tri), len(x))
        bvh.addVertices(x)
        bvh.addTriangles(tri.astype(np.int64))
        bvh.endModel()
        assert coal.distance(bvh, coal.Transform3s(), bar, bar_pose, coal.DistanceRequest(), coal.DistanceResult()) > 0
    # the gripper clear of the bar at every state
    pipeline = load_pipeline(plan["file"])
    assert np.all(pipeline.stages[0].space.clearance(q) > 0)


def test_the_area_of_interest_is_visible_at_the_end_by_an_independent_ray_test(plan):
    states = plan["states"]
    end = states["positions"][-1].astype(float)
    triangles = end[states["triangles"]]
    points = states["area_points"]
    camera = np.array([0.040, 0.025, 0.150])
    assert not ray_hits(points, np.repeat(camera[None], len(points), 0), triangles).any()
    start = states["positions"][0].astype(float)[states["triangles"]]
    assert ray_hits(points, np.repeat(camera[None], len(points), 0), start).all()  # hidden at the grasp
    assert states["visible"].all()


def test_the_chosen_grasp_is_the_cheapest_candidate_and_its_cost_is_reproduced_alone(plan, tmp_path):
    m = plan["result"]["metrics"]
    candidates = m["grasp_candidates"]
    assert len(candidates) == 3
    costs = [c["cost"] if c["cost"] is not None else np.inf for c in candidates]
    assert m["grasp"] == int(np.argmin(costs)) and m["cost"] == min(costs)
    # plan another candidate on its own (same samples: the seed follows the grasp; equilibria are reused)
    other = next(i for i, c in enumerate(candidates) if i != m["grasp"] and c["cost"] is not None)

    def alone(d):
        stage = d["pipeline"][0]
        stage["start"] = {"xyz": [c / MM for c in candidates[other]["xyz_m"]]}
        stage["settings"]["grasps"] = {}
        stage["settings"]["figures"] = False

    file = pipeline_file(plan["root"] / "alone.yaml", plan["root"] / "out", alone)
    outcome = run_pipeline(load_pipeline(file))
    assert outcome.results[0].metrics["cost"] == pytest.approx(candidates[other]["cost"], rel=1e-9)


def test_control_effort_plan_uses_the_same_equilibria(plan):
    def effort(d):
        d["pipeline"][0]["settings"]["metric"] = "control_effort"
        d["pipeline"][0]["settings"]["figures"] = False
        d["pipeline"][0]["settings"]["grasps"] = {}

    file = pipeline_file(plan["root"] / "effort.yaml", plan["root"] / "out", effort)
    outcome = run_pipeline(load_pipeline(file))
    m = outcome.results[0].metrics
    assert outcome.results[0].status == "solved"
    assert m["metric"] == "control_effort" and m["cost"] > 0 and m["control_effort_Jm"] > 0


def test_stored_artifact_is_loaded_and_gives_the_same_plan(tmp_path):
    def small(d):
        d["pipeline"][0]["settings"]["grasps"] = {}
        d["pipeline"][0]["settings"]["sampling"]["samples"] = 12
        d["pipeline"][0]["settings"]["sampling"]["chunk"] = 6
        d["pipeline"][0]["settings"]["figures"] = False
        d["output"]["figures"] = False
        d["pipeline"][0]["artifact"] = str(tmp_path / "page.npz")

    file = pipeline_file(tmp_path / "p.yaml", tmp_path / "out", small)
    first = run_pipeline(load_pipeline(file)).results[0]
    # an interrupted build resumes: remove one checkpointed chunk, keep the other
    stored = sorted((tmp_path / "out" / ".work" / "retraction-equilibria").glob("*.npz"))
    chunks = [f for f in stored if "-assess-" not in f.name]
    assert len(chunks) == 2 and len(stored) == 4  # two chunks of equilibria, and their assessments
    chunks[0].unlink()
    (tmp_path / "page.npz").rename(tmp_path / "kept.npz")
    rebuilt = run_pipeline(load_pipeline(file)).results[0]
    assert rebuilt.metrics["artifact"] == "built"
    (tmp_path / "kept.npz").replace(tmp_path / "page.npz")
    loaded = run_pipeline(load_pipeline(file)).results[0]
    assert loaded.metrics["artifact"] == "loaded"
    for other in (rebuilt, loaded):
        assert other.status == first.status
        assert other.metrics.get("cost") == first.metrics.get("cost")
        assert np.array_equal(other.path, first.path)


def test_no_goal_state_is_no_path_with_the_reason(tmp_path):
    def blind(d):
        # a plate between the camera and the area of interest: A can never be seen
        d["scene"]["obstacles"].append({"name": "plate", "box": {"min": [30, 10, 90], "max": [60, 40, 92]}})
        d["pipeline"][0]["settings"]["grasps"] = {}
        d["pipeline"][0]["settings"]["sampling"]["samples"] = 10

    outcome = run_pipeline(load_pipeline(pipeline_file(tmp_path / "p.yaml", tmp_path / "out", blind)))
    result = outcome.results[0]
    assert result.status == "no_path"
    assert "no goal state" in result.message and "exposes 100%" in result.message
    assert not outcome.ok


def test_rotation_relief_follows_the_energy_gradient_and_relieves_the_grasp():
    fem = model()
    q0 = np.array([0.05, 0.025, 0.00125, 0, 0, 0, 1.0])
    grasped = np.flatnonzero(np.all(np.abs(fem.rest_nodes - q0[:3]) <= [0.0035, 0.0035, 0.002], axis=1))
    anchored = np.setdiff1d(fem.nodes_in_region([0, 0, 0], [0, 0.05, 0.0025]), grasped)
    frame = GraspFrame(fem.rest_nodes, anchored, grasped, q0)
    chain = _Chain.__new__(_Chain)
    chain.model, chain.frame, chain.collision, chain.fem_s, chain.validation_s = fem, frame, None, 0.0, 0.0
    from scipy.spatial.transform import Rotation

    twisted = configuration([0.04, 0.025, 0.012], Rotation.from_euler("xyz", [0.5, -0.3, 0.4]).as_matrix())
    state = chain.solve(twisted, chain.rest())
    assert state.converged and state.valid
    # the envelope theorem: the jaws' moment is dΠ/dω (checked against finite differences of Π)
    moment = _moment(chain, state, twisted)
    assert np.allclose(moment, _moment_by_differences(chain, state, twisted, h=1e-5), rtol=2e-3, atol=1e-7)
    near = np.isin(fem.elements, grasped).any(axis=1)
    q, relaxed, iterations, angle, _ = relieve(
        chain, twisted, state, {"max_step": 0.5, "tolerance": 0.01, "max_iterations": 4}
    )
    assert iterations >= 1 and angle > 0.05
    assert np.allclose(q[:3], twisted[:3])  # the position is kept
    assert relaxed.energy < state.energy
    assert np.linalg.norm(_moment(chain, relaxed, q)) < 0.5 * np.linalg.norm(moment)
    assert relaxed.stress[near].max() < state.stress[near].max()


def test_the_relief_stops_once_the_moment_has_fallen_to_the_given_fraction():
    from scipy.spatial.transform import Rotation
    from surgiplan.plugins.planners.retraction.settings import ReliefModel

    assert ReliefModel().model_dump()["moment_ratio"] == 0.2  # the planner's default
    fem = model()
    q0 = np.array([0.05, 0.025, 0.00125, 0, 0, 0, 1.0])
    grasped = np.flatnonzero(np.all(np.abs(fem.rest_nodes - q0[:3]) <= [0.0035, 0.0035, 0.002], axis=1))
    anchored = np.setdiff1d(fem.nodes_in_region([0, 0, 0], [0, 0.05, 0.0025]), grasped)
    chain = _Chain.__new__(_Chain)
    chain.model, chain.frame, chain.collision, chain.fem_s, chain.validation_s = (
        fem,
        GraspFrame(fem.rest_nodes, anchored, grasped, q0),
        None,
        0.0,
        0.0,
    )
    twisted = configuration([0.04, 0.025, 0.012], Rotation.from_euler("xyz", [0.5, -0.3, 0.4]).as_matrix())
    state = chain.solve(twisted, chain.rest())
    moment = float(np.linalg.norm(_moment(chain, state, twisted)))
    options = {"max_step": 0.5, "tolerance": 0.01, "max_iterations": 4}
    full = relieve(chain, twisted, state, {**options, "moment_ratio": 0.0})
    q1, first, iterations, _, _ = relieve(chain, twisted, state, {**options, "max_iterations": 1})
    after_first = float(np.linalg.norm(_moment(chain, first, q1)))
    assert full[2] >= 2 and iterations == 1 and after_first < moment  # the first step is taken and helps
    ratio = 0.5 * (after_first / moment + 1.0)  # above what the first step leaves: the descent stops there
    q1, first, iterations, _, _ = relieve(chain, twisted, state, {**options, "moment_ratio": ratio})
    assert iterations == 1 and first.energy < state.energy
    assert np.linalg.norm(_moment(chain, first, q1)) <= ratio * moment
    assert first.energy >= full[1].energy  # what the further steps would have gained, given up


def test_a_grasp_that_already_exposes_the_area_needs_no_motion(tmp_path):
    def uncovered(d):
        settings = d["pipeline"][0]["settings"]
        settings["visibility"]["area"] = [[55, 20], [60, 20], [60, 30], [55, 30]]  # beside the flap
        settings["grasps"] = {}
        settings["sampling"]["samples"] = 6
        settings["figures"] = False
        d["output"]["figures"] = False

    result = run_pipeline(load_pipeline(pipeline_file(tmp_path / "p.yaml", tmp_path / "out", uncovered))).results[0]
    assert result.status == "solved"
    assert result.metrics["trajectory_states"] == 1 and result.metrics["visible_fraction"] == 1.0
    # a plan has two waypoints at least (the framework's rule): q0 to q0, a motion of length zero
    assert np.allclose(result.path, [[0.05, 0.025, 0.00125, 0, 0, 0, 1]] * 2)


class InterfaceOnly(StVKModel):
    """A deformable model whose states carry nothing beyond the interface: no reactions, no timings."""

    def solve(self, constraints, initial=None):
        state = super().solve(constraints, initial)
        state.data = {}
        state.reaction_forces = None
        return state


def test_a_model_with_only_the_interface_gets_finite_difference_relief():
    from surgiplan.plugins.planners.retraction.equilibria import sample_chain
    from surgiplan.plugins.planners.retraction.geometry import boundary_faces

    fem = model()
    assert {tuple(sorted(t)) for t in boundary_faces(fem.elements)} == {tuple(sorted(t)) for t in fem.surface_triangles}
    q0 = np.array([0.05, 0.025, 0.00125, 0, 0, 0, 1.0])
    grasped = np.flatnonzero(np.all(np.abs(fem.rest_nodes - q0[:3]) <= [0.0035, 0.0035, 0.002], axis=1))
    anchored = np.setdiff1d(fem.nodes_in_region([0, 0, 0], [0, 0.05, 0.0025]), grasped)
    from scipy.spatial.transform import Rotation

    twisted = configuration([0.04, 0.025, 0.012], Rotation.from_euler("xyz", [0.5, -0.3, 0.4]).as_matrix())
    args = {
        "model_settings": fem.settings.model_dump(mode="json"),
        "frame": GraspFrame(fem.rest_nodes, anchored, grasped, q0),
        "collision": None,
        "relief": {"enabled": True, "max_iterations": 2, "max_step": 0.5, "tolerance": 0.01},
        "configurations": twisted[None],
    }
    exact = sample_chain({**args, "model_class": StVKModel})
    generic = sample_chain({**args, "model_class": InterfaceOnly})
    assert generic["ok"][0] and generic["relief_iterations"][0] >= 1
    assert generic["grasp_stress_after"][0] < generic["grasp_stress_before"][0]
    # the finite-difference gradient leads the relief the same way as the exact moment
    turn = Rotation.from_quat(generic["q"][0, 3:]) * Rotation.from_quat(exact["q"][0, 3:]).inv()
    assert turn.magnitude() < 0.05


class FailsAway(StVKModel):
    """A model that raises on configurations far from the grasp (a numerical failure of the model)."""

    def solve(self, constraints, initial=None):
        if np.max(constraints.prescribed_positions[:, 2]) > 0.02:
            raise np.linalg.LinAlgError("Singular matrix")
        return super().solve(constraints, initial)


def test_a_model_that_raises_on_one_sample_loses_that_sample_not_the_chain():
    from surgiplan.plugins.planners.retraction.equilibria import sample_chain

    fem = model()
    q0 = np.array([0.05, 0.025, 0.00125, 0, 0, 0, 1.0])
    grasped = np.flatnonzero(np.all(np.abs(fem.rest_nodes - q0[:3]) <= [0.0035, 0.0035, 0.002], axis=1))
    anchored = np.setdiff1d(fem.nodes_in_region([0, 0, 0], [0, 0.05, 0.0025]), grasped)
    q = np.array(
        [[0.048, 0.025, 0.01, 0, 0, 0, 1.0], [0.045, 0.025, 0.03, 0, 0, 0, 1.0], [0.046, 0.025, 0.012, 0, 0, 0, 1]]
    )
    out = sample_chain(
        {
            "model_class": FailsAway,
            "model_settings": fem.settings.model_dump(mode="json"),
            "frame": GraspFrame(fem.rest_nodes, anchored, grasped, q0),
            "collision": None,
            "relief": {"enabled": False, "max_iterations": 1, "max_step": 0.5, "tolerance": 0.01},
            "configurations": q,
        }
    )
    assert out["ok"].tolist() == [True, False, True]
    reason = out["reason"][1]
    assert "the deformable model 'test_retraction_plan.FailsAway' failed: LinAlgError: Singular matrix" in reason


def test_a_chain_gives_the_same_states_whatever_its_worker_solved_before():
    """Results must not depend on the executor's scheduling: a worker keeps its model between tasks."""
    from surgiplan.plugins.planners.retraction.equilibria import edge_chain, sample_chain

    fem = model()
    q0 = np.array([0.05, 0.025, 0.00125, 0, 0, 0, 1.0])
    grasped = np.flatnonzero(np.all(np.abs(fem.rest_nodes - q0[:3]) <= [0.0035, 0.0035, 0.002], axis=1))
    anchored = np.setdiff1d(fem.nodes_in_region([0, 0, 0], [0, 0.05, 0.0025]), grasped)
    from scipy.spatial.transform import Rotation

    tilt = Rotation.from_euler("xyz", [0.3, -0.2, 0.1]).as_matrix()
    base = {
        "model_class": StVKModel,
        "model_settings": fem.settings.model_dump(mode="json"),
        "frame": GraspFrame(fem.rest_nodes, anchored, grasped, q0),
        "collision": None,
        "relief": {"enabled": True, "max_iterations": 2, "max_step": 0.5, "tolerance": 0.01},
    }
    lifted = configuration([0.044, 0.025, 0.011], np.eye(3))
    chunk = {**base, "configurations": np.array([configuration([0.046, 0.025, 0.008], tilt), lifted])}
    other = {**base, "configurations": np.array([configuration([0.04, 0.02, 0.015], tilt.T)])}
    first = sample_chain(chunk)
    sample_chain(other)  # the same process (and model) solves something else in between
    again = sample_chain(chunk)
    assert first["ok"].all()
    for name in ("q", "positions", "energy", "max_stress", "relief_iterations"):
        assert np.asarray(first[name]).tobytes() == np.asarray(again[name]).tobytes(), name
    edge = {"q": again["q"][1:], "start": first["positions"][0], "end": first["positions"][1]}
    edges = {**base, "edges": [edge], "surface_nodes": fem.surface_nodes, "branch_tolerance": 5e-4}
    one = edge_chain(edges)
    sample_chain(other)
    assert one["energies"] == edge_chain(edges)["energies"]
