"""Visibility, collisions, grasps, sampling and the C¹ spline of the retraction planner (paper 002).

Visibility is checked against cases with an analytic answer (a flat flap
over A hides all of it; the flap folded away reveals all of it; a flap
covering half of A hides exactly that half; an occluder behind the camera
hides nothing); collisions against a direct point-in-box count; the spline
against finite differences.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation
from surgiplan.geometry.shapes import Box
from surgiplan.geometry.transforms import Pose
from surgiplan.plugins.fem import box_mesh
from surgiplan.plugins.planners.retraction.geometry import CollisionModel, boundary_faces
from surgiplan.plugins.planners.retraction.grasp import GraspFrame, nodes_in_jaws, pose_matrices
from surgiplan.plugins.planners.retraction.sampling import rotations_in_ball, sample_configurations
from surgiplan.plugins.planners.retraction.settings import JawsModel, SamplingModel, VisibilityModel
from surgiplan.plugins.planners.retraction.trajectory import SE3Spline
from surgiplan.plugins.planners.retraction.visibility import Visibility
from surgiplan.scene import Scene
from surgiplan.spaces.se3 import SE3Settings, SE3Space

MM = 1e-3


def area(camera=(15, 15, 150)):
    return VisibilityModel(
        camera=tuple(c * MM for c in camera),
        area=[(10 * MM, 10 * MM), (20 * MM, 10 * MM), (20 * MM, 20 * MM), (10 * MM, 20 * MM)],
        resolution=1 * MM,
    )


def flap(width=50.0):
    mesh = trimesh.creation.box(extents=[width * MM, 50 * MM, 2.5 * MM])
    mesh.apply_translation([width / 2 * MM, 25 * MM, 1.25 * MM])
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def test_area_of_interest_is_sampled_on_its_grid():
    v = Visibility(area(), [], [])
    assert len(v.points) == 100  # 10 x 10 cells of 1 mm
    assert np.allclose(v.points[:, 2], 1e-6)


def test_a_flat_flap_hides_the_area_and_a_flap_folded_away_reveals_it():
    v = Visibility(area(), [], [])
    vertices, faces = flap()
    assert v.fraction(vertices, faces) == 0.0
    # fold the flap 120 degrees about its anchored edge x = 0: it now lies over x < 0
    folded = Rotation.from_euler("y", -120, degrees=True).apply(vertices)
    assert folded[:, 0].max() < 1e-9
    assert v.fraction(folded, faces) == 1.0


def test_a_flap_over_half_the_area_hides_exactly_that_half():
    v = Visibility(area(), [], [])
    vertices, faces = flap(width=15.0)  # covers x < 15 mm; the camera is above x = 15 mm
    visible = v.visible(vertices, faces)
    assert np.array_equal(visible, v.points[:, 0] > 15 * MM)
    assert v.fraction(vertices, faces) == 0.5


def test_only_occluders_between_the_point_and_the_camera_count():
    plate = trimesh.creation.box(extents=[0.2, 0.2, 0.002])
    above = plate.copy().apply_translation([0.015, 0.015, 0.200])  # behind the camera (z = 150 mm)
    between = plate.copy().apply_translation([0.015, 0.015, 0.100])
    empty = (np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    assert Visibility(area(), [above], []).fraction(*empty) == 1.0
    assert Visibility(area(), [between], []).fraction(*empty) == 0.0


def test_the_gripper_occludes_when_asked():
    jaws = trimesh.creation.box(extents=[0.03, 0.03, 0.005])
    pose = pose_matrices(np.array([0.015, 0.015, 0.05, 0, 0, 0, 1.0]))
    empty = (np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    assert Visibility(area(), [], [jaws]).fraction(*empty, pose) == 0.0
    settings = area().model_copy(update={"gripper_occludes": False})
    assert Visibility(settings, [], [jaws]).fraction(*empty, pose) == 1.0


def scene_with(box_min, box_max):
    lo, hi = np.asarray(box_min) * MM, np.asarray(box_max) * MM
    obstacle = Box("block", Pose(np.eye(3), 0.5 * (lo + hi)), size=tuple(hi - lo))
    return Scene(np.array([-0.05, -0.05, -0.01]), np.array([0.1, 0.1, 0.1]), [obstacle])


def test_flap_collisions_agree_with_a_direct_count_of_nodes_inside_the_obstacle():
    mesh = box_mesh((0.05, 0.05, 0.0025), (10, 10, 2), pattern="five")
    triangles = boundary_faces(mesh.tets)
    space = SE3Space(scene_with([0, 0, 0], [1, 1, 1]), SE3Settings())
    for lo, hi, touching in [([20, 20, -5], [30, 30, 1.5], True), ([20, 20, 4], [30, 30, 8], False)]:
        scene = scene_with(lo, hi)
        model = CollisionModel.build(scene, space, triangles, np.array([0]), 0.0, False)
        inside = np.all((mesh.nodes >= np.asarray(lo) * MM) & (mesh.nodes <= np.asarray(hi) * MM), axis=1).any()
        assert inside == touching
        reason = model.check(mesh.nodes, np.array([0, 0, 0.05, 0, 0, 0, 1.0]))
        assert bool(reason) == touching
        if touching:
            assert "block" in reason
    # with a margin: the block 4 mm above the flap (top at 2.5 mm) is 1.5 mm away
    scene = scene_with([20, 20, 4], [30, 30, 8])
    near = CollisionModel.build(scene, space, triangles, np.array([0]), 2.0 * MM, False)
    far = CollisionModel.build(scene, space, triangles, np.array([0]), 1.0 * MM, False)
    q = np.array([0, 0, 0.05, 0, 0, 0, 1.0])
    assert "1.5 mm" in near.check(mesh.nodes, q) and far.check(mesh.nodes, q) == ""


def test_grasped_nodes_move_rigidly_with_the_gripper():
    mesh = box_mesh((0.05, 0.05, 0.0025), (20, 20, 2), pattern="five")
    q0 = np.array([0.05, 0.025, 0.00125, 0, 0, 0, 1.0])
    grasped = nodes_in_jaws(mesh.nodes, JawsModel(size=(0.006, 0.006, 0.005)), q0)
    expected = np.all(np.abs(mesh.nodes - q0[:3]) <= [0.003, 0.003, 0.0025], axis=1)
    assert np.array_equal(grasped, np.flatnonzero(expected)) and len(grasped) == 2 * 3 * 3
    frame = GraspFrame(mesh.nodes, np.array([0]), grasped, q0)
    assert np.allclose(frame.grasped_positions(q0), mesh.nodes[grasped])
    turn = Rotation.from_euler("xyz", [0.3, -0.5, 0.2])
    q = np.concatenate([q0[:3] + np.array([0.0, 0.01, 0.02]), turn.as_quat()])
    moved = frame.grasped_positions(q)
    assert np.allclose(moved - q[:3], turn.apply(mesh.nodes[grasped] - q0[:3]))


@pytest.mark.parametrize("max_angle", [0.3, 1.2, np.pi])
def test_rotations_are_uniform_within_the_ball(max_angle):
    angles = rotations_in_ball(np.random.default_rng(0), 20000, max_angle).magnitude()
    assert angles.max() <= max_angle + 1e-9
    # the Haar measure's angle density is proportional to 1 - cos(theta)
    grid = np.linspace(0, max_angle, 20001)
    density = 1 - np.cos(grid)
    mean = np.trapezoid(grid * density, grid) / np.trapezoid(density, grid)
    assert angles.mean() == pytest.approx(mean, rel=0.02)
    if max_angle == np.pi:  # the whole of SO(3): compare with scipy's uniform rotations
        reference = Rotation.random(20000, random_state=1).magnitude()
        assert angles.mean() == pytest.approx(reference.mean(), rel=0.02)


def test_guided_samples_lie_in_the_tube_around_the_surgeons_line():
    scene = scene_with([90, 90, 90], [95, 95, 95])
    space = SE3Space(scene, SE3Settings())
    grasp = np.array([0.05, 0.025, 0.001, 0, 0, 0, 1.0])
    goal = np.array([0.02, 0.025, 0.03])
    settings = SamplingModel(kind="guided", samples=500, spread=0.004, neighbourhood="uniform", max_rotation=0.5)
    q = sample_configurations(settings, grasp, space, goal=goal)
    a, b = grasp[:3], goal
    t = np.clip((q[:, :3] - a) @ (b - a) / np.dot(b - a, b - a), 0, 1)
    distance = np.linalg.norm(q[:, :3] - (a + t[:, None] * (b - a)), axis=1)
    assert len(q) == 500 and distance.max() <= 0.004 + 1e-12
    assert np.all(Rotation.from_quat(q[:, 3:]).magnitude() <= 0.5 + 1e-9)
    # spread along the whole line
    assert t.min() < 0.05 and t.max() > 0.95


def test_spline_passes_through_the_configurations_and_is_c1():
    rng = np.random.default_rng(2)
    rotations = Rotation.from_rotvec(np.cumsum(rng.normal(scale=0.4, size=(5, 3)), axis=0))
    q = np.concatenate([np.cumsum(rng.normal(scale=0.01, size=(5, 3)), axis=0), rotations.as_quat()], axis=1)
    knots = np.array([0.0, 0.004, 0.01, 0.013, 0.02])
    spline = SE3Spline(knots, q)
    at = spline(knots)
    assert np.allclose(at[:, :3], q[:, :3])
    assert np.allclose((Rotation.from_quat(at[:, 3:]) * rotations.inv()).magnitude(), 0, atol=1e-9)
    dense = spline(np.linspace(0, 0.02, 401))
    assert np.allclose(np.linalg.norm(dense[:, 3:], axis=1), 1)
    h = 1e-7
    for u in knots[1:-1]:  # first derivatives agree on both sides of every interior knot
        left_p, left_w = spline.velocity(u - h)
        right_p, right_w = spline.velocity(u + h)
        # a jump would be O(1); what remains is the second derivative times 2h
        assert np.allclose(left_p, right_p, atol=1e-3)
        assert np.allclose(left_w, right_w, rtol=1e-3, atol=1e-3)
    # and the rotation's rate is the derivative of the interpolated rotation (finite differences, body frame)
    u = 0.007
    r0, r1 = Rotation.from_quat(spline(u - h)[0, 3:]), Rotation.from_quat(spline(u + h)[0, 3:])
    assert np.allclose((r0.inv() * r1).as_rotvec() / (2 * h), spline.velocity(u)[1], rtol=1e-3)
