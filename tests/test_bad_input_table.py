"""Bad input, the table: a bad input a careless user or a hostile file brings, the command, what the message says.

Each row must exit 2, name the problem (file, line or YAML path where there is one), print no traceback and
write nothing (no output directory at all).
"""

from __future__ import annotations

import textwrap

import pytest
import yaml
from bad_input_support import BASE, assert_clean_failure, pipeline_file
from conftest import CONFIGS

#: the example plugin package (via_point) is what the pipelines plan with
pytestmark = pytest.mark.usefixtures("with_example_plugin")


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
    ("list-as-key", "validate", _text("name: p\n? [a, b]\n: 1\n"), ["pipeline.yaml:2:", "a key is a list"]),
    ("mapping-as-key", "validate", _text("name: p\n{a: 1}: 2\n"), ["pipeline.yaml:2:", "a key is a mapping"]),
    (
        "list-as-key-with-anchors",
        "validate",
        _text("name: &n p\n? [a, b]\n: 1\n"),
        ["pipeline.yaml:2:", "a key is a list"],
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
        ["pipeline[0].stage:", "unknown stage kind 'planx'; did you mean 'plan'? choose one of: execute, "],
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
        ["path_from applies to execute, guide and export stages only, not to plan stages"],
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
