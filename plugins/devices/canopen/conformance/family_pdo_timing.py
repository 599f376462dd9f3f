"""PDO transmission (CiA 301 §7.2.2.2, §7.5.2.35): synchronous cyclic (every n-th SYNC), acyclic
synchronous, event-driven with its inhibit time and event timer; RPDOs acted on at the next SYNC or at once,
and not at all when shorter than mapped. Cases of the PDO family (:mod:`.family_pdo`; CTT 3.4-3.7, 6.3).

Every drive at once: each case maps the PDO it watches on every drive (canopen's ``PdoMap.save()``), starts
them, sends SYNCs or changes the statusword (the controlword by SDO moves a CiA 402 drive between SWITCH ON
DISABLED and READY TO SWITCH ON, nothing moves) and reads the frames as they came.
"""

from __future__ import annotations

import time

from canopen import objectdictionary as od

from . import standard as cia
from .cases import Family, Finding, failed, judge, not_applicable, passed, periodic
from .family_pdo import (
    QUIET,
    READY,
    _candidates,
    _configure_all,
    _controlword,
    _frames,
    _map,
    _new_mapping,
    _statusword,
    _statusword_var,
    _tpdo_n,
)
from .session import Frame, Session

#: cases of the PDO family (the same name: they are reported with it)
PDO = Family("PDO")


def _start_all(session: Session, settle: dict[int, int] | None = None) -> None:
    """NMT start every drive; ``settle`` (node-ID -> COB-ID): wait for the TPDO a drive may send on entering
    OPERATIONAL (bounded), so that it is not taken for a later one."""
    mark = session.recorder.mark()
    for node_id in session.ids:
        session.nmt(cia.START, node_id)
    if settle:
        session.recorder.wait(lambda f: set(settle.values()) <= {x.can_id for x in f}, mark, 0.3)
    time.sleep(QUIET)


def _sync(session: Session) -> float:
    when = time.monotonic()
    session.network.sync.transmit()
    return when


def _after(frames: list[Frame], syncs: list[float]) -> list[int]:
    """For each frame, the number (1-based) of the last SYNC sent before it arrived (0: before any)."""
    return [sum(1 for s in syncs if s <= f.received) for f in frames]


@PDO.case("3.9", "synchronous cyclic TPDO (type 3): after every third SYNC, never between", ctt="3.6, 6.3")
def cyclic(session: Session) -> dict[int, Finding]:
    failed_to_map = _configure_all(session, False, 1, lambda n: _new_mapping(session, n, False, 0), 3)
    _start_all(session)
    mark, syncs = session.recorder.mark(), []
    cob = {node_id: cia.tpdo(1, node_id) for node_id in session.ids}
    for k in range(1, 13):
        syncs.append(_sync(session))
        if k % 3 == 0:
            session.recorder.wait(
                lambda f, k=k: all(len([x for x in f if x.can_id == c]) >= k // 3 for c in cob.values()), mark, 1.0
            )
        time.sleep(QUIET)
    out = {}
    for node_id in session.ids:
        if node_id in failed_to_map:
            out[node_id] = failed(failed_to_map[node_id])
            continue
        after = _after(_frames(session, mark, cob[node_id]), syncs)
        out[node_id] = judge(
            [] if after == [3, 6, 9, 12] else [f"TPDO1 after SYNC {after} of 12"], "TPDO1 after SYNC 3, 6, 9, 12 of 12"
        )
    session.reset()
    return out


@PDO.case("3.10", "acyclic synchronous TPDO (type 0): at the SYNC after a change, only then", ctt="3.7")
def acyclic(session: Session) -> dict[int, Finding]:
    n_of = {node_id: _tpdo_n(session, node_id) for node_id in session.ids}
    failed_to_map = {}
    for node_id in session.ids:
        try:
            _map(session, node_id, False, n_of[node_id], [_statusword_var(session, node_id)], 0)
        except Exception as exc:  # the drive's refusal is the finding
            failed_to_map[node_id] = f"mapping TPDO{n_of[node_id]}: {exc}"
    _start_all(session)
    first = session.recorder.mark()
    syncs = [_sync(session)]
    cobs = {cia.tpdo(n_of[n], n) for n in session.ids}
    session.recorder.wait(lambda f: cobs <= {x.can_id for x in f}, first, 0.3)  # bounded: it may send none
    time.sleep(QUIET)
    mark = session.recorder.mark()  # an initial transmission at the first SYNC is the drive's choice
    syncs += [_sync(session), _sync(session)]
    time.sleep(QUIET)
    changed = time.monotonic()
    _controlword(session, 0x06)  # SWITCH ON DISABLED -> READY TO SWITCH ON: the statusword changes
    time.sleep(2 * QUIET)
    syncs.append(_sync(session))
    session.recorder.wait(lambda f: len({x.can_id for x in f}) >= len(session.ids), mark, 1.0)
    time.sleep(QUIET)
    syncs.append(_sync(session))
    time.sleep(QUIET)
    out = {}
    for node_id in session.ids:
        if node_id in failed_to_map:
            out[node_id] = failed(failed_to_map[node_id])
            continue
        frames = _frames(session, mark, cia.tpdo(n_of[node_id], node_id))
        problems = []
        early = [f for f in frames if f.received < syncs[3]]
        if early:
            problems.append(
                f"{len(early)} TPDOs before the SYNC that follows the change"
                f"{' (sent at the change, not at a SYNC)' if any(f.received > changed for f in early) else ''}"
            )
        at_sync = [f for f in frames if syncs[3] <= f.received < syncs[4]]
        if len(at_sync) != 1 or _statusword(at_sync[0]) != READY:
            problems.append(f"{len(at_sync)} TPDOs after the SYNC that follows the change (1 with READY expected)")
        if [f for f in frames if f.received >= syncs[4]]:
            problems.append("a TPDO at a SYNC without a change")
        out[node_id] = judge(
            problems,
            f"TPDO{n_of[node_id]}: nothing at 2 SYNCs without a change nor at the change; "
            "one (READY TO SWITCH ON) at the next SYNC",
        )
    session.reset()
    return out


@PDO.case("3.11", "event-driven TPDO (types 254, 255): sent at a change without SYNC, not at SYNC", ctt="3.4")
def event_driven(session: Session) -> dict[int, Finding]:
    out: dict[int, Finding] = {}
    for trans in (255, 254):
        n_of = {node_id: _tpdo_n(session, node_id) for node_id in session.ids}
        for node_id in session.ids:
            try:
                _map(session, node_id, False, n_of[node_id], [_statusword_var(session, node_id)], trans)
            except Exception as exc:  # the drive's refusal is the finding
                out[node_id] = failed(f"mapping TPDO{n_of[node_id]} type {trans}: {exc}")
        _start_all(session, {n: cia.tpdo(n_of[n], n) for n in session.ids})
        mark = session.recorder.mark()
        _sync(session)
        _sync(session)
        time.sleep(QUIET)
        quiet = session.recorder.since(mark)
        changed = session.recorder.mark()
        _controlword(session, 0x06)
        ids = {cia.tpdo(n_of[n], n): n for n in session.ids}
        session.recorder.wait(lambda f, ids=ids: set(ids) <= {x.can_id for x in f}, changed, 1.0)
        time.sleep(2 * QUIET)
        for node_id in session.ids:
            if node_id in out and out[node_id].verdict.value == "fail":
                continue
            cob = cia.tpdo(n_of[node_id], node_id)
            problems = [f"type {trans}: a TPDO at SYNC without a change"] if any(f.can_id == cob for f in quiet) else []
            frames = _frames(session, changed, cob)
            if len(frames) != 1 or _statusword(frames[0]) != READY:
                problems.append(f"type {trans}: {len(frames)} TPDOs after one change (1 with READY expected)")
            out[node_id] = judge(problems, "types 255 and 254: one TPDO at the change (no SYNC), none at SYNC")
        session.reset()
    return out


def _map_statusword_tpdos(
    session: Session, trans: int, what: str, **timing: int
) -> tuple[dict[int, int], dict[int, str]]:
    """Map every drive's event-driven TPDO (:func:`_tpdo_n`) to its statusword with transmission type ``trans``
    and ``timing`` (``inhibit_time``, ``event_timer``). Returns each node's TPDO number, and the nodes whose
    drive refused the mapping with why (the refusal is the finding; ``what`` names the timing in it)."""
    n_of = {node_id: _tpdo_n(session, node_id) for node_id in session.ids}
    problems_of = {}
    for node_id in session.ids:
        try:
            _map(session, node_id, False, n_of[node_id], [_statusword_var(session, node_id)], trans, **timing)
        except Exception as exc:  # the drive's refusal is the finding
            problems_of[node_id] = f"mapping TPDO{n_of[node_id]} with {what}: {exc}"
    return n_of, problems_of


@PDO.case("3.12", "the inhibit time keeps event-driven TPDOs apart; the last value still goes")
def inhibit(session: Session) -> dict[int, Finding]:
    inhibit_s = 0.1
    n_of, problems_of = _map_statusword_tpdos(
        session, 255, "an inhibit time", inhibit_time=round(inhibit_s * 1e4), event_timer=0
    )
    _start_all(session, {n: cia.tpdo(n_of[n], n) for n in session.ids})
    time.sleep(inhibit_s)
    mark, start = session.recorder.mark(), time.monotonic()
    changes = 12  # a change every quarter of the inhibit time, for three of them: the last one READY TO SWITCH ON
    for k in range(changes):
        _controlword(session, 0x06 if (changes - 1 - k) % 2 == 0 else 0x00)
        time.sleep(inhibit_s / 4)
    span = time.monotonic() - start  # the changes' span: the inhibit time allows one TPDO per inhibit time in it
    time.sleep(2 * inhibit_s)
    out = {}
    for node_id in session.ids:
        if node_id in problems_of:
            out[node_id] = failed(problems_of[node_id])
            continue
        frames = _frames(session, mark, cia.tpdo(n_of[node_id], node_id))
        problems = []
        if not frames:
            problems.append("no TPDO")
        elif _statusword(frames[-1]) != READY:
            problems.append(f"the last TPDO says 0x{_statusword(frames[-1]):02X}, the drive is READY (0x21)")
        # by count, not by the gaps between reception stamps (a receiver that falls behind stamps a burst at once)
        most = int(span / inhibit_s) + 2
        if len(frames) > most or len(frames) < 2:
            problems.append(
                f"{len(frames)} TPDOs for {changes} changes in {span * 1000:.0f} ms "
                f"(inhibit {inhibit_s * 1000:.0f} ms: 2 to {most})"
            )
        out[node_id] = judge(
            problems,
            f"{changes} changes in {span * 1000:.0f} ms: {len(frames)} TPDOs (at most {most} with an inhibit time "
            f"of {inhibit_s * 1000:.0f} ms), the last one READY",
        )
    session.reset()
    return out


@PDO.case("3.13", "the event timer sends an unchanged event-driven TPDO every period", ctt="3.5")
def event_timer(session: Session) -> dict[int, Finding]:
    period = 0.05
    n_of, problems_of = _map_statusword_tpdos(
        session, 254, "an event timer", event_timer=round(period * 1000), inhibit_time=0
    )
    _start_all(session)
    mark, start = session.recorder.mark(), time.monotonic()
    time.sleep(12 * period)
    window = time.monotonic() - start
    out = {}
    for node_id in session.ids:
        if node_id in problems_of:
            out[node_id] = failed(problems_of[node_id])
            continue
        frames = _frames(session, mark, cia.tpdo(n_of[node_id], node_id))
        # the timer sets the rate: a drive that sent early would send more often than once a period
        problems = periodic(len(frames), window, period, "TPDOs")
        out[node_id] = judge(
            problems,
            f"{len(frames)} unchanged TPDOs in {window * 1000:.0f} ms (event timer {period * 1000:.0f} ms)",
        )
    session.reset()
    return out


def _rpdo_object(session: Session, node_id: int) -> od.ODVariable | None:
    """A process output an RPDO can carry without side effects in SWITCH ON DISABLED (not the controlword)."""
    pool = [v for v in _candidates(session, node_id, "out") if v.index != 0x6040 and len(v) >= 16]
    return next((v for v in pool if v.index == 0x607A), pool[0] if pool else None)


@PDO.case("3.14", "RPDOs: type 1 acted on at the next SYNC, type 255 at once; shorter than mapped: ignored")
def rpdos(session: Session) -> dict[int, Finding]:
    out = {}
    objects = {node_id: _rpdo_object(session, node_id) for node_id in session.ids}
    for trans in (1, 255):
        for node_id in session.ids:
            if objects[node_id] is None:
                out[node_id] = not_applicable("no process output besides the controlword")
                continue
            try:
                _map(session, node_id, True, 1, [objects[node_id]], trans)
            except Exception as exc:  # the drive's refusal is the finding
                out[node_id] = failed(f"mapping RPDO1 type {trans}: {exc}")
        _start_all(session)
        for node_id in session.ids:
            var = objects[node_id]
            if node_id in out or var is None:
                continue

            def read(var=var, node_id=node_id) -> bytes:
                return session.nodes[node_id].sdo.upload(var.index, var.subindex)

            before = read()
            value = 1000 + trans
            session.network.send_message(cia.rpdo(1, node_id), var.encode_raw(value))
            time.sleep(QUIET)
            at_once = var.decode_raw(read())
            _sync(session)
            time.sleep(QUIET)
            after_sync = var.decode_raw(read())
            session.network.send_message(cia.rpdo(1, node_id), var.encode_raw(value + 1)[:1])  # too short
            time.sleep(QUIET)
            _sync(session)
            time.sleep(QUIET)
            after_short = var.decode_raw(read())
            problems = []
            if trans == 1 and at_once != var.decode_raw(before):
                problems.append(f"type 1: 0x{var.index:04X} = {at_once} before the SYNC")
            if (after_sync if trans == 1 else at_once) != value:
                problems.append(f"type {trans}: 0x{var.index:04X} = {after_sync}, {value} was sent")
            if after_short != value:
                problems.append(f"type {trans}: a 1-byte RPDO changed 0x{var.index:04X} to {after_short}")
            if problems:
                out[node_id] = failed("; ".join(problems))
        session.reset()
    for node_id in session.ids:
        out.setdefault(
            node_id,
            passed(
                f"0x{objects[node_id].index:04X} by RPDO1: type 1 at the SYNC, type 255 at once; a 1-byte frame ignored"
            ),
        )
    return out
