"""Planner benchmarks in OMPL's formats, so surgiplan's planners sit beside OMPL's in Planner Arena.

OMPL's benchmarking tools write a text log per experiment (``ompl::tools::Benchmark::saveResultsToStream``);
``ompl_benchmark_statistics.py`` turns logs into the SQLite database that Planner Arena
(plannerarena.org, or ``ompl plannerarena``) reads. :func:`write_log` writes that log format exactly, and
:func:`write_database` builds the database with OMPL's own parser (``ompl._benchmark_statistics``, part of
the ``ompl`` package), so what Planner Arena opens is what OMPL's tool made.

:func:`benchmark_pipeline` runs every plan stage of a pipeline ``runs`` times (a fresh build and query each
time, the planner's ``seed`` setting advanced by the run's index), measured by the framework as a pipeline
run measures it, and reports per run the properties OMPL's benchmark records (``time``, ``memory``,
``solved``, ``status``, ``solution length``, ``solution clearance``, ``solution smoothness``, ``solution
segments``, ``correct solution``, ``graph states``/``graph motions`` when the planner reports its roadmap)
and surgiplan's own (``build time``, ``query time``, ``clearance threshold``, ``length below threshold``,
``critical regions``, ``certified clearance``).
"""

from __future__ import annotations

import dataclasses
import math
import os
import platform
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .clearance import threshold_value
from .errors import SurgiplanError
from .executors import InlineExecutor
from .kinds import RunState, StageSpec
from .progress import NullProgress
from .results import StageContext, StageResult
from .runner import run_stage
from .status import PlanStatus, RunStatus
from .storage import write_text_atomic
from .units import LENGTH_UNITS

#: OMPL's PlannerStatus::asString for each StatusType (ABORT and INFEASIBLE print as "Unknown status")
OMPL_STATUS = [
    "Unknown status",
    "Invalid start",
    "Invalid goal",
    "Unrecognized goal type",
    "Timeout",
    "Approximate solution",
    "Exact solution",
    "Crash",
    "Unknown status",
    "Unknown status",
]
#: a plan stage's status as OMPL's status enum value
STATUS_VALUE = {
    PlanStatus.SOLVED.value: 6,  # EXACT_SOLUTION
    PlanStatus.INVALID_START.value: 1,
    PlanStatus.INVALID_GOAL.value: 2,
    PlanStatus.TIMEOUT.value: 4,
    PlanStatus.NO_PATH.value: 4,  # TIMEOUT: "the planner failed to find a solution"
    RunStatus.INVALID_RESULT.value: 7,  # CRASH: its answer was refused
    RunStatus.ERROR.value: 7,
}


@dataclass
class PlannerRuns:
    """One planner configuration of an experiment: its common settings and one property dict per run."""

    name: str
    common: dict[str, Any] = field(default_factory=dict)
    runs: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class Experiment:
    name: str
    planners: list[PlannerRuns]
    properties: dict[str, Any] = field(default_factory=dict)  # "name TYPE" -> value
    host: str = field(default_factory=platform.node)
    started: str = field(default_factory=lambda: time.strftime("%Y-%m-%d %H:%M:%S"))
    setup: str = ""
    cpu: str = ""
    seed: int = 0
    time_limit: float = 0.0
    memory_limit: float = 0.0
    runs: int = 0
    total_s: float = 0.0


def _value(value: Any) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ""  # OMPL's parser stores an empty field as NULL
    if isinstance(value, bool):
        return str(int(value))
    return str(value)


def log_text(experiment: Experiment) -> str:
    """The experiment in the text format of ``ompl::tools::Benchmark::saveResultsToStream``."""
    e = experiment
    lines = [f"surgiplan version {__version__}", f"Experiment {e.name or 'NO_NAME'}"]
    lines.append(f"{len(e.properties)} experiment properties")
    lines += [f"{name} = {_value(value)}" for name, value in e.properties.items()]
    lines += [f"Running on {e.host or 'UNKNOWN'}", f"Starting at {e.started}"]
    lines += ["<<<|", *e.setup.rstrip("\n").split("\n"), "|>>>", "<<<|", *e.cpu.rstrip("\n").split("\n"), "|>>>"]
    lines += [
        f"{e.seed} is the random seed",
        f"{e.time_limit} seconds per run",
        f"{e.memory_limit} MB per run",
        f"{e.runs} runs per planner",
        f"{e.total_s} seconds spent to collect the data",
        "1 enum type",
        "status|" + "|".join(OMPL_STATUS),
        f"{len(e.planners)} planners",
    ]
    for planner in e.planners:
        lines.append(planner.name)
        common = sorted(planner.common)
        lines.append(f"{len(common)} common properties")
        lines += [f"{name} = {_value(planner.common[name])}" for name in common]
        properties = sorted({name for run in planner.runs for name in run})
        lines.append(f"{len(properties)} properties for each run")
        lines += properties
        lines.append(f"{len(planner.runs)} runs")
        lines += ["".join(f"{_value(run.get(name))}; " for name in properties) for run in planner.runs]
        lines.append(".")
    return "\n".join(lines) + "\n"


def write_log(path: Path, experiment: Experiment) -> Path:
    write_text_atomic(path, log_text(experiment))
    return path


def write_database(database: Path, logs: Sequence[Path]) -> Path:
    """The SQLite database of ``logs`` that Planner Arena reads, made by OMPL's own parser."""
    try:
        from ompl._benchmark_statistics import readBenchmarkLog
    except ImportError as exc:
        raise SurgiplanError(
            "the Planner Arena database is made by OMPL's ompl_benchmark_statistics: pip install 'surgiplan[ompl]' "
            f"({exc}); the logs are written all the same"
        ) from None
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()):  # it prints a line per file and planner
        readBenchmarkLog(str(database), [str(p) for p in logs], False)
    return database


# ----------------------------------------------------------------------------- running plan stages


def smoothness(space, path: np.ndarray) -> float:
    """OMPL's ``PathGeometric::smoothness``: the sum over interior waypoints of (2 x outside angle / (a + b))²,
    angles from the law of cosines on the space's distances (0 for a straight or two-point path)."""
    s = 0.0
    if len(path) > 2:
        a = float(space.distance(path[0], path[1]))
        for i in range(2, len(path)):
            b = float(space.distance(path[i - 1], path[i]))
            c = float(space.distance(path[i - 2], path[i]))
            if a > 0 and b > 0:
                cos = (a * a + b * b - c * c) / (2.0 * a * b)
                if -1.0 < cos < 1.0:
                    k = 2.0 * (math.pi - math.acos(cos)) / (a + b)
                    s += k * k
            a = b
    return s


def _memory_mb() -> float:
    """This process's resident memory (MB), as OMPL's benchmark measures a run's by difference."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
    except (OSError, ValueError, IndexError):
        return float("nan")
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def run_properties(result: StageResult, spec: StageSpec, memory_mb: float) -> dict[str, Any]:
    """One run's properties in OMPL's names (``name TYPE``) and surgiplan's own."""
    m = result.metrics
    solved = result.status == PlanStatus.SOLVED.value
    props: dict[str, Any] = {
        "time REAL": float(m.get("build_s", 0.0)) + float(m.get("query_s", 0.0)),
        "build time REAL": m.get("build_s"),
        "query time REAL": m.get("query_s"),
        "memory REAL": memory_mb,
        "solved BOOLEAN": solved,
        "status ENUM": STATUS_VALUE.get(result.status, 0),
        "approximate solution BOOLEAN": False,
        "correct solution BOOLEAN": solved,  # verified by the framework (surgiplan.verify)
        "clearance threshold REAL": threshold_value(result.clearance_threshold),
    }
    if solved:
        path = np.asarray(result.path, dtype=float)
        props |= {
            "solution length REAL": m.get("length_m"),
            "solution clearance REAL": m.get("min_clearance_m"),
            "certified clearance REAL": m.get("min_clearance_m"),
            "solution smoothness REAL": smoothness(spec.space, path),
            "solution segments INTEGER": len(path) - 1,
            "length below threshold REAL": m.get("length_below_threshold_m", 0.0),
            "critical regions INTEGER": len(result.critical_regions),
        }
    states = m.get("milestones", m.get("vertices"))
    motions = m.get("edges")
    if isinstance(states, int | float):
        props["graph states INTEGER"] = int(states)
    if isinstance(motions, int | float):
        props["graph motions INTEGER"] = int(motions)
    return props


def benchmark_pipeline(
    pipeline, runs: int, *, on_run: Callable[[str, int, StageResult], None] | None = None
) -> Experiment:
    """Run every plan stage of ``pipeline`` ``runs`` times; an :class:`Experiment` in OMPL's terms."""
    if runs < 1:
        raise SurgiplanError(f"--runs must be at least 1, got {runs}", location="--runs")
    plans = [s for s in pipeline.stages if s.kind == "plan"]
    if not plans:
        raise SurgiplanError(f"{pipeline.file} has no plan stage to benchmark", file=pipeline.file)
    unit = pipeline.model.length_unit
    started = time.perf_counter()
    experiment = Experiment(
        pipeline.name,
        [],
        properties={"pipeline file VARCHAR(512)": str(pipeline.file), "length unit VARCHAR(8)": unit},
        setup=f"surgiplan {__version__}: {pipeline.file}",
        cpu=f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        runs=runs,
    )
    work = Path(pipeline.output_dir) / ".benchmark"
    for spec in plans:
        kind = pipeline.kind(spec)
        planner = PlannerRuns(f"{spec.name} ({spec.plugin.name})", common=_common(spec))
        for k in range(runs):
            run_spec = _seeded(spec, k)
            context = StageContext(spec.name, spec.scene, work, pipeline.base_dir, InlineExecutor(), NullProgress())
            state = RunState(pipeline.name, work, pipeline.record, unit, LENGTH_UNITS[unit], figures=False)
            before = _memory_mb()
            result = run_stage(kind, run_spec, context, state)
            planner.runs.append(run_properties(result, run_spec, max(_memory_mb() - before, 0.0)))
            if on_run is not None:
                on_run(spec.name, k, result)
        experiment.planners.append(planner)
    experiment.total_s = time.perf_counter() - started
    return experiment


def _common(spec: StageSpec) -> dict[str, Any]:
    settings = spec.settings.model_dump(mode="json") if spec.settings is not None else {}
    common = {f"{name} VARCHAR(256)": value for name, value in _flat(settings).items()}
    common["package VARCHAR(128)"] = f"{spec.plugin.package} {spec.plugin.version}"
    common["space VARCHAR(32)"] = spec.space.kind if spec.space is not None else ""
    return common


def _flat(data: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out |= _flat(value, f"{name}.")
        else:
            out[name] = value if isinstance(value, int | float | str | bool) or value is None else str(value)
    return out


def _seeded(spec: StageSpec, k: int) -> StageSpec:
    """The stage for run ``k``: its planner's ``seed`` advanced by ``k``, no stored artifact (a fresh build)."""
    settings = spec.settings
    if settings is not None and isinstance(getattr(settings, "seed", None), int):
        settings = settings.model_copy(update={"seed": settings.seed + k})
    return dataclasses.replace(spec, settings=settings, artifact=None)
