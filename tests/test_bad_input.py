"""Bad input: each case exits 2 with a message naming what and where, no traceback, no output."""

from __future__ import annotations

import copy
import textwrap

import pytest
import trimesh
import yaml
from conftest import CONFIGS

BASE = {
    "name": "probe",
    "length_unit": "mm",
    "scene": {
        "bounds": {"min": [0, 0, 0], "max": [150, 100, 40]},
        "obstacles": [{"name": "A1", "box": {"min": [35, 0, 0], "max": [45, 47, 40]}}],
        "points": {"entry": [10, 50, 20], "target": [140, 50, 20]},
    },
    "pipeline": [
        {"stage": "plan", "plugin": "via_point", "settings": {"via_points": 50}, "start": "entry", "goal": "target"}
    ],
}


def pipeline_file(tmp_path, change=None, text=None):
    data = copy.deepcopy(BASE)
    data["output"] = {"dir": str(tmp_path / "out")}
    if change:
        change(data)
    path = tmp_path / "pipeline.yaml"
    path.write_text(text if text is not None else yaml.safe_dump(data, sort_keys=False))
    return path


def assert_clean_failure(result, tmp_path, *fragments):
    code, out, err = result
    assert code == 2, (code, out, err)
    assert "Traceback" not in err and "Traceback" not in out
    for fragment in fragments:
        assert fragment in err, f"{fragment!r} not in {err!r}"
    assert not (tmp_path / "out").exists(), "nothing may be written for bad input"


@pytest.fixture(autouse=True)
def _example(with_example_plugin):
    return with_example_plugin


def test_the_base_pipeline_is_valid(cli, tmp_path):
    code, out, err = cli("validate", pipeline_file(tmp_path))
    assert code == 0, err
    assert "ok" in out


def test_malformed_yaml(cli, tmp_path):
    text = "name: probe\npipeline: [\n  {stage: plan,\n"
    assert_clean_failure(
        cli("validate", pipeline_file(tmp_path, text=text)), tmp_path, "pipeline.yaml:", "invalid YAML"
    )


def test_unknown_top_level_key(cli, tmp_path):
    def change(d):
        d["nmae"] = d.pop("name")

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "nmae: unknown key 'nmae'",
        "did you mean 'name'?",
        "name: required key is missing",
    )


def test_unknown_plugin_name(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["plugin"] = "via_pont"

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "pipeline[0].plugin: unknown planner 'via_pont'",
        "did you mean 'via_point'?",
        "choose one of:",
    )


def test_plugin_of_the_wrong_kind(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["plugin"] = "r3"

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)), tmp_path, "unknown planner 'r3' ('r3' is a space)"
    )


def test_misspelt_setting_with_line_number(cli, tmp_path):
    text = textwrap.dedent("""\
        name: probe
        length_unit: mm
        scene: {bounds: {min: [0, 0, 0], max: [150, 100, 40]}, points: {a: [1, 1, 1], b: [9, 9, 9]}}
        pipeline:
          - stage: plan
            plugin: via_point
            settings:
              via_point: 10
            start: a
            goal: b
        """)
    assert_clean_failure(
        cli("validate", pipeline_file(tmp_path, text=text)),
        tmp_path,
        "pipeline.yaml:8: pipeline[0].settings.via_point: unknown key 'via_point'",
        "did you mean 'via_points'?",
    )


def test_wrong_type(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["settings"]["via_points"] = "many"

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "pipeline[0].settings.via_points: Input should be a valid integer",
    )


@pytest.mark.parametrize(("value", "message"), [(-3, "must be a positive length"), (float("nan"), "finite")])
def test_negative_or_nan_length(cli, tmp_path, value, message):
    def change(d):
        d["scene"]["obstacles"].append({"name": "ball", "sphere": {"radius": value}})

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)), tmp_path, "scene.obstacles[1].sphere.radius:", message
    )


def test_negative_setting_length(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["settings"]["margin"] = -1

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "pipeline[0].settings.margin: must be a non-negative length",
    )


def test_missing_mesh_file(cli, tmp_path):
    def change(d):
        d["scene"]["obstacles"].append({"name": "liver", "mesh": "meshes/liver.stl"})

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "scene.obstacles[1].mesh: mesh file not found",
        "liver.stl",
    )


def test_unreadable_mesh(cli, tmp_path):
    (tmp_path / "liver.stl").write_bytes(b"solid nonsense\n this is not an STL file at all")

    def change(d):
        d["scene"]["obstacles"].append({"name": "liver", "mesh": "liver.stl"})

    assert_clean_failure(cli("run", pipeline_file(tmp_path, change)), tmp_path, "scene.obstacles[1].mesh:", "liver.stl")


def test_mesh_paths_resolve_relative_to_the_file_that_names_them(cli, tmp_path):
    (tmp_path / "meshes").mkdir()
    trimesh.creation.icosphere(radius=5.0).export(tmp_path / "meshes" / "ball.stl")

    def change(d):
        d["scene"]["obstacles"].append({"name": "ball", "mesh": "meshes/ball.stl", "pose": {"xyz": [100, 20, 20]}})

    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    import os

    cwd = os.getcwd()
    os.chdir(elsewhere)
    try:
        code, _, err = cli("validate", pipeline_file(tmp_path, change))
    finally:
        os.chdir(cwd)
    assert code == 0, err


@pytest.mark.parametrize("key", ["start", "goal"])
def test_start_or_goal_outside_the_bounds(cli, tmp_path, key):
    def change(d):
        d["pipeline"][0][key] = [200, 50, 20]

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        f"pipeline[0].{key}: {key} (200, 50, 20) mm is outside the scene bounds",
    )


@pytest.mark.parametrize("key", ["start", "goal"])
def test_start_or_goal_inside_an_obstacle(cli, tmp_path, key):
    def change(d):
        d["pipeline"][0][key] = [40, 20, 20]

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        f"pipeline[0].{key}: {key} (40, 20, 20) mm lies inside obstacle 'A1'",
        "clearance -5 mm",
    )


def test_point_name_that_does_not_exist(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["goal"] = "tagret"

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "pipeline[0].goal: no point named 'tagret'",
        "did you mean 'target'?",
    )


def test_output_directory_not_writable(cli, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a regular file where a directory should be")
    path = pipeline_file(tmp_path)
    code, _, err = cli("run", path, "--out", blocker / "out", "--quiet")
    assert code == 2
    assert "output.dir: cannot write to output directory" in err and "Traceback" not in err


def test_several_problems_are_reported_together(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["settings"]["via_points"] = -5
        d["pipeline"][0]["settings"]["seed"] = "x"

    code, _, err = cli("validate", pipeline_file(tmp_path, change))
    assert code == 2
    assert "2 problems" in err and "via_points" in err and "seed" in err


def test_gimbal_target_out_of_reach(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["space"] = {
            "kind": "cast_gimbal",
            "fulcrum": {"xyz": [75, -60, 120], "rpy": [0, 0, "90 deg"]},
            "insertion": {"min": 20, "max": 100},
        }

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)), tmp_path, "pipeline[0].start: out of the gimbal's reach: insertion"
    )


def test_unknown_space_kind(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["space"] = {"kind": "r4"}

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "pipeline[0].space.kind: unknown space 'r4'",
        "did you mean 'r3'?",
    )


def test_shipped_configs_are_valid(cli):
    for path in sorted(CONFIGS.glob("*.yaml")):
        code, _, err = cli("validate", path)
        assert code == 0, f"{path}: {err}"


# ----------------------------------------------------------------------------- the table
# Each row: a bad input a careless user or a hostile file brings, the command, and what the message must
# say. Every row must exit 2, name the problem (file, line or YAML path where there is one), print no
# traceback and write nothing (no output directory at all).


def _set(path, value):
    """A change that sets data[path...] = value (creating nothing else)."""

    def change(d):
        target = d
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return change


def _stage(**kw):
    return {"stage": "plan", "plugin": "via_point", "start": "entry", "goal": "target", **kw}


def _text(text):
    return lambda tmp_path: pipeline_file(tmp_path, text=textwrap.dedent(text))


def _change(change):
    return lambda tmp_path: pipeline_file(tmp_path, change)


def _with_file(name, content, change):
    def make(tmp_path):
        (tmp_path / name).write_bytes(content if isinstance(content, bytes) else content.encode())
        return pipeline_file(tmp_path, change)

    return make


def _random_stl():
    import struct

    import numpy as np

    rng = np.random.default_rng(3)
    return b"\0" * 80 + struct.pack("<I", 200) + rng.bytes(50 * 200)


def _binary_stl(triangles):
    import struct

    body = b"".join(struct.pack("<12fH", 0, 0, 0, *[c for v in tri for c in v], 0) for tri in triangles)
    return b"\0" * 80 + struct.pack("<I", len(triangles)) + body


def _bomb(levels=9):
    text = "name: probe\nl0: &l0 [a, a, a, a, a, a, a, a, a]\n"
    for i in range(1, levels + 1):
        text += f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]\n"
    return text + f"pipeline: *l{levels}\n"


def _mesh_obstacle(name):
    return lambda d: d["scene"]["obstacles"].append({"name": "m", "mesh": name})


BASE_YAML = yaml.safe_dump({k: v for k, v in BASE.items() if k != "pipeline"}, sort_keys=False)

TABLE = [
    # --- the YAML itself
    ("unclosed-bracket", "validate", _text("name: p\npipeline: [\n"), ["pipeline.yaml:", "invalid YAML"]),
    ("tab-indentation", "validate", _text("name: p\npipeline:\n\t- stage: plan\n"), ["invalid YAML"]),
    ("alias-bomb", "validate", lambda t: pipeline_file(t, text=_bomb()), ["expands to more than 1,000,000 values"]),
    ("self-alias", "validate", _text("name: &a [*a]\n"), ["an alias refers to the value that contains it"]),
    (
        "duplicate-top-key",
        "validate",
        _text("name: a\nname: b\n"),
        ["pipeline.yaml:2:", "duplicate key 'name' (lines 1 and 2)"],
    ),
    (
        "duplicate-setting",
        "run",
        lambda t: pipeline_file(
            t,
            text=yaml.safe_dump(BASE, sort_keys=False).replace("via_points: 50", "via_points: 50\n    via_points: 60"),
        ),
        ["duplicate key 'via_points'"],
    ),
    ("not-a-mapping", "validate", _text("- a\n- b\n"), ["a pipeline file must be a mapping"]),
    ("empty-file", "validate", _text(""), ["a pipeline file must be a mapping"]),
    (
        "not-utf8",
        "validate",
        lambda t: (t / "pipeline.yaml").write_bytes(b"name: \xff\xfe\x00") and t / "pipeline.yaml",
        ["cannot read file"],
    ),
    (
        "python-tag",
        "validate",
        _text("name: !!python/object/apply:os.system ['true']\n"),
        ["invalid YAML", "python/object/apply"],
    ),
    # --- structure
    ("unknown-top-key", "validate", _change(_set(["nmae"], "x")), ["nmae: unknown key 'nmae'", "did you mean 'name'?"]),
    ("no-pipeline", "validate", lambda t: pipeline_file(t, text=BASE_YAML), ["pipeline: required key is missing"]),
    ("empty-pipeline", "validate", _change(_set(["pipeline"], [])), ["pipeline: List should have at least 1 item"]),
    (
        "unknown-stage-kind",
        "validate",
        _change(_set(["pipeline", 0, "stage"], "planx")),
        ["pipeline[0].stage:", "unknown stage kind 'planx'; did you mean 'plan'? choose one of: execute, guide, plan"],
    ),
    (
        "unknown-plugin",
        "validate",
        _change(_set(["pipeline", 0, "plugin"], "via_pont")),
        ["unknown planner 'via_pont'", "did you mean 'via_point'?"],
    ),
    (
        "plugin-of-another-kind",
        "validate",
        _change(_set(["pipeline", 0, "plugin"], "cast_gimbal")),
        ["unknown planner 'cast_gimbal' ('cast_gimbal' is a device)"],
    ),
    (
        "misspelt-setting",
        "validate",
        _change(_set(["pipeline", 0, "settings", "via_point"], 3)),
        ["settings.via_point: unknown key", "did you mean 'via_points'?"],
    ),
    (
        "setting-wrong-type",
        "validate",
        _change(_set(["pipeline", 0, "settings", "seed"], "x")),
        ["pipeline[0].settings.seed: Input should be a valid integer"],
    ),
    (
        "setting-zero",
        "validate",
        _change(_set(["pipeline", 0, "settings", "via_points"], 0)),
        ["settings.via_points: Input should be greater than 0"],
    ),
    (
        "negative-length",
        "validate",
        _change(_set(["pipeline", 0, "settings", "margin"], -1)),
        ["settings.margin: must be a non-negative length"],
    ),
    (
        "nan-length",
        "validate",
        _change(_set(["pipeline", 0, "settings", "margin"], float("nan"))),
        ["settings.margin: must be a finite number"],
    ),
    (
        "infinite-length",
        "validate",
        _change(_set(["pipeline", 0, "settings", "margin"], float("inf"))),
        ["settings.margin: must be a finite number"],
    ),
    (
        "unknown-length-unit-in-value",
        "validate",
        _change(_set(["pipeline", 0, "settings", "margin"], "4 parsec")),
        ["settings.margin: unknown length unit 'parsec'"],
    ),
    (
        "unknown-file-length-unit",
        "validate",
        _change(_set(["length_unit"], "inch")),
        ["length_unit: unknown length unit 'inch'"],
    ),
    (
        "length-with-garbage",
        "validate",
        _change(_set(["pipeline", 0, "settings", "margin"], "four mm")),
        ["expected a number or a number with a unit"],
    ),
    (
        "boolean-as-length",
        "validate",
        _change(_set(["pipeline", 0, "settings", "margin"], True)),
        ["expected a length (a number), got true"],
    ),
    (
        "memory-estimate",
        "validate",
        _change(_set(["pipeline", 0, "settings", "via_points"], 10**13)),
        ["settings.via_points: 10,000,000,000,000 via points needs about", "of memory; this machine allows"],
    ),
    (
        "milestones-1e9",
        "validate",
        _change(lambda d: d["pipeline"].__setitem__(0, _stage(plugin="safe_prm", settings={"milestones": 10**9}))),
        ["pipeline[0].settings.milestones: a roadmap pair of 1,000,000,000 milestones (k = 15) needs about 3.87 TiB"],
    ),
    (
        "fem-mesh-too-large",
        "validate",
        _change(
            lambda d: d["pipeline"].append(
                {
                    "stage": "simulate",
                    "plugin": "stvk",
                    "settings": {
                        "mesh": {"box": {"size": [50, 50, 2.5], "divisions": [1000, 1000, 100]}},
                        "anchored": [{"region": {"min": [0, 0, 0], "max": [0, 50, 2.5]}}],
                    },
                }
            )
        ),
        ["pipeline[1].settings.mesh: a mesh of 600,000,000 linear tetrahedra (303,606,303 unknowns) needs about"],
    ),
    (
        "duplicate-stage-names",
        "validate",
        _change(lambda d: d["pipeline"].extend([_stage(name="a"), _stage(name="a")])),
        ["stage name 'a' is used twice"],
    ),
    (
        "path-from-unknown",
        "validate",
        _change(lambda d: d["pipeline"].append({"stage": "execute", "plugin": "cast_gimbal", "path_from": "nope"})),
        ["no earlier plan stage named 'nope'"],
    ),
    (
        "execute-first",
        "validate",
        _change(_set(["pipeline"], [{"stage": "execute", "plugin": "cast_gimbal"}])),
        ["an execute stage needs an earlier plan stage"],
    ),
    ("plan-without-start", "validate", _change(lambda d: d["pipeline"][0].pop("start")), ["a plan stage needs start"]),
    (
        "path-from-on-plan",
        "validate",
        _change(_set(["pipeline", 0, "path_from"], "x")),
        ["path_from applies to execute and guide stages only"],
    ),
    (
        "unknown-executor",
        "validate",
        _change(_set(["executor"], {"kind": "slurm"})),
        ["executor.kind:", "'local' or 'dask'"],
    ),
    (
        "device-setting-typo",
        "validate",
        _change(
            lambda d: d["pipeline"].append(
                {"stage": "execute", "plugin": "cast_gimbal", "settings": {"control_rat": 100}}
            )
        ),
        ["settings.control_rat: unknown key", "did you mean 'control_rate'?"],
    ),
    # --- the scene
    (
        "bounds-inverted",
        "validate",
        _change(_set(["scene", "bounds"], {"min": [150, 0, 0], "max": [0, 100, 40]})),
        ["scene.bounds"],
    ),
    (
        "box-negative-size",
        "validate",
        _change(lambda d: d["scene"]["obstacles"].append({"name": "b", "box": {"size": [-1, 2, 2]}})),
        ["scene.obstacles[1].box.size"],
    ),
    (
        "obstacle-two-shapes",
        "validate",
        _change(
            lambda d: d["scene"]["obstacles"].append({"name": "b", "sphere": {"radius": 1}, "box": {"size": [1, 1, 1]}})
        ),
        ["scene.obstacles[1]"],
    ),
    (
        "obstacle-unknown-shape",
        "validate",
        _change(lambda d: d["scene"]["obstacles"].append({"name": "b", "cone": {"radius": 1}})),
        ["scene.obstacles[1].cone: unknown key 'cone'"],
    ),
    ("point-not-3d", "validate", _change(_set(["scene", "points", "entry"], [10, 50])), ["scene.points.entry"]),
    (
        "mesh-missing",
        "validate",
        _change(_mesh_obstacle("nowhere.stl")),
        ["scene.obstacles[1].mesh: mesh file not found", "nowhere.stl"],
    ),
    (
        "mesh-not-a-mesh",
        "validate",
        _with_file("m.stl", "solid x\n nonsense\n", _mesh_obstacle("m.stl")),
        ["scene.obstacles[1].mesh:", "m.stl"],
    ),
    (
        "mesh-random-bytes",
        "validate",
        _with_file("noise.stl", _random_stl(), _mesh_obstacle("noise.stl")),
        ["noise.stl has", "non-finite coordinates"],
    ),
    (
        "mesh-in-wrong-unit",
        "validate",
        _with_file("big.stl", _binary_stl([[(0, 0, 0), (2e7, 0, 0), (0, 2e7, 0)]]), _mesh_obstacle("big.stl")),
        ["big.stl has coordinates up to 2e+04 m after scaling", "its unit is wrong"],
    ),
    (
        "mesh-degenerate",
        "validate",
        _with_file("flat.stl", _binary_stl([[(0, 0, 0), (1, 1, 1), (2, 2, 2)]] * 3), _mesh_obstacle("flat.stl")),
        ["flat.stl has only degenerate triangles (3, all of zero area)"],
    ),
    ("scene-file-missing", "validate", _change(_set(["scene"], "scenes/none.yaml")), ["scene: scene file not found"]),
    # --- meaning
    (
        "start-outside",
        "validate",
        _change(_set(["pipeline", 0, "start"], [200, 50, 20])),
        ["start (200, 50, 20) mm is outside the scene bounds"],
    ),
    (
        "goal-inside-obstacle",
        "validate",
        _change(_set(["pipeline", 0, "goal"], [40, 20, 20])),
        ["goal (40, 20, 20) mm lies inside obstacle 'A1'", "clearance -5 mm"],
    ),
    (
        "unknown-point",
        "validate",
        _change(_set(["pipeline", 0, "goal"], "tagret")),
        ["no point named 'tagret'", "did you mean 'target'?"],
    ),
    (
        "unknown-space",
        "validate",
        _change(_set(["pipeline", 0, "space"], {"kind": "r4"})),
        ["space.kind: unknown space 'r4'"],
    ),
    (
        "space-setting-typo",
        "validate",
        _change(_set(["pipeline", 0, "space"], {"kind": "r3", "tip_radus": 1})),
        ["space.tip_radus: unknown key"],
    ),
    (
        "scene-file-as-pipeline",
        "run",
        lambda t: CONFIGS / "scenes" / "block_world.yaml",
        ["this is a scene file (bounds, obstacles, points), not a pipeline"],
    ),
]


@pytest.mark.parametrize(("command", "make", "fragments"), [row[1:] for row in TABLE], ids=[row[0] for row in TABLE])
def test_bad_input_table(cli, tmp_path, command, make, fragments):
    assert len(TABLE) >= 40
    path = make(tmp_path)
    args = [command, path] + (["--quiet", "--out", tmp_path / "out"] if command == "run" else [])
    assert_clean_failure(cli(*args), tmp_path, *fragments)


def test_every_problem_is_reported_in_one_pass_sorted_by_line(cli, tmp_path):
    """Mistakes of every pass at once: structure (a top-level typo, a stage's bad type), a plugin setting,
    the scene, a start: one `validate` lists them all, in file order."""
    text = textwrap.dedent("""\
        name: probe
        lenght_unit: mm
        length_unit: mm
        scene:
          bounds: {min: [0, 0, 0], max: [150, 100, 40]}
          obstacles:
            - {name: A1, box: {min: [35, 0, 0], max: [45, 47, 40]}}
            - {name: ball, sphere: {radius: -3}}
          points: {entry: [10, 50, 20], target: [140, 50, 20]}
        pipeline:
          - stage: plan
            plugin: via_point
            settings: {via_point: 10}
            start: entry
            goal: target
          - stage: plan
            plugin: via_point
            start: [40, 20, 20]
            goal: tagret
          - stage: plan
            plugin: via_point
            settings: {seed: many}
            start: entry
            goal: target
        """)
    code, _, err = cli("validate", pipeline_file(tmp_path, text=text))
    assert code == 2
    lines = [line.strip() for line in err.splitlines()]
    assert lines[0] == "error: 6 problems:", err
    expected = [
        "pipeline.yaml:2: lenght_unit: unknown key 'lenght_unit'",
        "pipeline.yaml:8: scene.obstacles[1].sphere.radius: must be a positive length",
        "pipeline.yaml:13: pipeline[0].settings.via_point: unknown key 'via_point'",
        # the scene had an error: its other obstacles still catch a start inside A1
        "pipeline.yaml:18: pipeline[1].start: start (40, 20, 20) mm lies inside obstacle 'A1'",
        "pipeline.yaml:19: pipeline[1].goal: no point named 'tagret'; did you mean 'target'?",
        "pipeline.yaml:22: pipeline[2].settings.seed: Input should be a valid integer",
    ]
    for fragment, line in zip(expected, lines[1:], strict=True):
        assert fragment in line, (fragment, line)
