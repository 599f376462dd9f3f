"""With CI set, a browser or interop test that would skip fails; every run prints the skipped count (ci_skips.py).

A small suite in a temporary directory uses the same hooks (ci_skips.py copied beside its conftest): a browser
test whose helper skips (no chromium), an interop test whose peer does not import, and three skips that must
stay skips whatever CI says (a marker, unittest.skip, a run-time skip in an ordinary test).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent

FILES = {
    "conftest.py": "from ci_skips import pytest_runtest_makereport, pytest_terminal_summary  # noqa\n",
    "browser_support.py": "import pytest\n\n\ndef chromium():\n    pytest.skip('no chromium on this machine')\n",
    "test_page_browser.py": "from browser_support import chromium\n\n\ndef test_page():\n    chromium()\n",
    "interop/test_peer.py": "import pytest\n\n\ndef test_peer():\n"
    "    pytest.importorskip('surgiplan_no_such_peer', reason='the peer is not installed')\n",
    "test_marked.py": "import unittest\n\nimport pytest\n\n\n@pytest.mark.skip(reason='on purpose')\n"
    "def test_marked():\n    pass\n\n\nclass Case(unittest.TestCase):\n"
    "    @unittest.skip('upstream skips this')\n    def test_upstream(self):\n        pass\n",
    "test_ordinary.py": "import pytest\n\n\ndef test_ordinary():\n    pytest.skip('no SCHED_FIFO here')\n",
}


def run_suite(tmp_path: Path, ci: str | None) -> tuple[dict, str]:
    for name, text in FILES.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    shutil.copy(HERE / "ci_skips.py", tmp_path / "ci_skips.py")
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    if ci is not None:
        env["CI"] = ci
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rfs", "--rootdir", str(tmp_path), "."],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    counts = {k: int(n) for n, k in re.findall(r"(\d+) (passed|failed|skipped)", done.stdout.splitlines()[-1])}
    return counts, done.stdout


@pytest.mark.parametrize("value", [None, "false"])
def test_without_ci_the_missing_peers_skip_and_are_counted(tmp_path, value):
    counts, out = run_suite(tmp_path, value)
    assert counts == {"skipped": 5}, out
    assert re.search(r"-+ skipped: 5 -+", out), out
    assert "no chromium on this machine" in out and "the peer is not installed" in out


@pytest.mark.parametrize("value", ["true"])
def test_with_ci_a_missing_peer_fails(tmp_path, value):
    counts, out = run_suite(tmp_path, value)
    assert counts == {"failed": 2, "skipped": 3}, out
    assert "FAILED test_page_browser.py::test_page" in out and "FAILED interop/test_peer.py::test_peer" in out
    assert "would have skipped (no chromium on this machine)" in out
    assert "would have skipped (the peer is not installed)" in out
    # the deliberate skips stay skips, and are counted
    assert re.search(r"-+ skipped: 3 \(CI is set\) -+", out), out
    for reason in ("on purpose", "upstream skips this", "no SCHED_FIFO here"):
        assert reason in out
