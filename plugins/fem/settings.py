"""Settings of the ``stvk`` model (and of its ``simulate`` stage), SI after validation.

Lengths are :data:`~surgiplan.units.Length`/:data:`~surgiplan.units.Vec3`
typed, so a pipeline's ``length_unit: mm`` applies to them; material values
are in Pa and kg/m^3, gravity in m/s^2 (never scaled by ``length_unit``).
A relative mesh or image file is resolved against the pipeline file's
directory when the settings are validated, so the settings alone rebuild
the model (in a worker process, for instance).

Example (the paper's flap, mm)::

    settings:
      mesh: {box: {size: [50, 50, 2.5], divisions: [20, 20, 2], pattern: five}}
      material: {youngs_modulus: 1.0e6, poisson_ratio: 0.45, density: 1000}
      gravity: [0, 0, -9.8]
      anchored: [{region: {min: [0, 0, 0], max: [0, 50, 2.5]}}]
      grasp: {region: {min: [48, 22, 0], max: [50, 28, 2.5]}, transform: {xyz: [0, 0, 10]}}
      base_plane: {point: [0, 0, 0]}
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, PositiveFloat, PositiveInt, ValidationInfo, model_validator
from surgiplan.models import PoseModel, RegionModel, StrictModel
from surgiplan.units import LENGTH_SCALE_KEY, LENGTH_UNITS, Coordinate, Finite, PositiveLength, Vec3
from surgiplan.validation import file_length_scale, input_path

LengthUnit = Literal[tuple(LENGTH_UNITS)]  # type: ignore[valid-type]
PoissonRatio = Annotated[float, Field(ge=-0.99, lt=0.5)]


def _resolve(path: str, info: ValidationInfo) -> str:
    return str(input_path(path, info))


class BoxMeshModel(StrictModel):
    """A structured box mesh: ``size`` (lengths), ``divisions`` (cells per axis), ``origin`` (lowest corner)."""

    size: tuple[PositiveLength, PositiveLength, PositiveLength]
    divisions: tuple[PositiveInt, PositiveInt, PositiveInt]
    origin: Vec3 = (0.0, 0.0, 0.0)
    #: tetrahedra per hexahedral cell: six (around the cell's diagonal) or five
    pattern: Literal["six", "five"] = "six"


class MeshSettings(StrictModel):
    """Either a ``box`` or a ``file`` (a volume mesh meshio reads, or a closed surface for TetGen).

    ``order: 2`` turns linear tetrahedra into quadratic (10-node) ones, which
    do not lock in bending; a file of ``tetra10`` cells is quadratic anyway.
    """

    box: BoxMeshModel | None = None
    file: str | None = None
    #: element order: 1 (4-node tetrahedra) or 2 (10-node: a node at the middle of every edge)
    order: Literal[1, 2] = 1
    #: unit of the file's coordinates (default: the pipeline's length_unit)
    unit: LengthUnit | None = None
    #: TetGen only: target largest tetrahedron volume, m^3 (TetGen keeps to it approximately)
    max_tet_volume: PositiveFloat | None = None
    #: metres per file unit; filled in at validation
    file_scale: float = Field(default=1.0, gt=0)

    @model_validator(mode="after")
    def _one_source(self, info: ValidationInfo):
        if (self.box is None) == (self.file is None):
            raise ValueError("give exactly one of box or file")
        if self.file is not None:
            self.file = _resolve(self.file, info)
            if not Path(self.file).is_file():
                raise ValueError(f"mesh file not found: {self.file}")
            if self.unit is not None:
                self.file_scale = LENGTH_UNITS[self.unit]
            elif info.context and LENGTH_SCALE_KEY in info.context:
                self.file_scale = file_length_scale(info)
        return self


class ImageRegionModel(StrictModel):
    """A grey-scale image laid over the x-y rectangle ``min``-``max``; pixels past ``threshold`` select."""

    file: str
    min: tuple[Coordinate, Coordinate]
    max: tuple[Coordinate, Coordinate]
    threshold: float = Field(default=0.5, ge=0, le=1)
    #: select dark pixels (veins drawn dark on light); false selects bright ones
    dark: bool = True

    @model_validator(mode="after")
    def _check(self, info: ValidationInfo):
        self.file = _resolve(self.file, info)
        if not Path(self.file).is_file():
            raise ValueError(f"image file not found: {self.file}")
        if self.max[0] <= self.min[0] or self.max[1] <= self.min[1]:
            raise ValueError("max must exceed min along x and y")
        return self


class MaterialRegionModel(StrictModel):
    """Material of the elements whose rest centroid is in ``region`` or on the ``image``'s selected pixels."""

    region: RegionModel | None = None
    image: ImageRegionModel | None = None
    youngs_modulus: PositiveFloat | None = None
    poisson_ratio: PoissonRatio | None = None
    density: Annotated[float, Field(ge=0)] | None = None

    @model_validator(mode="after")
    def _one_selector(self):
        if (self.region is None) == (self.image is None):
            raise ValueError("give exactly one of region or image")
        if self.youngs_modulus is None and self.poisson_ratio is None and self.density is None:
            raise ValueError("give at least one of youngs_modulus, poisson_ratio, density")
        return self


class MaterialSettings(StrictModel):
    """St. Venant-Kirchhoff tissue: E (Pa), nu, rho (kg/m^3), and regions that override them."""

    youngs_modulus: PositiveFloat = 1.0e6
    poisson_ratio: PoissonRatio = 0.45
    density: Annotated[float, Field(ge=0)] = 1000.0
    #: volume-penalty modulus as a fraction of the bulk modulus (0 turns it off)
    volume_penalty: Annotated[float, Field(ge=0)] = 0.1
    regions: list[MaterialRegionModel] = Field(default_factory=list)


class AnchorModel(StrictModel):
    """Nodes in ``region`` held at their rest position along ``axes`` (all three: anchored)."""

    region: RegionModel
    axes: list[Literal["x", "y", "z"]] = Field(default_factory=lambda: ["x", "y", "z"], min_length=1)


class LoadModel(StrictModel):
    """A dead load: ``total_force`` (N) shared equally by the nodes in ``region``."""

    region: RegionModel
    total_force: tuple[Finite, Finite, Finite]


class GraspModel(StrictModel):
    """Nodes in ``region`` moved rigidly: ``x = pivot + xyz + R(rpy) (X - pivot)``.

    ``pivot`` defaults to the centroid of the grasped nodes' rest positions.
    """

    region: RegionModel
    transform: PoseModel = Field(default_factory=PoseModel)
    pivot: Vec3 | None = None


class BasePlaneModel(StrictModel):
    """The underlying base (penalty contact): the plane through ``point`` with upward ``normal``.

    ``stiffness`` N/m per node; default ``E h / 10`` (E the mean Young's
    modulus, h the mean edge length): a node of the paper's flap sinks
    0.2 micrometres under its own weight. Stiffer penalties make Newton's
    method slower where nodes touch down or lift off.
    """

    point: Vec3 = (0.0, 0.0, 0.0)
    normal: tuple[Finite, Finite, Finite] = (0.0, 0.0, 1.0)
    stiffness: PositiveFloat | None = None


class ProbeModel(StrictModel):
    """A displacement a simulate stage reports: the mean displacement of the nodes in ``region`` along
    ``direction`` (a unit vector; e.g. [0, 0, -1] for a deflection downwards), optionally against a
    ``reference`` value (a length, with its ``source``): the metrics then give the relative error."""

    name: Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")]
    region: RegionModel
    direction: tuple[Finite, Finite, Finite] = (0.0, 0.0, 1.0)
    reference: Coordinate | None = None
    #: where the reference comes from (shown in the figure and the metrics)
    source: str = ""

    @model_validator(mode="after")
    def _direction(self):
        length = sum(c * c for c in self.direction) ** 0.5
        if not length > 0:
            raise ValueError("direction must not be zero")
        self.direction = tuple(c / length for c in self.direction)
        return self


class SolverSettings(StrictModel):
    """Newton's stopping rules (see ``newton.py``)."""

    #: largest residual force on a free node, relative to the largest applied force or reaction
    residual_tol: PositiveFloat = 1e-6
    #: largest node motion of the last Newton step, relative to the mean edge length
    step_tol: PositiveFloat = 1e-4
    max_iterations: PositiveInt = 60
    #: auto: exact tangent, positive semi-definite surrogate when needed; definite; exact
    tangent: Literal["auto", "definite", "exact"] = "auto"
    #: the sparse direct solver: auto (PARDISO where pypardiso and oneMKL are installed, else SuperLU),
    #: pardiso (an error where it is not installed) or superlu (scipy's, always there)
    linear_solver: Literal["auto", "pardiso", "superlu"] = "auto"

    @model_validator(mode="after")
    def _solver_available(self):
        if self.linear_solver == "pardiso":
            from .linear import pardiso_available

            ok, why = pardiso_available()
            if not ok:
                raise ValueError(
                    "linear_solver 'pardiso' needs pypardiso and Intel oneMKL: pip install 'surgiplan[pardiso]' "
                    f"(or linear_solver: auto, which falls back to SuperLU); here: {why}"
                )
        return self


class StVKSettings(StrictModel):
    """Settings of the ``stvk`` model and its ``simulate`` stage."""

    mesh: MeshSettings
    material: MaterialSettings = Field(default_factory=MaterialSettings)
    #: m/s^2 (not scaled by length_unit)
    gravity: tuple[Finite, Finite, Finite] = (0.0, 0.0, -9.8)
    anchored: list[AnchorModel] = Field(default_factory=list)
    loads: list[LoadModel] = Field(default_factory=list)
    grasp: GraspModel | None = None
    base_plane: BasePlaneModel | None = None
    solver: SolverSettings = Field(default_factory=SolverSettings)
    #: check the deformed surface for self-intersection (part of validity)
    self_intersection: bool = True
    #: simulate stage: apply the grasp's motion and the dead loads in this many equal increments, each
    #: warm-started from the one before, and write every step (a ParaView .pvd animation)
    steps: PositiveInt = 1
    #: simulate stage: displacements to report (metrics and figure), each optionally against a reference
    probes: list[ProbeModel] = Field(default_factory=list)

    @model_validator(mode="after")
    def _unique_probes(self):
        names = [p.name for p in self.probes]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"probe names must be unique: {', '.join(twice)} given twice")
        return self


__all__ = [
    "AnchorModel",
    "BasePlaneModel",
    "BoxMeshModel",
    "GraspModel",
    "ImageRegionModel",
    "LoadModel",
    "MaterialRegionModel",
    "MaterialSettings",
    "MeshSettings",
    "ProbeModel",
    "RegionModel",
    "SolverSettings",
    "StVKSettings",
]
