"""A witness of the machine's stalls beside a real-time benchmark: on every CPU, a process of its own pinned to it,
under SCHED_FIFO 99 (where allowed), that wakes every millisecond and notes each wake-up later than ``threshold``.

Nothing in this machine can keep a SCHED_FIFO-99 thread from running on its CPU for milliseconds: such a late
wake-up means that CPU stopped (the hypervisor ran something else on it: stolen time, ``/proc/stat``; or an
interrupt storm). A virtual machine's CPUs are stopped one at a time too, so there is one witness per CPU: a
single one, running on the CPU that kept going, would miss the other's stall. When a loop under test misses its
deadline at the moment a witness was late too, the miss is the machine's, not the loop's; when every witness was
on time, it is the loop's. The stolen ticks (10 ms each) say how much; the witnesses say when and on which CPU, to
the millisecond, on the same clock as the loop (CLOCK_MONOTONIC: ``time.perf_counter``).

    with Witness() as witness:
        ...  # the real-time attempt
    witness.summary()  # {"witness_late_over_2ms": .., "witness_late_max_ms": .., "steal_ticks": ..}
    witness.late_during(a, b)  # the worst lateness of a witness while perf_counter time ran from a to b (0: none)
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

from common import steal_ticks

#: the witness's loop (run with ``python -c``): argv period (s), threshold (s), priority (0: ordinary), CPU
_PROGRAM = r"""
import ctypes, gc, json, os, signal, sys, time
gc.disable()
period, threshold, priority, cpu = float(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
os.sched_setaffinity(0, {cpu})
policy = "ordinary"
if priority:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        policy = f"SCHED_FIFO {priority}"
    except OSError:
        pass
try:
    ctypes.CDLL(None).prctl(29, 1000, 0, 0, 0)  # timer slack 1 us
except (OSError, AttributeError):
    pass
stop = []
signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
late, wakes, worst = [], 0, 0.0
print("ready", flush=True)
deadline = time.perf_counter() + period
while not stop and wakes < 10_000_000:
    pause = deadline - time.perf_counter()
    if pause > 0:
        time.sleep(pause)
    now = time.perf_counter()
    wakes += 1
    lateness = now - deadline
    worst = max(worst, lateness)
    if lateness > threshold and len(late) < 100_000:
        late.append((round(deadline, 6), round(lateness, 6)))
    deadline = max(deadline + period, now)  # a stall is one late wake-up, not a burst of catching up
json.dump({"policy": policy, "wakes": wakes, "worst": worst, "late": late}, sys.stdout)
"""


class Witness:
    """Run the witnesses for the ``with`` block (see the module); ``threshold``: the lateness noted (s). ``late``:
    every CPU's late wake-ups (deadline, lateness; s) in time order, ``late_by_cpu`` each CPU's."""

    def __init__(self, period: float = 1e-3, threshold: float = 2e-3, priority: int = 99):
        self.period, self.threshold, self.priority = period, threshold, priority
        self.cpus = sorted(os.sched_getaffinity(0))
        self.late: list[tuple[float, float]] = []
        self.late_by_cpu: dict[int, list[tuple[float, float]]] = {}
        self.wakes = 0
        self.worst = 0.0
        self.policy = "not run"
        self.steal = 0

    def __enter__(self) -> Witness:
        self._steal = steal_ticks()
        self._processes = {}
        for cpu in self.cpus:
            command = [sys.executable, "-c", _PROGRAM, str(self.period), str(self.threshold), str(self.priority),
                       str(cpu)]  # fmt: skip
            process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
            self._processes[cpu] = process
            if process.stdout.readline().strip() != "ready":
                self.__exit__()
                raise RuntimeError(f"the stall witness of CPU {cpu} did not start")
        return self

    def __exit__(self, *exc) -> None:
        self.steal = steal_ticks() - self._steal
        for process in self._processes.values():
            process.send_signal(signal.SIGTERM)
        policies = set()
        for cpu, process in self._processes.items():
            try:
                out, _ = process.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.communicate(timeout=10)
                continue
            if process.returncode == 0 and out:
                data = json.loads(out)
                policies.add(data["policy"])
                self.wakes += data["wakes"]
                self.worst = max(self.worst, data["worst"])
                self.late_by_cpu[cpu] = [tuple(x) for x in data["late"]]
        self.late = sorted(x for late in self.late_by_cpu.values() for x in late)
        self.policy = f"{' / '.join(sorted(policies)) or 'not run'}, one per CPU ({len(self.late_by_cpu)})"

    def late_during(self, start: float, end: float) -> float:
        """The longest a witness was late (s) while perf_counter time ran from ``start`` to ``end``: the largest
        lateness of the late wake-ups whose wait (deadline to wake-up) overlaps that span; 0.0 if none did."""
        return max((late for d, late in self.late if d < end and d + late > start), default=0.0)

    def summary(self) -> dict:
        return {
            "witness": self.policy,
            "witness_late_over_2ms": sum(1 for _, late in self.late if late > 2e-3),
            "witness_late_max_ms": round(1e3 * self.worst, 3),
            "steal_ticks": self.steal,
        }
