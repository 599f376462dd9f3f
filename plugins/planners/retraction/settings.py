"""Settings of the ``retraction`` planner (paper 002, Patil & Alterovitz), SI after validation.

Lengths are :data:`~surgiplan.units.Length` typed, so a pipeline's
``length_unit: mm`` applies; angles take radians or ``"30 deg"``. The
deformable model is named by plugin and validated with that plugin's own
settings model (so ``stvk`` can be replaced by any
:class:`~surgiplan.DeformableModel`)::

    settings:
      deformable:
        plugin: stvk
        settings: {mesh: {box: {size: [50, 50, 2.5], divisions: [20, 20, 2], pattern: five}},
                   material: {youngs_modulus: 1.0e6}, base_plane: {}}
      anchored: [{min: [0, 0, 0], max: [0, 50, 2.5]}]       # rest-state boxes of held nodes
      jaws: {size: [5, 5, 4]}                                 # the gripper jaws' box (gripper frame)
      sampling: {kind: uniform, samples: 1000, region: {min: [...], max: [...]}, max_rotation: 45 deg}
      visibility: {camera: [25, 25, 150], area: [[40, 15], [60, 15], [55, 35]], threshold: 1.0}
      metric: max_energy                                      # max_stress | control_effort
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, PositiveInt, ValidationError, ValidationInfo, model_validator
from surgiplan.models import QuaternionPoseModel, RegionModel, StrictModel
from surgiplan.units import Angle, Coordinate, Length, PositiveLength, Vec3

Fraction = Annotated[float, Field(gt=0, le=1)]


class DeformableSpec(StrictModel):
    """The deformable model: a registered ``deformable_model`` plugin and its settings.

    The settings are validated with the plugin's own model when the pipeline
    is loaded and kept in SI (``model_dump(mode="json")``), so worker
    processes rebuild the same model from them.
    """

    plugin: str = "stvk"
    settings: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _validate_with_plugin(self, info: ValidationInfo):
        from surgiplan.errors import SurgiplanError
        from surgiplan.registry import default_registry

        try:
            info_ = default_registry().get("deformable_model", self.plugin)
        except SurgiplanError as exc:  # as a validation error, so that it names the file, line and key
            raise ValueError(exc.message) from None
        held = [k for k in ("anchored", "grasp") if self.settings.get(k)]
        if held:
            raise ValueError(
                f"remove {' and '.join(held)} from the deformable model's settings: the retraction planner "
                "holds the nodes in its own 'anchored' regions and grasps with its 'jaws'"
            )
        try:
            validated = info_.settings_model.model_validate(self.settings, context=info.context)
        except ValidationError as exc:
            problems = "; ".join(
                f"settings.{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors(include_url=False)
            )
            raise ValueError(f"deformable model '{self.plugin}': {problems}") from None
        self.settings = validated.model_dump(mode="json")
        return self


class JawsModel(StrictModel):
    """The gripper jaws: a box of ``size`` centred at ``offset`` in the gripper frame.

    The nodes whose rest position lies inside this box when the gripper is at
    the initial grasp are grasped; they move rigidly with the gripper (§IV-A).
    """

    size: tuple[PositiveLength, PositiveLength, PositiveLength]
    offset: Vec3 = (0.0, 0.0, 0.0)


class EdgeGraspModel(StrictModel):
    """``count`` grasps evenly spaced from ``start`` to ``end`` (e.g. along a free edge of the flap)."""

    start: Vec3
    end: Vec3
    count: PositiveInt = 5
    #: the jaws' orientation along this edge (default: the stage's start orientation)
    rpy: tuple[Angle, Angle, Angle] | None = None


class GraspCandidatesModel(StrictModel):
    """Objective 2 of the paper: the initial grasps to search exhaustively (§III, §VI).

    The stage's ``start`` is always a candidate; these are added (duplicates of it are dropped).
    """

    edges: list[EdgeGraspModel] = Field(default_factory=list)
    poses: list[QuaternionPoseModel] = Field(default_factory=list)


class SamplingModel(StrictModel):
    """How gripper configurations are sampled (§IV-A).

    ``uniform``: positions uniform in ``region``. ``guided`` (user-guided
    heuristic sampling, Fig. 4): positions in a neighbourhood of the
    polyline from the grasp through ``waypoints`` to the stage's ``goal``
    (the surgeon's estimate of the final gripper position); ``spread`` is
    the standard deviation (gaussian) or the radius (uniform tube) of the
    neighbourhood. Orientations: the grasp's, turned by a rotation drawn
    uniformly from the ball of rotations of at most ``max_rotation``.
    """

    kind: Literal["uniform", "guided"] = "uniform"
    samples: PositiveInt = 1000
    seed: int = 0
    region: RegionModel | None = None
    waypoints: list[Vec3] = Field(default_factory=list)
    spread: PositiveLength = 0.005
    neighbourhood: Literal["gaussian", "uniform"] = "gaussian"
    max_rotation: Angle = 0.7853981633974483
    #: samples per equilibrium task (each task is a warm-started chain, checkpointed when done)
    chunk: PositiveInt = 25

    @model_validator(mode="after")
    def _check(self):
        if self.kind == "uniform" and self.region is None:
            raise ValueError("uniform sampling needs a region {min, max} of gripper positions")
        if not 0 <= self.max_rotation <= 3.141592653589793:
            raise ValueError("max_rotation must lie in [0, 180 deg]")
        return self


class ReliefModel(StrictModel):
    """The local optimisation of each sample's gripper rotation (§IV-A, Fig. 3).

    Gradient descent on the rotation, position fixed, of the equilibrium's
    energy Π. By the envelope theorem dΠ/dω is the moment the jaws exert on
    the tissue about the gripper origin, so every step costs one solve.
    """

    enabled: bool = True
    max_iterations: Annotated[int, Field(ge=1)] = 2
    #: largest rotation of one step
    max_step: Angle = 0.5235987755982988
    #: stop when a step turns less than this
    tolerance: Angle = 0.017453292519943295
    #: stop once the jaws' moment |dΠ/dω| is at most this fraction of its value at the sample (0: never):
    #: near the optimal rotation the energy is about quadratic in it, so what further steps could still
    #: gain is about this fraction squared of what the relief has gained (0.2: 4 %), at a solve each
    moment_ratio: Annotated[float, Field(ge=0, lt=1)] = 0.2


class VisibilityModel(StrictModel):
    """The area of interest A (a polygon in the plane z = ``height``) and the camera V (§IV-B).

    A is sampled on a square grid of ``resolution``; a point is visible when
    the segment from it to the camera meets no occluder (the deformed flap,
    the obstacles and, with ``gripper_occludes``, the gripper). A state is a
    goal when the visible fraction of A is at least ``threshold``.
    """

    camera: Vec3
    area: list[tuple[Coordinate, Coordinate]] = Field(min_length=3)
    height: Coordinate = 0.0
    resolution: PositiveLength = 0.001
    threshold: Fraction = 1.0
    gripper_occludes: bool = True


class RoadmapModel(StrictModel):
    """Neighbours by the DISP distance and local planning along SE(3) interpolation (§IV-C)."""

    #: nearest neighbours of each state by DISP (edges are the symmetric union)
    k: PositiveInt = 10
    #: longest edge (DISP); none: no limit
    max_distance: PositiveLength | None = None
    #: largest surface-node displacement between consecutive FEM states along an edge
    step: PositiveLength = 0.002
    #: d = disp_weight * DISP + configuration_weight * d_SE3 (the paper found DISP alone works)
    disp_weight: Annotated[float, Field(ge=0)] = 1.0
    configuration_weight: Annotated[float, Field(ge=0)] = 0.0
    #: an edge's last state must come back to the stored sample within this DISP (same equilibrium branch)
    branch_tolerance: PositiveLength = 0.0005

    @model_validator(mode="after")
    def _weights(self):
        if self.disp_weight == 0 and self.configuration_weight == 0:
            raise ValueError("disp_weight and configuration_weight cannot both be 0")
        return self


class SmoothingModel(StrictModel):
    """The C¹ trajectory: a cubic spline through the path's configurations (§IV-E), re-simulated."""

    enabled: bool = True
    #: FEM states along the trajectory are at most this far apart (DISP)
    step: PositiveLength = 0.002


class RetractionSettings(StrictModel):
    deformable: DeformableSpec
    anchored: list[RegionModel] = Field(min_length=1)
    jaws: JawsModel
    sampling: SamplingModel
    visibility: VisibilityModel
    metric: Literal["max_energy", "max_stress", "control_effort"] = "max_energy"
    grasps: GraspCandidatesModel = Field(default_factory=GraspCandidatesModel)
    relief: ReliefModel = Field(default_factory=ReliefModel)
    roadmap: RoadmapModel = Field(default_factory=RoadmapModel)
    smoothing: SmoothingModel = Field(default_factory=SmoothingModel)
    #: clearance the flap and the gripper keep from the obstacles
    margin: Length = 0.0
    #: check that the instrument does not pass through the tissue away from its jaws
    instrument_tissue_check: bool = True
    #: write the figures (the states file is always written)
    figures: bool = True


__all__ = [
    "DeformableSpec",
    "EdgeGraspModel",
    "GraspCandidatesModel",
    "JawsModel",
    "RegionModel",
    "ReliefModel",
    "RetractionSettings",
    "RoadmapModel",
    "SamplingModel",
    "SmoothingModel",
    "VisibilityModel",
]
