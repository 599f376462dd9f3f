"""Every status a stage or a device can report, in one place.

A stage's ``status`` in ``result.json`` (and in the summary table) is one of
these values. Plugins return the first four kinds; the framework sets the
last one when it must speak for a plugin. A stage kind registered by a third
party (:mod:`surgiplan.kinds`) declares its own statuses the same way.

======================= ================================================================  ==========
enum                    values                                                            succeeded
======================= ================================================================  ==========
:class:`PlanStatus`     ``solved``; ``no_path``, ``invalid_start``, ``invalid_goal``,     ``solved``
                        ``timeout``
:class:`SimulateStatus` ``converged``, ``completed``; ``failed``                          the first two
:class:`ExecuteStatus`  ``completed``; ``stopped`` (a fault, a failsafe: the reason is    ``completed``
                        in the message), ``refused`` (before any motion)
:class:`GuideStatus`    ``completed`` (the goal reached); ``incomplete``, ``stopped``     ``completed``
:class:`RunStatus`      ``invalid_result`` (the framework refused a plugin's answer:      never
                        a colliding or malformed path, an unknown status),
                        ``unsafe`` (a device's executed motion, re-measured, touched
                        an obstacle or came inside the device's safety margin),
                        ``error`` (the plugin raised), ``skipped`` (the stage it
                        depends on gave it nothing to work on), ``not_run`` (an
                        earlier stage ended the run), ``interrupted``
======================= ================================================================  ==========

A device's :class:`~surgiplan.devices.ExecutionReport` must carry an
:class:`ExecuteStatus` value; anything else (``"done"``) makes the stage
``invalid_result`` with a message naming the plugin and the value.

The whole run has a status too (``result.json``'s top-level ``status``):
:class:`RunOutcomeStatus`.
"""

from __future__ import annotations

import enum


class PlanStatus(enum.StrEnum):
    """What a planner's query returns."""

    SOLVED = "solved"
    NO_PATH = "no_path"
    INVALID_START = "invalid_start"
    INVALID_GOAL = "invalid_goal"
    TIMEOUT = "timeout"


class SimulateStatus(enum.StrEnum):
    """What a deformable model's ``simulate`` stage returns."""

    CONVERGED = "converged"
    COMPLETED = "completed"
    FAILED = "failed"


class ExecuteStatus(enum.StrEnum):
    """What a device's execution returns."""

    COMPLETED = "completed"
    STOPPED = "stopped"
    REFUSED = "refused"


class GuideStatus(enum.StrEnum):
    """How a guided attempt ended."""

    COMPLETED = "completed"  # the instrument reached the end of the recommended path
    INCOMPLETE = "incomplete"  # the attempt ended before the goal
    STOPPED = "stopped"  # the source stopped sending (the reason in the message)


class RunStatus(enum.StrEnum):
    """Statuses the framework sets on a stage."""

    INVALID_RESULT = "invalid_result"
    UNSAFE = "unsafe"  # what a device executed, re-measured on the scene, touched or came inside its safety margin
    ERROR = "error"
    SKIPPED = "skipped"
    NOT_RUN = "not_run"
    INTERRUPTED = "interrupted"


class RunOutcomeStatus(enum.StrEnum):
    """The whole run, in ``result.json``: every stage succeeded, or not, or it stopped early."""

    SUCCEEDED = "succeeded"
    FAILED = "failed"  # every stage ran; at least one did not succeed
    ERROR = "error"  # a stage raised; later stages did not run
    INTERRUPTED = "interrupted"


#: the statuses that count as success, per stage kind: each kind declares its own (surgiplan.kinds.StageKind)
_SUCCEEDED: dict[str, frozenset[str]] = {}


def declare_statuses(kind: str, succeeded: frozenset[str] | set[str], *, replace: bool = True) -> None:
    """Record which statuses of stage kind ``kind`` count as success. The registry does it for every kind it
    registers (``replace``); a StageKind subclass does it when defined, unless the name is already declared
    (so results made by hand know them, and a class that reuses a registered name changes nothing)."""
    if replace or kind not in _SUCCEEDED:
        _SUCCEEDED[kind] = frozenset(str(s) for s in succeeded)


def succeeded(kind: str, status: str) -> bool:
    """Whether a ``kind`` stage that ended ``status`` succeeded (never, for a kind nobody declared)."""
    return status in _SUCCEEDED.get(kind, frozenset())
