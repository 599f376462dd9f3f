"""EMCY and error control (CiA 301 §7.2.7, §7.2.8.3): the EMCY object and its COB-ID, the error register
0x1001 and the pre-defined error field 0x1003 against the EMCY an error produces, the error reset, the
heartbeat producer (0x1017) and consumer (0x1016), and node guarding refused or served as the EDS says.
The CTT's Emergency (5.x), Heartbeat (7.1xx) and Guarding (7.x) families.

The error every CANopen device can be made to raise is a heartbeat consumer's: the drives watch this
master's heartbeat, which then stops (EMCY 0x8130, communication error).
"""

from __future__ import annotations

import time

from . import standard as cia
from .cases import Family, Finding, every, failed, judge, not_applicable, periodic
from .session import MASTER_ID, Session, hexcode

ERRORS = Family("EMCY and error control")
SILENT_PRODUCER = 0x7E  # a node-ID nobody on the test bus uses


def _emcys(session: Session, mark: int, node_id: int) -> list[bytes]:
    return [f.data for f in session.recorder.since(mark, cia.emcy(node_id))]


@ERRORS.case("5.1", "the EMCY COB-ID 0x1014 is 0x80 + node-ID and valid", ctt="5.1")
def cob_id(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        if 0x1014 not in session.drive(node_id).dictionary.indices:
            out[node_id] = not_applicable("the EDS has no 0x1014")
            continue
        value = session.nodes[node_id].sdo[0x1014].raw
        out[node_id] = judge(
            [] if value == cia.emcy(node_id) else [f"0x1014 = 0x{value:08X}"], f"0x1014 = 0x{value:08X}"
        )
    return out


@ERRORS.case("5.2", "without an error: 0x1001 = 0, 0x1003:0 = 0 and 0x1003:1 is refused", ctt="5.2, 5.3")
def no_error(session: Session) -> dict[int, Finding]:
    session.reset()
    out = {}
    for node_id in session.ids:
        problems = []
        register = session.nodes[node_id].sdo[0x1001].raw
        if register:
            problems.append(f"0x1001 = 0x{register:02X}")
        if 0x1003 in session.drive(node_id).dictionary.indices:
            count = session.nodes[node_id].sdo[0x1003][0].raw
            if count:
                problems.append(f"0x1003:0 = {count}")
            code = session.upload(node_id, 0x1003, 1)
            if isinstance(code, bytes) or code not in cia.ACCEPT["no error"]:
                problems.append(f"0x1003:1: {'read' if isinstance(code, bytes) else hexcode(code)}")
        out[node_id] = judge(problems, "0x1001 = 0; 0x1003:0 = 0, 0x1003:1 aborted 0x08000024")
    return out


@ERRORS.case("5.3", "a lost heartbeat: EMCY 0x8130 with 0x1001's bits, the same code in 0x1003:1", ctt="5.4-5.6, 7.105")
def emcy_on_error(session: Session) -> dict[int, Finding]:
    if any(0x1016 not in session.drive(n).dictionary.indices for n in session.ids):
        return every(session.ids, not_applicable("no heartbeat consumer (0x1016) to raise an error with"))
    beat = session.network.send_periodic(cia.heartbeat(MASTER_ID), b"\x05", 0.02)
    try:
        for node_id in session.ids:
            sdo = session.nodes[node_id].sdo[0x1016]
            sdo[1].raw = MASTER_ID << 16 | 150
            if 2 in session.drive(node_id).dictionary[0x1016].subindices:
                sdo[2].raw = SILENT_PRODUCER << 16 | 100  # never heard: must not count as lost
        time.sleep(0.3)
        quiet = session.recorder.mark()
        time.sleep(0.2)
        spurious = {node_id: _emcys(session, quiet, node_id) for node_id in session.ids}
        mark = session.recorder.mark()
    finally:
        beat.stop()
    stopped = time.monotonic()
    session.recorder.wait(lambda f: all(_emcys(session, mark, n) for n in session.ids), mark, 2.0)
    time.sleep(0.1)
    out, notes = {}, {}
    for node_id in session.ids:
        problems = []
        if spurious[node_id]:
            problems.append(f"EMCY while the heartbeat was there: {spurious[node_id][0].hex()}")
        frames = _emcys(session, mark, node_id)
        if not frames:
            out[node_id] = failed("no EMCY within 2 s of the consumed heartbeat stopping")
            continue
        emcy = frames[0]
        delay = session.recorder.since(mark, cia.emcy(node_id))[0].received - stopped
        code, register = int.from_bytes(emcy[:2], "little"), emcy[2] if len(emcy) > 2 else None
        if len(emcy) != 8:
            problems.append(f"EMCY of {len(emcy)} bytes")
        if code != cia.EMCY_HEARTBEAT:
            problems.append(f"EMCY code 0x{code:04X}, not 0x8130 (heartbeat error)")
        if register is None or not register & cia.REGISTER_GENERIC or not register & cia.REGISTER_COMMUNICATION:
            problems.append(f"error register {register!r}: generic (bit 0) and communication (bit 4) expected")
        if len(frames) > 1:
            problems.append(f"{len(frames)} EMCYs for one lost producer")
        read = session.nodes[node_id].sdo[0x1001].raw
        if read != register:
            problems.append(f"0x1001 = 0x{read:02X}, the EMCY said 0x{register or 0:02X}")
        history = None
        if 0x1003 in session.drive(node_id).dictionary.indices:
            count = session.nodes[node_id].sdo[0x1003][0].raw
            history = session.nodes[node_id].sdo[0x1003][1].raw if count else None
            if not count or history & 0xFFFF != code:
                problems.append(f"0x1003:0 = {count}, 0x1003:1 = {history!r}: not the EMCY's code")
            elif history >> 16 != int.from_bytes(emcy[3:5], "little"):
                problems.append(f"0x1003:1 additional information 0x{history >> 16:04X} is not the EMCY's bytes 3-4")
        notes[node_id] = emcy
        evidence = f"EMCY {emcy.hex()} {delay * 1000:.0f} ms after the 150 ms consumer's producer stopped; "
        out[node_id] = judge(problems, evidence + f"0x1001 = 0x{read:02X}; 0x1003:1 = 0x{history or 0:08X}")
    session.notes["emcy"] = notes
    return out


@ERRORS.case("5.4", "the error gone (heartbeat back, CiA 402 fault reset): EMCY 0x0000, 0x1001 = 0")
def error_reset(session: Session) -> dict[int, Finding]:
    raised = session.notes.get("emcy", {})
    for node_id in raised:  # the consumer kept, with a time this master's heartbeat thread meets under any load
        session.nodes[node_id].sdo[0x1016][1].raw = MASTER_ID << 16 | 1000
    beat = session.network.send_periodic(cia.heartbeat(MASTER_ID), b"\x05", 0.02)
    try:
        mark = session.recorder.mark()
        session.recorder.wait(lambda f: all(_reset_seen(session, mark, n) for n in raised), mark, 0.3)
        by_heartbeat = {n for n in raised if _reset_seen(session, mark, n)}
        for node_id in raised:
            if node_id not in by_heartbeat:  # CiA 402: an error is acknowledged by a fault reset (bit 7 rising)
                session.nodes[node_id].sdo[0x6040].raw = 0x00
                session.nodes[node_id].sdo[0x6040].raw = 0x80
        session.recorder.wait(lambda f: all(_reset_seen(session, mark, n) for n in raised), mark, 1.0)
    finally:
        beat.stop()
    out = {}
    for node_id in session.ids:
        if node_id not in raised:
            out[node_id] = failed("no error was raised (5.3)")
            continue
        problems = []
        resets = [d for d in _emcys(session, mark, node_id) if d[:2] == b"\x00\x00"]
        if not resets:
            problems.append("no EMCY 0x0000 (error reset)")
        elif resets[0][2] != 0:
            problems.append(f"EMCY 0x0000 with error register 0x{resets[0][2]:02X}")
        register = session.nodes[node_id].sdo[0x1001].raw
        if register:
            problems.append(f"0x1001 = 0x{register:02X} after the reset")
        how = "the heartbeat's return" if node_id in by_heartbeat else "a fault reset (controlword bit 7)"
        out[node_id] = judge(problems, f"EMCY 0x0000 (register 0) after {how}; 0x1001 = 0")
    for node_id in session.ids:
        session.nodes[node_id].sdo[0x1016][1].raw = 0
    return out


def _reset_seen(session: Session, mark: int, node_id: int) -> bool:
    return any(d[:2] == b"\x00\x00" for d in _emcys(session, mark, node_id))


@ERRORS.case("5.5", "writing 0 to 0x1003:0 clears the history; any other value is refused", ctt="2.10")
def clear_history(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        if 0x1003 not in session.drive(node_id).dictionary.indices:
            out[node_id] = not_applicable("the EDS has no 0x1003")
            continue
        before = session.nodes[node_id].sdo[0x1003][0].raw
        problems = []
        code = session.download(node_id, 0x1003, 0, bytes([1]))
        if code not in cia.ACCEPT["error history"]:
            problems.append(f"0x1003:0 <- 1: {hexcode(code)}")
        session.nodes[node_id].sdo[0x1003][0].raw = 0
        after = session.nodes[node_id].sdo[0x1003][0].raw
        if after:
            problems.append(f"0x1003:0 = {after} after writing 0")
        code = session.upload(node_id, 0x1003, 1)
        if isinstance(code, bytes):
            problems.append("0x1003:1 still readable")
        out[node_id] = judge(problems, f"{before} errors recorded; 1 refused (0x06090030), 0 cleared them")
    return out


@ERRORS.case("7.1", "heartbeat producer 0x1017: every period, reporting PRE-OPERATIONAL (7Fh)", ctt="7.101, 7.102")
def producer(session: Session) -> dict[int, Finding]:
    period = 0.05
    session.set_heartbeat(round(period * 1000))
    mark, start = session.recorder.mark(), time.monotonic()
    time.sleep(12 * period)
    window = time.monotonic() - start
    out = {}
    for node_id in session.ids:
        frames = session.recorder.since(mark, cia.heartbeat(node_id))
        problems = periodic(len(frames), window, period, "heartbeats")
        states = {f.data for f in frames}
        if frames and states != {bytes([cia.PRE_OPERATIONAL])}:
            problems.append(f"heartbeats {sorted(s.hex() for s in states)} in PRE-OPERATIONAL")
        evidence = f"{len(frames)} heartbeats 7Fh in {window * 1000:.0f} ms (0x1017 = {period * 1000:.0f} ms)"
        out[node_id] = judge(problems, evidence)
    return out


@ERRORS.case("7.2", "0x1017 = 0 stops the heartbeat", ctt="7.103")
def producer_off(session: Session) -> dict[int, Finding]:
    session.set_heartbeat(0)
    time.sleep(0.06)
    mark = session.recorder.mark()
    time.sleep(0.2)
    out = {}
    for node_id in session.ids:
        frames = session.recorder.since(mark, cia.heartbeat(node_id))
        out[node_id] = judge(
            [f"{len(frames)} heartbeats after 0x1017 = 0"] if frames else [], "no heartbeat for 200 ms after 0x1017 = 0"
        )
    return out


@ERRORS.case("7.3", "two heartbeat consumer entries for one producer are refused 0x06040043", ctt="7.104")
def consumer_twice(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        dictionary = session.drive(node_id).dictionary
        if 0x1016 not in dictionary.indices or len(dictionary[0x1016].subindices) < 3:
            out[node_id] = not_applicable("fewer than two heartbeat consumer entries")
            continue
        entry = MASTER_ID << 16 | 500
        session.nodes[node_id].sdo[0x1016][1].raw = entry
        code = session.download(node_id, 0x1016, 2, entry.to_bytes(4, "little"))
        other = session.download(node_id, 0x1016, 2, (SILENT_PRODUCER << 16 | 500).to_bytes(4, "little"))
        for sub in (1, 2):
            session.nodes[node_id].sdo[0x1016][sub].raw = 0
        problems = (
            [] if code in cia.ACCEPT["heartbeat consumer twice"] else [f"the same producer twice: {hexcode(code)}"]
        )
        if other is not None:
            problems.append(f"another producer refused: {hexcode(other)}")
        out[node_id] = judge(problems, "the same producer in 0x1016:2 refused (0x06040043), another accepted")
    return out


@ERRORS.case("7.4", "node guarding: refused when the EDS has no guard time (RTR unanswered)", ctt="7.1-7.6, 7.2xx")
def guarding(session: Session) -> dict[int, Finding]:
    out = {}
    mark = session.recorder.mark()
    for node_id in session.ids:
        if {0x100C, 0x100D} & set(session.drive(node_id).dictionary.indices):
            continue
        session.network.send_message(cia.heartbeat(node_id), b"", remote=True)
    time.sleep(session.timing.silence)
    for node_id in session.ids:
        if {0x100C, 0x100D} & set(session.drive(node_id).dictionary.indices):
            out[node_id] = not_applicable("the EDS declares node guarding (0x100C/0x100D): not checked by this suite")
            continue
        answers = session.recorder.since(mark, cia.heartbeat(node_id))
        out[node_id] = judge(
            [f"answered the guarding RTR: {answers[0].data.hex()}"] if answers else [],
            "no 0x100C/0x100D; the guarding RTR went unanswered (heartbeat only)",
        )
    return out
