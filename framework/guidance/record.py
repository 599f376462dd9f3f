"""The trainee record: every attempt of every trainee, per task, in one SQLite file a lab keeps for a cohort.

Python's own :mod:`sqlite3`, one file (default ``out/trainees.sqlite``;
``record:`` in a pipeline). An attempt and its samples are written in one
transaction when the attempt ends, so a crash (even ``kill -9``) mid-attempt
leaves every earlier attempt intact and no half-written one. The file is in
WAL mode with full synchronisation.

Schema (version :data:`SCHEMA_VERSION`, in ``PRAGMA user_version``;
:data:`MIGRATIONS` brings an older file up to date when it is opened)::

    trainees(id INTEGER PRIMARY KEY, name TEXT UNIQUE NOT NULL, created TEXT NOT NULL)
    attempts(id INTEGER PRIMARY KEY, trainee_id INTEGER NOT NULL REFERENCES trainees(id),
             task TEXT NOT NULL, started TEXT NOT NULL,            -- ISO 8601, local time with offset
             status TEXT NOT NULL, score REAL, duration_s REAL, d_thresh_m REAL,
             path_length_m REAL, recommended_length_m REAL, deviation_rms_m REAL, deviation_max_m REAL,
             deviation_p95_m REAL, min_clearance_m REAL, below_threshold_s REAL, below_threshold_m REAL,
             contacts INTEGER, completion REAL, events TEXT,       -- JSON list of the events
             pipeline TEXT, stage TEXT, source TEXT, output_dir TEXT)
    samples(attempt_id INTEGER NOT NULL REFERENCES attempts(id), i INTEGER NOT NULL,
            t REAL NOT NULL, x REAL, y REAL, z REAL,               -- tip position, m
            deviation_m REAL, progress_m REAL, clearance_m REAL, critical INTEGER,
            PRIMARY KEY (attempt_id, i)) WITHOUT ROWID
    index attempts_by_trainee_task on attempts(trainee_id, task, started)

A trainee's **proficiency** on a task (:meth:`TraineeRecord.proficiency`) is
the ``percentile`` of the tip deviations of their recorded samples on that
task (all attempts, or the ``last`` few), as paper 000's d_thresh from
recorded attempts: a path with that clearance keeps the trainee's
instrument off the obstacles in that share of their motion.
"""

from __future__ import annotations

import json
import sqlite3
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SurgiplanError

SCHEMA_VERSION = 1

#: MIGRATIONS[v] brings a file of version v to v + 1
MIGRATIONS: list[str] = [
    """
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
    """,
]

ATTEMPT_COLUMNS = (
    "status",
    "score",
    "duration_s",
    "d_thresh_m",
    "path_length_m",
    "recommended_length_m",
    "deviation_rms_m",
    "deviation_max_m",
    "deviation_p95_m",
    "min_clearance_m",
    "below_threshold_s",
    "below_threshold_m",
    "contacts",
    "completion",
)


class RecordError(SurgiplanError):
    """The trainee record cannot be opened, or has nothing for the trainee or task asked for."""


@dataclass(frozen=True)
class Proficiency:
    d_thresh: float
    percentile: float
    attempts: int
    samples: int
    deviation_median: float
    deviation_max: float


class TraineeRecord:
    """An open trainee record (a context manager)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.db = sqlite3.connect(self.path, timeout=10.0)
            self.db.execute("PRAGMA journal_mode=WAL")
            self.db.execute("PRAGMA synchronous=FULL")
            self.db.execute("PRAGMA foreign_keys=ON")
            self._migrate()
        except sqlite3.DatabaseError as exc:
            raise RecordError(f"cannot open the trainee record {self.path}: {exc}") from None
        except OSError as exc:
            raise RecordError(f"cannot create the trainee record {self.path}: {exc.strerror or exc}") from None

    def _migrate(self) -> None:
        version = self.db.execute("PRAGMA user_version").fetchone()[0]
        if version > SCHEMA_VERSION:
            raise RecordError(
                f"the trainee record {self.path} has schema version {version}, newer than this surgiplan's "
                f"{SCHEMA_VERSION}; upgrade surgiplan"
            )
        for v in range(version, SCHEMA_VERSION):
            try:
                self.db.executescript(f"BEGIN; {MIGRATIONS[v]} PRAGMA user_version = {v + 1}; COMMIT;")
            except sqlite3.DatabaseError:
                self.db.rollback()
                raise

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> TraineeRecord:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ writing
    def add_attempt(
        self,
        trainee: str,
        task: str,
        metrics: dict[str, Any],
        events: Sequence[dict[str, Any]],
        samples: dict[str, np.ndarray],
        *,
        status: str,
        pipeline: str = "",
        stage: str = "",
        source: str = "",
        output_dir: str = "",
    ) -> int:
        """Store one attempt and its samples in one transaction; returns its id."""
        n = len(samples["t"])
        with self.db:  # one transaction: all of the attempt or none of it
            self.db.execute("INSERT OR IGNORE INTO trainees(name, created) VALUES (?, ?)", (trainee, _now()))
            trainee_id = self.db.execute("SELECT id FROM trainees WHERE name = ?", (trainee,)).fetchone()[0]
            values = [metrics.get(c) for c in ATTEMPT_COLUMNS[1:]]
            cursor = self.db.execute(
                f"INSERT INTO attempts(trainee_id, task, started, {', '.join(ATTEMPT_COLUMNS)}, events, pipeline, "
                f"stage, source, output_dir) VALUES ({', '.join('?' * (len(ATTEMPT_COLUMNS) + 8))})",
                (
                    trainee_id,
                    task,
                    _now(),
                    status,
                    *values,
                    json.dumps(list(events)),
                    pipeline,
                    stage,
                    source,
                    output_dir,
                ),
            )
            attempt_id = int(cursor.lastrowid)
            tip = np.asarray(samples["tip"], float).reshape(n, 3)
            rows = zip(
                [attempt_id] * n,
                range(n),
                np.asarray(samples["t"], float).tolist(),
                tip[:, 0].tolist(),
                tip[:, 1].tolist(),
                tip[:, 2].tolist(),
                np.asarray(samples["deviation"], float).tolist(),
                np.asarray(samples["progress"], float).tolist(),
                np.asarray(samples["clearance"], float).tolist(),
                np.asarray(samples["critical"], int).tolist(),
                strict=True,
            )
            self.db.executemany("INSERT INTO samples VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", rows)
        return attempt_id

    # ------------------------------------------------------------------ reading
    def trainees(self) -> list[str]:
        return [r[0] for r in self.db.execute("SELECT name FROM trainees ORDER BY name")]

    def tasks(self, trainee: str) -> list[str]:
        self._trainee_id(trainee)
        rows = self.db.execute(
            "SELECT DISTINCT task FROM attempts JOIN trainees ON trainees.id = trainee_id WHERE name = ? ORDER BY task",
            (trainee,),
        )
        return [r[0] for r in rows]

    def _trainee_id(self, trainee: str) -> int:
        row = self.db.execute("SELECT id FROM trainees WHERE name = ?", (trainee,)).fetchone()
        if row is None:
            from ..errors import choices_hint

            raise RecordError(
                f"no trainee '{trainee}' in the record {self.path}; {choices_hint(trainee, self.trainees())}"
            )
        return int(row[0])

    def attempts(self, trainee: str, task: str | None = None) -> list[dict[str, Any]]:
        """The trainee's attempts (oldest first), each a dict of the attempts table's columns (events parsed)."""
        trainee_id = self._trainee_id(trainee)
        query = "SELECT * FROM attempts WHERE trainee_id = ?" + (" AND task = ?" if task else "") + " ORDER BY id"
        cursor = self.db.execute(query, (trainee_id, task) if task else (trainee_id,))
        names = [d[0] for d in cursor.description]
        out = []
        for row in cursor:
            entry = dict(zip(names, row, strict=True))
            entry["events"] = json.loads(entry["events"] or "[]")
            out.append(entry)
        return out

    def samples(self, attempt_id: int) -> dict[str, np.ndarray]:
        rows = np.array(
            self.db.execute(
                "SELECT t, x, y, z, deviation_m, progress_m, clearance_m, critical FROM samples "
                "WHERE attempt_id = ? ORDER BY i",
                (attempt_id,),
            ).fetchall(),
            dtype=float,
        ).reshape(-1, 8)
        return {
            "t": rows[:, 0],
            "tip": rows[:, 1:4],
            "deviation": rows[:, 4],
            "progress": rows[:, 5],
            "clearance": rows[:, 6],
            "critical": rows[:, 7].astype(bool),
        }

    def proficiency(self, trainee: str, task: str, percentile: float = 95.0, last: int | None = None) -> Proficiency:
        """d_thresh from the trainee's recorded deviations on the task (see the module docstring)."""
        attempts = self.attempts(trainee, task)
        if not attempts:
            tasks = self.tasks(trainee)
            raise RecordError(
                f"trainee '{trainee}' has no recorded attempt at task '{task}' in {self.path}"
                + (f"; recorded tasks: {', '.join(tasks)}" if tasks else "")
            )
        chosen = attempts[-last:] if last else attempts
        deviation = np.concatenate([self.samples(a["id"])["deviation"] for a in chosen])
        return Proficiency(
            d_thresh=float(np.percentile(deviation, percentile)),
            percentile=float(percentile),
            attempts=len(chosen),
            samples=len(deviation),
            deviation_median=float(np.median(deviation)),
            deviation_max=float(deviation.max()),
        )


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")
