"""Shared by the bad-input tests (test_bad_input_*.py): a valid pipeline to break, and what a clean failure is."""

from __future__ import annotations

import copy

import yaml

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
