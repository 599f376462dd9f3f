"""Where the drives under test are: simulated drives in a process of their own, or drives on a real bus.

:class:`SimulatedDrives` starts ``surgiplan-sim-drives`` for the device (``python -m
surgiplan.plugins.devices.canopen.sim.process``: the master side never imports the simulator) on the
``loopback`` interface (a hub on 127.0.0.1 the master hosts: it hears the drives from power-up on), with a
non-volatile memory of its own (a temporary folder) and without node-IDs, so that the LSS family has
drives to configure; :meth:`SimulatedDrives.restart` is a power cycle.
:class:`BusDrives` is whatever python-can interface and channel the lab names; a power cycle there is the
lab's to do, so the cases that need one are skipped.
"""

from __future__ import annotations

import select
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from surgiplan.processes import child_env

from ..bus import BusError


@dataclass
class BusDrives:
    """Drives on a real bus (any python-can interface)."""

    interface: str
    channel: str
    bitrate: int = 1_000_000
    options: dict[str, Any] = field(default_factory=dict)
    #: the drives were started without node-IDs: the LSS family gives them theirs
    unconfigured: bool = False
    #: the store/restore family may change what the drives keep over a power cycle
    may_store: bool = False
    can_power_cycle = False

    @property
    def description(self) -> str:
        return f"{self.interface} channel {self.channel} at {self.bitrate // 1000} kbit/s"

    def bus_arguments(self) -> dict[str, Any]:
        return {"interface": self.interface, "channel": self.channel, "bitrate": self.bitrate, **self.options}

    def start(self) -> None:
        pass

    def restart(self) -> None:  # pragma: no cover - never called: can_power_cycle is False
        raise BusError("a power cycle of real drives is the lab's to do")

    def close(self) -> None:
        pass


class SimulatedDrives:
    """``surgiplan-sim-drives --device NAME --unconfigured`` on a loopback channel of its own."""

    can_power_cycle = True
    may_store = True
    interface = "loopback"
    bitrate = 1_000_000

    def __init__(self, device: str, node_ids: list[int], start_timeout: float = 120.0) -> None:
        self.device = device
        self.node_ids = node_ids
        self.start_timeout = start_timeout
        self.unconfigured = True
        self.state_dir = Path(tempfile.mkdtemp(prefix=f"surgiplan-ctt-{device}-"))
        self.channel = str(_free_port())
        self.process: subprocess.Popen | None = None

    @property
    def description(self) -> str:
        return f"surgiplan-sim-drives --device {self.device} (loopback channel {self.channel}, 127.0.0.1)"

    def bus_arguments(self) -> dict[str, Any]:
        """The master hosts the loopback hub: the drives join it when they power up."""
        return {"interface": "loopback", "channel": self.channel, "hub": "host"}

    def start(self) -> None:
        command = [sys.executable, "-m", "surgiplan.plugins.devices.canopen.sim.process", "--device", self.device]
        command += ["--interface", "loopback", "--channel", self.channel, "--option", "hub=join"]
        command += ["--state-dir", str(self.state_dir), "--node-ids", *map(str, self.node_ids)]
        if self.unconfigured:
            command.append("--unconfigured")
        self.process = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=child_env()
        )
        ready, _, _ = select.select([self.process.stdout], [], [], self.start_timeout)
        line = self.process.stdout.readline().strip() if ready else ""
        if line != "ready":
            self._stop()
            error = self.process.stderr.read()[-2000:] if self.process.stderr else ""
            raise BusError(f"the simulated drives of '{self.device}' did not start ({line!r}): {error}")

    def restart(self) -> None:
        """A power cycle: the process ends and starts again with the same memory."""
        self._stop()
        time.sleep(0.05)
        self.start()

    def _stop(self) -> None:
        if self.process is None:
            return
        self.process.terminate()
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(timeout=10)
        for stream in (self.process.stdout, self.process.stderr):
            if stream is not None:
                stream.close()
        self.process = None

    def close(self) -> None:
        self._stop()
        shutil.rmtree(self.state_dir, ignore_errors=True)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]
