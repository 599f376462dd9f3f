"""The deformable-model interface: static equilibria of soft tissue.

A :class:`DeformableModel` owns a rest mesh (nodes and tetrahedra) and
answers :meth:`DeformableModel.solve`: the static equilibrium reached when
some nodes are held at prescribed positions (anchored or grasped) and
external forces act. Paper 002 plans tissue retraction on such equilibria
computed with a nonlinear St. Venant-Kirchhoff FEM (the ``stvk`` plugin); a
mass-spring or co-rotational model can implement the same interface.

A model also runs a ``simulate`` stage of a pipeline on its own through
:meth:`DeformableModel.run_stage`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from pydantic import BaseModel

from .resources import ResourceEstimate

if TYPE_CHECKING:
    from .results import StageContext, StageResult


@dataclass
class Constraints:
    """Boundary conditions of one equilibrium (SI).

    ``prescribed_nodes`` (k,) are held at ``prescribed_positions`` (k, 3);
    ``external_forces`` (n, 3) in newtons act on the nodes (dead loads), in
    addition to gravity when the model has it.
    """

    prescribed_nodes: np.ndarray
    prescribed_positions: np.ndarray
    external_forces: np.ndarray | None = None


@dataclass
class EquilibriumState:
    """A solved (or failed) static equilibrium.

    ``positions`` (n, 3) m; ``energy`` J (elastic energy plus the work of the
    external forces, Π in paper 002); ``stress`` (elements,) Pa, the largest
    absolute principal value of the second Piola-Kirchhoff stress per
    element; ``valid``: no inverted element and no self-penetration.

    ``reaction_forces`` (optional; ``None`` when the model does not compute
    them): (k, 3) N, the force each prescribed node's constraint exerts on
    the tissue, one row per entry of ``Constraints.prescribed_nodes`` in
    that order (a coordinate that is not held has none). At an equilibrium
    this is dΠ/d(prescribed position) (envelope theorem), so a planner gets
    the gradient of Π with respect to a grasp without extra solves.
    """

    positions: np.ndarray
    energy: float
    stress: np.ndarray
    valid: bool
    converged: bool
    iterations: int
    residual: float
    message: str = ""
    data: dict[str, Any] = field(default_factory=dict)
    reaction_forces: np.ndarray | None = None


class DeformableModel(ABC):
    """Base class of deformable-model plugins."""

    Settings: ClassVar[type[BaseModel]]

    @classmethod
    def estimate_resources(cls, settings: BaseModel) -> list[ResourceEstimate]:
        """What a stage with these settings will need, before any work (see :mod:`surgiplan.resources`);
        override it when a setting scales memory. The default estimates nothing."""
        return []

    def __init__(self, settings: BaseModel) -> None:
        self.settings = settings

    @property
    @abstractmethod
    def rest_nodes(self) -> np.ndarray:
        """Rest positions (n, 3) in metres."""

    @property
    @abstractmethod
    def elements(self) -> np.ndarray:
        """Element connectivity (m, nodes per element)."""

    @abstractmethod
    def solve(self, constraints: Constraints, initial: EquilibriumState | None = None) -> EquilibriumState:
        """The static equilibrium under ``constraints``, warm-started from ``initial``.

        A configuration the model cannot solve (a degenerate state, a
        numerical failure) is answered, not raised: a state with ``valid``
        and ``converged`` False and the reason in ``message``. The answer
        should depend on the arguments only, not on earlier solves.
        """

    def run_stage(self, context: StageContext) -> StageResult:
        """Run a ``simulate`` stage (one equilibrium or a sweep) from this model's settings."""
        raise NotImplementedError(f"{type(self).__name__} does not run simulate stages")
