"""Every committed benchmark result carries its provenance: the commit it ran on and whether the tree was dirty,
the load average (and, since it was added, a reference workload's time) before and after, the machine, and the
peers' versions and settings (benchmarks/common.py)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
FILES = sorted(RESULTS.glob("*.json"))


def test_there_are_results_to_check():
    assert len(FILES) >= 20


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_a_result_names_the_commit_the_load_and_its_peers(path: Path):
    provenance = json.loads(path.read_text()).get("provenance")
    assert provenance, f"{path.name} has no provenance: rerun its benchmark"
    assert re.fullmatch(r"[0-9a-f]{40}", provenance["commit"] or ""), f"{path.name}: commit {provenance['commit']!r}"
    assert isinstance(provenance["dirty"], bool), f"{path.name}: dirty {provenance['dirty']!r}"
    for key in ("load_before", "load_after"):
        load = provenance[key]
        assert len(load) == 3 and all(x >= 0 for x in load), f"{path.name}: {key} {load!r}"
    assert provenance["cpus"] >= 1 and provenance["machine"] and provenance["python"]
    for name, peer in provenance.get("peers", {}).items():
        assert peer.get("version"), f"{path.name}: peer {name} has no version"
    if "reference" in provenance:  # results saved since the reference workload was added
        for key in ("reference_before", "reference_after"):
            speed = provenance[key]
            assert 0 < speed["fastest_ms"] <= speed["median_ms"], f"{path.name}: {key} {speed!r}"


def test_the_reference_workload_times_the_same_work_each_run():
    """benchmarks/common.host_reference: the fastest of its runs at most their median, both positive and of the
    order a sort of 262,144 doubles takes (between 1 and 1,000 ms on any machine this runs on)."""
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from common import REFERENCE, host_reference

    speed = host_reference()
    assert 1.0 < speed["fastest_ms"] <= speed["median_ms"] < 1000.0
    assert "262,144" in REFERENCE


@pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(), reason="not a git checkout")
def test_every_result_came_from_a_commit_of_this_history():
    shallow = subprocess.run(
        ["git", "rev-parse", "--is-shallow-repository"], cwd=ROOT, capture_output=True, text=True, timeout=30
    )
    if shallow.stdout.strip() != "false":
        pytest.skip("a shallow clone: the history is not here")
    commits = {json.loads(p.read_text())["provenance"]["commit"] for p in FILES if "provenance" in p.read_text()}
    for commit in sorted(c for c in commits if c):
        ancestor = subprocess.run(
            ["git", "merge-base", "--is-ancestor", commit, "HEAD"], cwd=ROOT, capture_output=True, timeout=30
        )
        assert ancestor.returncode == 0, f"{commit} is not in this branch's history"


def test_the_kernels_preemption_model_is_read_from_its_configuration_and_boot_line():
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from common import kernel, preemption

    dynamic_none = "# a comment\nCONFIG_PREEMPT_NONE=y\n# CONFIG_PREEMPT is not set\nCONFIG_PREEMPT_DYNAMIC=y\n"
    assert preemption(dynamic_none, "console=ttyS0 quiet") == "none (build default; dynamic)"
    assert preemption(dynamic_none, "quiet preempt=full") == "full (boot option; dynamic)"
    assert preemption("CONFIG_PREEMPT_NONE=y\n", "preempt=full") == "none"  # a fixed build ignores the option
    assert preemption("CONFIG_PREEMPT=y\nCONFIG_PREEMPT_RT=y\n", "") == "full, real-time (PREEMPT_RT)"
    assert preemption("CONFIG_PREEMPT=y\n", "") == "full"
    assert preemption("", "") == "unknown"
    assert set(kernel()) == {"release", "preemption", "kdamonds", "cpuidle", "cpu_latency_request"}
