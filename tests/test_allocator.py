"""The allocator policy (:mod:`surgiplan.allocator`): with it, a process that allocates and frees arrays of
changing sizes stops faulting pages in once it has reached its peak; without it, glibc hands the memory back and
every round faults it in again. Counted in fresh interpreters (the policy is for a whole process), by the
kernel's count of minor page faults."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

_ROUNDS = r"""
import json, resource, sys
import numpy as np
from surgiplan.allocator import keep_freed_memory, policy
applied = keep_freed_memory() if sys.argv[1] == "on" else None
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
sizes = [1, 3, 8, 2, 12, 5, 1, 9]  # MiB: stages of different sizes, as a pipeline's are
for round in range(5):
    if round == 1:
        before = faults()  # the first round reaches the peak; from here on, what is faulted again
    for mib in sizes:
        a = np.ones(mib << 17)
        b = np.ones(mib << 16)
        del a, b
print(json.dumps({"faults": faults() - before, "applied": applied, "policy": policy()}))
"""


def _rounds(switch: str) -> dict:
    # numpy asks for transparent huge pages on large arrays where the kernel offers them on request (THP
    # "madvise"): a 2 MiB page then faults in once, not 512 times, and the count depends on whether the kernel
    # had huge pages free at that moment (130 faults against the usual 1,000s, in one CI run). Without that
    # request every page is a base page, and the counts below measure the allocator alone.
    env = {**os.environ, "NUMPY_MADVISE_HUGEPAGE": "0"}
    done = subprocess.run(
        [sys.executable, "-c", _ROUNDS, switch], capture_output=True, text=True, timeout=120, check=True, env=env
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(sys.platform != "linux", reason="the policy is glibc's (Linux)")
def test_kept_memory_is_not_faulted_in_again():
    off, on = _rounds("off"), _rounds("on")
    assert off["policy"] == "the C library's default" and off["applied"] is None
    assert on["applied"] == on["policy"] == "glibc mallopt: M_MMAP_THRESHOLD 32 MiB, M_TRIM_THRESHOLD 256 MiB"
    # 4 rounds of 41 + 20.5 MiB: the default gives hundreds of pages back and faults them in again
    assert off["faults"] > 200
    assert on["faults"] < 20


def test_the_command_line_applies_it():
    """Importing surgiplan leaves the process's allocator alone; ``surgiplan`` (any command) sets the policy
    before the command runs (each in a fresh interpreter)."""
    imported = "import surgiplan.cli; from surgiplan.allocator import policy; print(policy())"
    ran = (
        "import contextlib, io; from surgiplan.cli import main; from surgiplan.allocator import policy\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        "    code = main(['plugins'])\n"
        "print(code, policy())"
    )
    outputs = [
        subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=True)
        for script in (imported, ran)
    ]
    assert outputs[0].stdout.strip().splitlines()[-1] == "the C library's default"
    expected = "glibc mallopt" if sys.platform == "linux" else "the C library's default"
    assert outputs[1].stdout.strip().splitlines()[-1].startswith(f"0 {expected}")
