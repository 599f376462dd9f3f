"""Scene queries: nearest obstacle, exact motion clearance, and certified motion checks."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import (
    coal_point_distance,
    coal_scene_point_distance,
    coal_scene_segment_distance,
    dense_min_clearance,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from surgiplan.geometry.shapes import Box, Capsule, Cylinder, Sphere
from surgiplan.geometry.transforms import Pose
from surgiplan.scene import Scene
from surgiplan.spaces import CastGimbalSettings, CastGimbalSpace, R3Space, SE3Settings, SE3Space


@pytest.fixture(scope="module")
def mixed_scene():
    return Scene(
        [0, 0, 0],
        [0.15, 0.10, 0.08],
        [
            Box("block", Pose.from_xyz_rpy([0.04, 0.05, 0.02], [0, 0, 0.3]), size=(0.01, 0.05, 0.04)),
            Sphere("ball", Pose.from_xyz_rpy([0.09, 0.03, 0.03]), radius=0.012),
            Cylinder("post", Pose.from_xyz_rpy([0.11, 0.07, 0.04], [0.4, 0.2, 0]), radius=0.008, length=0.06),
            Capsule("vessel", Pose.from_xyz_rpy([0.07, 0.08, 0.06], [0, 1.2, 0.5]), radius=0.004, length=0.08),
        ],
        {"a": [0.01, 0.01, 0.01]},
    )


def test_signed_distance_names_the_nearest_obstacle(mixed_scene, rng):
    points = rng.uniform(mixed_scene.bounds_min, mixed_scene.bounds_max, (800, 3))
    distance, index = mixed_scene.signed_distance(points)
    per_obstacle = np.stack([coal_point_distance(o, points) for o in mixed_scene.obstacles])
    clear = per_obstacle.min(axis=0) > 0
    np.testing.assert_allclose(distance[clear], per_obstacle.min(axis=0)[clear], atol=1e-8)
    assert np.all(index[clear] == per_obstacle.argmin(axis=0)[clear])
    assert np.all(distance[~clear] <= 1e-9)


def test_cutoff_keeps_values_below_it_exact_and_bounds_the_rest(mixed_scene, rng):
    points = rng.uniform(mixed_scene.bounds_min, mixed_scene.bounds_max, (800, 3))
    exact, _ = mixed_scene.signed_distance(points)
    cut, _ = mixed_scene.signed_distance(points, cutoff=0.005)
    below = exact < 0.005
    np.testing.assert_allclose(cut[below], exact[below], atol=0)
    assert np.all(cut[~below] >= 0.005 - 1e-15)
    assert np.all(cut <= exact + 1e-15), "always a lower bound"


def test_motion_clearance_is_the_exact_capsule_distance(mixed_scene, rng):
    a = rng.uniform(mixed_scene.bounds_min, mixed_scene.bounds_max, (300, 3))
    b = rng.uniform(mixed_scene.bounds_min, mixed_scene.bounds_max, (300, 3))
    radius = 0.002
    ours = mixed_scene.motion_clearance(a, b, radius)
    reference = coal_scene_segment_distance(mixed_scene, a, b, radius)
    clear = reference > 1e-9
    assert clear.sum() > 50
    np.testing.assert_allclose(ours[clear], reference[clear], atol=1e-8)
    assert np.all(ours[~clear] <= 1e-9)


finite = st.floats(0.0, 1.0, allow_nan=False)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    a=st.tuples(finite, finite, finite),
    b=st.tuples(finite, finite, finite),
    margin=st.floats(0.0, 0.01),
    radius=st.floats(0.0, 0.003),
)
def test_no_motion_reported_clear_comes_closer_than_its_margin(mixed_scene, a, b, margin, radius):
    lo, hi = mixed_scene.bounds_min, mixed_scene.bounds_max
    start = lo + np.array(a) * (hi - lo)
    end = lo + np.array(b) * (hi - lo)
    clear = mixed_scene.is_motion_clear(start[None], end[None], radius, margin)[0]
    if clear:
        # dense coal distances along the motion: spacing 0.05 mm, so a violation of more
        # than that would show up between samples
        sampled = dense_min_clearance(mixed_scene, start[None], end[None], spacing=5e-5)[0] - radius
        assert sampled >= margin - 5e-5
        exact = coal_scene_segment_distance(mixed_scene, start[None], end[None], radius)[0]
        assert exact >= margin - 1e-8


def test_bounds_are_not_obstacles(block_world):
    # a point on the floor of the box is free; its clearance is to the blocks only
    d = block_world.clearance(np.array([[10.0e-3, 20e-3, 0.0]]))
    assert d[0] == pytest.approx(25e-3)
    assert not block_world.in_bounds(np.array([[0.2, 0.05, 0.02]]))[0]


# ----------------------------------------------------------------------------- spaces


def gimbal(scene, **kw) -> CastGimbalSpace:
    settings = CastGimbalSettings.model_validate(
        {"fulcrum": {"xyz": [0.075, -0.06, 0.12], "rpy": [0, 0, np.pi / 2]}, **kw}
    )
    return CastGimbalSpace(scene, settings)


def test_gimbal_inverse_kinematics_is_the_closed_form_of_forward(block_world, rng):
    space = gimbal(block_world)
    q = space.sample(rng, 500)
    q[:, 3] = 0.0
    np.testing.assert_allclose(space.inverse(space.tip(q)), q, atol=1e-12)
    # forward kinematics by an independent construction: rotate the neutral axis with scipy
    from scipy.spatial.transform import Rotation

    for qi in q[:20]:
        r = Rotation.from_euler("z", np.pi / 2) * Rotation.from_euler("ZY", [qi[0], qi[1]])
        expected = np.array([0.075, -0.06, 0.12]) + qi[2] * r.apply([1.0, 0.0, 0.0])
        np.testing.assert_allclose(space.tip(qi[None])[0], expected, atol=1e-12)


def test_gimbal_clearance_is_the_whole_shaft(block_world, rng):
    space = gimbal(block_world, shaft_radius=0.002)
    q = space.inverse(rng.uniform(block_world.bounds_min, block_world.bounds_max, (300, 3)))
    fulcrum = np.broadcast_to(space.fulcrum, (len(q), 3))
    reference = coal_scene_segment_distance(block_world, fulcrum, space.tip(q), 0.002)
    ours = space.clearance(q)
    clear = reference > 1e-9
    np.testing.assert_allclose(ours[clear], reference[clear], atol=1e-8)
    # the tip alone can be free while the shaft is not: such configurations are invalid
    tip_free = block_world.clearance(space.tip(q), 0.002) > 0
    assert np.any(tip_free & ~(ours > 0)), "the sample must contain a shaft-only collision"


def valid_gimbal_configurations(space, rng, n, margin):
    tips = rng.uniform(space.scene.bounds_min, space.scene.bounds_max, (n, 3))
    q = space.inverse(tips)
    return q[space.is_valid(q, margin)]


def test_gimbal_motions_reported_clear_keep_the_margin(block_world, rng):
    space = gimbal(block_world, shaft_radius=0.002)
    q = valid_gimbal_configurations(space, rng, 400, 0.004)
    q1, q2 = q[:-1:2], q[1::2]
    m = min(len(q1), len(q2))
    q1, q2 = q1[:m], q2[:m]
    clear = space.motion_is_clear(q1, q2, 0.004)
    assert clear.sum() >= 5 and (~clear).sum() >= 5
    t = np.linspace(0.0, 1.0, 801)
    for a, b in zip(q1[clear], q2[clear], strict=True):
        states = space.interpolate(np.repeat(a[None], len(t), 0), np.repeat(b[None], len(t), 0), t)
        fulcrum = np.broadcast_to(space.fulcrum, (len(t), 3))
        shaft = coal_scene_segment_distance(block_world, fulcrum, space.tip(states), 0.002)
        assert shaft.min() >= 0.004 - 1e-6
        assert np.all(block_world.in_bounds(space.tip(states)))


def test_gimbal_segment_clearance_is_a_tight_lower_bound(block_world, rng):
    space = gimbal(block_world, shaft_radius=0.002)
    q = valid_gimbal_configurations(space, rng, 60, 0.0)
    lower = space.segment_clearance(q[:-1], q[1:])
    t = np.linspace(0.0, 1.0, 3001)
    for i in range(len(q) - 1):
        states = space.interpolate(np.repeat(q[i][None], len(t), 0), np.repeat(q[i + 1][None], len(t), 0), t)
        sampled = space.clearance(states).min()
        assert lower[i] <= sampled + 1e-12
        assert sampled - lower[i] <= space.segment_clearance_tolerance() + 2e-5


def test_se3_body_motions_reported_clear_keep_the_margin(mixed_scene, rng):
    settings = SE3Settings.model_validate(
        {
            "body": [
                {"capsule": {"a": [0, 0, 0], "b": [0, 0, 0.02], "radius": 0.002}},
                {"box": {"size": [0.006, 0.012, 0.004]}, "pose": {"xyz": [0, 0, 0.022]}},
            ],
            "rotation_weight": 0.02,
        }
    )
    space = SE3Space(mixed_scene, settings)
    q = space.sample(rng, 120)
    q = q[space.is_valid(q, 0.002)]
    q1, q2 = q[:-1:2], q[1::2]
    m = min(len(q1), len(q2))
    # short motions, so that some are clear
    q2 = space.interpolate(q1[:m], q2[:m], np.full(m, 0.15))
    clear = space.motion_is_clear(q1[:m], q2, 0.002)
    assert clear.sum() >= 3
    t = np.linspace(0.0, 1.0, 201)
    for a, b in zip(q1[:m][clear], q2[clear], strict=True):
        states = space.interpolate(np.repeat(a[None], len(t), 0), np.repeat(b[None], len(t), 0), t)
        assert space.clearance(states).min() >= 0.002 - 1e-9


def test_se3_interpolation_is_geodesic(mixed_scene, rng):
    from scipy.spatial.transform import Rotation, Slerp

    space = SE3Space(mixed_scene, SE3Settings())
    q = space.sample(rng, 2)
    t = np.linspace(0, 1, 11)
    states = space.interpolate(np.repeat(q[:1], 11, 0), np.repeat(q[1:], 11, 0), t)
    reference = Slerp([0, 1], Rotation.from_quat(q[:, 3:]))(t)
    angle = (Rotation.from_quat(states[:, 3:]) * reference.inv()).magnitude()
    np.testing.assert_allclose(angle, 0.0, atol=1e-9)
    d = space.distance(q[0], q[1])
    steps = space.distance(states[:-1], states[1:])
    assert steps.sum() == pytest.approx(d, rel=1e-9), "distance is additive along the interpolation"


def test_r3_scene_queries_match_coal_on_the_block_world(block_world, rng):
    space = R3Space(block_world, tip_radius=0.001)
    q = space.sample(rng, 500)
    np.testing.assert_allclose(
        space.clearance(q)[space.clearance(q) > 0],
        (coal_scene_point_distance(block_world, q) - 0.001)[space.clearance(q) > 0],
        atol=1e-8,
    )
