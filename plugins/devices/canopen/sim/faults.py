"""Faults injected into the simulated drives: the drive side of the bus's ``faults:`` (:mod:`..bus`).

Timed from the origin the device arms them at (its first trajectory's start,
or an observed attempt's): ``heartbeat_loss`` stops a node's heartbeat
producer, ``following_error`` pushes an axis with an external load (a jam,
a collision) for a while, ``dead_node`` silences a node for good (heartbeat,
PDOs, SDO). Frame loss at each drive's receiver and nodes that never answer
are set up with the drives themselves (:class:`.drives.DriveSimulator`).
"""

from __future__ import annotations

import numpy as np

from .statemachine import NOT_READY


class FaultInjection:
    """The injected faults of the simulated drives (a part of :class:`.drives.DriveSimulator`)."""

    def arm(self, origin: float) -> None:
        """Schedule the injected faults relative to ``origin`` (the trajectory start, s)."""
        index = {node_id: i for i, node_id in enumerate(self.ids)}
        for fault in self.faults.faults:
            i = index.get(getattr(fault, "node", None))
            if fault.kind == "heartbeat_loss" and i is not None and fault.node in self.nodes:
                self.scheduler.call_at(origin + fault.at_s, self.nodes[fault.node].nmt.stop_heartbeat)
            elif fault.kind == "following_error" and i is not None:
                self.scheduler.call_at(origin + fault.at_s, lambda i=i, f=fault: self._push(i, f.load))
                self.scheduler.call_at(origin + fault.at_s + fault.duration_s, lambda i=i: self._push(i, 0.0))
            elif fault.kind == "dead_node" and i is not None and fault.at_s is not None:
                self.scheduler.call_at(origin + fault.at_s, lambda i=i: self._die(i))

    def _push(self, i: int, load: float) -> None:
        with self._lock:
            self._advance_locked(self.clock.now())
            direction = -np.sign(self.vel[i]) if self.vel[i] != 0 else -1.0
            self.load[i] = direction * load * self.peak[i]

    def _die(self, i: int) -> None:
        with self._lock:
            self._advance_locked(self.clock.now())
            node = self.nodes.get(self.ids[i])
            if node is not None:
                node.nmt.stop_heartbeat()
                node.alive = False
                del self.network[self.ids[i]]
            self.alive[i] = False
            self._set_state(i, NOT_READY, self.t)
            self.vel[i] = 0.0
