"""The ``simulate`` stage: a deformable model runs on its own (one equilibrium or a sweep of them).

::

    - stage: simulate
      plugin: stvk                      # a deformable model (hook surgiplan_register_deformable_models)
      settings: {...}                   # the model's own: mesh, material, anchors, grasps, steps

The model's :meth:`~surgiplan.DeformableModel.run_stage` returns the stage's
:class:`~surgiplan.results.StageResult`; its status must be a
:class:`~surgiplan.status.SimulateStatus`.
"""

from __future__ import annotations

import time

from ..deformable import DeformableModel
from ..hookspecs import PluginSpec, hookspec
from ..kinds import PluginKind, StageKind, StageRun
from ..outputs.report.meshes import simulate_mesh
from ..results import StageResult
from ..status import SimulateStatus


class Hooks:
    """The hook simulate stages take their plugins from."""

    @hookspec
    def surgiplan_register_deformable_models(self) -> list[PluginSpec]:
        """Deformable-model plugins (subclasses of :class:`surgiplan.DeformableModel`).

        Used by ``stage: simulate`` and by planners that deform tissue.
        """


DEFORMABLE_MODEL = PluginKind("deformable_model", "surgiplan_register_deformable_models", DeformableModel)


class SimulateKind(StageKind):
    """``stage: simulate``: a deformable-model plugin computes equilibria of tissue on its own (no path)."""

    name = "simulate"
    description = "a deformable model computes equilibria of tissue on its own"
    plugin_kind = DEFORMABLE_MODEL
    hookspecs = Hooks
    statuses = SimulateStatus
    succeeded = frozenset({SimulateStatus.CONVERGED.value, SimulateStatus.COMPLETED.value})

    def run(self, run: StageRun) -> StageResult:
        spec = run.spec
        model = run.call("construction", spec.plugin.cls, spec.settings)
        started = time.perf_counter()
        result = run.call("run_stage", model.run_stage, run.context)
        if not isinstance(result, StageResult):
            return run.invalid(f"run_stage returned a {type(result).__name__}, not a StageResult")
        if not isinstance(result.metrics, dict):
            result.metrics = {}
        result.metrics.setdefault("run_s", time.perf_counter() - started)
        return result

    def details(self, result: StageResult, k: float, unit: str) -> list[str]:
        from ..outputs.summary import si  # rich: the summary table is being drawn anyway

        if not result.succeeded:
            return []
        m = result.metrics
        parts = []
        if "energy_J" in m:
            parts.append(f"energy {si(m['energy_J'], 'J')}")
        if "max_stress_Pa" in m:
            parts.append(f"max stress {si(m['max_stress_Pa'], 'Pa')}")
        if "max_displacement_m" in m:
            parts.append(f"max displacement {m['max_displacement_m'] * k:.3g} {unit}")
        for key, label in (("tip_deflection_error", "tip deflection vs elastica"), ("sag_error_m", "sag error")):
            if key in m:
                parts.append(f"{label} {m[key]:.3g}")
        return parts

    def report(self, stage, entry, inputs) -> None:
        stage["mesh"] = simulate_mesh(inputs.out, entry, inputs.notes)
