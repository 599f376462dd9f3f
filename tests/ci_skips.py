"""CI cannot pass silently: skips of the browser and interop tests fail when ``CI`` is set, and every run says how
many tests skipped.

A browser test (report.html, the live view: ``tests/browser_support.py`` and the ``*browser*`` test modules) or an
interop test (``tests/interop/``: MAVSDK, MAVProxy, pymavlink, python-can, canopen) skips on a developer's machine
that lacks its peer (no chromium, no MAVSDK, ...), saying why. On CI the peer is installed by ``make test`` (the
``interop`` and ``browser`` extras, Debian's chromium), so such a skip means the check did not run: with ``CI`` set
(any value but empty, ``0`` or ``false``) it is reported as a failure that quotes the skip's reason.

Only skips *raised at run time* from those files count (``pytest.skip``, ``pytest.importorskip``): a test that is
skipped by a marker on purpose (python-can's own vendored tests mark some with ``unittest.skip``) stays a skip.
The hooks are imported by ``tests/conftest.py``.
"""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
INTEROP = TESTS / "interop"


def ci() -> bool:
    """Whether the suite runs on CI (the ``CI`` environment variable, as CI services set it)."""
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def peer_file(filename: str) -> bool:
    """Whether ``filename`` is a browser or interop test file (or one of their helpers)."""
    path = Path(filename).resolve()
    return (
        path == TESTS / "browser_support.py"
        or INTEROP in path.parents
        or (path.parent == TESTS and "browser" in path.stem)
    )


def raised_by_peer_check(excinfo) -> bool:
    """Whether a skip was raised at run time by code in a browser or interop test file (not by a marker)."""
    if excinfo is None or not isinstance(excinfo.value, pytest.skip.Exception):
        return False  # unittest.SkipTest and the like: the test's own decision, not a missing peer
    return any(peer_file(str(entry.path)) for entry in excinfo.traceback)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if report.skipped and ci() and raised_by_peer_check(call.excinfo):
        reason = str(call.excinfo.value.msg if hasattr(call.excinfo.value, "msg") else call.excinfo.value)
        report.outcome = "failed"
        report.longrepr = (
            f"CI is set: this browser/interop test would have skipped ({reason}); on CI its peer must be installed "
            "(`make test` installs the interop and browser extras and Debian's chromium)"
        )


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    skipped = terminalreporter.stats.get("skipped", [])
    reasons: Counter = Counter()
    for report in skipped:
        longrepr = report.longrepr
        reasons[longrepr[2] if isinstance(longrepr, tuple) and len(longrepr) == 3 else str(longrepr)] += 1
    terminalreporter.write_sep("-", f"skipped: {len(skipped)}" + (" (CI is set)" if ci() else ""))
    for reason, count in reasons.most_common():
        terminalreporter.write_line(f"{count:5d}  {reason}")
