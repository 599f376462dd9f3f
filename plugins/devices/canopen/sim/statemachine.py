"""The CiA 402 state machine of the simulated drives: controlword, statusword, quick stop, fault reaction.

The state machine is driven by the controlword (written by SDO or RPDO: the
same object, :func:`..cia402.next_state` for the transitions); entering
OPERATION ENABLED holds the axis where it is, leaving it for a state without
power lets the brake hold. Quick stop with option codes 0, 1, 2, 5, 6
(0x605A) at 0x6085 (or 0x6084 for the slow-down ramps); the abort connection
option 0x6007 (1 fault, 2 disable voltage, 3 quick stop) when the
communication is lost. The statusword reports the state, warning, remote,
and per mode: following the command (cyclic synchronous modes), set-point
acknowledge and target reached within 0x6067 for 0x6068 ms (profile
position), speed zero and target reached within 0x606D for 0x606E ms
(profile velocity), internal limit, following error. A following error
(outside 0x6065 for longer than 0x6066 in the position modes, watched as the
motors are integrated, :mod:`.drives`) is a FAULT with EMCY 0x8611, the
brake holding the axis.

The state is a code per axis (its index in :data:`_STATES`).
"""

from __future__ import annotations

import logging

import numpy as np

from .. import cia402
from .reference import stop_segments

log = logging.getLogger(__name__)

_STATES = list(cia402.STATUSWORD)
_CODE = {name: i for i, name in enumerate(_STATES)}
NOT_READY = _CODE[cia402.NOT_READY]
SOD = _CODE[cia402.SWITCH_ON_DISABLED]
OE = _CODE[cia402.OPERATION_ENABLED]
QS = _CODE[cia402.QUICK_STOP_ACTIVE]
FAULT = _CODE[cia402.FAULT]
_STATUSWORD = [cia402.STATUSWORD[name] | cia402.SW_REMOTE for name in _STATES]
#: the modes with target-reached windows (profile position and velocity)
_PROFILE_MODES = (cia402.PP, cia402.PV)


class Cia402StateMachine:
    """The simulator's CiA 402 state machine (a part of :class:`.drives.DriveSimulator`: its per-axis state
    ``state``, ``controlword``, ``mode``, ``reference`` and the motor's ``pos`` and ``vel``)."""

    # ------------------------------------------------------------------ statusword
    def statusword(self, i: int) -> int:
        state = self.state.item(i)
        word = _STATUSWORD[state]
        errors = self.errors[i]
        if errors and state != FAULT:
            word |= cia402.SW_WARNING
        if state == OE:
            mode = self.mode.item(i)
            if mode in cia402.CYCLIC_MODES:
                word |= cia402.SW_FOLLOWING_COMMAND
            elif mode == cia402.PP:
                if self.set_point_ack[i]:
                    word |= cia402.SW_SET_POINT_ACKNOWLEDGE
                if self._target_reached(i):
                    word |= cia402.SW_TARGET_REACHED
            elif mode == cia402.PV:
                if abs(self.vel[i]) * self.cpu[i] < 1.0:
                    word |= cia402.SW_SPEED_ZERO
                if self._target_reached(i):
                    word |= cia402.SW_TARGET_REACHED
            if self.limit_active[i]:
                word |= cia402.SW_INTERNAL_LIMIT
        if self.following_error[i]:
            word |= cia402.SW_FOLLOWING_ERROR
        return word

    def _target_reached(self, i: int) -> bool:
        if self.mode[i] == cia402.PP:
            if self.moving_to_target[i] or self.t < self.reference.end(i):
                return False
            return self.t - self.inside_since[i] >= self.position_window_time[i] - 1e-12
        if self.mode[i] == cia402.PV:
            return self.t - self.inside_since[i] >= self.velocity_window_time[i] - 1e-12
        return False

    # ------------------------------------------------------------------ transitions
    def _set_state(self, i: int, code: int, t: float) -> None:
        if code != self.state[i]:
            self.transitions.append((t, self.ids[i], _STATES[self.state[i]], _STATES[code]))
        self.state[i] = code

    def _controlword(self, i: int, controlword: int, now: float) -> None:
        previous = self.controlword.item(i)
        self.controlword[i] = controlword
        state = _STATES[self.state[i]]
        new = cia402.next_state(state, controlword, previous)
        rising_reset = controlword & cia402.CW_FAULT_RESET and not previous & cia402.CW_FAULT_RESET
        if new != state:
            self._set_state(i, _CODE[new], now)
            if new == cia402.OPERATION_ENABLED:
                self._enable(i, now)
            elif new == cia402.QUICK_STOP_ACTIVE:
                self._quick_stop(i, now)
            elif new == cia402.SWITCH_ON_DISABLED and state == cia402.FAULT:
                self._clear_errors(i)  # transition 15: fault reset
            if state == cia402.QUICK_STOP_ACTIVE:
                self._clear_errors(i, communication_only=True)  # the stop was acknowledged
            if new in (cia402.SWITCH_ON_DISABLED, cia402.READY, cia402.SWITCHED_ON):
                self.vel[i] = 0.0  # power stage off: the brake holds
                self.reference.hold(i, now, self.pos[i])
        elif rising_reset and state != cia402.FAULT:
            self._clear_errors(i, communication_only=True)
        if self.state[i] != OE:
            return
        mode = self.mode.item(i)
        if mode == cia402.PP:
            self._profile_position_bits(i, controlword, previous, now)
        if controlword & cia402.CW_HALT and not previous & cia402.CW_HALT:
            self._halt(i, now)
        elif previous & cia402.CW_HALT and not controlword & cia402.CW_HALT:
            if mode == cia402.PV:
                self._plan_velocity(i, now)
            elif mode == cia402.PP and self.moving_to_target[i]:
                self._plan_position(i, now)

    def _enable(self, i: int, now: float) -> None:
        self.reference.hold(i, now, self.pos[i])  # hold where it is: no jump
        self.over_time[i] = 0.0
        self.following_error[i] = False
        self.moving_to_target[i] = False
        self.set_point_ack[i] = False
        self.inside_since[i] = now
        self.last_sync[i] = now
        self.target[i] = self.pos[i]
        if self.mode[i] in cia402.VELOCITY_MODES:
            self.target_velocity[i] = 0.0

    def _switch_mode(self, i: int, mode: int, now: float) -> None:
        if mode == self.mode[i]:
            return
        self.mode[i] = mode
        self.moving_to_target[i] = False
        self.set_point_ack[i] = False
        if self.state[i] == OE:  # a new mode starts from rest where the reference is
            p, v = self.reference.at(now)
            self.reference.set(i, stop_segments(now, p[i], v[i], self.profile_decel[i]))
            self.target[i] = p[i]
            self.target_velocity[i] = 0.0
            self.last_sync[i] = now

    def _halt(self, i: int, now: float) -> None:
        p, v = self.reference.at(now)
        self.reference.set(i, stop_segments(now, p[i], v[i], self.profile_decel[i]))

    def _quick_stop(self, i: int, now: float) -> None:
        option = int(self.qs_option[i])
        if option == 0:  # disable drive function: no ramp
            self._set_state(i, SOD, now)
            self.vel[i] = 0.0
            self.reference.hold(i, now, self.pos[i])
            return
        decel = self.profile_decel[i] if option in (1, 5) else self.qs_decel[i]
        # the ramp starts from where the motor is and how fast it moves
        segments = stop_segments(now, self.pos[i], self.vel[i], decel)
        self.reference.set(i, segments)
        self.qs_end[i] = segments[-1][0] if option in (1, 2) else np.inf

    def _abort_connection(self, i: int, why: str) -> None:
        """The abort connection option 0x6007 (CiA 402): 1 fault, 2 disable voltage, 3 quick stop."""
        now = self.t
        option = int(self.abort_option[i])
        log.info("node %d: abort connection (%s), option %d", self.ids[i], why, option)
        if option == 1:
            self._fault(i, None)
        elif option == 2:
            self._set_state(i, SOD, now)
            self.vel[i] = 0.0
            self.reference.hold(i, now, self.pos[i])
        elif option == 3 and self.state[i] == OE:
            self._set_state(i, QS, now)
            self._quick_stop(i, now)

    # ------------------------------------------------------------------ fault reaction, windows
    def _fault(self, i: int, code: int | None, following_error: bool = False) -> None:
        self._set_state(i, FAULT, self.t)  # fault reaction: the brake holds the axis
        self.vel[i] = 0.0
        self.reference.hold(i, self.t, self.pos[i])
        self.following_error[i] = following_error
        if code is not None:
            self._raise_error(i, code)

    def _windows(self, t: float) -> None:
        """Target-reached windows (pp: position, pv: velocity), quick stop ramps that end in SWITCH ON DISABLED."""
        # Python lists: numpy's per-call cost is most of it on a few axes, at every SYNC
        states, modes = self.state.tolist(), self.mode.tolist()
        if QS not in states and not any(s == OE and m in _PROFILE_MODES for s, m in zip(states, modes, strict=True)):
            return
        for i in np.flatnonzero(self.state == OE):
            mode = self.mode[i]
            if mode == cia402.PP:
                inside = abs(self.pos[i] - min(max(self.target[i], self.limit_lo[i]), self.limit_hi[i]))
                inside = inside <= self.position_window[i] + 0.5 / self.cpu[i]
                if self.moving_to_target[i] and t >= self.reference.end(i):
                    self.moving_to_target[i] = False
            elif mode == cia402.PV:
                target = 0.0 if self.controlword[i] & cia402.CW_HALT else self.target_velocity[i]
                inside = abs(self.vel[i] - target) <= self.velocity_window[i]
            else:
                continue
            if not inside:
                self.inside_since[i] = np.inf
            elif not np.isfinite(self.inside_since[i]):
                self.inside_since[i] = t
        for i in np.flatnonzero((self.state == QS) & (t >= self.qs_end)):
            self._set_state(i, SOD, t)
            self.vel[i] = 0.0
            self.qs_end[i] = np.inf
            self.reference.hold(i, t, self.pos[i])
