"""The report's shared primitives: arrays packed for the page, notes on what is not shown, safe file access.

Numeric arrays are packed as little-endian base64 (:func:`pack`) so a large roadmap or mesh sequence stays
compact and loads fast in the browser. A file that is missing, unreadable, outside the output directory or too
large is skipped with a note in the report (:class:`Notes`), never an error.
"""

from __future__ import annotations

import base64
import itertools
import logging
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger("surgiplan.outputs.report.data")

#: at most this many points are drawn per path, samples per timeline, frames per mesh sequence
MAX_PATH_POINTS = 4000
MAX_TIMELINE_SAMPLES = 6000
MAX_FRAMES = 120
#: files larger than this are not read into the report
MAX_FILE_BYTES = 512 * 1024 * 1024


def pack(array, dtype: str = "f4") -> dict[str, Any]:
    """A numeric array as ``{"dtype", "shape", "b64"}`` (little-endian), for the page's ``decode``."""
    a = np.ascontiguousarray(np.asarray(array), dtype=np.dtype(dtype).newbyteorder("<"))
    return {"dtype": {"f4": "f32", "u4": "u32"}[dtype], "shape": list(a.shape), "b64": base64.b64encode(a).decode()}


def finite_rows(a: np.ndarray) -> np.ndarray:
    return a[np.all(np.isfinite(a), axis=1)] if a.ndim == 2 else a


class Notes:
    """What could not be shown, and why (listed in the report)."""

    def __init__(self) -> None:
        self.items: list[str] = []

    def add(self, text: str) -> None:
        log.info("report: %s", text)
        self.items.append(text)


def inside(out: Path, relative: str, notes: Notes, *, what: str = "file") -> Path | None:
    """``out / relative`` if it is a regular file inside ``out`` and not too large, else None (noted)."""
    if not isinstance(relative, str) or not relative:
        return None
    try:
        root = out.resolve()
        path = (out / relative).resolve()
        path.relative_to(root)
    except (ValueError, OSError):
        notes.add(f"{what} {relative!r} is outside the output directory; not shown")
        return None
    if not path.is_file():
        notes.add(f"{what} {relative!r} is missing; not shown")
        return None
    if path.stat().st_size > MAX_FILE_BYTES:
        notes.add(f"{what} {relative!r} is larger than {MAX_FILE_BYTES // 2**20} MiB; not shown")
        return None
    return path


def keep_indices(n: int, flags: np.ndarray | None, limit: int) -> np.ndarray:
    """Indices of at most about ``limit`` samples: a stride, plus both ends of every change of ``flags``."""
    stride = max(1, math.ceil(n / limit))
    keep = set(range(0, n, stride))
    keep.add(n - 1)
    if flags is not None and len(flags):
        changes = np.flatnonzero(np.diff(flags.astype(np.int8))) if len(flags) > 1 else []
        for i in changes:  # segment i differs from segment i+1: keep point i+1 (their joint) and its neighbours
            keep.update((int(i), int(i) + 1, min(int(i) + 2, n - 1)))
    return np.array(sorted(keep), dtype=np.int64)


def itertools_pairs(values: Iterable[int]) -> list[tuple[int, int]]:
    return list(itertools.pairwise(values))


def as_array(value, columns: int | None = None) -> np.ndarray | None:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    if columns is not None and (a.ndim != 2 or a.shape[1] != columns):
        return None
    return a
