"""The simulated drives' CiA 301 communication: NMT events, heartbeat consumers, SYNC, PDOs, EMCY.

* NMT: entering OPERATIONAL compiles the PDOs; leaving OPERATIONAL for
  STOPPED or a reset while the drive is enabled performs the abort
  connection option 0x6007 (CiA 402); *reset node* restarts the drive
  itself (SWITCH ON DISABLED, errors cleared, the brake holding).
* Heartbeat consumer (0x1016): a consumed node's heartbeat that stops coming
  raises EMCY 0x8130 and, while enabled, 0x6007; so does, in the cyclic
  synchronous modes, a SYNC that stops coming (0x2000, the SYNC watchdog).
* PDO: RPDO transmission types 0-240 apply at the next SYNC, 254/255 on
  reception; TPDO types 1-240 go every n-th SYNC, 0 on SYNC when changed,
  254/255 on change (after the inhibit time) and on the event timer.
* EMCY on entering every error, EMCY 0x0000 when the last is gone; error
  register 0x1001, error code 0x603F, pre-defined error field 0x1003 (newest
  first).

The drives' own monitoring (SYNC watchdog, heartbeat consumers, event-driven
TPDOs) runs every :data:`TICK` seconds.
"""

from __future__ import annotations

import functools
import time

import can
import numpy as np

from .. import cia402
from ..cia402 import NMT_OPERATIONAL, NMT_PRE_OPERATIONAL, NMT_STOPPED
from .node import Pdo
from .statemachine import NOT_READY, OE, SOD

#: how often the drives' own monitoring runs (s): SYNC watchdog, heartbeat consumer, event-driven TPDOs
TICK = 0.005


class Communication:
    """The simulated drives' CiA 301 side (a part of :class:`.drives.DriveSimulator`: its ``network``,
    ``nodes`` and per-axis communication state)."""

    # ------------------------------------------------------------------ heartbeat consumers
    def _consumers(self, i: int, subindex: int, value: int) -> None:
        """Heartbeat consumer entry ``subindex`` of 0x1016: (producer node id, time ms); 0 disables."""
        node = self.nodes[self.ids[i]]
        entries = {}
        for sub in (1, 2):
            word = value if sub == subindex else int(node.value(0x1016, sub))
            producer, period = (word >> 16) & 0xFF, word & 0xFFFF
            if producer and period:
                previous = self.consumers[i].get(producer)
                entries[producer] = [period / 1000.0, previous[1] if previous else None]
        self.consumers[i] = entries
        for producer in entries:
            can_id = 0x700 + producer
            if can_id not in self._subscribed:
                callback = functools.partial(self._on_heartbeat, producer)
                self._subscribed[can_id] = callback
                self.network.subscribe(can_id, callback)

    # ------------------------------------------------------------------ NMT
    def on_nmt(self, i: int, old: int, new: int) -> None:
        node = self.nodes[self.ids[i]]
        if new == NMT_OPERATIONAL:
            node.compile_pdos()
            self._subscribe_rpdos()
            for pdo in node.tpdos:
                pdo.sync_count, pdo.last, pdo.sent_at = 0, None, -np.inf
        elif old == NMT_OPERATIONAL:
            self.pending[i].clear()
        if new == NMT_STOPPED and self.state[i] == OE:
            self._abort_connection(i, f"NMT stopped (from {old})")

    def on_reset(self, i: int, old: int, application: bool) -> None:
        now = self.clock.now()
        with self._lock:
            self._advance_locked(now)
            if self.state[i] == OE and not application:
                self._abort_connection(i, "NMT reset communication")
            if application:  # the drive restarts: power stage off, brake, errors gone
                self._set_state(i, NOT_READY, now)
                self.vel[i] = 0.0
                self.reference.hold(i, now, self.pos[i])
                self.errors[i].clear()
                self.following_error[i] = False
                self.limit_active[i] = False
                self.controlword[i] = 0
                self.pending[i].clear()
                self._set_state(i, SOD, now)  # transitions 0, 1: automatic after initialisation
            self.error_history[i].clear()  # 0x1003 is in the communication area

    def reload(self, i: int) -> None:
        with self._lock:
            self._load_parameters(i)
            self._subscribe_rpdos()

    def _subscribe_rpdos(self) -> None:
        wanted = {}
        for i, node_id in enumerate(self.ids):
            node = self.nodes.get(node_id)
            if node is None or not self.alive[i] or node.nmt._state != NMT_OPERATIONAL:
                continue
            for pdo in node.rpdos:
                if pdo.valid:
                    wanted[pdo.cob_id] = (i, pdo)
        for cob_id, callback in list(self._rpdo_callbacks.items()):
            if cob_id not in wanted:
                self.network.unsubscribe(cob_id, callback)
                del self._rpdo_callbacks[cob_id]
        for cob_id, (i, pdo) in wanted.items():
            old = self._rpdo_callbacks.pop(cob_id, None)
            if old is not None:
                self.network.unsubscribe(cob_id, old)
            callback = functools.partial(self._on_rpdo, i, pdo)
            self._rpdo_callbacks[cob_id] = callback
            self.network.subscribe(cob_id, callback)

    def _on_heartbeat(self, producer: int, can_id, data, timestamp) -> None:
        now = self.clock.now()
        for consumers in self.consumers:
            entry = consumers.get(producer)
            if entry is not None:
                entry[1] = now

    # ------------------------------------------------------------------ PDOs
    def _on_rpdo(self, i: int, pdo: Pdo, can_id, data, timestamp) -> None:
        node = self.nodes.get(self.ids[i])
        if node is None or not node.on_bus or node.nmt._state != NMT_OPERATIONAL:
            return
        if pdo.trans <= 240:
            self.pending[i][pdo.cob_id] = bytes(data)  # applied at the next SYNC
        else:
            with self._lock:
                node.write_rpdo(pdo, bytes(data))
            self._event_tpdos(i)

    def _on_sync(self, can_id, data, timestamp) -> None:
        with self._lock:
            now = self.clock.now()
            if self.realtime:
                # a drive latches and samples at the SYNC's arrival (in hardware); this thread may run
                # later, so go back by the frame's age (python-can stamps frames with time.time()); an
                # implausible age (an interface without receive timestamps) is ignored
                age = time.time() - timestamp
                if 0.0 < age < self.model.sync_timeout:
                    now = max(self.t, now - age)
            self._advance_locked(now)
            self._event_time = now
            try:
                self._sync_axes(now)
            finally:
                self._event_time = None

    def _sync_axes(self, now: float) -> None:
        batch = []
        for i, node_id in enumerate(self.ids):
            node = self.nodes.get(node_id)
            if node is None or not node.on_bus or node.nmt._state not in (NMT_OPERATIONAL, NMT_PRE_OPERATIONAL):
                continue
            if self.sync_drop is not None and self.sync_drop.drop(0x80):
                continue  # this drive missed the SYNC: nothing latched, nothing sampled
            self.last_sync[i] = now
            if node.nmt._state != NMT_OPERATIONAL:
                continue
            pending = self.pending[i]
            if pending:
                for pdo in node.rpdos:
                    data = pending.pop(pdo.cob_id, None)
                    if data is not None:
                        node.write_rpdo(pdo, data)
            if not node.talking:
                continue  # inside an LSS switch delay: no TPDO
            for pdo in node.sync_tpdos:
                if pdo.trans:  # every n-th SYNC
                    pdo.sync_count += 1
                    if pdo.sync_count >= pdo.trans:
                        pdo.sync_count = 0
                        batch.append((pdo, node.tpdo_data(pdo)))
                else:  # on SYNC when changed
                    payload = node.tpdo_data(pdo)
                    if payload != pdo.last:
                        batch.append((pdo, payload))
        self._send_tpdos(batch, now)

    def _send_tpdos(self, batch: list, now: float) -> None:
        if not batch:
            return
        bus = self.network.bus
        send_batch = getattr(bus, "send_batch", None)
        for pdo, payload in batch:
            pdo.last = payload
        if send_batch is not None and self.network.link is None:
            # each TPDO's frame is made once and its data rewritten (the bus encodes it as it is sent)
            frames = []
            for pdo, payload in batch:
                frame = pdo.frame
                if frame is None:
                    frame = pdo.frame = can.Message(arbitration_id=pdo.cob_id, data=payload, is_extended_id=False)
                else:
                    frame.data[:] = payload
                    frame.dlc = len(payload)
                frames.append(frame)
            send_batch(frames)
        else:
            for pdo, payload in batch:
                self.network.send_message(pdo.cob_id, payload)
        # the inhibit time and the event timer count from when the frame went (a late send does not shorten them)
        sent = max(now, self.clock.now())
        for pdo, _ in batch:
            pdo.sent_at = sent

    def _event_tpdos(self, i: int | None = None, now: float | None = None) -> None:
        """Event-driven TPDOs (254/255): on change (after the inhibit time) and on the event timer."""
        now = self.clock.now() if now is None else now
        batch = []
        for j, node_id in enumerate(self.ids):
            if i is not None and j != i:
                continue
            node = self.nodes.get(node_id)
            if node is None or not node.talking or node.nmt._state != NMT_OPERATIONAL:
                continue
            for pdo in node.event_tpdos:
                if now - pdo.sent_at < pdo.inhibit:
                    continue
                payload = node.tpdo_data(pdo)
                if payload != pdo.last or (pdo.event > 0 and now - pdo.sent_at >= pdo.event - 1e-9):
                    batch.append((pdo, payload))
        self._send_tpdos(batch, now)

    # ------------------------------------------------------------------ errors
    def _raise_error(self, i: int, code: int) -> None:
        errors = self.errors[i]
        if code in errors:
            return
        errors[code] = cia402.ERROR_REGISTER.get(code, cia402.ERR_GENERIC)
        history = self.error_history[i]
        history.insert(0, code)
        del history[8:]
        node = self.nodes.get(self.ids[i])
        if node is not None and self.alive[i]:
            node.emcy.send(code, self._error_register(i))

    def _error_register(self, i: int) -> int:
        """0x1001: the bits of every error present."""
        register = 0
        for bits in self.errors[i].values():
            register |= bits
        return register

    def _clear_errors(self, i: int, communication_only: bool = False) -> None:
        errors = self.errors[i]
        if not errors:
            return
        for code in list(errors):
            if not communication_only or errors[code] & cia402.ERR_COMMUNICATION:
                del errors[code]
        if not errors:
            node = self.nodes.get(self.ids[i])
            if node is not None and self.alive[i]:
                node.emcy.reset()  # EMCY 0x0000: no error left

    # ------------------------------------------------------------------ monitoring
    def _tick(self) -> None:
        """The drives' own monitoring: SYNC watchdog, heartbeat consumer, event-driven TPDOs."""
        with self._lock:
            now = self.clock.now()
            self._advance_locked(now)
            # Python lists: numpy's per-call cost is most of it on a few axes
            watched = zip(self.state.tolist(), self.alive.tolist(), self.mode.tolist(), self.sync_watchdog.tolist(),
                          self.last_sync.tolist(), strict=True)  # fmt: skip
            lost = [i for i, (state, alive, mode, watchdog, last) in enumerate(watched)
                    if state == OE and alive and mode in cia402.CYCLIC_MODES and 0 < watchdog < now - last]  # fmt: skip
            for i in lost:
                self._raise_error(i, cia402.EMCY_SYNC_LOST)
                self._abort_connection(i, "SYNC lost")
            for i, consumers in enumerate(self.consumers):
                for producer, entry in consumers.items():
                    period, last = entry
                    if last is not None and now - last > period and self.alive[i]:
                        entry[1] = None  # monitoring resumes with the producer's next heartbeat
                        self._raise_error(i, cia402.EMCY_HEARTBEAT_LOST)
                        if self.state[i] == OE:
                            self._abort_connection(i, f"heartbeat of node {producer} lost")
            self._event_tpdos(now=now)
