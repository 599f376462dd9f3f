"""Planner benchmarks in OMPL's formats: the log parses with OMPL's own ompl_benchmark_statistics, the database
has the schema Planner Arena reads, and the numbers in it are the runs' (smoothness checked against OMPL's own
PathGeometric::smoothness on the same path)."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest
from pipeline_support import block_world_pipeline, safe_prm_stage
from surgiplan.plannerarena import Experiment, PlannerRuns, log_text, smoothness, write_database, write_log

pytest.importorskip("ompl", reason="OMPL's own parser makes the database (the ompl extra)")


def test_the_log_round_trips_through_ompls_own_parser(tmp_path):
    runs = [
        {"time REAL": 0.5, "solved BOOLEAN": True, "status ENUM": 6, "solution length REAL": 0.13},
        {"time REAL": 0.7, "solved BOOLEAN": False, "status ENUM": 4, "solution length REAL": None},
    ]
    experiment = Experiment(
        "probe",
        [PlannerRuns("safe_prm", {"milestones INTEGER": 300}, runs)],
        properties={"length unit VARCHAR(8)": "mm"},
        runs=2,
        total_s=1.2,
    )
    log = write_log(tmp_path / "probe.log", experiment)
    database = write_database(tmp_path / "probe.db", [log])
    c = sqlite3.connect(database)
    assert c.execute("select name, runcount, totaltime, lengthunit from experiments").fetchall() == [
        ("probe", 2, 1.2, "mm")
    ]
    assert c.execute("select name, settings from plannerConfigs").fetchall() == [
        ("safe_prm", "milestones INTEGER = 300\n;")
    ]
    rows = c.execute("select time, solved, status, solution_length from runs order by id").fetchall()
    assert rows == [(0.5, 1, 6, 0.13), (0.7, 0, 4, None)]
    assert dict(c.execute("select value, description from enums").fetchall())[6] == "Exact solution"
    assert log_text(experiment).splitlines()[-1] == "."


def test_benchmark_command_writes_what_planner_arena_reads(cli, tmp_path):
    stages = [safe_prm_stage("beginner", 2000, seed=4)]
    path = block_world_pipeline(tmp_path / "arena.yaml", "arena", stages, tmp_path / "out")
    code, out, err = cli("benchmark", path, "--runs", "3", "--out", tmp_path / "bench")
    assert code == 0, err
    assert "beginner (safe_prm): 3 of 3 solved" in out
    c = sqlite3.connect(tmp_path / "bench" / "arena.db")
    tables = {r[0] for r in c.execute("select name from sqlite_master where type = 'table'")}
    assert {"experiments", "plannerConfigs", "enums", "runs", "progress"} <= tables
    columns = {r[1] for r in c.execute("pragma table_info(runs)")}
    assert {
        "experimentid",
        "plannerid",
        "time",
        "memory",
        "solved",
        "status",
        "solution_length",
        "solution_clearance",
        "solution_smoothness",
        "solution_segments",
        "graph_states",
        "graph_motions",
        "critical_regions",
        "certified_clearance",
        "clearance_threshold",
        "length_below_threshold",
    } <= columns
    rows = c.execute(
        "select solved, status, graph_states, clearance_threshold, critical_regions, solution_clearance from runs"
    ).fetchall()
    assert len(rows) == 3 and all(r[:4] == (1, 6, 2000, 0.008) for r in rows)
    # the beginner's 8 mm closes every passage of the block world: each path has critical regions below 8 mm
    assert all(r[4] >= 1 and 0 < r[5] < 0.008 for r in rows)
    settings = c.execute("select settings from plannerConfigs").fetchone()[0]
    assert "proficiency VARCHAR(256) = beginner" in settings and "package VARCHAR(128) = surgiplan" in settings


def test_smoothness_is_ompls(block_world):
    """A zig-zag path through R3: OMPL's PathGeometric::smoothness on the same states, through its bindings."""
    from ompl import base as ob
    from ompl import geometric as og
    from surgiplan import R3Space

    path = np.array([[0.01, 0.05, 0.02], [0.03, 0.06, 0.02], [0.05, 0.05, 0.025], [0.09, 0.05, 0.02]])
    space = ob.RealVectorStateSpace(3)
    bounds = ob.RealVectorBounds(3)
    bounds.setLow(0.0)
    bounds.setHigh(1.0)
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)
    si.setStateValidityChecker(lambda state: True)
    si.setup()
    geometric = og.PathGeometric(si)
    state = space.allocState()
    for p in path:
        for i in range(3):
            state[i] = float(p[i])
        geometric.append(state)
    assert smoothness(R3Space(block_world), path) == pytest.approx(geometric.smoothness(), rel=1e-12)
