"""Pydantic models of the scene and pipeline files (the user's contract).

Values are SI after validation: lengths typed :data:`~surgiplan.units.Length`
are scaled by the file's ``length_unit`` through the validation context.
Every model forbids unknown keys, so a misspelt key is an error that names it.
See ``DESIGN.md`` and ``configs/`` for complete examples.
"""

from __future__ import annotations

from collections import Counter
from typing import Annotated, Any, Literal

from pydantic import (
    BeforeValidator,
    Discriminator,
    Field,
    PositiveInt,
    Tag,
    model_validator,
)

from .models import PoseModel, QuaternionPoseModel, StrictModel
from .units import LENGTH_UNITS, Angle, Finite, Length, PositiveLength, Vec3

LengthUnit = Literal[tuple(LENGTH_UNITS)]  # type: ignore[valid-type]


# ----------------------------------------------------------------------------- scene


class BoundsModel(StrictModel):
    """The workspace box: corners ``min`` and ``max`` ([x, y, z] in the file's ``length_unit``); ``max`` must exceed
    ``min`` along every axis. Planners sample inside it and paths must stay in it."""

    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _non_empty(self):
        bad = [axis for axis, lo, hi in zip("xyz", self.min, self.max, strict=True) if hi <= lo]
        if bad:
            raise ValueError(f"max must exceed min along {', '.join(bad)}")
        return self


class BoxModel(StrictModel):
    """Either ``min``/``max`` corners or a ``size`` centred on the obstacle's pose."""

    min: Vec3 | None = None
    max: Vec3 | None = None
    size: tuple[PositiveLength, PositiveLength, PositiveLength] | None = None

    @model_validator(mode="after")
    def _one_form(self):
        corners = self.min is not None or self.max is not None
        if corners == (self.size is not None):
            raise ValueError("give either min and max, or size")
        if corners:
            if self.min is None or self.max is None:
                raise ValueError("give both min and max")
            bad = [a for a, lo, hi in zip("xyz", self.min, self.max, strict=True) if hi <= lo]
            if bad:
                raise ValueError(f"max must exceed min along {', '.join(bad)}")
        return self


class SphereModel(StrictModel):
    """A solid sphere of ``radius`` centred on the obstacle's pose."""

    radius: PositiveLength


class CylinderModel(StrictModel):
    """A solid cylinder along the obstacle's local z axis, centred on its pose."""

    radius: PositiveLength
    length: PositiveLength


class CapsuleModel(StrictModel):
    """``radius`` with either a ``length`` along local z (centred) or end points ``a`` and ``b``."""

    radius: PositiveLength
    length: Length | None = None
    a: Vec3 | None = None
    b: Vec3 | None = None

    @model_validator(mode="after")
    def _one_form(self):
        ends = self.a is not None or self.b is not None
        if ends == (self.length is not None):
            raise ValueError("give either length, or end points a and b")
        if ends and (self.a is None or self.b is None):
            raise ValueError("give both a and b")
        return self


def _mesh_shorthand(value: Any) -> Any:
    return {"file": value} if isinstance(value, str) else value


class MeshModel(StrictModel):
    """A mesh file (STL, OBJ, PLY, GLB, ...), relative to the file that names it.

    ``unit``: the unit of the coordinates in the mesh file (default: the
    naming file's ``length_unit``); ``scale``: an extra factor.
    """

    file: str
    unit: LengthUnit | None = None
    scale: Annotated[float, Field(gt=0, allow_inf_nan=False)] = 1.0


def _one_or_three(value: Any) -> Any:
    return [value] * 3 if isinstance(value, int | float | str) else value


class OccupancyGridModel(StrictModel):
    """A voxelised scan: a grid ``file`` (``.npy``/``.npz``; ``key`` names the array of an ``.npz``, a voxel is
    occupied when its value is at least ``threshold``) or a point cloud ``points`` (PLY, ...; in ``unit``, default
    the naming file's), with ``voxel_size`` (one length or three) and ``origin`` (the corner of voxel [0, 0, 0],
    before the obstacle's pose). Turned into boxes by greedy meshing (``surgiplan.geometry.occupancy``)."""

    file: str | None = None
    key: str | None = None
    threshold: Finite = 0.5
    points: str | None = None
    unit: LengthUnit | None = None
    voxel_size: Annotated[tuple[PositiveLength, PositiveLength, PositiveLength], BeforeValidator(_one_or_three)]
    origin: Vec3 = (0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _one_source(self):
        if (self.file is None) == (self.points is None):
            raise ValueError("give either file (a .npy/.npz grid) or points (a point cloud file)")
        if self.points is not None and self.key is not None:
            raise ValueError("key names an array of an .npz grid file; a point cloud has none")
        if self.file is not None and self.unit is not None:
            raise ValueError("unit is the point cloud's; a grid's voxels are sized by voxel_size")
        return self


class ObstacleModel(StrictModel):
    """A named obstacle: exactly one shape (``box``, ``sphere``, ``cylinder``, ``capsule`` or ``mesh``) placed by
    ``pose`` (default: at the origin, unrotated). Names are unique within a scene."""

    name: str = Field(min_length=1)
    box: BoxModel | None = None
    sphere: SphereModel | None = None
    cylinder: CylinderModel | None = None
    capsule: CapsuleModel | None = None
    mesh: Annotated[MeshModel | None, BeforeValidator(_mesh_shorthand)] = None
    occupancy_grid: OccupancyGridModel | None = None
    pose: PoseModel = Field(default_factory=PoseModel)

    @model_validator(mode="after")
    def _one_shape(self):
        given = [k for k in SHAPES if getattr(self, k) is not None]
        if len(given) != 1:
            found = ", ".join(given) if given else "none"
            raise ValueError(f"give exactly one shape ({', '.join(SHAPES)}); found {found}")
        return self

    @property
    def shape(self) -> str:
        return next(k for k in SHAPES if getattr(self, k) is not None)


SHAPES = ("box", "sphere", "cylinder", "capsule", "mesh", "occupancy_grid")


class SceneModel(StrictModel):
    """A scene file, or the ``scene:`` block of a pipeline file."""

    name: str | None = None
    length_unit: LengthUnit | None = None
    bounds: BoundsModel
    obstacles: list[ObstacleModel] = Field(default_factory=list)
    points: dict[str, Vec3] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _unique_names(self):
        names = [o.name for o in self.obstacles]
        repeated = sorted(n for n, times in Counter(names).items() if times > 1)  # linear: 10,000 voxel boxes
        if repeated:
            raise ValueError(f"obstacle names must be unique; repeated: {', '.join(repeated)}")
        return self


# ----------------------------------------------------------------------------- pipeline


class GimbalConfigurationModel(StrictModel):
    """An explicit CAST gimbal configuration."""

    yaw: Angle
    pitch: Angle
    insertion: Length
    roll: Angle = 0.0


def _endpoint_form(value: Any) -> str:
    if isinstance(value, str):
        return "name"
    if isinstance(value, dict):
        return "gimbal" if "yaw" in value or "insertion" in value else "pose"
    if isinstance(value, GimbalConfigurationModel):
        return "gimbal"
    if isinstance(value, QuaternionPoseModel):
        return "pose"
    return "point"


#: a start or goal: a point name, coordinates [x, y, z], a gimbal configuration
#: {yaw, pitch, insertion, roll} or a pose {xyz, rpy | quaternion}
Endpoint = Annotated[
    Annotated[str, Tag("name")]
    | Annotated[Vec3, Tag("point")]
    | Annotated[GimbalConfigurationModel, Tag("gimbal")]
    | Annotated[QuaternionPoseModel, Tag("pose")],
    Discriminator(_endpoint_form),
]


class ExecutorModel(StrictModel):
    """``local`` (process pool, ``workers``) or ``dask`` (scheduler ``address``)."""

    kind: Literal["local", "dask"] = "local"
    workers: PositiveInt | None = None
    address: str | None = None

    @model_validator(mode="after")
    def _address_for_dask(self):
        if self.kind == "dask" and not self.address:
            raise ValueError("the dask executor needs the scheduler's address (e.g. tcp://127.0.0.1:8786)")
        if self.kind == "local" and self.address:
            raise ValueError("address applies to the dask executor only")
        return self


class OutputModel(StrictModel):
    """Where a run writes and what: ``figures`` draws a PNG per plan stage (and ``overview.png`` when there are
    several), ``gltf`` writes the scene and the paths as ``scene.glb``."""

    #: output directory, relative to the current directory; default out/<name>
    dir: str | None = None
    figures: bool = True
    gltf: bool = True


class PipelineModel(StrictModel):
    """A pipeline file: its ``name``, the scene (inline or a file), the stages in order, where they run
    (``executor``), what they write (``output``) and the trainee record guide stages use."""

    name: str = Field(min_length=1)
    description: str | None = None
    length_unit: LengthUnit = "m"
    #: the scene inline, or the path of a scene file (relative to this file)
    scene: Annotated[
        Annotated[SceneModel, Tag("inline")] | Annotated[str, Tag("file")],
        Discriminator(lambda v: "file" if isinstance(v, str) else "inline"),
    ]
    #: the stages, each validated against the keys of its kind (surgiplan.kinds)
    pipeline: list[dict[str, Any]] = Field(min_length=1)
    executor: ExecutorModel = Field(default_factory=ExecutorModel)
    output: OutputModel = Field(default_factory=OutputModel)
    #: the trainee record (SQLite) guide stages write to and proficiency: {trainee: ...} reads; relative to the
    #: current directory, like output.dir
    record: str = "out/trainees.sqlite"
