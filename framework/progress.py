"""Progress reporting for long offline phases.

Plugins receive a :class:`Progress` and open tasks on it::

    with problem.progress.task("building roadmap", total=n) as task:
        for chunk in chunks:
            ...
            task.advance(len(chunk))

The command line passes a :class:`RichProgress` (bars on stderr); tests and
library users get :class:`NullProgress` unless they ask otherwise.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator


class ProgressTask:
    """Handle of one running task; ``advance`` by finished units.

    A task whose ``with`` block ends normally is shown finished (its bar full, whatever the last update
    was: a flight that arrived within the acceptance radius of its goal has flown the whole path). One
    that ends early without finishing (a flight the vehicle stopped) calls :meth:`abandon`: its bar stays
    where it got to, and an exception leaves it there too.
    """

    abandoned = False

    def abandon(self) -> None:
        """Mark the task as ended unfinished: its bar stays where it got to when the ``with`` block ends."""
        self.abandoned = True

    def advance(self, amount: float = 1.0) -> None:  # pragma: no cover - interface
        """Add ``amount`` finished units (of the task's ``total``)."""
        pass

    def update(self, completed: float) -> None:  # pragma: no cover - interface
        """Set the finished units to ``completed`` (of the task's ``total``)."""
        pass


class Progress:
    """Base progress reporter: reports nothing."""

    @contextlib.contextmanager
    def task(self, description: str, total: float | None = None) -> Iterator[ProgressTask]:
        """A context manager giving the :class:`ProgressTask` of one task, shown as ``description`` with ``total``
        units (None: unknown) while the ``with`` block runs."""
        yield ProgressTask()

    def close(self) -> None:
        """Stop reporting (the run calls it at its end); the base has nothing to stop."""


class NullProgress(Progress):
    """Reports nothing (the default outside the command line)."""


class StageProgress(Progress):
    """A stage's view of the run's progress: every task it opens is named after the stage
    (``expert: sampling milestones``), so four plan stages do not show four identical bars."""

    def __init__(self, inner: Progress, stage: str) -> None:
        self.inner = inner
        self.stage = stage

    def task(self, description: str, total: float | None = None):
        """The run's task, its description prefixed with the stage's name (``expert: sampling milestones``)."""
        if not description.startswith(f"{self.stage}:"):
            description = f"{self.stage}: {description}"
        return self.inner.task(description, total)

    def close(self) -> None:  # the run closes the real one
        """Nothing: the run closes the progress this view wraps."""


class _RichTask(ProgressTask):
    def __init__(self, progress, task_id) -> None:
        self._progress = progress
        self._task_id = task_id

    def advance(self, amount: float = 1.0) -> None:
        self._progress.advance(self._task_id, amount)

    def update(self, completed: float) -> None:
        self._progress.update(self._task_id, completed=completed)


class RichProgress(Progress):
    """Progress bars on stderr with rich: description, bar, count, elapsed and remaining time."""

    def __init__(self, console=None) -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )
        from rich.progress import Progress as _Progress

        self._progress = _Progress(
            TextColumn("[progress.description]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=console or Console(stderr=True),
            transient=False,
        )
        self._started = False

    @contextlib.contextmanager
    def task(self, description: str, total: float | None = None) -> Iterator[ProgressTask]:
        """A bar for the task (the display starts with the first); full at the end of the ``with`` block unless
        abandoned or left by an exception."""
        if not self._started:
            self._progress.start()
            self._started = True
        task_id = self._progress.add_task(description, total=total)
        try:
            handle = _RichTask(self._progress, task_id)
            yield handle
            if total is not None and not handle.abandoned:
                self._progress.update(task_id, completed=total)
        finally:
            self._progress.stop_task(task_id)

    def close(self) -> None:
        """Stop the display, leaving the bars on the terminal."""
        if self._started:
            self._progress.stop()
            self._started = False
