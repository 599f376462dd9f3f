"""Helper programs a run starts (the simulated vehicle, simulated drives) never outlive it, even a kill -9."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

LAUNCHER = """
import subprocess, sys
from surgiplan.processes import child_env
child = subprocess.Popen([sys.executable, "-m", "surgiplan.plugins.devices.mavlink.sim.vehicle",
                          "udpout:127.0.0.1:" + sys.argv[1]], env=child_env(), stdout=subprocess.PIPE, text=True)
print(child.pid, flush=True)
print(child.stdout.readline().strip(), flush=True)
import time
time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow
def test_the_simulated_vehicle_exits_when_the_run_that_started_it_is_killed():
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    launcher = subprocess.Popen([sys.executable, "-c", LAUNCHER, str(port)], stdout=subprocess.PIPE, text=True)
    try:
        child = int(launcher.stdout.readline())
        launcher.stdout.readline()  # the vehicle says it is up (or its error): it has started its watch
        assert _alive(child)
        os.kill(launcher.pid, signal.SIGKILL)
        launcher.wait(timeout=10)
        for _ in range(100):  # bounded: 10 s
            if not _alive(child):
                break
            time.sleep(0.1)
        left = _alive(child)
        if left:
            os.kill(child, signal.SIGKILL)
        assert not left, "the simulated vehicle outlived the run that started it"
    finally:
        if launcher.poll() is None:
            launcher.kill()


def test_without_a_parent_to_watch_nothing_is_started(monkeypatch):
    from surgiplan.processes import PARENT_ENV, child_env, exit_with_parent

    monkeypatch.delenv(PARENT_ENV, raising=False)
    assert exit_with_parent() is False
    assert child_env({})[PARENT_ENV] == str(os.getpid())
