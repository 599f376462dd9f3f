"""Shared fixtures.

Third-party plugins installed on the machine must not leak into the suite:
by default only surgiplan's own entry points are loaded
(SURGIPLAN_PLUGIN_PACKAGES=surgiplan); tests about the example third-party
package opt in with the ``with_example_plugin`` fixture.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import pytest
from surgiplan import registry

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"
DATA = Path(__file__).resolve().parent / "data"

# ----------------------------------------------------------------------------- loopback only
# Every socket the suite (and each Python process it starts) binds, connects or sends to must be on
# loopback: tests/netguard/sitecustomize.py refuses anything else and logs it; a test that tried fails.
NETGUARD = Path(__file__).resolve().parent / "netguard"
_NETGUARD_LOG = Path(os.environ.setdefault("SURGIPLAN_NETGUARD_LOG", f"/tmp/surgiplan-netguard-{os.getpid()}.log"))
os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(NETGUARD), os.environ.get("PYTHONPATH")) if p)
_site = sys.modules.get("sitecustomize")
if _site is not None and Path(getattr(_site, "__file__", "") or "").parent == NETGUARD:
    _netguard = _site  # this pytest was itself started by a guarded test: the guard is already in
else:
    _spec = importlib.util.spec_from_file_location("surgiplan_netguard", NETGUARD / "sitecustomize.py")
    _netguard = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(_netguard)
sys.modules["surgiplan_netguard"] = _netguard
_netguard.install()


@pytest.fixture(autouse=True)
def _loopback_only():
    _NETGUARD_LOG.unlink(missing_ok=True)
    yield
    if _NETGUARD_LOG.exists():
        text = _NETGUARD_LOG.read_text()
        _NETGUARD_LOG.unlink(missing_ok=True)
        pytest.fail(f"this test used a non-loopback address (tests send only to 127.0.0.1 / ::1):\n{text}")


os.environ["SURGIPLAN_PLUGIN_PACKAGES"] = "surgiplan"
os.environ.pop("SURGIPLAN_DISABLE_PLUGINS", None)
os.environ.pop("SURGIPLAN_STRICT_PLUGINS", None)


@pytest.fixture(autouse=True)
def _fresh_registry():
    registry.reset_default_registry()
    yield
    registry.reset_default_registry()


@pytest.fixture
def with_example_plugin(monkeypatch):
    monkeypatch.setenv("SURGIPLAN_PLUGIN_PACKAGES", "surgiplan,surgiplan-hello")
    registry.reset_default_registry()
    names = registry.default_registry().names("planner")
    if "via_point" not in names:
        pytest.fail(
            "the example plugin package is not installed: pip install -e examples/surgiplan-hello "
            "(the Makefile's test target does this)"
        )
    return registry.default_registry()


@pytest.fixture
def block_world():
    from surgiplan import load_scene

    return load_scene(CONFIGS / "scenes" / "block_world.yaml")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def run_cli(args, capsys):
    """Run the CLI in-process; returns (exit code, stdout, stderr)."""
    from surgiplan.cli import main

    code = main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture
def cli(capsys):
    return lambda *args: run_cli(args, capsys)


def assert_error_record(out_dir: Path, *fragments: str, stage: str | None = None) -> dict:
    """A run a stage's error ended still leaves its record: result.json (status ``error``) with every stage so
    far, the failing one last with ``error`` and the message (containing ``fragments``), and no in-progress
    marker. Returns the document."""
    import json

    document = json.loads((Path(out_dir) / "result.json").read_text())
    assert document["status"] == "error", document["status"]
    last = document["stages"][-1]
    assert last["status"] == "error", last
    if stage is not None:
        assert last["name"] == stage, last["name"]
    for fragment in fragments:
        assert fragment in last["message"], f"{fragment!r} not in {last['message']!r}"
    assert not (Path(out_dir) / ".in-progress.json").exists()
    return document


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


sys.path.insert(0, str(Path(__file__).resolve().parent))


@pytest.fixture(scope="session")
def ghosted(tmp_path_factory):
    """Experts' attempts recorded, the task's benchmark from them, and a beginner's attempt with an expert ghost
    (``assessment_support.ghost_run``): (the directory, the record, the beginner run's result.json)."""
    from assessment_support import ghost_run

    tmp = tmp_path_factory.mktemp("ghost")
    record, document = ghost_run(tmp)
    return tmp, record, document


PLUGINS = Path(__file__).resolve().parent / "plugins"


@pytest.fixture
def hostile(tmp_path, monkeypatch):
    """The hostile package, discoverable in this process and in subprocesses; returns their environment."""
    site = tmp_path / "site"
    info = site / "surgiplan_hostile-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: surgiplan-hostile\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[surgiplan]\nhostile = surgiplan_hostile\n")
    monkeypatch.syspath_prepend(str(PLUGINS))
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setenv("SURGIPLAN_PLUGIN_PACKAGES", "surgiplan,surgiplan-hostile")
    registry.reset_default_registry()
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(site), str(PLUGINS), env.get("PYTHONPATH", "")])
    return env


# CI cannot pass silently: with CI set, a browser or interop test that would skip fails; every run prints the
# skipped count (tests/ci_skips.py)
from ci_skips import pytest_runtest_makereport, pytest_terminal_summary  # noqa: E402, F401
