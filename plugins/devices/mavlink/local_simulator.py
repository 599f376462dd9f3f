"""The simulated vehicle the ``mavlink_vehicle`` device starts when no ``connection`` is given.

:class:`LocalSimulator` runs ``surgiplan-sim-vehicle`` on a free 127.0.0.1
UDP port, as the real program in a subprocess (the default: it exits with
its parent) or in a thread of this process (``sim_process: thread``), tells
the ground station where to reach it, asks it for its own link statistics
(SIGUSR1: it prints them as a line of JSON) and stops it.

This is the only module of the device, with :mod:`.device`, that imports the
simulated vehicle: the ground-station protocol modules do not (the
``mavlink-sim`` import contract).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from typing import Literal

from surgiplan.plugins.devices.mavlink.sim.settings import SimSettings
from surgiplan.processes import child_env

from .link import VehicleError


class LocalSimulator:
    """The simulated vehicle on 127.0.0.1: a subprocess (``how="subprocess"``) or a thread (``"thread"``).

    ``timeout``: how long (s) the subprocess may take to say where it listens.
    """

    def __init__(self, settings: SimSettings, how: Literal["subprocess", "thread"], timeout: float) -> None:
        self.settings = settings
        self.how = how
        self.timeout = timeout
        self.process: subprocess.Popen | None = None
        self.simulator = None  # the in-thread simulated vehicle
        self._stderr = None

    def start(self) -> str:
        """Start it; returns the connection string the ground station reaches it by."""
        sim = self.settings
        if self.how == "thread":
            from surgiplan.plugins.devices.mavlink.sim.vehicle import SimulatedVehicle

            self.simulator = SimulatedVehicle(sim, "udpin:127.0.0.1:0").start()
            return f"udpout:127.0.0.1:{self.simulator.port}"
        self._stderr = tempfile.TemporaryFile(mode="w+")
        command = [
            sys.executable,
            "-m",
            "surgiplan.plugins.devices.mavlink.sim.vehicle",
            "udpin:127.0.0.1:0",
            "--settings",
            json.dumps(sim.model_dump(mode="json")),
            "--exit-with-parent",
        ]
        self.process = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=self._stderr, text=True, env=child_env()
        )
        line = self._first_line(self.timeout)
        if line is None or " on udpin:" not in line:
            self._stderr.seek(0)  # what it said, read before stop() closes the file
            detail = self._stderr.read().strip().splitlines()[-3:]
            self.stop()
            raise VehicleError(
                f"the simulated vehicle did not start ({' / '.join(detail) or 'no output'})", step="connect"
            )
        return "udpout:" + line.rsplit(" on udpin:", 1)[1].strip()

    def _first_line(self, timeout: float) -> str | None:
        import selectors

        with selectors.DefaultSelector() as selector:
            selector.register(self.process.stdout, selectors.EVENT_READ)
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                if selector.select(timeout=0.1):
                    return self.process.stdout.readline()
                if self.process.poll() is not None:
                    return None
        return None

    def link_statistics(self) -> dict | None:
        """The simulated vehicle's own link statistics (None when it does not say, or has stopped)."""
        if self.simulator is not None:
            return self.simulator.link_statistics()
        if self.process is None or self.process.poll() is not None:
            return None
        import selectors
        import signal

        self.process.send_signal(signal.SIGUSR1)
        with selectors.DefaultSelector() as selector:
            selector.register(self.process.stdout, selectors.EVENT_READ)
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline:
                if selector.select(timeout=0.1):
                    line = self.process.stdout.readline()
                    try:
                        return json.loads(line)["link"]
                    except (ValueError, KeyError, TypeError):
                        continue
        return None

    def stop(self) -> None:
        """Stop it (the thread, or the subprocess: terminated, killed after 5 s); again is harmless."""
        if self.simulator is not None:
            self.simulator.stop()
            self.simulator = None
        if self.process is not None:
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=5)
            for stream in (self.process.stdout,):
                if stream is not None:
                    stream.close()
            self.process = None
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None
