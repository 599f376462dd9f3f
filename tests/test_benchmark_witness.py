"""benchmarks/witness.py: the stall witness notes a stop of the machine, when it happened and for how long.

A stop of the whole machine cannot be made on purpose here; stopping the witness's process (SIGSTOP) for a known
time looks the same to it."""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

from witness import Witness


def test_the_witness_notes_a_stop_with_its_time_and_length():
    with Witness(priority=0) as witness:
        time.sleep(0.1)
        stopped = time.perf_counter()
        [os.kill(p.pid, signal.SIGSTOP) for p in witness._processes.values()]
        time.sleep(0.05)
        [os.kill(p.pid, signal.SIGCONT) for p in witness._processes.values()]
        time.sleep(0.1)
    summary = witness.summary()
    assert witness.wakes > 100
    assert summary["witness_late_over_2ms"] >= 1
    assert 45 <= summary["witness_late_max_ms"] < 500
    inside = stopped + 0.02  # a moment inside the stop
    assert witness.late_during(inside, inside) >= 0.045
    before = stopped - 0.05
    assert witness.late_during(before, before) == 0.0  # before it, on time
