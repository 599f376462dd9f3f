"""The trainee record: every attempt of every trainee, per task, in one SQLite file a lab keeps for a cohort.

Python's own :mod:`sqlite3`, one file (default ``out/trainees.sqlite``;
``record:`` in a pipeline). An attempt and its samples are written in one
transaction when the attempt ends, so a crash (even ``kill -9``) mid-attempt
leaves every earlier attempt intact and no half-written one. The file is in
WAL mode with full synchronisation, created mode 0600 (personal data), and
written by several processes at once without loss (:mod:`.transaction`:
``BEGIN IMMEDIATE``, busy timeout, retried).

The schema (version :data:`~.schema.SCHEMA_VERSION`, in ``PRAGMA user_version``) and its migrations are
:mod:`.schema`'s and ``docs/trainee-record.md``'s: trainees (and their level), attempts, their samples and
metrics, and the proficiency benchmarks of each task. Opening an older file migrates it; a newer one is
refused. Every write to the file is a method of :class:`TraineeRecord`, each one transaction.

A trainee's **proficiency** on a task (:meth:`TraineeRecord.proficiency`) is
the ``percentile`` of the tip deviations of their recorded samples on that
task (all attempts, or the ``last`` few), as paper 000's d_thresh from
recorded attempts: a path with that clearance keeps the trainee's
instrument off the obstacles in that share of their motion.
"""

from __future__ import annotations

import json
import numbers
import sqlite3
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SurgiplanError
from .benchmark import Benchmark, Threshold
from .metrics import METRIC_BY_NAME, AttemptSamples
from .schema import SCHEMA_VERSION, migrate
from .transaction import BUSY_TIMEOUT_S, create_private, immediate, wait_for_lock

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
    """A trainee's proficiency on a task (:meth:`TraineeRecord.proficiency`): ``d_thresh`` (m), the ``percentile`` of
    their tip deviations it is, from how many ``attempts`` and ``samples``, and the deviations' median and maximum
    (m)."""

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
            create_private(self.path)  # personal data: 0600 from the start (the -wal and -shm files follow)
            self.db = sqlite3.connect(self.path, timeout=BUSY_TIMEOUT_S)
            # before anything writes to the file: a newer one is left as it is
            version = wait_for_lock(self._version, self.path)
            # a new file: another process may be creating it now, and the switch to WAL does not wait for it
            wait_for_lock(lambda: self.db.execute("PRAGMA journal_mode=WAL"), self.path)
            self.db.execute("PRAGMA synchronous=FULL")
            self.db.execute("PRAGMA foreign_keys=ON")
            if version < SCHEMA_VERSION:
                with immediate(self.db, self.path):  # another process may be migrating it now: once, not twice
                    migrate(self.db, self.db.execute("PRAGMA user_version").fetchone()[0])
        except sqlite3.DatabaseError as exc:
            raise RecordError(f"cannot open the trainee record {self.path}: {exc}") from None
        except (ValueError, TypeError, KeyError) as exc:  # a migration's backfill met data it cannot read
            self.db.close()
            raise RecordError(
                f"cannot migrate the trainee record {self.path} to schema version {SCHEMA_VERSION} (it is left as "
                f"it was): {type(exc).__name__}: {exc}"
            ) from None
        except OSError as exc:
            raise RecordError(f"cannot create the trainee record {self.path}: {exc.strerror or exc}") from None

    def _version(self) -> int:
        version = self.db.execute("PRAGMA user_version").fetchone()[0]
        if version > SCHEMA_VERSION:
            self.db.close()
            raise RecordError(
                f"the trainee record {self.path} has schema version {version}, newer than this surgiplan's "
                f"{SCHEMA_VERSION} (written by a newer surgiplan); upgrade surgiplan to read it (the file is "
                "left as it is)"
            )
        return version

    def close(self) -> None:
        """Close the database (also on leaving a ``with`` block); everything written is already committed."""
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
        samples: AttemptSamples,
        *,
        status: str,
        level: str | None = None,
        assessment: dict[str, Any] | None = None,
        pipeline: str = "",
        stage: str = "",
        source: str = "",
        output_dir: str = "",
    ) -> int:
        """Store one attempt, its samples and its metrics (those of ``surgiplan.guidance.METRICS`` it has) in one
        transaction; returns its id. ``level`` (when given) becomes the trainee's level."""
        n = len(samples.t)
        with immediate(self.db, self.path):  # one transaction: all of the attempt or none of it
            self.db.execute("INSERT OR IGNORE INTO trainees(name, created) VALUES (?, ?)", (trainee, _now()))
            if level is not None:
                self.db.execute("UPDATE trainees SET level = ? WHERE name = ?", (level, trainee))
            trainee_id = self.db.execute("SELECT id FROM trainees WHERE name = ?", (trainee,)).fetchone()[0]
            values = [metrics.get(c) for c in ATTEMPT_COLUMNS[1:]]
            cursor = self.db.execute(
                f"INSERT INTO attempts(trainee_id, task, started, {', '.join(ATTEMPT_COLUMNS)}, events, pipeline, "
                f"stage, source, output_dir, assessment) VALUES ({', '.join('?' * (len(ATTEMPT_COLUMNS) + 9))})",
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
                    json.dumps(assessment or {}),
                ),
            )
            attempt_id = int(cursor.lastrowid)
            tip = np.asarray(samples.tip, float).reshape(n, 3)
            lateral = (
                np.asarray(samples.lateral, float).reshape(n, 2)
                if samples.lateral is not None
                else np.full((n, 2), np.nan)
            )
            insertion = np.asarray(samples.insertion, float) if samples.insertion is not None else np.full(n, np.nan)
            rows = zip(
                [attempt_id] * n,
                range(n),
                np.asarray(samples.t, float).tolist(),
                tip[:, 0].tolist(),
                tip[:, 1].tolist(),
                tip[:, 2].tolist(),
                np.asarray(samples.deviation, float).tolist(),
                np.asarray(samples.progress, float).tolist(),
                np.asarray(samples.clearance, float).tolist(),
                np.asarray(samples.critical, int).tolist(),
                _nullable(lateral[:, 0]),
                _nullable(lateral[:, 1]),
                _nullable(insertion),
                strict=True,
            )
            self.db.executemany(
                "INSERT INTO samples(attempt_id, i, t, x, y, z, deviation_m, progress_m, clearance_m, critical, "
                "lateral_u_m, lateral_v_m, insertion_m) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                rows,
            )
            self.db.executemany(
                "INSERT INTO attempt_metrics VALUES (?, ?, ?)",
                [
                    (attempt_id, name, float(value))
                    for name in METRIC_BY_NAME
                    if isinstance(value := metrics.get(name), numbers.Real)
                    and not isinstance(value, bool)
                    and np.isfinite(value)
                ],
            )
        return attempt_id

    def set_level(self, trainee: str, level: str | None) -> None:
        """The trainee's level (the group a lab puts them in: expert, intermediate, ...; None: none)."""
        self._trainee_id(trainee)
        with immediate(self.db, self.path):
            self.db.execute("UPDATE trainees SET level = ? WHERE name = ?", (level, trainee))

    def add_benchmark(self, benchmark: Benchmark) -> int:
        """Store a task's benchmark (it becomes the task's current one); returns its id."""
        with immediate(self.db, self.path):
            cursor = self.db.execute(
                "INSERT INTO benchmarks(task, created, method, k, percentile, consecutive, experts, attempts) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    benchmark.task,
                    _now(),
                    benchmark.method,
                    benchmark.k,
                    benchmark.percentile,
                    benchmark.consecutive,
                    json.dumps(benchmark.experts),
                    benchmark.attempts,
                ),
            )
            benchmark_id = int(cursor.lastrowid)
            self.db.executemany(
                "INSERT INTO benchmark_thresholds VALUES (?, ?, ?, ?, ?, ?, ?)",
                [(benchmark_id, t.metric, t.better, t.mean, t.sd, t.value, t.n) for t in benchmark.thresholds.values()],
            )
        return benchmark_id

    # ------------------------------------------------------------------ reading
    def trainees(self, task: str | None = None) -> list[str]:
        """Every trainee, or those with an attempt at ``task``, by name."""
        if task is None:
            return [r[0] for r in self.db.execute("SELECT name FROM trainees ORDER BY name")]
        rows = self.db.execute(
            "SELECT DISTINCT name FROM trainees JOIN attempts ON trainees.id = trainee_id WHERE task = ? ORDER BY name",
            (task,),
        )
        return [r[0] for r in rows]

    def all_tasks(self) -> list[str]:
        """Every task with an attempt in the record, sorted."""
        return [r[0] for r in self.db.execute("SELECT DISTINCT task FROM attempts ORDER BY task")]

    def levels(self) -> dict[str, str | None]:
        """Each trainee's level."""
        return dict(self.db.execute("SELECT name, level FROM trainees ORDER BY name").fetchall())

    def tasks(self, trainee: str) -> list[str]:
        """The tasks ``trainee`` has attempted, sorted; :class:`RecordError` naming the recorded trainees when there
        is no such trainee."""
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
            entry["assessment"] = json.loads(entry["assessment"] or "{}")
            out.append(entry)
        return out

    def samples(self, attempt_id: int) -> dict[str, np.ndarray]:
        """The attempt's samples as arrays (SI; NaN where a version-1 attempt has no lateral or insertion)."""
        rows = np.array(
            self.db.execute(
                "SELECT t, x, y, z, deviation_m, progress_m, clearance_m, critical, lateral_u_m, lateral_v_m, "
                "insertion_m FROM samples WHERE attempt_id = ? ORDER BY i",
                (attempt_id,),
            ).fetchall(),
            dtype=float,
        ).reshape(-1, 11)
        return {
            "t": rows[:, 0],
            "tip": rows[:, 1:4],
            "deviation": rows[:, 4],
            "progress": rows[:, 5],
            "clearance": rows[:, 6],
            "critical": rows[:, 7].astype(bool),
            "lateral": rows[:, 8:10],
            "insertion": rows[:, 10],
        }

    def metrics(self, attempt_id: int) -> dict[str, float]:
        """The attempt's metrics (those it has), by name."""
        return dict(self.db.execute("SELECT metric, value FROM attempt_metrics WHERE attempt_id = ?", (attempt_id,)))

    def history(self, trainee: str, task: str) -> list[dict[str, Any]]:
        """The trainee's attempts at the task (oldest first): the attempts table's columns, ``n`` (1-based)
        and ``metrics`` (by name)."""
        out = []
        for n, attempt in enumerate(self.attempts(trainee, task), start=1):
            attempt["n"] = n
            attempt["metrics"] = self.metrics(attempt["id"])
            out.append(attempt)
        return out

    def attempt(self, attempt_id: int) -> dict[str, Any] | None:
        """One attempt's row (with its trainee's name), or None when there is no such attempt."""
        cursor = self.db.execute(
            "SELECT attempts.*, trainees.name AS trainee FROM attempts JOIN trainees ON trainees.id = trainee_id "
            "WHERE attempts.id = ?",
            (attempt_id,),
        )
        row = cursor.fetchone()
        return None if row is None else dict(zip([d[0] for d in cursor.description], row, strict=True))

    def benchmark(self, task: str) -> Benchmark | None:
        """The task's current benchmark (the latest set), or None."""
        cursor = self.db.execute("SELECT * FROM benchmarks WHERE task = ? ORDER BY id DESC LIMIT 1", (task,))
        row = cursor.fetchone()
        if row is None:
            return None
        b = dict(zip([d[0] for d in cursor.description], row, strict=True))
        thresholds = {
            metric: Threshold(metric, better, mean, sd, value, n)
            for metric, better, mean, sd, value, n in self.db.execute(
                "SELECT metric, better, mean, sd, threshold, n FROM benchmark_thresholds WHERE benchmark_id = ?",
                (b["id"],),
            )
        }
        order = list(METRIC_BY_NAME)
        return Benchmark(
            task=b["task"],
            method=b["method"],
            k=b["k"],
            percentile=b["percentile"],
            consecutive=b["consecutive"],
            experts=json.loads(b["experts"]),
            attempts=b["attempts"],
            thresholds=dict(sorted(thresholds.items(), key=lambda kv: order.index(kv[0]) if kv[0] in order else 99)),
            id=b["id"],
            created=b["created"],
        )

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


def _nullable(values: np.ndarray) -> list[float | None]:
    return [v if np.isfinite(v) else None for v in np.asarray(values, float).tolist()]


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")
