"""Stage kinds are plugins: the example package's ``export`` kind plugs in through the same entry points as any
plugin (``surgiplan_register_stage_kinds``), with a plugin kind of its own, and the registry refuses what
is not a stage kind.

The exported trajectory is checked independently of the code that wrote it: read back with PyYAML and
numpy, it passes through every waypoint of the plan, never exceeds a velocity or acceleration limit
(measured by finite differences of the positions), and on every segment some limit is reached (no time
is wasted)."""

from __future__ import annotations

import itertools
import json
import textwrap

import numpy as np
import pytest
import yaml
from conftest import CONFIGS
from surgiplan.registry import PluginRegistry
from test_plugins import fake_distribution

VMAX = [0.05, 0.04, 0.03]  # m/s, per coordinate
AMAX = 0.25  # m/s², every coordinate


def export_pipeline(tmp_path, *exports, plan=None):
    data = {
        "name": "export",
        "length_unit": "mm",
        "scene": str(CONFIGS / "scenes" / "block_world.yaml"),
        "pipeline": [
            plan
            or {
                "stage": "plan",
                "name": "plan",
                "plugin": "safe_prm",
                "settings": {"milestones": 800, "seed": 2},
                "start": "entry",
                "goal": "target",
            },
            *exports,
        ],
        "output": {"dir": str(tmp_path / "out"), "figures": False, "gltf": False},
    }
    path = tmp_path / "export.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def export_stage(plugin, **keys):
    return {
        "stage": "export",
        "plugin": plugin,
        "velocity_limit": VMAX,
        "acceleration_limit": AMAX,
        "rate": 200,
        **keys,
    }


def test_export_writes_a_ros_joint_trajectory_and_a_csv_a_robot_can_follow(cli, tmp_path, with_example_plugin):
    path = export_pipeline(
        tmp_path,
        export_stage("ros_joint_trajectory", name="ros", file="trajectory.yaml"),
        export_stage("joint_csv", name="csv"),
    )
    code, out, err = cli("run", path)
    assert code == 0, err
    assert "samples," in out  # the kind's own line in the summary table
    out_dir = tmp_path / "out"
    document = json.loads((out_dir / "result.json").read_text())
    plan, ros, _ = document["stages"]
    assert (ros["stage"], ros["status"], ros["files"]) == ("export", "written", ["trajectory.yaml"])
    waypoints = np.asarray(plan["path"])

    message = yaml.safe_load((out_dir / "trajectory.yaml").read_text())
    assert message["joint_names"] == ["x", "y", "z"] and message["header"]["frame_id"] == "world"
    points = message["points"]
    t = np.array([p["time_from_start"]["sec"] + 1e-9 * p["time_from_start"]["nanosec"] for p in points])
    q = np.array([p["positions"] for p in points])
    qd = np.array([p["velocities"] for p in points])
    qdd = np.array([p["accelerations"] for p in points])
    assert all(0 <= p["time_from_start"]["nanosec"] < 1_000_000_000 for p in points)
    assert t[0] == 0 and np.all(np.diff(t) > 0)
    # through every waypoint, at rest
    knots = [int(np.argmin(np.linalg.norm(q - w, axis=1))) for w in waypoints]
    assert np.all(np.diff(knots) > 0)
    np.testing.assert_allclose(q[knots], waypoints, atol=1e-12)
    np.testing.assert_allclose(qd[knots], 0.0, atol=1e-12)
    # within the limits, measured on the positions themselves (the slope of a sampled trapezoid is below its
    # peak speed), and the reported velocities agree with those slopes
    slopes = np.diff(q, axis=0) / np.diff(t)[:, None]
    assert np.all(np.abs(slopes) <= np.asarray(VMAX) * (1 + 1e-6))
    assert np.all(np.abs(qd) <= np.asarray(VMAX) * (1 + 1e-9)) and np.all(np.abs(qdd) <= AMAX * (1 + 1e-9))
    mid = 0.5 * (qd[1:] + qd[:-1])
    np.testing.assert_allclose(slopes, mid, atol=0.02 * max(VMAX))
    # time-optimal per segment: on each, some coordinate reaches its velocity or its acceleration limit
    for a, b in itertools.pairwise(knots):
        v_used = np.max(np.abs(qd[a : b + 1]) / np.asarray(VMAX))
        a_used = np.max(np.abs(qdd[a : b + 1]) / AMAX)
        assert max(v_used, a_used) == pytest.approx(1.0, abs=1e-9)
    assert ros["metrics"]["duration_s"] == pytest.approx(t[-1], abs=1e-9)

    table = np.genfromtxt(out_dir / "csv.csv", delimiter=",", names=True)
    assert table.dtype.names == ("t_s", "x", "y", "z", "x_vel", "y_vel", "z_vel", "x_acc", "y_acc", "z_acc")
    np.testing.assert_allclose(table["t_s"], t, atol=1e-9)
    np.testing.assert_allclose(np.column_stack([table["x"], table["y"], table["z"]]), q, atol=1e-9)

    # the report plays the exported motion back like an execution (the kind's report contribution)
    html = (out_dir / "report.html").read_text()
    start = html.index('<script type="application/json" id="surgiplan-data">') + 52
    data = json.loads(html[start : html.index("</script>", start)])
    drawn = {s["name"]: s for s in data["stages"]}
    assert drawn["ros"]["timeline"]["source"] == "timeline" and drawn["ros"]["timeline"]["samples"] == len(t)
    assert drawn["ros"]["reference"]["name"] == "plan"


@pytest.mark.parametrize(
    "keys, fragment",
    [
        ({"velocity_limit": [0.05, 0.05]}, "velocity_limit has 2 values; the r3 space of plan stage 'plan' has 3"),
        ({"acceleration_limit": -1}, "acceleration_limit: must be a positive number or a list of them"),
        ({"file": "../outside.yaml"}, "must be a file name in the run's output directory"),
        ({"settings": {"frame": "map"}}, "settings.frame: unknown key 'frame'; did you mean 'frame_id'?"),
        ({"plugin": "gcode"}, "unknown exporter 'gcode'; choose one of: joint_csv, ros_joint_trajectory"),
        ({"path_from": "nope"}, "no earlier plan stage named 'nope'"),
        ({"guidance": {}}, "guidance applies to guide stages only, not to export stages"),
    ],
)
def test_export_keys_are_checked_like_the_built_in_kinds(cli, tmp_path, with_example_plugin, keys, fragment):
    stage = export_stage("ros_joint_trajectory")
    stage.update(keys)
    code, _, err = cli("validate", export_pipeline(tmp_path, stage))
    assert code == 2 and fragment in err, err
    assert "Traceback" not in err


def test_without_the_package_installed_an_export_stage_names_the_kinds_there_are(cli, tmp_path):
    code, _, err = cli("validate", export_pipeline(tmp_path, export_stage("joint_csv")))
    assert code == 2
    assert "pipeline[1].stage: unknown stage kind 'export'; choose one of: execute, guide, plan, simulate" in err


KIND_PLUGIN = textwrap.dedent("""\
    from surgiplan import hookimpl
    from surgiplan.kinds import StageKind

    class Count(StageKind):
        name = "count"
        def run(self, run):
            return run.result("done")

    @hookimpl
    def surgiplan_register_stage_kinds():
        return {kinds}
    """)


def test_the_registry_refuses_what_is_not_a_stage_kind(tmp_path, monkeypatch):
    fake_distribution(tmp_path, "bad-kinds", "bad_kinds", KIND_PLUGIN.format(kinds="[object(), Count()]"), monkeypatch)
    registry = PluginRegistry()
    assert "count" in registry.stage_kinds and registry.stage_kinds["count"].package == "bad-kinds"
    [failure] = registry.failures
    assert "stage kind" in failure.error and "not an instance of a surgiplan.kinds.StageKind subclass" in failure.error


def test_a_stage_kind_cannot_take_a_built_in_name(tmp_path, monkeypatch):
    code = KIND_PLUGIN.replace('name = "count"', 'name = "plan"').format(kinds="[Count()]")
    fake_distribution(tmp_path, "clash-kinds", "clash_kinds", code, monkeypatch)
    registry = PluginRegistry()
    assert registry.stage_kinds["plan"].package == "surgiplan"
    assert any("stage kind 'plan' is already registered by package 'surgiplan'" in f.error for f in registry.failures)


def test_a_plugin_for_a_kind_nobody_installed_is_refused_by_name(tmp_path, monkeypatch):
    code = textwrap.dedent("""\
        from surgiplan import hookimpl

        @hookimpl
        def surgiplan_register_exporters():
            return []
        """)
    fake_distribution(tmp_path, "orphan-pkg", "orphan", code, monkeypatch)
    registry = PluginRegistry()
    [failure] = registry.failures
    assert failure.package == "orphan-pkg"
    assert "implements surgiplan_register_exporters, which no installed stage kind declares" in failure.error
    assert "ompl" in registry.names("planner")  # the rest loads
