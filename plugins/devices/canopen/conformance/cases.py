"""Cases, verdicts and findings: what a conformance case is and what it says about each drive."""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field


class Verdict(enum.StrEnum):
    """A case's outcome on one drive."""

    PASS = "pass"
    #: conforms, with what a CTT reports as a warning (an EDS's ambiguous mapping direction)
    WARN = "warning"
    FAIL = "fail"
    #: the drive's EDS says it does not have what the case checks (no write-only object, no node guarding)
    NOT_APPLICABLE = "n/a"
    #: not run on this target (a power cycle or LSS on real drives, without the setting that allows it)
    SKIPPED = "skipped"


@dataclass
class Finding:
    """One case's verdict on one drive, with the evidence (what was sent, what came back)."""

    verdict: Verdict
    evidence: str


def passed(evidence: str) -> Finding:
    return Finding(Verdict.PASS, evidence)


def failed(evidence: str) -> Finding:
    return Finding(Verdict.FAIL, evidence)


def not_applicable(evidence: str) -> Finding:
    return Finding(Verdict.NOT_APPLICABLE, evidence)


def skipped(evidence: str) -> Finding:
    return Finding(Verdict.SKIPPED, evidence)


def judge(problems: list[str], evidence: str, limit: int = 3) -> Finding:
    """Pass with ``evidence`` if there are no ``problems``, else fail naming the first few."""
    if not problems:
        return passed(evidence)
    more = f" (+{len(problems) - limit} more)" if len(problems) > limit else ""
    return failed("; ".join(problems[:limit]) + more)


@dataclass(frozen=True)
class Case:
    """A conformance case: ``run(session)`` returns a finding per node-ID of the session's drives."""

    id: str
    family: str
    title: str
    run: Callable
    #: the CiA conformance test tool's cases this one corresponds to (its published numbering), if any
    ctt: str = ""


@dataclass
class Family:
    """A family of cases, run in order on a session."""

    name: str
    cases: list[Case] = field(default_factory=list)

    def case(self, id: str, title: str, ctt: str = "") -> Callable:
        """Decorator: register ``fn(session) -> {node_id: Finding}`` as a case of this family."""

        def register(fn: Callable) -> Callable:
            self.cases.append(Case(id, self.name, title, fn, ctt))
            return fn

        return register


def every(nodes: Iterable[int], finding: Finding) -> dict[int, Finding]:
    """The same finding for every node."""
    return {node: finding for node in nodes}


def periodic(count: int, window: float, period: float, what: str) -> list[str]:
    """Judge a periodic producer (heartbeat, event timer) by how many frames came in ``window`` s: never more
    often than ``period`` (at most ``window / period`` + 2, the two ends' frames), and still sending (at least a
    third of that: a loaded sender is late, not silent). By count, not by the gaps between reception stamps: a
    receiver that falls behind stamps a burst of frames at once, which says nothing about when they were sent."""
    most, least = int(window / period) + 2, max(2, int(window / period / 3))
    if count > most:
        return [f"{count} {what} in {window * 1000:.0f} ms: more often than every {period * 1000:.0f} ms"]
    if count < least:
        return [f"{count} {what} in {window * 1000:.0f} ms at {period * 1000:.0f} ms (at least {least} expected)"]
    return []
