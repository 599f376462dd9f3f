"""``surgiplan trainee --export FILE``: the record's attempts, one row each, as a CSV for statistics tools; with
``--pseudonymise``, every trainee's name replaced by a stable pseudonym.

A pseudonym is ``P-`` and the first 16 hex digits of HMAC-SHA256(key, name), with a random 256-bit key made
for the record when it is first pseudonymised and kept in it (table ``record_secrets``). So:

* the same trainee has the same pseudonym in every export of one record (a cohort's exports can be joined),
  and different pseudonyms in two records (each has its own key);
* a name cannot be recovered from a pseudonym without the key: the record holds the key, so whoever may read
  the record can re-identify (it holds the names anyway), and whoever has only the export cannot, not even by
  trying every name on a list, short of guessing a 256-bit key.

This is pseudonymisation (GDPR art. 4(5)), not anonymisation: the rows keep levels, times and metrics.
Columns a name could hide in (the pipeline file, the output directory, the pose source) are never exported.
The CSV is written atomically, mode 0600.
"""

from __future__ import annotations

import csv
import hashlib
import hmac
import io
import secrets
from pathlib import Path
from typing import Any

from ..storage import write_text_atomic
from .metrics import METRICS
from .record import ATTEMPT_COLUMNS, RecordError, TraineeRecord
from .transaction import immediate

#: the record's table of secrets (created by the first pseudonymised export)
SECRETS_TABLE = "record_secrets"
_KEY = "pseudonym_hmac_sha256"


def pseudonym_key(record: TraineeRecord) -> bytes:
    """The record's pseudonym key, made (random, 32 bytes) and stored the first time it is asked for."""
    with immediate(record.db, record.path):  # two exports at once make one key, not two
        record.db.execute(f"CREATE TABLE IF NOT EXISTS {SECRETS_TABLE} (name TEXT PRIMARY KEY, value BLOB NOT NULL)")
        record.db.execute(f"INSERT OR IGNORE INTO {SECRETS_TABLE} VALUES (?, ?)", (_KEY, secrets.token_bytes(32)))
        (key,) = record.db.execute(f"SELECT value FROM {SECRETS_TABLE} WHERE name = ?", (_KEY,)).fetchone()
    return bytes(key)


def pseudonym(key: bytes, name: str) -> str:
    """The stable pseudonym of ``name`` under ``key`` (see the module)."""
    return "P-" + hmac.new(key, name.encode("utf-8"), hashlib.sha256).hexdigest()[:16]


def export_rows(
    record: TraineeRecord, *, trainee: str | None = None, task: str | None = None, pseudonymise: bool = False
) -> list[dict[str, Any]]:
    """Every attempt (of ``trainee``, at ``task``: default all), one row each, names replaced when asked."""
    names = [trainee] if trainee else record.trainees(task)
    if not names:
        raise RecordError(f"no attempt{f' at task {task!r}' if task else ''} in the record {record.path}")
    key = pseudonym_key(record) if pseudonymise else b""
    levels = record.levels()
    rows = []
    for name in names:
        who = pseudonym(key, name) if pseudonymise else name
        for task_name in [task] if task else record.tasks(name):
            for attempt in record.history(name, task_name):
                row: dict[str, Any] = {
                    "trainee": who,
                    "level": levels.get(name),
                    "task": task_name,
                    "attempt": attempt["n"],
                    "started": attempt["started"],
                }
                row.update({c: attempt[c] for c in ATTEMPT_COLUMNS})
                row.update({m.name: attempt["metrics"].get(m.name) for m in METRICS if m.name not in row})
                rows.append(row)
    if pseudonymise and len({r["trainee"] for r in rows}) != len(names):  # 2^-64 per pair: never, but checked
        raise RecordError("two trainees have the same pseudonym; export without --pseudonymise")
    return rows


def write_rows_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    """Rows of trainee data as CSV at ``path``, the first row's keys as the header (atomically, mode 0600)."""
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if v is None else v for k, v in row.items()})
    write_text_atomic(path, out.getvalue(), private=True)
