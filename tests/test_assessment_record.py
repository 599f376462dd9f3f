"""The trainee record keeps up (schema 2, migrated from a version-1 file built as version 1 wrote it, a newer file
refused), and the commands a lab runs on it: benchmark-task, trainee, cohort (--json, --csv) and validity, each
checked against the record read independently with sqlite3; and a guide stage with a ghost and a gate."""

from __future__ import annotations

import csv
import hashlib
import itertools
import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from conftest import CONFIGS
from pipeline_support import block_world_pipeline, recommended_stage
from surgiplan import load_pipeline, run_pipeline
from surgiplan.clearance import intervals
from surgiplan.guidance import GuidanceSettings, Guide, TraineeRecord
from surgiplan.guidance.assessment import record_attempt
from surgiplan.guidance.cusum import CusumSettings, parameters
from surgiplan.guidance.record import RecordError
from surgiplan.guidance.trainee import TraineeModel, follow

SCENE = CONFIGS / "scenes" / "block_world.yaml"

# the schema as surgiplan's version 1 created it (framework/guidance/record.py at version 1, verbatim)
V1_SCHEMA = """
    CREATE TABLE trainees (id INTEGER PRIMARY KEY, name TEXT UNIQUE NOT NULL, created TEXT NOT NULL);
    CREATE TABLE attempts (
        id INTEGER PRIMARY KEY, trainee_id INTEGER NOT NULL REFERENCES trainees(id),
        task TEXT NOT NULL, started TEXT NOT NULL, status TEXT NOT NULL, score REAL, duration_s REAL,
        d_thresh_m REAL, path_length_m REAL, recommended_length_m REAL, deviation_rms_m REAL,
        deviation_max_m REAL, deviation_p95_m REAL, min_clearance_m REAL, below_threshold_s REAL,
        below_threshold_m REAL, contacts INTEGER, completion REAL, events TEXT,
        pipeline TEXT, stage TEXT, source TEXT, output_dir TEXT);
    CREATE TABLE samples (
        attempt_id INTEGER NOT NULL REFERENCES attempts(id), i INTEGER NOT NULL, t REAL NOT NULL,
        x REAL, y REAL, z REAL, deviation_m REAL, progress_m REAL, clearance_m REAL, critical INTEGER,
        PRIMARY KEY (attempt_id, i)) WITHOUT ROWID;
    CREATE INDEX attempts_by_trainee_task ON attempts(trainee_id, task, started);
"""


def write_v1_record(path: Path) -> dict:
    """A version-1 record as version 1 wrote it (its schema, PRAGMA user_version 1, its INSERTs): one attempt of
    a tip moving at 20 mm/s along x, standing still for 1 s in the middle."""
    t = np.arange(0, 6.01, 0.01)
    x = 0.010 + 0.020 * np.minimum(t, 2.0) + 0.020 * np.clip(t - 3.0, 0.0, None)
    samples = [
        (1, i, float(ti), float(xi), 0.050, 0.020, 0.0, float(xi - 0.010), 0.003, 0)
        for i, (ti, xi) in enumerate(zip(t, x, strict=True))
    ]
    db = sqlite3.connect(path)
    db.executescript(f"BEGIN; {V1_SCHEMA} PRAGMA user_version = 1; COMMIT;")
    with db:
        db.execute("INSERT OR IGNORE INTO trainees(name, created) VALUES (?, ?)", ("vera", "2025-01-02T10:00:00+0100"))
        db.execute(
            "INSERT INTO attempts(trainee_id, task, started, status, score, duration_s, d_thresh_m, path_length_m, "
            "recommended_length_m, deviation_rms_m, deviation_max_m, deviation_p95_m, min_clearance_m, "
            "below_threshold_s, below_threshold_m, contacts, completion, events, pipeline, stage, source, "
            "output_dir) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                1,
                "block-world",
                "2025-01-02T10:01:00+0100",
                "completed",
                83.5,
                6.0,
                0.004,
                0.100,
                0.125,
                0.0,
                0.0,
                0.0,
                0.003,
                6.0,
                0.100,
                0,
                0.8,
                "[]",
                "p",
                "attempt",
                "recorded_attempt",
                "out",
            ),
        )
        db.executemany("INSERT INTO samples VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", samples)
    db.close()
    return {"t": t, "x": x}


def test_a_version_1_record_is_migrated_with_the_metrics_its_samples_allow(tmp_path):
    path = tmp_path / "v1.sqlite"
    written = write_v1_record(path)
    with TraineeRecord(path) as record:
        assert record.db.execute("PRAGMA user_version").fetchone()[0] == 2
        (attempt,) = record.history("vera", "block-world")
        m = attempt["metrics"]
    # version 1's own columns, kept as they were
    assert m["score"] == 83.5 and m["duration_s"] == 6.0 and m["contacts"] == 0 and m["completion"] == 0.8
    # computed from the samples: economy = path length / recommended length; 1 s standing is idle
    assert m["economy"] == pytest.approx(0.100 / 0.125)
    assert m["idle_s"] == pytest.approx(1.0, abs=1e-9)
    assert m["jerk"] > 0 and m["sparc"] < 0
    # what version 1 did not record stays unmeasured
    assert "corrections" not in m and "depth_reversals" not in m
    assert attempt["assessment"]["schema"] == 1 and "version 1" in attempt["assessment"]["score"]
    with TraineeRecord(path) as record:
        samples = record.samples(attempt["id"])
        np.testing.assert_allclose(samples["tip"][:, 0], written["x"])
        assert np.all(np.isnan(samples["lateral"])) and np.all(np.isnan(samples["insertion"]))
        assert record.levels() == {"vera": None}
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    assert {"attempt_metrics", "benchmarks", "benchmark_thresholds"} <= tables


def test_a_migration_that_fails_leaves_the_file_as_it_was(tmp_path):
    path = tmp_path / "v1.sqlite"
    write_v1_record(path)
    db = sqlite3.connect(path)
    with db:
        db.execute("UPDATE samples SET x = 'not a number' WHERE i = 5")
    db.close()
    with pytest.raises(RecordError, match=r"cannot migrate the trainee record .* to schema version 2 \(it is left"):
        TraineeRecord(path)
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA user_version").fetchone()[0] == 1
    assert "attempt_metrics" not in {r[0] for r in db.execute("SELECT name FROM sqlite_master")}
    assert [r[1] for r in db.execute("PRAGMA table_info(trainees)")] == ["id", "name", "created"]


def test_a_record_newer_than_this_surgiplan_is_refused_and_left_alone(tmp_path, cli):
    path = tmp_path / "v3.sqlite"
    write_v1_record(path)
    db = sqlite3.connect(path)
    db.execute("PRAGMA user_version = 3")
    db.close()
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    with pytest.raises(RecordError, match=r"has schema version 3, newer than this surgiplan's 2 .*upgrade surgiplan"):
        TraineeRecord(path)
    code, _, err = cli("trainee", "vera", "--record", path)
    assert code == 2 and "schema version 3, newer than this surgiplan's 2" in err and "Traceback" not in err
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before


# ----------------------------------------------------------------------------- a synthetic cohort in a record


LEVELS = {"expert": ["ann", "ben"], "intermediate": ["cal", "dee"], "beginner": ["eve", "fay"]}
ATTEMPTS = 3


class Keys:
    def __init__(self, name, task, level):
        self.name, self.task, self.level = name, task, level


@pytest.fixture(scope="module")
def cohort_record(tmp_path_factory):
    """Two trainees of each level, three synthetic attempts each (18), recorded through the guide stage's call."""
    tmp = tmp_path_factory.mktemp("cohort")
    path = block_world_pipeline(tmp / "plan.yaml", "plan", [recommended_stage("intermediate", 600)], tmp / "plan")
    pipeline = load_pipeline(path)
    plan = run_pipeline(pipeline).results[0]
    spec = pipeline.stages[0]
    record = tmp / "record.sqlite"
    seed = itertools.count(11)
    for level, names in LEVELS.items():
        for name in names:
            for _ in range(ATTEMPTS):
                guide = Guide(
                    spec.space,
                    plan.path,
                    spec.scene,
                    plan.clearance_threshold.value,
                    intervals(plan.critical_regions),
                    GuidanceSettings(),
                    unit="mm",
                )
                follow(guide, TraineeModel(level=level, seed=next(seed)))
                status = "completed" if guide.reached_goal else "incomplete"
                record_attempt(record, Keys(name, "bw", level), guide, guide.metrics(), guide.events, status=status)
    return record


def metric_values(record: Path, names: list[str], metric: str) -> list[float]:
    """Straight from the file: the metric of every attempt of ``names`` (oldest first)."""
    db = sqlite3.connect(record)
    rows = db.execute(
        f"SELECT value FROM attempt_metrics JOIN attempts ON attempts.id = attempt_id JOIN trainees ON "
        f"trainees.id = trainee_id WHERE metric = ? AND name IN ({', '.join('?' * len(names))}) ORDER BY attempts.id",
        (metric, *names),
    ).fetchall()
    db.close()
    return [r[0] for r in rows]


def test_benchmark_task_sets_each_threshold_from_the_experts_attempts(cohort_record, cli):
    code, out, err = cli("benchmark-task", "bw", "--record", cohort_record, "--json")
    assert code == 0, err
    benchmark = json.loads(out)
    assert benchmark["experts"] == ["ann", "ben"] and benchmark["attempts"] == 2 * ATTEMPTS
    assert benchmark["method"] == "mean_sd" and benchmark["consecutive"] == 2
    for metric, t in benchmark["thresholds"].items():
        values = np.array(metric_values(cohort_record, ["ann", "ben"], metric))
        sign = 1 if t["better"] == "lower" else -1
        assert t["threshold"] == pytest.approx(values.mean() + sign * values.std(ddof=1), rel=1e-12, abs=1e-15)
    assert {"score", "duration_s", "economy", "corrections", "deviation_rms_m"} <= set(benchmark["thresholds"])
    # the 90th percentile, named experts, and a choice of metrics
    code, out, err = cli(
        "benchmark-task",
        "bw",
        "--record",
        cohort_record,
        "--from-trainees",
        "ann",
        "--method",
        "percentile",
        "--percentile",
        "90",
        "--metrics",
        "duration_s,score",
        "--json",
    )
    assert code == 0, err
    p90 = json.loads(out)
    durations = metric_values(cohort_record, ["ann"], "duration_s")
    assert p90["thresholds"]["duration_s"]["threshold"] == pytest.approx(np.percentile(durations, 90))
    assert p90["thresholds"]["score"]["threshold"] == pytest.approx(
        np.percentile(metric_values(cohort_record, ["ann"], "score"), 10)
    )
    # the current benchmark is the latest: set the default one again for the tests below
    assert cli("benchmark-task", "bw", "--record", cohort_record)[0] == 0


def test_trainee_shows_each_metric_against_its_threshold_and_the_gate(cohort_record, cli):
    code, out, err = cli("trainee", "cal", "--record", cohort_record, "--task", "bw", "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["level"] == "intermediate"
    standing = report["assessment"]["bw"]["gate"]
    with TraineeRecord(cohort_record) as record:
        benchmark = record.benchmark("bw")
        history = record.history("cal", "bw")
    expected = [all(t.within(h["metrics"].get(n)) for n, t in benchmark.thresholds.items()) for h in history]
    assert standing["within"] == expected and standing["consecutive"] == 2
    for name, judged in standing["last"].items():
        value = history[-1]["metrics"].get(name)
        assert judged["value"] == value and judged["threshold"] == benchmark.thresholds[name].value
        assert judged["within"] == (
            value <= judged["threshold"] if judged["better"] == "lower" else value >= judged["threshold"]
        )
    figure = Path(report["assessment"]["bw"]["figure"])
    assert figure.is_file() and figure.stat().st_size > 20_000
    code, out, _ = cli("trainee", "cal", "--record", cohort_record, "--task", "bw")
    assert code == 0 and "gate" in out and "threshold" in out and "economy of motion" in out


def test_cohort_prints_the_table_writes_figures_and_exports_json_and_csv(cohort_record, cli, tmp_path):
    code, out, err = cli(
        "cohort", "--task", "bw", "--record", cohort_record, "--json", "--csv", tmp_path / "bw.csv", "--out", tmp_path
    )
    assert code == 0, err
    result = json.loads(out)
    assert [t["trainee"] for t in result["trainees"]] == sorted(n for names in LEVELS.values() for n in names)
    s, _, _ = parameters(CusumSettings())
    with TraineeRecord(cohort_record) as record:
        benchmark = record.benchmark("bw")
        for row in result["trainees"]:
            history = record.history(row["trainee"], "bw")
            assert row["attempts"] == ATTEMPTS and row["last_score"] == history[-1]["score"]
            failed = [not benchmark.within(h["metrics"]) for h in history]
            assert row["cusum"]["values"] == pytest.approx(np.cumsum(np.array(failed, float) - s).tolist())
            run = [sum(1 for _ in g) for k, g in itertools.groupby(failed) if not k]
            assert (row["gate_passed_at"] is not None) == any(r >= 2 for r in run)
    with (tmp_path / "bw.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 6 * ATTEMPTS and {"trainee", "attempt", "score", "economy", "failed", "cusum"} <= set(rows[0])
    assert float(rows[0]["score"]) == pytest.approx(result["attempts"][0]["score"])
    for figure in result["figures"].values():
        assert Path(figure).is_file() and Path(figure).stat().st_size > 20_000
    code, out, err = cli("cohort", "--task", "bw", "--record", cohort_record, "--out", tmp_path)
    assert code == 0 and "gate passed at attempt #" in out and "ann" in out


def test_validity_from_the_record_matches_brute_force(cohort_record, cli):
    code, out, err = cli("validity", "--task", "bw", "--record", cohort_record, "--json")
    assert code == 0, err
    result = json.loads(out)
    assert result["attempts"] == {"expert": 6, "intermediate": 6, "beginner": 6}
    rows = {(r["metric"], r["higher"]): r for r in result["separations"]}
    for metric, better in (("deviation_rms_m", "lower"), ("score", "higher")):
        for high, low in (("expert", "intermediate"), ("intermediate", "beginner")):
            a = metric_values(cohort_record, LEVELS[high], metric)
            b = metric_values(cohort_record, LEVELS[low], metric)
            wins = sum((x < y if better == "lower" else x > y) + 0.5 * (x == y) for x, y in itertools.product(a, b))
            assert rows[(metric, high)]["auc"] == pytest.approx(wins / (len(a) * len(b)))
    # named groups instead of recorded levels
    code, out, err = cli(
        "validity",
        "--task",
        "bw",
        "--record",
        cohort_record,
        "--levels",
        "expert,beginner",
        "--group",
        "expert=ann",
        "--group",
        "beginner=eve,fay",
        "--json",
    )
    assert code == 0, err
    assert json.loads(out)["attempts"] == {"expert": 3, "beginner": 6}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("benchmark-task", "bw", "--metrics", "speed"), "--metrics: unknown metric(s) speed"),
        (("benchmark-task", "bw", "--from-level", "master"), "no trainee of level 'master'"),
        (("benchmark-task", "bw", "--from-trainees", "zed"), "no trainee 'zed'"),
        (("benchmark-task", "suturing"), "expert 'ann' has no attempt at task 'suturing'"),
        (("cohort", "--task", "bw", "--p0", "0.4"), "--p0/--p1: the unacceptable failure rate p1 (0.3) must exceed"),
        (("cohort", "--task", "suturing"), "no attempt at task 'suturing'"),
        (("validity", "--task", "bw", "--group", "expert"), "--group 'expert': give LEVEL=NAME,NAME,..."),
        (("validity", "--task", "bw", "--group", "master=ann"), "--group master: not one of --levels"),
        (("validity", "--task", "bw", "--levels", "expert,novice"), "no trainee of level 'novice' has an attempt"),
    ],
)
def test_bad_options_are_clear_errors(cohort_record, cli, args, message):
    code, _, err = cli(*args, "--record", cohort_record)
    assert code == 2 and message in err and "Traceback" not in err, err
