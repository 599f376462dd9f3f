"""Exceptions surgiplan raises for problems a user can fix.

Every error a user can cause (a broken file, an unknown plugin, a start inside
an obstacle) is a :class:`SurgiplanError`. The command line prints its message
without a traceback and exits with status 2; anything else is a bug.

Messages name *what* and *where*: the file, the YAML path inside it
(``pipeline[0].settings.milestones``), and, when there is a fixed set of valid
choices, the choices.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path


class SurgiplanError(Exception):
    """Base class of every user-facing error.

    Attributes:
        file: the file the problem is in, if any.
        location: the YAML path inside that file (``scene.obstacles[2].mesh``).
        line: 1-based line number inside the file, when known.
    """

    exit_code = 2

    def __init__(
        self,
        message: str,
        *,
        file: str | Path | None = None,
        location: str | None = None,
        line: int | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.file = Path(file) if file is not None else None
        self.location = location
        self.line = line

    def __str__(self) -> str:
        where = []
        if self.file is not None:
            where.append(f"{self.file}:{self.line}" if self.line else str(self.file))
        if self.location:
            where.append(self.location)
        prefix = ": ".join(where)
        return f"{prefix}: {self.message}" if prefix else self.message


class ConfigError(SurgiplanError):
    """A pipeline or scene file is malformed or names something invalid."""


class ConfigErrors(ConfigError):
    """Several problems found in one file; reported together."""

    def __init__(self, errors: Iterable[ConfigError]) -> None:
        self.errors = list(errors)
        first = self.errors[0]
        super().__init__(first.message, file=first.file, location=first.location, line=first.line)

    def __str__(self) -> str:
        if len(self.errors) == 1:
            return str(self.errors[0])
        lines = [f"{len(self.errors)} problems:"]
        lines += [f"  {e}" for e in self.errors]
        return "\n".join(lines)


class SceneError(SurgiplanError):
    """A scene cannot be built: missing or unreadable mesh, empty geometry, bad bounds."""


class PluginError(SurgiplanError):
    """A plugin is unknown, broken, disabled, or two plugins claim the same name."""


class PlanningInputError(SurgiplanError):
    """A start or goal is outside the bounds, inside an obstacle, or not a known point."""


class ArtifactError(SurgiplanError):
    """A stored artifact (roadmap, path repository) is corrupt or of another format."""


class OutputError(SurgiplanError):
    """The output directory cannot be created or written."""


class ExecutorError(SurgiplanError):
    """An executor cannot start (e.g. no dask scheduler at the given address)."""


class StageError(SurgiplanError):
    """A plugin failed while running a stage; names the stage and the plugin.

    Not a user error: exits with status 1.
    """

    exit_code = 1


def choices_hint(name: str, choices: Iterable[str]) -> str:
    """``"choose one of: a, b, c"`` plus a did-you-mean suggestion when one is close."""
    import difflib

    options = sorted(set(choices))
    if not options:
        return "none are available"
    hint = "choose one of: " + ", ".join(options)
    close = difflib.get_close_matches(name, options, n=1, cutoff=0.5)
    if close:
        hint = f"did you mean '{close[0]}'? {hint}"
    return hint


def debug_enabled() -> bool:
    """Whether ``SURGIPLAN_DEBUG`` asks for tracebacks of internal errors (any value but empty or ``0``)."""
    return os.environ.get("SURGIPLAN_DEBUG", "") not in ("", "0")
