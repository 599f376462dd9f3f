"""Atomic files and the array bundle format used for artifacts and checkpoints.

Everything surgiplan writes goes through :func:`atomic_write` (or, for a file a library writes itself,
:func:`commit_file`): a temporary file in the destination directory, flushed and fsynced, then renamed over the
target, and the directory fsynced so the rename is durable. A crash, ``kill -9`` or Ctrl-C leaves either the
old file or the new one, never a truncated one. ``docs/howto/reliability.md`` has the crash walk that proves
it: :mod:`surgiplan.faults` makes the n-th write, fsync or rename fail or kill the process.

A *bundle* is a ``.npz`` file of named numpy arrays plus one JSON document
(``__meta__``) for everything else. It is read with ``allow_pickle=False``:
loading a stored file never runs code.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import tempfile
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from . import faults
from .errors import OutputError

_META = "__meta__"
_UMASK = os.umask(0o022)
os.umask(_UMASK)


class _FaultyHandle:
    """A file handle whose writes are fault points (only while a fault or a trace is armed)."""

    def __init__(self, handle: Any, path: Path) -> None:
        self._handle, self._path = handle, path

    def write(self, data: Any) -> int:
        faults.point("write", self._path, partial=lambda: self._write_half(data))
        return self._handle.write(data)

    def _write_half(self, data: Any) -> None:  # a kill inside a write: half of it reaches the file first
        self._handle.write(data[: len(data) // 2])
        self._handle.flush()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._handle, name)


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "wb", *, private: bool = False) -> Iterator[Any]:
    """Open a temporary file next to ``path``; on success sync it and rename it over ``path``.

    ``private``: the file is created mode 0600 (personal data: a trainee's exports), else as the umask says.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o600 if private else 0o666 & ~_UMASK)  # mkstemp makes 0600; outputs are ordinary files
        with os.fdopen(fd, mode) as handle:
            yield _FaultyHandle(handle, path) if faults.ARMED else handle
            handle.flush()
            _fsync(handle.fileno(), path)
        _rename(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def temporary_path(path: str | Path, suffix: str = ".tmp") -> Path:
    """A new, empty temporary file next to ``path`` (for a library that writes a file by name); hand it to
    :func:`commit_file` once written, or remove it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    return Path(tmp)


def commit_file(tmp: str | Path, path: str | Path, *, mode: int | None = None) -> None:
    """Sync a complete temporary file and rename it over ``path`` (then sync the directory); the temporary
    file is removed if that fails. ``mode``: its permissions (default: as the umask says)."""
    try:
        os.chmod(tmp, mode if mode is not None else 0o666 & ~_UMASK)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            _fsync(fd, Path(path))
        finally:
            os.close(fd)
        _rename(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _fsync(fd: int, path: Path) -> None:
    if faults.ARMED:
        faults.point("fsync", path)
    os.fsync(fd)


def _rename(tmp: str | Path, path: str | Path) -> None:
    if faults.ARMED:
        faults.point("rename", path)
    os.replace(tmp, path)
    sync_directory(Path(path).parent)


def sync_directory(directory: Path) -> None:
    """fsync a directory, so a rename or a new file in it survives a power loss (where the OS allows it)."""
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_bytes_atomic(path: str | Path, data: bytes, *, private: bool = False) -> None:
    """Write ``data`` to ``path`` atomically (``private``: mode 0600)."""
    with atomic_write(path, "wb", private=private) as handle:
        handle.write(data)


def write_text_atomic(path: str | Path, text: str, *, private: bool = False) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (``private``: mode 0600)."""
    write_bytes_atomic(path, text.encode("utf-8"), private=private)


def write_json_atomic(path: str | Path, value: Any) -> None:
    write_text_atomic(path, json.dumps(value, indent=2, sort_keys=False, default=_json_default) + "\n")


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


def to_jsonable(value: Any) -> Any:
    """Arrays to lists, numpy scalars to Python numbers, recursively."""
    return json.loads(json.dumps(value, default=_json_default))


def save_bundle(path: str | Path, arrays: Mapping[str, Any], meta: Mapping[str, Any] | None = None) -> None:
    """Write named arrays and a JSON ``meta`` document atomically to a ``.npz`` file."""
    buffer = io.BytesIO()
    payload = {k: np.asarray(v) for k, v in arrays.items()}
    if _META in payload:
        raise ValueError(f"'{_META}' is reserved")
    for key, array in payload.items():
        if array.dtype == object:
            raise TypeError(f"array '{key}' has dtype object; store numbers, or put it in meta")
    payload[_META] = np.frombuffer(json.dumps(dict(meta or {}), default=_json_default).encode(), dtype=np.uint8)
    np.savez_compressed(buffer, **payload)
    write_bytes_atomic(path, buffer.getvalue())


def load_bundle(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a bundle; raises ``ValueError`` with the reason when it is not a valid one."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, KeyError) as exc:
        raise ValueError(f"not a readable bundle ({exc.__class__.__name__}: {exc})") from None
    if _META not in arrays:
        raise ValueError("no metadata record")
    try:
        meta = json.loads(arrays.pop(_META).tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"metadata is not valid JSON ({exc})") from None
    return arrays, meta


_TEMPORARY = re.compile(r"^\..+\.[A-Za-z0-9_]{8}\.tmp$")


def remove_temporaries(directory: Path) -> list[Path]:
    """Remove the temporary files (``.NAME.XXXXXXXX.tmp``, :func:`atomic_write`'s) a killed run left in
    ``directory`` and below; only for a directory this process holds (its run's lock). Returns them."""
    removed = []
    for path in directory.rglob(".*.tmp"):
        if _TEMPORARY.match(path.name) and path.is_file() and not path.is_symlink():
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed.append(path)
    return removed


def prepare_output_dir(path: Path) -> Path:
    """Create the output directory and prove it is writable, before any work starts."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-test-"):
            pass
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise OutputError(f"cannot write to output directory {path}: {reason}", location="output.dir") from None
    return path
