"""canopen networks without receive threads, for the simulated clock.

canopen's :class:`canopen.Network` normally receives in a python-can
``Notifier`` thread. Under the simulated clock nothing may happen behind the
control loop's back, so :class:`PumpedNetwork` receives only when pumped,
and a :class:`SimulationLink` pumps every network on the virtual bus after
each frame sent, until no frame is left in flight: an SDO request is answered
before ``SdoClient`` starts waiting, a SYNC's TPDOs are in before the next
cycle. Periodic frames (the drives' heartbeat producers, started by canopen's
``NmtSlave``) become timers of the clock's :class:`~.clock.Scheduler` instead
of python-can threads.
"""

from __future__ import annotations

from collections.abc import Callable

import can
import canopen

from .clock import PeriodicFrame, Scheduler


class SimulationLink:
    """Delivers frames between networks sharing a virtual bus, at once and in order."""

    def __init__(self) -> None:
        self.networks: list[PumpedNetwork] = []
        self._settling = False

    def add(self, network: PumpedNetwork) -> None:
        self.networks.append(network)

    def settle(self) -> None:
        if self._settling:  # a frame sent while delivering: the loop below picks it up
            return
        self._settling = True
        try:
            moved = True
            while moved:
                moved = False
                for network in self.networks:
                    moved |= network.pump() > 0
        finally:
            self._settling = False


class PumpedNetwork(canopen.Network):
    """A canopen network that receives when pumped; periodic frames run on a :class:`Scheduler`.

    ``now`` gives the scheduler's time; ``drop(can_id)`` (optional) loses a
    received frame (fault injection at this receiver).
    """

    def __init__(
        self,
        bus: can.BusABC,
        scheduler: Scheduler,
        now: Callable[[], float],
        link: SimulationLink | None = None,
        drop: Callable[[int], bool] | None = None,
    ) -> None:
        super().__init__(bus)
        self.scheduler = scheduler
        self.now = now
        self.link = link
        self.drop = drop
        if link is not None:
            link.add(self)

    def pump(self, timeout: float = 0.0, limit: int | None = None) -> int:
        """Deliver the frames waiting on the bus (blocking up to ``timeout`` s for the first), at most
        ``limit`` of them."""
        count = 0
        while limit is None or count < limit:
            msg = self.bus.recv(timeout if count == 0 else 0.0)
            if msg is None:
                return count
            count += 1
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            if self.drop is not None and self.drop(msg.arbitration_id):
                continue
            self.notify(msg.arbitration_id, msg.data, msg.timestamp)
        return count

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        super().send_message(can_id, data, remote)
        if self.link is not None:
            self.link.settle()

    def send_periodic(self, can_id: int, data, period: float, remote: bool = False) -> PeriodicFrame:
        frame = None

        def send(payload: bytes) -> None:
            try:
                self.send_message(can_id, payload)
            except can.CanError:  # as python-can's cyclic tasks: a task that cannot send stops
                frame.stop()

        frame = PeriodicFrame(self.scheduler, self.now() + period, period, send, data)
        return self.scheduler.add(frame)
