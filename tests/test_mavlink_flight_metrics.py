"""A flight's clearance inside and outside the critical regions does not depend on where the samples fall.

The vehicle's position arrives as telemetry samples (LOCAL_POSITION_NED, 20 Hz: 5 cm apart at 1 m/s).
Classifying whole segments between samples as inside or outside a critical region made the shipped
hall flight's clearance 'outside the door' move between 0.479 and 0.504 m from one flight to the
next with the same flown path. The segments are now cut at the regions' ends; these tests fly one
straight line, sampled at different phases, and compare with the closed form.
"""

from __future__ import annotations

import numpy as np
import pytest
from surgiplan import load_scene
from surgiplan.plugins.devices.mavlink.report import flight_metrics, split_at_regions
from surgiplan.spaces import R3Space

SCENE = """\
name: one-pillar
length_unit: m
bounds: {min: [0, 0, 0], max: [1, 1, 1]}
obstacles:
  - {name: pillar, box: {min: [0.4, 0.4, 0], max: [0.6, 0.6, 1]}}
"""


@pytest.fixture()
def space(tmp_path):
    path = tmp_path / "scene.yaml"
    path.write_text(SCENE)
    return R3Space(load_scene(path))


def fly(space, phase: float, spacing: float = 0.07):
    """The straight line y = 0.3, z = 0.5 from x = 0.1 to 0.9, sampled every ``spacing`` from ``phase``."""
    x = np.concatenate([[0.1], np.arange(0.1 + phase, 0.9, spacing), [0.9]])
    flown = np.column_stack([x, np.full_like(x, 0.3), np.full_like(x, 0.5)])
    planned = np.array([[0.1, 0.3, 0.5], [0.9, 0.3, 0.5]])
    t = x - 0.1  # 1 m/s
    velocity = np.tile([1.0, 0.0, 0.0], (len(x), 1))
    # the critical region: arc length 0.25-0.55 along the planned path (x 0.35-0.65)
    metrics, _ = flight_metrics(t, flown, velocity, space, planned, (0.0, 0.8), 0.2, [(0.25, 0.55)])
    return metrics


@pytest.mark.parametrize("phase", [0.0, 0.013, 0.031, 0.05, 0.069])
def test_clearance_outside_the_region_is_the_closed_form_whatever_the_sampling(space, phase):
    m = fly(space, phase)
    # inside (x 0.35-0.65): the pillar's face at y = 0.4, 0.1 m away over x 0.4-0.6
    assert m["flown_min_clearance_in_critical_m"] == pytest.approx(0.1, abs=1e-9)
    # outside: nearest at the region's ends, x = 0.35 or 0.65, to the pillar's vertical edges
    assert m["flown_min_clearance_outside_critical_m"] == pytest.approx(np.hypot(0.05, 0.1), abs=1e-9)
    # below the 0.2 m threshold outside the region: where hypot(dx, 0.1) < 0.2 with dx > 0.05, both sides;
    # the length of the pieces that come below it, so at most one sample spacing more on each side
    below = 2 * (np.sqrt(0.2**2 - 0.1**2) - 0.05)
    assert below - 1e-9 <= m["flown_length_below_threshold_outside_critical_m"] <= below + 2 * 0.07


def test_segments_are_cut_at_the_regions_ends():
    a = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    b = np.array([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    pa, pb, inside = split_at_regions(a, b, np.array([0.0, 1.0]), np.array([1.0, 2.0]), [(0.25, 0.5), (1.5, 3.0)])
    np.testing.assert_allclose(pa[:, 0], [0.0, 0.25, 0.5, 1.0, 1.5])
    np.testing.assert_allclose(pb[:, 0], [0.25, 0.5, 1.0, 1.5, 2.0])
    assert inside.tolist() == [False, True, False, False, True]
    # a segment flown backwards along the path (arc decreasing) is cut the same way
    pa, pb, inside = split_at_regions(b[:1], a[:1], np.array([1.0]), np.array([0.0]), [(0.25, 0.5)])
    np.testing.assert_allclose(pa[:, 0], [1.0, 0.5, 0.25])
    assert inside.tolist() == [False, True, False]
