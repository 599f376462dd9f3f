"""The scene's broad phase for many obstacles (``surgiplan.geometry.bvh``) answers as the brute force does.

On a scene of 300 primitives (boxes, some turned, and spheres, cylinders, capsules among them): clearances of
points and segments equal the all-obstacle brute force (``geometry.compiled.nearest``) to 1e-9 m, below a cutoff
too, and the certified verdicts of a roadmap's edges are the same. coal's own distance (an independent measure)
agrees with the tree's answer on a sample.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import coal_scene_point_distance
from surgiplan.geometry import bvh, compiled
from surgiplan.geometry.shapes import Box, Capsule, Cylinder, Sphere
from surgiplan.geometry.transforms import Pose
from surgiplan.scene import Scene


def many_primitives(count: int, seed: int = 0) -> Scene:
    rng = np.random.default_rng(seed)
    obstacles = []
    for i in range(count):
        yaw = rng.uniform(0, np.pi) if i % 7 == 0 else 0.0
        pose = Pose.from_xyz_rpy(rng.uniform(0.0, 0.1, 3), [0.3 * yaw, 0.0, yaw])
        kind = i % 10
        if kind < 7:
            obstacles.append(Box(f"b{i}", pose, size=tuple(rng.uniform(0.001, 0.006, 3))))
        elif kind == 7:
            obstacles.append(Sphere(f"s{i}", pose, radius=float(rng.uniform(0.001, 0.004))))
        elif kind == 8:
            obstacles.append(Cylinder(f"c{i}", pose, radius=0.0015, length=float(rng.uniform(0.002, 0.008))))
        else:
            obstacles.append(Capsule(f"p{i}", pose, radius=0.001, length=float(rng.uniform(0.002, 0.008))))
    return Scene([0, 0, 0], [0.1, 0.1, 0.1], obstacles)


def brute_force(scene: Scene, a, b, cutoff):
    scene._prepare()
    return compiled.distances(scene._packed, a, None if b is None else b, cutoff)


@pytest.fixture(scope="module")
def scene() -> Scene:
    scene = many_primitives(300)
    scene._prepare()
    assert scene._tree is not None, "300 primitives must query through the tree"
    return scene


@pytest.mark.parametrize("cutoff", [np.inf, 0.004])
def test_tree_distances_equal_the_brute_force(scene, cutoff):
    rng = np.random.default_rng(2)
    a = rng.uniform(-0.01, 0.11, (4000, 3))
    # PRM-like edges, and a few long ones across the whole scene (a query's direct connection)
    b = a + rng.normal(0, 0.01, a.shape)
    b[:50] = rng.uniform(-0.01, 0.11, (50, 3))
    for ends in (None, b):
        ours, ours_index = scene.signed_distance(a, cutoff) if ends is None else scene.segment_distance(a, b, cutoff)
        ref, ref_index = brute_force(scene, a, ends, cutoff)
        below = ref < cutoff
        assert below.sum() > 400 and (ref < 0).sum() > 20, "the sample must reach inside and between obstacles"
        np.testing.assert_allclose(ours[below], ref[below], rtol=0, atol=1e-9)
        assert np.array_equal(ours_index[below], ref_index[below])
        # above the cutoff both are lower bounds of at least the cutoff: the decision is the same
        assert np.array_equal(ours < cutoff, below)


def test_tree_verdicts_equal_the_brute_force(scene):
    """The certified motion check of a roadmap's edges, tree against all-obstacle brute force: the same verdicts."""
    rng = np.random.default_rng(3)
    q = rng.uniform(0.0, 0.1, (3000, 3))
    a, b = q[:-1], q[1:] + rng.normal(0, 0.004, (len(q) - 1, 3)) - q[1:] + q[:-1]
    for radius, margin in ((0.0, 0.0), (0.0005, 0.001)):
        ours = scene.is_motion_clear(a, b, radius, margin)
        ref = brute_force(scene, a, b, radius + margin + 1e-12)[0] - radius
        expected = ref > 0 if margin <= 0 else ref >= margin
        assert 100 < ours.sum() < len(ours) - 100, "both verdicts must occur"
        assert np.array_equal(ours, expected)


def test_tree_agrees_with_coal(scene):
    rng = np.random.default_rng(4)
    points = rng.uniform(0.0, 0.1, (300, 3))
    ours = scene.signed_distance(points)[0]
    ref = coal_scene_point_distance(scene, points)
    outside = ref > 0
    np.testing.assert_allclose(ours[outside], ref[outside], atol=1e-8)
    assert np.all(ours[~outside] <= 1e-9)


def test_tree_holds_every_obstacle_once(scene):
    node_low, node_high, node_depth, child, start, count, order = scene._tree
    assert np.all(node_depth >= 0)
    assert sorted(order.tolist()) == list(range(len(scene.obstacles)))
    leaves = child < 0
    assert count[leaves].sum() == len(scene.obstacles) and count[leaves].max() <= bvh.LEAF
    # every node's box holds its obstacles' world boxes
    low, high = scene._packed[6], scene._packed[7]
    for node in range(len(child)):
        members = order[start[node] : start[node] + count[node]]
        assert np.all(low[members] >= node_low[node]) and np.all(high[members] <= node_high[node])
