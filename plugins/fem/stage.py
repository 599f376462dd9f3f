"""The ``simulate`` stage of the ``stvk`` model: one equilibrium, or a quasi-static sequence of them.

Users run a pipeline stage ``stage: simulate``, ``plugin: stvk`` to look at
the tissue before planning with it (Patil & Alterovitz §III: the tissue
moves slowly enough to be quasi-static). The settings' ``grasp`` moves a
region rigidly and ``loads`` add dead forces; with ``steps: N`` both are
applied in N equal increments (the rotation by slerp about the pivot, the
translation and loads linearly), each equilibrium warm-started from the one
before, as a gripper retracting the flap would.

Files written next to ``result.json``:

* ``<name>.vtu``: the final equilibrium (ParaView or any VTK viewer);
* ``<name>.png``: a first look at it, coloured by stress (:mod:`.figure`);
* with ``steps > 1``: ``<name>/step_000.vtu`` (the tissue held by its
  anchors, before the gripper moves) to ``<name>/step_N.vtu`` and
  ``<name>.pvd``, a collection ParaView plays as an animation (time = the
  fraction of the motion applied).

Point data: ``displacement`` (m), ``reaction_force`` (N, what anchors and
gripper apply), ``held`` (1 on prescribed nodes); cell data:
``max_principal_stress`` (Pa), ``volume_ratio``, ``youngs_modulus`` (Pa).
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
from surgiplan.deformable import EquilibriumState
from surgiplan.errors import ConfigError
from surgiplan.results import StageContext, StageResult
from surgiplan.storage import write_text_atomic

from .figure import stage_figure
from .model import StVKModel
from .output import write_vtu


def _write_state(model: StVKModel, path: Path, state: EquilibriumState) -> None:
    held = np.zeros(model.mesh.n_nodes)
    held[state.data["prescribed_nodes"]] = 1.0
    write_vtu(
        path,
        model.mesh.nodes,
        model.mesh.tets,
        state.positions,
        point_data={"reaction_force": state.data["reaction_field"], "held": held},
        cell_data={
            "max_principal_stress": state.stress,
            "volume_ratio": state.data["volume_ratio"],
            "youngs_modulus": model.material.youngs_modulus,
        },
    )


def _write_collection(path: Path, entries: list[tuple[float, str]]) -> None:
    """A ParaView ``.pvd`` collection: one dataset per time (the fraction of the motion applied)."""
    lines = ['<?xml version="1.0"?>', '<VTKFile type="Collection" version="0.1">', "  <Collection>"]
    lines += [f'    <DataSet timestep="{t:.6g}" part="0" file={quoteattr(f)}/>' for t, f in entries]
    lines += ["  </Collection>", "</VTKFile>", ""]
    write_text_atomic(path, "\n".join(lines))


def run_simulate_stage(model: StVKModel, context: StageContext) -> StageResult:
    """Solve the settings' equilibrium (or sequence), write the ``.vtu`` files and return the metrics."""
    settings = model.settings
    if not settings.anchored and settings.grasp is None:
        raise ConfigError("a simulate stage needs anchored nodes or a grasp to hold the tissue", location="settings")
    probe_nodes(model)  # a probe that selects nothing is reported before anything is solved or written
    steps = settings.steps
    out = Path(context.output_dir)
    name = context.name
    files: list[str] = []
    history: list[EquilibriumState] = []
    fractions = np.linspace(0.0, 1.0, steps + 1) if steps > 1 else np.array([1.0])
    state = None
    failure = ""
    with context.progress.task(
        f"{name}: static equilibrium" + (f", {steps} steps" if steps > 1 else ""), total=len(fractions)
    ) as task:
        for k, fraction in enumerate(fractions):
            state = model.solve(model.stage_constraints(float(fraction)), initial=state)
            history.append(state)
            if steps > 1:
                relative = f"{name}/step_{k:03d}.vtu"
                _write_state(model, out / relative, state)
                files.append(relative)
            task.advance(1)
            if not (state.converged and state.valid):
                if steps > 1:
                    failure = f"step {k} of {steps} ({fraction:.0%} of the motion): "
                break
    final = history[-1]
    _write_state(model, out / f"{name}.vtu", final)
    files.insert(0, f"{name}.vtu")
    if steps > 1:
        _write_collection(out / f"{name}.pvd", [(float(f), rel) for f, rel in zip(fractions, files[1:], strict=False)])
        files.insert(1, f"{name}.pvd")
    metrics = _metrics(model, final)
    probes = probe_metrics(model, final)
    metrics.update(probes)
    if steps > 1:
        metrics.update(
            {
                "steps": steps,
                "steps_solved": len(history) - 1,
                "newton_iterations_total": int(sum(s.iterations for s in history)),
                "step_fraction": [float(f) for f in fractions[: len(history)]],
                "step_energy_J": [float(s.energy) for s in history],
                "step_max_stress_Pa": [float(np.max(s.stress)) for s in history],
                "step_max_displacement_m": [_max_displacement(model, s) for s in history],
                "step_newton_iterations": [int(s.iterations) for s in history],
                "step_converged": [bool(s.converged and s.valid) for s in history],
            }
        )
    ok = final.converged and final.valid and len(history) == len(fractions)
    title = (
        f"{name}: energy {final.energy * 1e3:.4g} mJ, largest stress {metrics['max_stress_Pa'] / 1e3:.4g} kPa, "
        f"largest displacement {metrics['max_displacement_m'] * 1e3:.3g} mm"
        + ("" if ok else " (not converged or not valid)")
    )
    stage_figure(out / f"{name}.png", model, final, title, metrics if steps > 1 else None, _probe_lines(model, probes))
    files.insert(1, f"{name}.png")
    message = final.message
    if final.converged and not final.valid:
        message = "the equilibrium is not valid: " + message.split("; ", 1)[-1]
    return StageResult(
        "simulate",
        name,
        "stvk",
        "converged" if ok else "failed",
        metrics=metrics,
        message=failure + message,
        files=files,
    )


def probe_nodes(model: StVKModel) -> list[np.ndarray]:
    """The nodes of each probe's region; a region without a node is a configuration error (before solving)."""
    found = []
    for i, probe in enumerate(model.settings.probes):
        nodes = model.nodes_in_region(probe.region.min, probe.region.max)
        if len(nodes) == 0:
            raise ConfigError(
                "the probe's region contains no node of the mesh", location=f"settings.probes[{i}].region"
            )
        found.append(nodes)
    return found


def probe_metrics(model: StVKModel, state: EquilibriumState) -> dict:
    """The settings' probes: ``<name>_m`` (the mean displacement of the region's nodes along the direction)
    and, with a reference, ``<name>_reference_m``, ``<name>_relative_error`` ((measured - reference) /
    |reference|) and ``<name>_source``."""
    out: dict = {}
    for probe, nodes in zip(model.settings.probes, probe_nodes(model), strict=True):
        moved = (state.positions[nodes] - model.mesh.nodes[nodes]).mean(axis=0)
        value = float(moved @ np.asarray(probe.direction))
        out[f"{probe.name}_m"] = value
        if probe.reference is not None:
            out[f"{probe.name}_reference_m"] = float(probe.reference)
            out[f"{probe.name}_relative_error"] = (
                (value - probe.reference) / abs(probe.reference) if probe.reference != 0 else float("nan")
            )
            out[f"{probe.name}_source"] = probe.source
    return out


def _probe_lines(model: StVKModel, probes: dict) -> list[str]:
    """One line per probe for the figure: "tip_deflection 30.40 mm; elastica ...: 30.17 mm (+0.8 %)"."""
    lines = []
    for probe in model.settings.probes:
        line = f"{probe.name.replace('_', ' ')} {probes[probe.name + '_m'] * 1e3:.4g} mm"
        if probe.reference is not None:
            error = probes[probe.name + "_relative_error"]
            line += f"; {probe.source or 'reference'}: {probe.reference * 1e3:.4g} mm ({error:+.2%})"
        lines.append(line)
    return lines


def _max_displacement(model: StVKModel, state: EquilibriumState) -> float:
    return float(np.linalg.norm(state.positions - model.mesh.nodes, axis=1).max())


def _metrics(model: StVKModel, state: EquilibriumState) -> dict:
    return {
        "energy_J": state.energy,
        "max_stress_Pa": float(np.max(state.stress)),
        "max_displacement_m": _max_displacement(model, state),
        "newton_iterations": state.iterations,
        "residual": state.residual,
        "residual_tolerance": model.options.residual_tol * state.data["residual_scale"],
        "converged": state.converged,
        "valid": state.valid,
        "nodes": model.mesh.n_nodes,
        "elements": model.mesh.n_elements,
        "element_order": model.mesh.order,
        "elastic_energy_J": state.data["elastic_energy"],
        "external_work_J": state.data["external_work"],
        "contact_energy_J": state.data["contact_energy"],
        "min_volume_ratio": state.data["min_volume_ratio"],
        "inverted_elements": state.data["inverted_elements"],
        "self_intersections": state.data["self_intersections"],
        "grasp_force_N": state.data["reaction_field"][model.grasped_nodes()].sum(axis=0).tolist(),
        "anchor_force_N": state.data["reaction_field"][model.anchored_nodes()[0]].sum(axis=0).tolist(),
        "factorizations": state.data["factorizations"],
        "solve_s": state.data["solve_s"],
    }


class StVK(StVKModel):
    """The ``stvk`` plugin: :class:`~.model.StVKModel` (what planners solve with) plus the ``simulate`` stage.

    The stage lives here, above the model, so that the model never imports the pipeline's stage code.
    """

    def run_stage(self, context: StageContext) -> StageResult:
        """The equilibrium (or, with ``steps``, the sequence) the settings describe."""
        return run_simulate_stage(self, context)
