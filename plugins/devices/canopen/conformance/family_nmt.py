"""NMT (CiA 301 §7.2.8, §7.3.2): every command from every state, what a reset restores, and what a drive
answers in each state, STOPPED above all. The CTT's State (9.x) and Transition (10.x) families.

The state is what the drive's own heartbeat reports (0x1017 set to 20 ms after each reset, while it can
still be written); the resets are seen by their boot-up messages.
"""

from __future__ import annotations

import time

from . import standard as cia
from .cases import Family, Finding, failed, judge
from .objects import pick_parameter
from .session import MASTER_ID, Session, hexcode

NMT = Family("NMT")
HEARTBEAT_MS = 20
#: a path through the state machine that takes every command from every state at least once
PATH = [
    cia.START,
    cia.START,
    cia.ENTER_PRE_OPERATIONAL,
    cia.ENTER_PRE_OPERATIONAL,
    cia.STOP,
    cia.STOP,
    cia.START,
    cia.STOP,
    cia.ENTER_PRE_OPERATIONAL,
    cia.RESET_COMMUNICATION,
    cia.START,
    cia.RESET_COMMUNICATION,
    cia.STOP,
    cia.RESET_COMMUNICATION,
    cia.RESET_NODE,
    cia.START,
    cia.RESET_NODE,
    cia.STOP,
    cia.RESET_NODE,
]


def _state_after(session: Session, mark: int, expected: int, timeout: float = 0.5) -> dict[int, int | None]:
    """Each drive's state after ``mark``: the first heartbeat reporting ``expected``, else the last one heard."""
    wanted = {cia.heartbeat(node_id): node_id for node_id in session.ids}

    def seen(frames) -> bool:
        return set(wanted) <= {f.can_id for f in frames if f.data == bytes([expected])}

    session.recorder.wait(seen, mark, timeout)
    states: dict[int, int | None] = dict.fromkeys(session.ids)
    for frame in session.recorder.since(mark):
        node_id = wanted.get(frame.can_id)
        if node_id is None or len(frame.data) != 1 or frame.data == b"\x00":
            continue
        if states[node_id] != expected:
            states[node_id] = frame.data[0]
    return states


def _name(state: int | None) -> str:
    return "nothing" if state is None else cia.STATE_NAMES.get(state, f"0x{state:02X}")


@NMT.case("9.1", "every NMT command from every state (PRE-OPERATIONAL, OPERATIONAL, STOPPED)", ctt="9.1-9.4, 10.1-10.4")
def transitions(session: Session) -> dict[int, Finding]:
    session.reset(command=cia.RESET_COMMUNICATION)
    session.set_heartbeat(HEARTBEAT_MS)
    state = cia.PRE_OPERATIONAL
    problems: dict[int, list[str]] = {node_id: [] for node_id in session.ids}
    covered = set()
    for command in PATH:
        covered.add((state, command))
        expected = cia.AFTER[command]
        what = f"{cia.COMMAND_NAMES[command]} in {_name(state)}"
        mark = session.recorder.mark()
        if command in (cia.RESET_NODE, cia.RESET_COMMUNICATION):
            booted = session.reset(command=command)
            for node_id, ok in booted.items():
                if not ok:
                    problems[node_id].append(f"{what}: no boot-up")
            session.set_heartbeat(HEARTBEAT_MS)
            mark = session.recorder.mark()
        else:
            for node_id in session.ids:
                session.nmt(command, node_id)
        states = _state_after(session, mark, expected)
        for node_id, got in states.items():
            if got != expected:
                problems[node_id].append(f"{what}: {_name(got)}, not {_name(expected)}")
        if command not in (cia.RESET_NODE, cia.RESET_COMMUNICATION):
            boots = [f for f in session.recorder.since(mark) if f.data == b"\x00" and f.can_id >= 0x700]
            for frame in boots:
                problems.get(frame.can_id - 0x700, []).append(f"{what}: a boot-up message")
        state = expected
    assert len(covered) == 15  # the path covers 3 states x 5 commands
    session.reset()
    return {
        node_id: judge(p, f"{len(PATH)} commands, all 15 (state, command) pairs, as the heartbeat reports")
        for node_id, p in problems.items()
    }


@NMT.case(
    "9.2", "reset node brings back every default, reset communication only the communication area's", ctt="9.1, 10.1"
)
def resets(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        chosen = [
            pick_parameter(session, node_id, 0x1000, 0x1FFF, exclude=(0x1017,)),
            pick_parameter(session, node_id, 0x2000, 0x9FFF),
        ]
        chosen = [c for c in chosen if c is not None]
        if len(chosen) < 2:
            out[node_id] = failed("no communication and application parameter to change found in the EDS")
            continue
        (comm, comm_old, comm_new), (app, app_old, app_new) = chosen
        problems = []
        session.reset([node_id], cia.RESET_COMMUNICATION)
        read = {v.index: v.decode_raw(session.upload(node_id, v.index, v.subindex)) for v in (comm, app)}
        if read[comm.index] != comm_old or read[app.index] != app_new:
            problems.append(
                f"after reset communication 0x{comm.index:04X} = {read[comm.index]} (was {comm_new}, "
                f"default {comm_old}), 0x{app.index:04X} = {read[app.index]} (set {app_new})"
            )
        session.download(node_id, comm.index, comm.subindex, comm.encode_raw(comm_new))
        session.reset([node_id], cia.RESET_NODE)
        read = {v.index: v.decode_raw(session.upload(node_id, v.index, v.subindex)) for v in (comm, app)}
        if read[comm.index] != comm_old or read[app.index] != app_old:
            problems.append(
                f"after reset node 0x{comm.index:04X} = {read[comm.index]}, 0x{app.index:04X} = "
                f"{read[app.index]} (defaults {comm_old}, {app_old})"
            )
        out[node_id] = judge(
            problems,
            f"0x{comm.index:04X}:{comm.subindex} back by either reset; 0x{app.index:04X}:"
            f"{app.subindex} kept by reset communication, back by reset node",
        )
    return out


@NMT.case("9.3", "STOPPED: heartbeat 04h; no SDO answer, no TPDO at SYNC, no RPDO taken, no EMCY", ctt="9.4")
def stopped(session: Session) -> dict[int, Finding]:
    session.reset()
    session.set_heartbeat(HEARTBEAT_MS)
    tpdo = {node_id: _valid_synchronous_tpdo(session, node_id) for node_id in session.ids}
    rpdo = {node_id: _rpdo1_objects(session, node_id) for node_id in session.ids}
    before = {n: [session.upload(n, v.index, v.subindex) for v in rpdo[n]] for n in session.ids}
    beat = session.network.send_periodic(cia.heartbeat(MASTER_ID), b"\x05", 0.02)
    try:
        for node_id in session.ids:
            session.nodes[node_id].sdo[0x1016][1].raw = MASTER_ID << 16 | 100
        time.sleep(0.15)
        for node_id in session.ids:
            session.nmt(cia.STOP, node_id)
        time.sleep(0.1)  # a heartbeat sent before the command was taken is not STOPPED's
        mark = session.recorder.mark()
    finally:
        beat.stop()  # the drives' consumers now time out: an error, whose EMCY a STOPPED node must not send
    for _ in range(3):
        session.network.sync.transmit()
        time.sleep(0.03)
    for node_id in session.ids:
        payload = b"".join(v.encode_raw(_other(v)) for v in rpdo[node_id])
        session.network.send_message(cia.rpdo(1, node_id), payload)
    answers = {
        node_id: session.request(node_id, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]), session.timing.silence)
        for node_id in session.ids
    }
    time.sleep(0.3)
    frames = session.recorder.since(mark)
    for node_id in session.ids:
        session.nmt(cia.ENTER_PRE_OPERATIONAL, node_id)
    time.sleep(0.05)
    out = {}
    for node_id in session.ids:
        problems = []
        beats = [f.data for f in frames if f.can_id == cia.heartbeat(node_id)]
        if not beats or set(beats) != {bytes([cia.STOPPED])}:
            problems.append(f"heartbeats in STOPPED: {sorted({b.hex() for b in beats}) or 'none'}")
        if answers[node_id] is not None:
            problems.append(f"answered an SDO request: {answers[node_id].hex()}")
        if tpdo[node_id] is not None and any(f.can_id == tpdo[node_id] for f in frames):
            problems.append(f"TPDO 0x{tpdo[node_id]:03X} at a SYNC")
        emcys = [f.data.hex() for f in frames if f.can_id == cia.emcy(node_id)]
        if emcys:
            problems.append(f"EMCY {emcys[0]}")
        after = [session.upload(node_id, v.index, v.subindex) for v in rpdo[node_id]]
        if after != before[node_id]:
            problems.append("took the RPDO")
        session.nodes[node_id].sdo[0x1016][1].raw = 0
        out[node_id] = judge(
            problems,
            f"{len(beats)} heartbeats 04h; SDO, 3 SYNCs (TPDO 0x{tpdo[node_id] or 0:03X}),"
            " RPDO1 and a lost heartbeat: no answer, no TPDO, no EMCY",
        )
    session.reset()
    return out


def _valid_synchronous_tpdo(session: Session, node_id: int) -> int | None:
    """The COB-ID of TPDO1 made synchronous (type 1) and valid with its present mapping, or None."""
    tpdo = session.nodes[node_id].tpdo[1]
    tpdo.read()
    if not tpdo.map:
        return None
    tpdo.trans_type = 1
    tpdo.enabled = True
    tpdo.save()
    return tpdo.cob_id


def _rpdo1_objects(session: Session, node_id: int) -> list:
    rpdo = session.nodes[node_id].rpdo[1]
    rpdo.read()
    rpdo.trans_type = 255
    rpdo.enabled = True
    rpdo.save()
    return [
        session.drive(node_id).dictionary[v.index]
        if v.subindex == 0
        else session.drive(node_id).dictionary[v.index][v.subindex]
        for v in rpdo.map
    ]


def _other(var) -> int:
    default = var.default or 0
    return default + 6 if var.max is None or default + 6 <= var.max else default - 1


@NMT.case("9.4", "PRE-OPERATIONAL answers SDO but sends no PDO; OPERATIONAL sends its TPDOs at SYNC", ctt="9.2, 9.3")
def pre_operational_and_operational(session: Session) -> dict[int, Finding]:
    session.reset()
    tpdo = {node_id: _valid_synchronous_tpdo(session, node_id) for node_id in session.ids}
    mark = session.recorder.mark()
    for _ in range(3):
        session.network.sync.transmit()
        time.sleep(0.03)
    pre = session.recorder.since(mark)
    answers = {node_id: session.upload(node_id, 0x1000, 0) for node_id in session.ids}
    for node_id in session.ids:
        session.nmt(cia.START, node_id)
    time.sleep(0.05)
    mark = session.recorder.mark()
    for _ in range(3):
        session.network.sync.transmit()
        time.sleep(0.03)
    operational = session.recorder.since(mark)
    out = {}
    for node_id in session.ids:
        problems = []
        if not isinstance(answers[node_id], bytes):
            problems.append(f"SDO in PRE-OPERATIONAL: {hexcode(answers[node_id])}")
        if tpdo[node_id] is None:
            out[node_id] = failed("TPDO1 maps nothing")
            continue
        if any(f.can_id == tpdo[node_id] for f in pre):
            problems.append("a TPDO at SYNC in PRE-OPERATIONAL")
        sent = sum(1 for f in operational if f.can_id == tpdo[node_id])
        if sent != 3:
            problems.append(f"{sent} TPDOs for 3 SYNCs in OPERATIONAL")
        out[node_id] = judge(problems, "PRE-OPERATIONAL: SDO answered, no TPDO at 3 SYNCs; OPERATIONAL: 3 TPDOs")
    session.reset()
    return out


@NMT.case(
    "9.5",
    "a command for another node-ID changes nothing, a broadcast (node 0) everything; 1- and 3-byte "
    "NMT frames are ignored",
)
def addressing(session: Session) -> dict[int, Finding]:
    session.reset()
    session.set_heartbeat(HEARTBEAT_MS)
    other = next(n for n in range(1, 128) if n not in session.ids and n != MASTER_ID)
    steps = [
        (bytes([cia.START, other]), cia.PRE_OPERATIONAL, f"start for node {other}"),
        (bytes([cia.START]), cia.PRE_OPERATIONAL, "a 1-byte start"),
        (bytes([cia.START, 0, 0]), cia.PRE_OPERATIONAL, "a 3-byte start"),
        (bytes([cia.START, 0]), cia.OPERATIONAL, "start for every node (0)"),
        (bytes([cia.STOP, 0]), cia.STOPPED, "stop for every node (0)"),
    ]
    problems: dict[int, list[str]] = {node_id: [] for node_id in session.ids}
    for frame, expected, what in steps:
        session.network.send_message(0x000, frame)
        time.sleep(0.02)
        mark = session.recorder.mark()
        time.sleep(3 * HEARTBEAT_MS / 1000)
        states = _state_after(session, mark, expected, timeout=0.3)
        for node_id, got in states.items():
            if got != expected:
                problems[node_id].append(f"after {what}: {_name(got)}, not {_name(expected)}")
    session.reset()
    return {
        node_id: judge(p, "ignored: another node's start, 1- and 3-byte frames; obeyed: broadcast start, stop")
        for node_id, p in problems.items()
    }
