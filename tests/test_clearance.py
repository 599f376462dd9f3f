"""One clearance concept: the stage's clearance threshold goes into the planner, the framework measures the
critical regions, and every reader takes both from the plan stage's result.

Independent measure: coal's exact point-to-box distances (conftest helpers) on the densified path."""

from __future__ import annotations

import dataclasses
import itertools
import json
import textwrap

import numpy as np
import pytest
import yaml
from conftest import CONFIGS
from surgiplan import StrictModel, load_pipeline, run_pipeline
from surgiplan.clearance import ClearancePolicy, ClearanceThreshold, CriticalRegion, critical_regions
from surgiplan.errors import ConfigErrors
from test_plugins import fake_distribution

MM = 1e-3


def plan_file(tmp_path, *stages, **top):
    data = {
        "name": "clearance",
        "length_unit": "mm",
        "scene": str(CONFIGS / "scenes" / "block_world.yaml"),
        "pipeline": list(stages),
        "output": {"dir": str(tmp_path / "out"), "figures": False, "gltf": False},
        **top,
    }
    path = tmp_path / "clearance.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def safe_prm(**keys):
    return {
        "stage": "plan",
        "name": "plan",
        "plugin": "safe_prm",
        "settings": {"milestones": 800, "seed": 2, **keys.pop("settings", {})},
        "start": "entry",
        "goal": "target",
        **keys,
    }


def test_the_stage_threshold_reaches_the_planner_and_the_regions_are_measured(tmp_path, block_world):
    pipeline = load_pipeline(plan_file(tmp_path, safe_prm(clearance_threshold=6)))
    spec = pipeline.stages[0]
    assert spec.clearance_threshold == ClearanceThreshold(0.006, "pipeline[0].clearance_threshold")
    outcome = run_pipeline(pipeline)
    result = outcome.results[0]
    assert result.metrics["d_thresh_m"] == pytest.approx(0.006)  # safe_prm planned with the stage's value
    assert result.metrics["proficiency"] == "the stage's clearance_threshold"
    entry = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][0]
    assert entry["clearance_threshold"] == {"value_m": 0.006, "source": "pipeline[0].clearance_threshold"}
    regions = [CriticalRegion.model_validate(r) for r in entry["annotations"]["critical_regions"]]
    assert regions == result.critical_regions and len(regions) >= 1
    # independently: every densely sampled point of the path closer than 6 mm (coal) lies in a reported region
    path = np.asarray(entry["path"])
    dense = np.concatenate([np.linspace(a, b, 400, endpoint=False) for a, b in itertools.pairwise(path)])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
    clearance = block_world.clearance(dense)
    below = clearance < 0.006 - 1e-6
    assert below.any()
    inside = np.zeros(len(dense), dtype=bool)
    for r in regions:
        inside |= (arc >= r.start_m - 0.2 * MM) & (arc <= r.end_m + 0.2 * MM)
        assert r.min_clearance_m == pytest.approx(clearance[(arc >= r.start_m) & (arc <= r.end_m)].min(), abs=2e-5)
    assert np.all(inside[below])


def test_two_explicit_thresholds_that_differ_are_refused_naming_both(cli, tmp_path):
    path = plan_file(tmp_path, safe_prm(settings={"proficiency": "beginner"}, clearance_threshold=4))
    code, _, err = cli("validate", path)
    assert code == 2
    assert (
        "pipeline[0].clearance_threshold: clearance_threshold 4 mm differs from the 8 mm that "
        "settings.proficiency (beginner) asks for; give one of them"
    ) in err
    # the same value twice is one threshold
    path = plan_file(tmp_path, safe_prm(settings={"proficiency": "beginner"}, clearance_threshold=8))
    assert cli("validate", path)[0] == 0


def test_the_old_margin_spelling_works_and_says_it_is_deprecated(cli, tmp_path, with_example_plugin):
    """A planner's settings.margin (OMPL, optMIS, segmented A*, the example's via_point) is the threshold's older
    spelling: still planned with, reported as deprecated with the file and line. (Not OMPL here: its random
    generator is one per process, and another test's seeded path would change.)"""
    stage = {
        "stage": "plan",
        "plugin": "via_point",
        "settings": {"via_points": 300, "seed": 2, "margin": 2},
        "start": "entry",
        "goal": "target",
    }
    path = plan_file(tmp_path, stage)
    code, _, err = cli("run", path, "--quiet")
    assert code == 0, err
    line = path.read_text().splitlines().index("    margin: 2") + 1
    assert f"warning: {path}:{line}: pipeline[0].settings.margin: settings.margin is deprecated" in err
    entry = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][0]
    assert entry["clearance_threshold"] == {"value_m": 0.002, "source": "settings.margin"}
    assert entry["metrics"]["min_clearance_m"] >= 0.002 - 1e-9


STRAIGHT = textwrap.dedent("""\
    import numpy as np
    from surgiplan import Planner, PlanResult, PlanStatus, PluginSpec, StrictModel, hookimpl

    class Straight(Planner):
        '''Claims to keep the threshold everywhere, returns the straight line whatever it is.'''
        Settings = StrictModel
        def build(self, problem): return None
        def query(self, artifact, start, goal):
            return PlanResult(PlanStatus.SOLVED, np.stack([start, goal]), clearance_threshold=0.0)

    @hookimpl
    def surgiplan_register_planners():
        return [PluginSpec("straight", Straight, "the straight line")]
    """)


def test_a_planner_that_keeps_the_threshold_everywhere_and_does_not_is_refused(tmp_path, monkeypatch):
    fake_distribution(tmp_path, "straight-pkg", "straight", STRAIGHT, monkeypatch)
    from surgiplan import registry

    registry.reset_default_registry()
    stage = {"stage": "plan", "plugin": "straight", "start": "entry", "goal": "target", "clearance_threshold": 4}
    outcome = run_pipeline(load_pipeline(plan_file(tmp_path, stage)))
    [result] = outcome.results
    # the straight line is collision free (3 mm in the 6 mm gap between A1 and A2) but not 4 mm clear
    assert result.status == "invalid_result"
    assert "its path runs below the 4 mm clearance threshold (pipeline[0].clearance_threshold)" in result.message
    assert "which planner 'straight' keeps everywhere: 2 stretch(es)" in result.message
    assert "the first from 22.3 mm to 37.7 mm along it, clearance 3 mm (near 'A" in result.message  # 25 -/+ sqrt(7)
    # without a threshold the same line is a valid plan
    stage.pop("clearance_threshold")
    outcome = run_pipeline(load_pipeline(plan_file(tmp_path, stage)))
    assert outcome.results[0].status == "solved" and outcome.results[0].critical_regions == []


def test_a_planner_without_a_clearance_policy_refuses_a_threshold(tmp_path, monkeypatch):
    """Like the retraction planner (grasps through deforming tissue): a stage threshold is an error, not ignored."""
    from surgiplan import registry
    from surgiplan.plugins.planners.retraction.planner import RetractionPlanner

    assert RetractionPlanner.clearance_policy is None
    code = STRAIGHT.replace("Settings = StrictModel\n", "Settings = StrictModel\n    clearance_policy = None\n")
    fake_distribution(tmp_path, "blind-pkg", "blind", code, monkeypatch)
    registry.reset_default_registry()
    stage = {"stage": "plan", "plugin": "straight", "start": "entry", "goal": "target", "clearance_threshold": 4}
    with pytest.raises(ConfigErrors) as raised:
        load_pipeline(plan_file(tmp_path, stage))
    [error] = raised.value.errors
    assert error.location == "pipeline[0].clearance_threshold", error.message
    assert error.message == "planner 'straight' does not plan with a clearance threshold; remove clearance_threshold"


def test_devices_and_guide_stages_read_the_plan_stage_threshold_and_regions(tmp_path):
    """The execute stage hands the device the plan's threshold and regions in its Trajectory; a guide stage
    judges against the same ones (and records them)."""
    from surgiplan.devices import Device, ExecutionReport

    seen = {}

    class Recorder(Device):
        Settings = StrictModel

        def run(self, trajectory):
            seen["trajectory"] = trajectory
            return ExecutionReport("completed", executed_tip_path=np.asarray(trajectory.path))

    stages = [
        safe_prm(settings={"proficiency": "beginner"}),
        {"stage": "execute", "name": "device", "plugin": "cast_gimbal"},
        {"stage": "guide", "name": "attempt", "plugin": "synthetic_trainee", "settings": {"level": "expert"}},
    ]
    pipeline = load_pipeline(plan_file(tmp_path, *stages))
    pipeline.stages[1].plugin = dataclasses.replace(pipeline.stages[1].plugin, cls=Recorder)
    outcome = run_pipeline(pipeline)
    plan, _, attempt = outcome.results
    trajectory = seen["trajectory"]
    assert trajectory.clearance_threshold == ClearanceThreshold(0.008, "settings.proficiency (beginner)")
    assert trajectory.critical_regions == plan.critical_regions and len(plan.critical_regions) >= 1
    assert attempt.metrics["d_thresh_m"] == pytest.approx(0.008)
    assert attempt.clearance_threshold is plan.clearance_threshold
    assert attempt.critical_regions == plan.critical_regions


def test_critical_regions_of_a_known_stretch(block_world):
    """A straight segment through the A1/A2 gap (6 mm wide) below a 4 mm threshold: one region, from where the
    clearance falls below 4 mm to where it rises again, 3 mm least clearance, both blocks named."""
    from surgiplan import R3Space

    space = R3Space(block_world)
    path = np.array([[0.020, 0.050, 0.020], [0.060, 0.050, 0.020]])
    [region] = critical_regions(space, path, 0.004)
    # below 4 mm from x = 35 - sqrt(4² - 3²) to 45 + sqrt(7) mm: arc lengths 12.354 and 27.646 mm from x = 20
    assert region.start_m == pytest.approx(0.015 - np.sqrt(7) * MM, abs=0.1 * MM)
    assert region.end_m == pytest.approx(0.025 + np.sqrt(7) * MM, abs=0.1 * MM)
    assert region.min_clearance_m == pytest.approx(0.003, abs=1e-9)
    # across the gap from nearer A1 to nearer A2 (slope 0.075): both blocks close it; the least clearance is the
    # distance of the line from the blocks' edges at x = 35 and 45 mm: 2.625 mm / sqrt(1 + 0.075²)
    [region] = critical_regions(space, np.array([[0.020, 0.0485, 0.020], [0.060, 0.0515, 0.020]]), 0.004)
    assert region.obstacles == ("A1", "A2")
    assert region.min_clearance_m == pytest.approx(0.002625 / np.hypot(1, 0.075), abs=2e-7)
    assert critical_regions(space, path, 0.0) == []
    assert ClearancePolicy("except_critical") is ClearancePolicy.EXCEPT_CRITICAL
