"""The trainee record's schema and its migrations (``docs/trainee-record.md``).

The version is SQLite's ``PRAGMA user_version``. :data:`MIGRATIONS` ``[v]`` brings a file of version ``v`` to
``v + 1``: its SQL, then (for some) a step in Python that fills what the new tables need from what the file
already holds, all in one transaction with the new version number, so a failed migration leaves the file as
it was. The record refuses a file newer than :data:`SCHEMA_VERSION` and never touches it.

Version 2 (the skill assessment) adds the trainee's ``level`` (the group a lab puts them in: expert, ...),
per sample the lateral offset along the path's normals and the insertion depth, per attempt how it was
assessed and its metrics (``attempt_metrics``, one row a metric), and the proficiency benchmarks of each
task (``benchmarks`` and their ``benchmark_thresholds``). Migrating a version-1 file computes the metrics
its attempts' samples allow (``economy``, ``idle_s``, ``jerk``, ``sparc``; the others were columns already);
``corrections`` and ``depth_reversals`` need what version 1 did not record, and stay unmeasured.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .metrics import AssessmentSettings, AttemptSamples, measure

SCHEMA_VERSION = 2

V1 = """
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

V2 = """
ALTER TABLE trainees ADD COLUMN level TEXT;
ALTER TABLE attempts ADD COLUMN assessment TEXT;
ALTER TABLE samples ADD COLUMN lateral_u_m REAL;
ALTER TABLE samples ADD COLUMN lateral_v_m REAL;
ALTER TABLE samples ADD COLUMN insertion_m REAL;
CREATE TABLE attempt_metrics (
    attempt_id INTEGER NOT NULL REFERENCES attempts(id), metric TEXT NOT NULL, value REAL NOT NULL,
    PRIMARY KEY (attempt_id, metric)) WITHOUT ROWID;
CREATE TABLE benchmarks (
    id INTEGER PRIMARY KEY, task TEXT NOT NULL, created TEXT NOT NULL, method TEXT NOT NULL, k REAL,
    percentile REAL, consecutive INTEGER NOT NULL, experts TEXT NOT NULL, attempts INTEGER NOT NULL);
CREATE TABLE benchmark_thresholds (
    benchmark_id INTEGER NOT NULL REFERENCES benchmarks(id), metric TEXT NOT NULL, better TEXT NOT NULL,
    mean REAL, sd REAL, threshold REAL NOT NULL, n INTEGER NOT NULL,
    PRIMARY KEY (benchmark_id, metric)) WITHOUT ROWID;
CREATE INDEX benchmarks_by_task ON benchmarks(task, id);
"""

#: how a version-1 attempt's score was made (its ``assessment``)
V1_ASSESSMENT = {
    "schema": 1,
    "score": "100 x completion x (0.6 safety + 0.4 accuracy) (version 1)",
    "metrics": "economy, idle_s, jerk and sparc computed from the samples when the record was migrated to "
    "version 2, with the default assessment settings; corrections and depth_reversals not recorded",
}

#: the columns of a version-1 attempt that are metrics
V1_METRIC_COLUMNS = (
    "score",
    "duration_s",
    "path_length_m",
    "deviation_rms_m",
    "below_threshold_s",
    "below_threshold_m",
    "contacts",
    "completion",
)


def _backfill_v2(db: sqlite3.Connection) -> None:
    """The metrics of every version-1 attempt: its metric columns, and what its samples allow."""
    settings = AssessmentSettings()
    attempts = db.execute(
        f"SELECT id, recommended_length_m, d_thresh_m, {', '.join(V1_METRIC_COLUMNS)} FROM attempts"
    ).fetchall()
    for attempt_id, recommended, threshold, *columns in attempts:
        rows = np.array(
            db.execute(
                "SELECT t, x, y, z, deviation_m, progress_m, clearance_m, critical FROM samples "
                "WHERE attempt_id = ? ORDER BY i",
                (attempt_id,),
            ).fetchall(),
            dtype=float,
        ).reshape(-1, 8)
        values = dict(zip(V1_METRIC_COLUMNS, columns, strict=True))
        if len(rows) >= 2:
            samples = AttemptSamples(rows[:, 0], rows[:, 1:4], rows[:, 4], rows[:, 5], rows[:, 6], rows[:, 7] > 0)
            measured = measure(
                samples,
                recommended_length=recommended or 0.0,
                threshold=threshold or 0.0,
                completion=values["completion"] or 0.0,
                settings=settings,
            )
            for key in ("economy", "idle_s", "jerk", "sparc"):
                values[key] = measured[key]
        db.executemany(
            "INSERT INTO attempt_metrics VALUES (?, ?, ?)",
            [(attempt_id, k, float(v)) for k, v in values.items() if v is not None],
        )
        db.execute("UPDATE attempts SET assessment = ? WHERE id = ?", (json.dumps(V1_ASSESSMENT), attempt_id))


@dataclass(frozen=True)
class Migration:
    sql: str
    #: fills the new tables from the old ones, in the same transaction
    backfill: Callable[[sqlite3.Connection], None] | None = None


#: MIGRATIONS[v] brings a file of version v to v + 1
MIGRATIONS: list[Migration] = [Migration(V1), Migration(V2, _backfill_v2)]


def migrate(db: sqlite3.Connection, version: int) -> None:
    """Bring an open file of ``version`` (at most :data:`SCHEMA_VERSION`: the record refuses newer ones) up
    to :data:`SCHEMA_VERSION`, inside the caller's write transaction (the record's ``BEGIN IMMEDIATE``: a
    failed migration leaves the file as it was, and a second process waits, then finds it migrated)."""
    for v in range(version, SCHEMA_VERSION):
        migration = MIGRATIONS[v]
        for statement in migration.sql.split(";"):  # the schema's SQL has no ';' inside a statement
            if statement.strip():
                db.execute(statement)
        if migration.backfill is not None:
            migration.backfill(db)
        db.execute(f"PRAGMA user_version = {v + 1}")
