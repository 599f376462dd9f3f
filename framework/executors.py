"""Executors: where embarrassingly parallel offline work runs.

All-pairs optMIS paths and FEM equilibrium samples are many independent
tasks. An :class:`Executor` runs a picklable function over a list of task
arguments and yields results as they finish:

* ``local`` (:class:`LocalExecutor`, the default): a process pool on this
  machine (``workers``; 1 runs in-process). Its workers watch their parent
  and exit when it dies, however it dies (``kill -9`` included): no orphan
  keeps hundreds of megabytes blocked for good;
* ``dask`` (:class:`DaskExecutor`): a dask.distributed cluster reached at a
  scheduler address, for users who outgrow one machine. At connect time the
  workers are asked for the versions of surgiplan and of the stages' plugin
  packages; a worker that lacks one, or has another version, is named.

Tasks must be deterministic functions of their arguments (seeds travel with
the arguments), so both executors give the same results.

:func:`run_tasks` adds resumption: each finished result is written to a
:class:`TaskStore` as it arrives, and a second run skips what is there.
"""

from __future__ import annotations

import hashlib
import os
import re
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any

from .errors import ExecutorError
from .progress import NullProgress, Progress
from .storage import load_bundle, save_bundle, to_jsonable


class Executor(ABC):
    """Runs ``fn(item)`` for many items; results come back with their item index."""

    kind: str = "executor"

    @abstractmethod
    def imap_unordered(self, fn: Callable[[Any], Any], items: list[Any]) -> Iterator[tuple[int, Any]]:
        """Yield ``(index, fn(items[index]))`` as tasks finish, in any order."""

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        """``[fn(x) for x in items]``, computed by this executor."""
        items = list(items)
        results: list[Any] = [None] * len(items)
        for index, value in self.imap_unordered(fn, items):
            results[index] = value
        return results

    def close(self) -> None:
        """Release the workers (also on leaving a ``with`` block); the base has nothing to release."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def describe(self) -> str:
        """Where tasks run, for the run's log (``local (4 workers)``); the base gives :attr:`kind`."""
        return self.kind


class InlineExecutor(Executor):
    """Runs tasks one after another in this process (debugging, tiny jobs)."""

    kind = "inline"

    def imap_unordered(self, fn, items):
        for index, item in enumerate(items):
            yield index, fn(item)


#: how often (s) a local worker checks that the process that started it is still there
PARENT_POLL_S = 0.2


def _watch_parent(parent: int) -> None:
    """Pool-worker initializer: exit as soon as the parent process is gone (it was re-parented)."""

    def watch() -> None:
        while True:
            if os.getppid() != parent:
                os._exit(3)
            time.sleep(PARENT_POLL_S)

    threading.Thread(target=watch, name="surgiplan-parent-watch", daemon=True).start()


class LocalExecutor(Executor):
    """A process pool on this machine; ``workers=None`` uses every core.

    Each worker exits within :data:`PARENT_POLL_S` of its parent's death.
    """

    kind = "local"

    def __init__(self, workers: int | None = None) -> None:
        self.workers = workers or os.cpu_count() or 1
        self._pool: ProcessPoolExecutor | None = None

    def imap_unordered(self, fn, items):
        if self.workers == 1 or len(items) <= 1:
            yield from InlineExecutor().imap_unordered(fn, items)
            return
        if self._pool is None:
            self._pool = ProcessPoolExecutor(
                max_workers=self.workers, initializer=_watch_parent, initargs=(os.getpid(),)
            )
        futures = {self._pool.submit(fn, item): index for index, item in enumerate(items)}
        try:
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    yield futures[future], future.result()
        finally:
            for future in futures:
                future.cancel()

    def close(self):
        """Shut the process pool down (queued tasks cancelled, running ones awaited); a later task starts a new one."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def describe(self):
        """``local (N workers)``."""
        return f"local ({self.workers} worker{'s' if self.workers != 1 else ''})"


class DaskExecutor(Executor):
    """Runs tasks on a dask.distributed cluster at ``address`` (e.g. ``tcp://10.0.0.5:8786``)."""

    kind = "dask"

    def __init__(self, address: str, timeout: float = 10.0, required: Mapping[str, str] | None = None) -> None:
        try:
            from distributed import Client
        except ImportError:
            raise ExecutorError(
                "the dask executor needs dask.distributed: pip install 'surgiplan[dask]'",
                location="executor.kind",
            ) from None
        self.address = address
        try:
            self._client = Client(address, timeout=timeout, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise ExecutorError(
                f"cannot reach a dask scheduler at {address}: {exc}", location="executor.address"
            ) from None
        try:
            self._check_workers(dict(required or {}))
        except BaseException:
            self._client.close()
            raise

    def _check_workers(self, required: dict[str, str]) -> None:
        """Every worker has surgiplan and the plugin packages at this process's versions (else name it)."""
        from importlib import metadata

        try:
            required.setdefault("surgiplan", metadata.version("surgiplan"))
        except metadata.PackageNotFoundError:  # pragma: no cover - running from a source tree
            pass
        probe = _version_probe()
        try:
            answers = self._client.run(probe, sorted(required))
        except Exception as exc:
            raise ExecutorError(
                f"cannot ask the dask workers at {self.address} for their package versions: {exc}",
                location="executor.address",
            ) from None
        if not answers:
            raise ExecutorError(f"the dask scheduler at {self.address} has no workers", location="executor.address")
        problems = []
        for worker, versions in sorted(answers.items()):
            for package, wanted in sorted(required.items()):
                found = versions.get(package)
                if found is None:
                    problems.append(f"worker {worker} does not have {package} installed (this run uses {wanted})")
                elif found != wanted:
                    problems.append(f"worker {worker} has {package} {found}, this run uses {wanted}")
        if problems:
            raise ExecutorError(
                "the dask workers cannot run this pipeline: " + "; ".join(problems), location="executor.address"
            )

    def imap_unordered(self, fn, items):
        from distributed import as_completed

        futures = self._client.map(fn, items, pure=False)
        index = {future.key: i for i, future in enumerate(futures)}
        try:
            with self._client.as_current():  # not the process-wide default client
                for future in as_completed(futures):
                    yield index[future.key], future.result()
        finally:
            self._client.cancel(futures)

    def close(self):
        """Disconnect from the scheduler; the cluster (scheduler and workers) keeps running."""
        self._client.close()

    def describe(self):
        """``dask (ADDRESS)``: the scheduler's address."""
        return f"dask ({self.address})"


_PROBE_SOURCE = """
def versions(names):
    from importlib import metadata
    found = {}
    for name in names:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = None
    return found
"""


def _version_probe():
    """The workers' version check, defined outside any importable module so that cloudpickle sends it
    by value: a worker without surgiplan can still run it (and be named), rather than failing to
    deserialise a reference to ``surgiplan.executors``."""
    namespace: dict[str, Any] = {"__name__": "surgiplan_dask_probe"}
    exec(_PROBE_SOURCE, namespace)
    return namespace["versions"]


# ----------------------------------------------------------------------------- resumable task sets


class TaskStore:
    """A directory holding one bundle file per finished task.

    Writes are atomic, so an interrupted run keeps every task that finished
    and none that did not.
    """

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)

    def _path(self, key: str) -> Path:
        safe = re.sub(r"[^A-Za-z0-9_.-]", "_", key)[:80]
        digest = hashlib.sha1(key.encode()).hexdigest()[:10]
        return self.directory / f"{safe}.{digest}.npz"

    def __contains__(self, key: str) -> bool:
        return self._path(key).is_file()

    def save(self, key: str, result: Mapping[str, Any]) -> None:
        """Store the result of task ``key`` atomically: its numpy arrays as arrays, every other value as JSON."""
        arrays, meta = _split(result)
        save_bundle(self._path(key), arrays, {"key": key, "values": meta})

    def load(self, key: str) -> dict[str, Any]:
        """The result :meth:`save` stored for ``key`` (JSON values and arrays in one dict); :class:`ValueError` when
        its file is not a readable bundle."""
        arrays, meta = load_bundle(self._path(key))
        return {**meta["values"], **arrays}


def _split(result: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    import numpy as np

    arrays = {k: v for k, v in result.items() if isinstance(v, np.ndarray)}
    meta = to_jsonable({k: v for k, v in result.items() if not isinstance(v, np.ndarray)})
    return arrays, meta


def run_tasks(
    executor: Executor,
    fn: Callable[[Any], Mapping[str, Any]],
    tasks: Mapping[str, Any],
    *,
    store: TaskStore | None = None,
    progress: Progress | None = None,
    description: str = "tasks",
) -> dict[str, dict[str, Any]]:
    """Run ``fn(args)`` for every ``key: args`` in ``tasks``; resumable through ``store``.

    ``fn`` returns a mapping of numpy arrays and JSON values. Tasks already in
    the store are loaded, not recomputed; each new result is stored as soon as
    it arrives. Returns ``{key: result}`` for every task.
    """
    progress = progress or NullProgress()
    results: dict[str, dict[str, Any]] = {}
    todo = []
    for key, args in tasks.items():
        if store is not None and key in store:
            try:
                results[key] = store.load(key)
                continue
            except ValueError:
                pass  # a damaged checkpoint is recomputed
        todo.append((key, args))
    with progress.task(description, total=len(tasks)) as task:
        task.update(len(results))
        keys = [key for key, _ in todo]
        for index, value in executor.imap_unordered(fn, [args for _, args in todo]):
            arrays, meta = _split(value)
            value = {**meta, **arrays}  # the same form a resumed run loads
            if store is not None:
                store.save(keys[index], value)
            results[keys[index]] = value
            task.advance(1)
    return {key: results[key] for key in tasks}
