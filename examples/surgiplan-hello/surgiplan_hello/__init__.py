"""An example third-party surgiplan package: one plugin of each kind, and a stage kind of its own.

Copy it to start your own. Every plugin is small but real, and each is
exercised by surgiplan's test suite (``tests/test_examples.py``):

* :mod:`.via_point` — planner ``via_point``: the straight motion if it is
  clear, else the best detour through one stored via point (build, query,
  stored artifact, a memory estimate);
* :mod:`.planar` — space ``planar``: the instrument tip, a sphere, moving in
  a horizontal plane at a fixed height (2 coordinates);
* :mod:`.spring_chain` — deformable model ``spring_chain``: a chain of nodes
  joined by linear springs under gravity, solved exactly (and a ``simulate``
  stage comparing its sag with the closed form);
* :mod:`.point_robot` — device ``point_robot``: a simulated 3-axis gantry that
  refuses paths closer to an obstacle than its safety margin, then follows
  them at constant speed with a first-order lag and reports what it did;
* :mod:`.steady_hand` — pose source ``steady_hand``: a hand following the
  recommended path at constant speed with a tremor, for ``stage: guide``
  (its deviation has a closed form);
* :mod:`.export` — stage kind ``export``: a planned path timed within
  velocity and acceleration limits and written for a robot, by exporter
  plugins of its own plugin kind (``joint_csv``, ``ros_joint_trajectory``).

The whole registration is this module plus one table in ``pyproject.toml``::

    [project.entry-points.surgiplan]
    hello = "surgiplan_hello"
"""

from __future__ import annotations

from surgiplan import PluginSpec, hookimpl

from .export import ExportKind, JointCsv, RosJointTrajectory
from .planar import PlanarSpace
from .point_robot import PointRobot
from .spring_chain import SpringChain
from .steady_hand import SteadyHand
from .via_point import ViaPointPlanner

__all__ = [
    "ExportKind",
    "JointCsv",
    "PlanarSpace",
    "PointRobot",
    "RosJointTrajectory",
    "SpringChain",
    "ViaPointPlanner",
]


@hookimpl
def surgiplan_register_planners():
    return [PluginSpec("via_point", ViaPointPlanner, "straight line, or a detour through one via point")]


@hookimpl
def surgiplan_register_spaces():
    return [PluginSpec("planar", PlanarSpace, "the tip, a sphere, in a horizontal plane at a fixed height")]


@hookimpl
def surgiplan_register_deformable_models():
    return [PluginSpec("spring_chain", SpringChain, "a chain of linear springs under gravity, solved exactly")]


@hookimpl
def surgiplan_register_devices():
    return [PluginSpec("point_robot", PointRobot, "a simulated 3-axis gantry with a safety margin")]


@hookimpl
def surgiplan_register_sources():
    return [PluginSpec("steady_hand", SteadyHand, "a hand following the recommended path with a tremor")]


@hookimpl
def surgiplan_register_stage_kinds():
    return [ExportKind()]


@hookimpl
def surgiplan_register_exporters():
    return [
        PluginSpec("joint_csv", JointCsv, "time, positions, velocities and accelerations per coordinate (CSV)"),
        PluginSpec("ros_joint_trajectory", RosJointTrajectory, "a ROS 2 trajectory_msgs/JointTrajectory (YAML)"),
    ]
