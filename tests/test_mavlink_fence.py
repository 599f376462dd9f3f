"""The scene's fence, measured: zones against matplotlib's point-in-polygon and coal's distances, items both ways.

What is checked against something surgiplan did not write:

* PX4's inside tests (:mod:`surgiplan.plugins.devices.mavlink.zones`) against matplotlib's
  ``Path.contains_points``, on convex and non-convex polygons;
* each obstacle's zone against coal: every point closer than ``tip_radius + margin`` to the obstacle (in
  plan view: the least 3D distance over the obstacle's height) is inside its zone, and no point of the zone
  is farther than the circumscribing polygon allows (the arc step's secant);
* fence items through PX4's projection and MISSION_ITEM_INT's 1e-7 deg: vertices back within 1.1 cm.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from conftest import CONFIGS
from helpers import coal_point_distance
from matplotlib.path import Path as MplPath
from surgiplan import load_scene
from surgiplan.geometry.shapes import Box, Cylinder
from surgiplan.geometry.transforms import Pose
from surgiplan.plugins.devices.mavlink.conventions import MapProjection
from surgiplan.plugins.devices.mavlink.link import mavlink
from surgiplan.plugins.devices.mavlink.scene_fence import (
    FenceRefusal,
    FenceSettings,
    footprint,
    inflate,
    rally_positions,
    scene_fence,
)
from surgiplan.plugins.devices.mavlink.zones import (
    FenceFormatError,
    Zone,
    fence_items,
    inside_fence,
    path_clear,
    zones_from_items,
)

HALL = CONFIGS / "scenes" / "hall.yaml"
RADIUS, THRESHOLD = 0.25, 0.5
#: a route through the hall that keeps the threshold everywhere but in the door (scene m): take-off at the
#: pad, around A2 and B3 at 0.75 m and more, through the door's middle, landing at the other pad
ROUTE = np.array(
    [
        [2, 6, 0],
        [2, 6, 1.5],
        [5, 8.2, 1.5],
        [7, 8.2, 1.5],
        [10.8, 6, 1.5],
        [13.2, 6, 1.5],
        [15, 9.3, 1.5],
        [19, 9.3, 1.5],
        [22, 6, 1.5],
        [22, 6, 0],
    ],
    float,
)


def test_inside_tests_agree_with_matplotlib_on_convex_and_concave_polygons(rng):
    angles, radii = np.linspace(0, 2 * np.pi, 10, endpoint=False), np.array([3.0, 1.0] * 5)
    star = np.column_stack([np.cos(angles) * radii, np.sin(angles) * radii])
    square = np.array([[5, 5], [9, 5], [9, 9], [5, 9]], float)
    points = rng.uniform(-4, 10, (4000, 2))
    for vertices in (star, square, square[::-1]):
        zone = Zone.polygon(vertices)
        theirs = MplPath(np.vstack([vertices, vertices[:1]]), closed=True).contains_points(points)
        # points within 1e-9 of an edge are counted either way by the two; there are none in a random draw
        assert np.array_equal(zone.contains(points), theirs)
    circle = Zone.circle((2.0, -1.0), 1.5)
    assert np.array_equal(circle.contains(points), np.hypot(points[:, 0] - 2, points[:, 1] + 1) < 1.5)
    # PX4's rule for several zones: inside every inclusion zone and outside every exclusion zone
    zones = [Zone.polygon(square - 5, inclusion=True), circle]
    expected = MplPath(np.vstack([square - 5, square[:1] - 5])).contains_points(points) & ~circle.contains(points)
    assert np.array_equal(inside_fence(zones, points), expected)


def test_paths_are_judged_exactly():
    pillar = Zone.circle((5.0, 0.0), 1.0)
    box = Zone.polygon([[0, 3], [2, 3], [2, 5], [0, 5]])
    hall = Zone.polygon([[-10, -10], [10, -10], [10, 10], [-10, 10]], inclusion=True)
    zones = [hall, pillar, box]
    assert path_clear(zones, (0, 0), (4, 0)) and not path_clear(zones, (0, 0), (9, 0))  # into the pillar
    assert path_clear(zones, (0, 1.0001), (9, 1.0001)) and not path_clear(zones, (0, 0.999), (9, 0.999))
    assert not path_clear(zones, (-1, 4), (3, 4))  # through the box, both ends outside it
    assert not path_clear(zones, (0, 0), (12, 0))  # out of the hall
    # a segment that cuts the box's corner is not clear; one that only touches it (no point inside) is
    assert not path_clear(zones, (3, 2), (1, 6)) and path_clear(zones, (1, 2), (3, 4))


def test_fence_items_survive_the_wire_to_a_centimetre():
    projection = MapProjection(47.397742, 8.545594)
    zones = [
        Zone.polygon([[0, 0], [30, 0], [30, 20], [0, 20]], inclusion=True),
        Zone.polygon([[10, 5], [12, 5], [12.5, 6], [11, 7.5]]),
        Zone.circle((20.0, 12.0), 1.05),
    ]
    items = fence_items(zones, projection)
    assert [i.command for i in items] == [mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION] * 4 + [
        mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
    ] * 4 + [mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION]
    assert [i.param1 for i in items] == [4] * 4 + [4] * 4 + [1.05] and {i.frame for i in items} == {0}
    # as MISSION_ITEM_INT carries them (1e-7 deg), then back to local metres
    wire = [type(i).decode(i.encode(k, 1, 1, mavlink.MAV_MISSION_TYPE_FENCE)) for k, i in enumerate(items)]
    back, returns = zones_from_items(wire, projection)
    assert returns == 0 and [z.kind for z in back] == ["polygon", "polygon", "circle"]
    for sent, got in zip(zones, back, strict=True):
        assert got.inclusion == sent.inclusion
        if sent.vertices is not None:
            assert np.max(np.linalg.norm(got.vertices - sent.vertices, axis=1)) < 0.011
        else:
            assert np.linalg.norm(got.centre - sent.centre) < 0.011 and got.radius == pytest.approx(1.05)
    # a polygon whose vertices disagree on their count is named
    broken = list(items)
    broken[5] = type(items[5])(items[5].command, items[5].frame, items[5].x, items[5].y, 0.0, param1=5)
    with pytest.raises(FenceFormatError, match=r"item 5: vertex 1 of a 4-vertex polygon that began at item 4"):
        zones_from_items(broken, projection)


def plan_distance(obstacle, xy: np.ndarray) -> np.ndarray:
    """Distance in plan view (m) of points (x, y) to an obstacle, by coal: the least 3D distance over its
    height (41 levels)."""
    low, high = obstacle.aabb()
    levels = np.linspace(low[2], high[2], 41)
    points = np.array([[x, y, z] for x, y in xy for z in levels])
    return coal_point_distance(obstacle, points).reshape(len(xy), len(levels)).min(axis=1)


@pytest.mark.parametrize(
    "obstacle",
    [
        Box("wall", Pose.from_xyz_rpy((12, 2.7, 2), (0, 0, 0)), size=(0.3, 5.4, 4)),
        Box("crate", Pose.from_xyz_rpy((3, 4, 0.5), (0, 0, 0.6)), size=(1.2, 0.7, 1.0)),
        Cylinder("pillar", Pose.from_xyz_rpy((6, 5.1, 2), (0, 0, 0)), radius=0.3, length=4),
        Cylinder("pipe", Pose.from_xyz_rpy((8, 3, 1), (0.9, 0.3, 0.2)), radius=0.2, length=2.0),
    ],
    ids=lambda o: o.name,
)
def test_every_zone_holds_what_is_within_its_margin_and_little_more(obstacle, rng):
    distance = RADIUS + THRESHOLD
    step = math.radians(45)
    hull, centre, radius, bottom, top = footprint(obstacle)
    zone = Zone.circle(centre, radius + distance) if hull is None else Zone.polygon(inflate(hull, distance, step))
    low, high = obstacle.aabb()
    assert (bottom, top) == pytest.approx((low[2], high[2]), abs=0.02)
    xy = rng.uniform(low[:2] - distance - 0.5, high[:2] + distance + 0.5, (600, 2))
    d = plan_distance(obstacle, xy)
    inside = zone.contains(xy)
    assert inside[d < distance - 1e-6].all(), "a point within the margin is outside the zone"
    # and the zone overshoots the exact rounded footprint by at most the secant of the arc step (8 %)
    assert d[inside].max() <= distance / math.cos(step / 2) + 1e-3
    assert (hull is None) == (obstacle.name == "pillar")  # only the upright cylinder is a fence circle


def test_the_hall_fence_keeps_the_threshold_and_what_the_door_allows():
    scene = load_scene(HALL)
    fence = scene_fence(scene, ROUTE, RADIUS, THRESHOLD, FenceSettings())
    names = [z.name for z in fence.zones]
    assert names[0] == "bounds" and fence.zones[0].inclusion
    assert np.array_equal(fence.zones[0].vertices, [[0, 0], [24, 0], [24, 12], [0, 12]])
    # the lintel is flown under: PX4's zones have no bottom; every other obstacle is a zone
    assert set(fence.unfenced) == {"lintel"} and "2.2 to 4 m" in fence.unfenced["lintel"]
    assert sorted(names[1:]) == sorted(set(scene.obstacle_names) - {"lintel"})
    # the pillars keep the threshold (fence circles of 0.3 + 0.25 + 0.5 m); the door's walls, where the route
    # keeps 0.6 - 0.25 = 0.35 m (a critical region), keep that less critical_tolerance (0.1 m)
    for name in ("A1", "A2", "A3", "A4", "B1", "B2", "B3"):
        zone = fence.zones[names.index(name)]
        assert zone.kind == "circle" and zone.radius == pytest.approx(1.05) and fence.margins[name] == THRESHOLD
    assert fence.margins["wall-south"] == pytest.approx(0.25) and fence.margins["wall-north"] == pytest.approx(0.25)
    # 4 (bounds) + 8 per wall (a box's corners at 45 deg steps) + 7 circles
    assert fence.item_count == 4 + 2 * 8 + 7 == 27
    # the route is inside its own fence, leg by leg (what the vehicle's feasibility check asks)
    for a, b in itertools.pairwise(ROUTE):
        assert path_clear(fence.zones, a[:2], b[:2])
    # the ceiling is the scene's top; the annotation draws the zones from the floor to it
    assert fence.ceiling == 4.0 and fence.annotation()[1]["z"] == [0.0, 4.0]


def test_a_fence_beyond_the_vehicles_capacity_or_a_route_outside_the_bounds_is_refused_naming_why():
    scene = load_scene(HALL)
    with pytest.raises(FenceRefusal) as caught:
        scene_fence(scene, ROUTE, RADIUS, THRESHOLD, FenceSettings(capacity=20))
    message = str(caught.value)
    assert "needs 27 fence items (wall-south 8, wall-north 8, bounds 4" in message
    assert "more than the vehicle's fence capacity of 20 (fence.capacity; PX4 stores 64 fence points)" in message
    # a coarser arc step needs fewer (a box's corners as one vertex each) and fits
    coarse = scene_fence(scene, ROUTE, RADIUS, THRESHOLD, FenceSettings(capacity=20, arc_step=math.radians(90)))
    assert coarse.item_count == 4 + 2 * 4 + 7 == 19
    with pytest.raises(FenceRefusal, match=r"route point \[25.0, 6.0, 1.5\] m is outside the scene's bounds"):
        scene_fence(scene, np.vstack([ROUTE[:3], [[25, 6, 1.5]]]), RADIUS, THRESHOLD, FenceSettings())
    with pytest.raises(FenceRefusal, match=r"the route reaches z 4.000 m, the scene's top 4.000 m is the fence's"):
        scene_fence(scene, np.vstack([ROUTE[:2], [[2, 6, 4.0]]]), RADIUS, THRESHOLD, FenceSettings())
    assert rally_positions(scene, ["pad_b", (1.0, 2.0, 0.0)]).tolist() == [[22, 6, 1.5], [1, 2, 0]]
    with pytest.raises(
        FenceRefusal, match=r"rally_points\[0\]: the scene has no point 'pad_c' \(its points: pad_a, pad_b\)"
    ):
        rally_positions(scene, ["pad_c"])


def test_without_a_threshold_the_fence_keeps_the_vehicle_off_the_obstacles():
    scene = load_scene(HALL)
    fence = scene_fence(scene, ROUTE, RADIUS, None, FenceSettings())
    assert set(fence.margins.values()) == {0.0}
    assert fence.zones[[z.name for z in fence.zones].index("B2")].radius == pytest.approx(0.3 + RADIUS)
