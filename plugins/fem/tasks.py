"""Equilibria in worker processes: picklable task functions for ``Executor.map`` and ``run_tasks``.

Paper 002 computes its 1,000 roadmap samples in parallel (OpenMP, §VI). A
task here is a plain dict of SI values, so it pickles cheaply and a
``run_tasks`` checkpoint can resume it::

    from surgiplan.executors import LocalExecutor, TaskStore, run_tasks
    from surgiplan.plugins.fem.tasks import grasp_sequence_task

    task = {"settings": model.settings.model_dump(mode="json"),   # rebuilds the model in the worker
            "grasp_nodes": jaws,                                   # (k,) node indices
            "transforms": poses}                                   # (s, 4, 4) world transforms
    results = run_tasks(LocalExecutor(2), grasp_sequence_task, {"chunk-0": task, ...}, store=TaskStore(dir))

Each worker process builds a model once per distinct settings and keeps it
(:func:`model_for`), so later tasks reuse its sparsity pattern and
factorisations. Within a task the transforms are solved in the given order,
each warm-started from the previous equilibrium (order them along a path,
e.g. nearest neighbour first, for short predictor steps).
"""

from __future__ import annotations

import json
import time
from collections import OrderedDict
from typing import Any

import numpy as np

from .model import StVKModel
from .settings import StVKSettings

_MODELS: OrderedDict[str, StVKModel] = OrderedDict()
_KEEP = 4


def model_for(settings: StVKSettings | dict[str, Any]) -> StVKModel:
    """A model for these settings, built once per process (SI settings, as ``model_dump(mode="json")`` gives)."""
    data = settings.model_dump(mode="json") if isinstance(settings, StVKSettings) else settings
    key = json.dumps(data, sort_keys=True)
    model = _MODELS.get(key)
    if model is None:
        model = StVKModel(StVKSettings.model_validate(data))
        _MODELS[key] = model
        if len(_MODELS) > _KEEP:
            _MODELS.popitem(last=False)
    else:
        _MODELS.move_to_end(key)
    return model


def grasp_sequence_task(args: dict[str, Any]) -> dict[str, Any]:
    """Solve a sequence of grasp transforms, each warm-started from the one before.

    ``args``: ``settings`` (dict), ``transforms`` (s, 4, 4) world transforms
    of the grasped nodes' rest positions, ``grasp_nodes`` (optional; default
    the settings' grasp region), ``positions`` (bool, default true: return
    them), ``retry_cold`` (bool, default true: a warm-started sample that
    fails is solved again from rest, which may find an equilibrium the warm
    start missed, e.g. after the previous one buckled). Returns arrays over
    the s samples: ``energy`` (J), ``max_stress`` (Pa), ``valid``,
    ``converged``, ``iterations``, ``factorizations``, ``residual`` (N),
    ``solve_s`` (wall, s) and ``cpu_s`` (this process's CPU time, s),
    ``retried`` (solved again from rest), ``grasp_force`` (s, 3) N and, if
    asked, ``positions`` (s, n, 3) float32 m; and ``messages``, the solver's
    message per sample.
    """
    model = model_for(args["settings"])
    nodes = args.get("grasp_nodes")
    nodes = model.grasped_nodes() if nodes is None else np.asarray(nodes, dtype=np.int64)
    transforms = np.asarray(args["transforms"], dtype=float).reshape(-1, 4, 4)
    keep_positions = bool(args.get("positions", True))
    retry_cold = bool(args.get("retry_cold", True))
    s = len(transforms)
    out: dict[str, Any] = {
        "energy": np.full(s, np.nan),
        "max_stress": np.full(s, np.nan),
        "valid": np.zeros(s, dtype=bool),
        "converged": np.zeros(s, dtype=bool),
        "iterations": np.zeros(s, dtype=np.int64),
        "factorizations": np.zeros(s, dtype=np.int64),
        "residual": np.full(s, np.nan),
        "solve_s": np.zeros(s),
        "cpu_s": np.zeros(s),
        "retried": np.zeros(s, dtype=bool),
        "grasp_force": np.zeros((s, 3)),
        "messages": [""] * s,
    }
    if keep_positions:
        out["positions"] = np.zeros((s, model.mesh.n_nodes, 3), dtype=np.float32)
    state = model.solve(model.grasp_constraints(nodes, None))
    for i, transform in enumerate(transforms):
        started, cpu = time.perf_counter(), time.process_time()
        constraints = model.grasp_constraints(nodes, transform)
        new = model.solve(constraints, initial=state)
        if retry_cold and not (new.converged and new.valid):
            new = model.solve(constraints)
            out["retried"][i] = True
        out["solve_s"][i] = time.perf_counter() - started
        out["cpu_s"][i] = time.process_time() - cpu
        out["messages"][i] = new.message
        out["energy"][i] = new.energy
        out["max_stress"][i] = float(np.max(new.stress))
        out["valid"][i] = new.valid
        out["converged"][i] = new.converged
        out["iterations"][i] = new.iterations
        out["factorizations"][i] = new.data["factorizations"]
        out["residual"][i] = new.residual
        out["grasp_force"][i] = new.data["reaction_field"][nodes].sum(axis=0)
        if keep_positions:
            out["positions"][i] = new.positions
        if new.converged and new.valid:
            state = new  # a failed sample does not become the next one's start
    return out
