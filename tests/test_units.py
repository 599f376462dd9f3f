"""Length units: numbers in the file's unit, explicit units in strings, SI inside."""

from __future__ import annotations

import math

import pytest
from pydantic import BaseModel, ValidationError
from surgiplan import Angle, Length, Vec3
from surgiplan.units import LENGTH_SCALE_KEY


class Probe(BaseModel):
    length: Length = 0.0
    point: Vec3 = (0.0, 0.0, 0.0)
    angle: Angle = 0.0


@pytest.mark.parametrize(
    ("unit_scale", "value", "expected"),
    [
        (1e-3, 4, 0.004),
        (1e-2, 4, 0.04),
        (1.0, 4, 4.0),
        (1e-3, "4 cm", 0.04),
        (1.0, "250 um", 250e-6),
        (1e-3, "0.5m", 0.5),
        (1e-3, "1e1 mm", 0.01),
    ],
)
def test_lengths_are_converted_once_to_metres(unit_scale, value, expected):
    probe = Probe.model_validate({"length": value, "point": [value, 0, value]}, context={LENGTH_SCALE_KEY: unit_scale})
    assert probe.length == pytest.approx(expected, rel=1e-12)
    assert probe.point[0] == pytest.approx(expected, rel=1e-12)
    # a dump is SI and validates back to the same values without a context
    again = Probe.model_validate(probe.model_dump())
    assert again == probe


def test_angles_are_radians_unless_given_in_degrees():
    assert Probe.model_validate({"angle": 0.5}).angle == 0.5
    assert Probe.model_validate({"angle": "90 deg"}).angle == pytest.approx(math.pi / 2)


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (-1, "non-negative length"),
        (float("nan"), "finite"),
        (float("inf"), "finite"),
        ("4 furlongs", "unknown length unit 'furlongs'"),
        ("four mm", "expected a number"),
        (True, "expected a length"),
    ],
)
def test_bad_lengths_are_rejected_with_the_reason(value, message):
    with pytest.raises(ValidationError, match=message):
        Probe.model_validate({"length": value}, context={LENGTH_SCALE_KEY: 1e-3})


def test_scene_file_in_mm_is_si_inside(tmp_path):
    from surgiplan import load_scene

    path = tmp_path / "s.yaml"
    path.write_text(
        "length_unit: mm\nbounds: {min: [0, 0, 0], max: [100, 50, 20]}\n"
        "obstacles:\n  - {name: b, box: {size: [10, 10, 10]}, pose: {xyz: [50, 25, 10], rpy: ['0 deg', 0, '90 deg']}}\n"
        "  - {name: s, sphere: {radius: '0.5 cm'}, pose: {xyz: [20, 20, 10]}}\n"
        "points: {p: [1, 2, 3]}\n"
    )
    scene = load_scene(path)
    assert scene.bounds_max.tolist() == pytest.approx([0.1, 0.05, 0.02])
    assert scene.points["p"].tolist() == pytest.approx([0.001, 0.002, 0.003])
    assert scene.obstacle("s").radius == pytest.approx(0.005)
    assert scene.obstacle("b").size == pytest.approx((0.01, 0.01, 0.01))
    # 15 mm from the box centre along x is 10 mm from its face
    assert scene.signed_distance([[0.065, 0.025, 0.01]])[0][0] == pytest.approx(0.010)
