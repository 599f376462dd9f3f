"""LSS (CiA 305): drives started without a node-ID are found by canopen's ``LssMaster`` fast scan and given
their node-ID and bit rate, then the other services are checked on them.

Runs first: every later family needs the node-IDs this one gives. On drives that already have node-IDs (a
real bus without ``unconfigured``) its cases are skipped.
"""

from __future__ import annotations

import queue
import struct
import time

from canopen.lss import LssError

from . import standard as cia
from .cases import Family, Finding, every, failed, judge, passed, skipped
from .session import Session

LSS = Family("LSS")
_NOTE = "lss"


def _frame(*payload: int) -> bytes:
    data = bytearray(8)
    data[: len(payload)] = bytes(payload)
    return bytes(data)


def _u32(cs: int, value: int) -> bytes:
    return bytes([cs]) + struct.pack("<L", value) + bytes(3)


def _responses(session: Session, mark: int, cs: int) -> list[bytes]:
    return [f.data for f in session.recorder.since(mark, cia.LSS_RESPONSE) if f.data[:1] == bytes([cs])]


def _identity(session: Session, node_id: int) -> tuple[int, int, int, int]:
    identity = session.drive(node_id).dictionary[0x1018]
    return tuple(int(identity[sub].default) for sub in (1, 2, 3, 4))


def _supported_rates(session: Session, node_id: int) -> set[int]:
    """The bit rates (kbit/s) the drive's EDS says it supports (``[DeviceInfo] BaudRate_*``)."""
    info = session.drive(node_id).dictionary.device_information
    return {rate // 1000 for rate in info.allowed_baudrates}


def _skip_if_configured(session: Session) -> dict[int, Finding] | None:
    if not getattr(session.target, "unconfigured", False):
        why = "the drives have node-IDs (LSS needs drives started without one: --unconfigured)"
        return every(session.ids, skipped(why))
    return None


@LSS.case("11.1", "drives without a node-ID say nothing (no boot-up, heartbeat or SDO answer)")
def silent(session: Session) -> dict[int, Finding]:
    if (skip := _skip_if_configured(session)) is not None:
        return skip
    for node_id in session.ids:  # an SDO request to each node-ID the drives will have: nobody answers
        session.nodes[node_id].sdo.responses = queue.Queue()
        session.nodes[node_id].sdo.send_request(_frame(0x40, 0x00, 0x10, 0x00))
    time.sleep(session.timing.silence)
    heard = sorted({f"0x{f.can_id:03X}" for f in session.recorder.since(0) if f.can_id != cia.LSS_RESPONSE})
    out = {}
    for node_id in session.ids:
        problems = [f"frames on the bus before any LSS service: {', '.join(heard)}"] if heard else []
        out[node_id] = judge(problems, f"silent for {session.timing.silence:g} s; SDO to node-ID {node_id} unanswered")
    return out


@LSS.case("11.2", "identify non-configured remote slave (4Ch) is answered (50h)")
def identify_non_configured(session: Session) -> dict[int, Finding]:
    if (skip := _skip_if_configured(session)) is not None:
        return skip
    mark = session.recorder.mark()
    session.network.send_message(cia.LSS_REQUEST, _frame(cia.LSS_IDENTIFY_NON_CONFIGURED))
    session.recorder.wait(
        lambda f: len(_responses(session, mark, cia.LSS_NON_CONFIGURED)) >= len(session.ids),
        mark,
        session.timing.sdo,  # an answer is expected: as long as an SDO answer may take (not LSS's silence)
    )
    answers = len(_responses(session, mark, cia.LSS_NON_CONFIGURED))
    finding = judge([] if answers else ["no non-configured slave answered"], f"{answers} answers (50h)")
    return every(session.ids, finding)


@LSS.case("11.3", "the fast scan finds each drive by its LSS address (its identity 0x1018 in the EDS)")
def fast_scan(session: Session) -> dict[int, Finding]:
    """Finds and configures every drive (11.3-11.8): fast scan, inquire, configure node-ID and bit timing,
    store, switch to waiting: the drive boots with its node-ID."""
    if (skip := _skip_if_configured(session)) is not None:
        return skip
    lss = session.network.lss
    by_address = {_identity(session, node_id): node_id for node_id in session.ids}
    results: dict[str, dict[int, Finding]] = {case: {} for case in ("11.3", "11.4", "11.5", "11.6", "11.7", "11.8")}
    session.notes[_NOTE] = results
    strangers = []
    for _ in range(3 * len(session.ids) + 3):  # bounded: a scan a drive, and retries for a lost answer
        if all(node_id in results["11.8"] for node_id in session.ids):
            break
        started = time.monotonic()
        found, address = session.fast_scan()
        took = time.monotonic() - started
        if not found:
            continue
        address = tuple(address)
        node_id = by_address.get(address)
        if node_id is None or node_id in results["11.8"]:
            strangers.append("/".join(f"0x{part:X}" for part in address))
            lss.send_switch_state_global(lss.WAITING_STATE)
            continue
        results["11.3"][node_id] = passed(f"found in {took:.1f} s: " + "/".join(f"0x{p:X}" for p in address))
        _configure(session, node_id, address, results)
    for node_id in session.ids:
        if node_id not in results["11.3"]:
            why = "the fast scan never found its address " + "/".join(f"0x{p:X}" for p in _identity(session, node_id))
            if strangers:
                why += f" (found addresses no EDS states: {', '.join(strangers)})"
            for case in results:
                results[case].setdefault(node_id, failed(why))
    return results["11.3"]


def _configure(session: Session, node_id: int, address: tuple, results: dict) -> None:
    lss = session.network.lss
    # 11.4 inquire the identity and node-ID (the drive is in the configuration state)
    problems = []
    for (what, cs), expected in zip(cia.LSS_INQUIRE.items(), address, strict=True):
        try:
            value = lss.inquire_lss_address(cs)
        except LssError as exc:
            problems.append(f"inquire {what}: {exc}")
            continue
        if value != expected:
            problems.append(f"inquire {what}: 0x{value:X}, its address says 0x{expected:X}")
    try:
        current = lss.inquire_node_id()
    except LssError as exc:
        current = None
        problems.append(f"inquire node-ID: {exc}")
    if current is not None and current != cia.LSS_UNCONFIGURED:
        problems.append(f"inquire node-ID: {current}, not FFh (non-configured)")
    results["11.4"][node_id] = judge(problems, "vendor, product, revision, serial = its address; node-ID FFh")
    # 11.5 configure node-ID: out of range refused, its own accepted
    problems = []
    for wrong in (0, 128):
        try:
            lss.configure_node_id(wrong)
            problems.append(f"node-ID {wrong} accepted")
        except LssError as exc:
            if str(exc) != "LSS Error: 1":
                problems.append(f"node-ID {wrong}: {exc} (expected error 1, out of range)")
    try:
        lss.configure_node_id(node_id)
    except LssError as exc:
        problems.append(f"node-ID {node_id} refused: {exc}")
    results["11.5"][node_id] = judge(problems, f"0 and 128 refused (error 1), {node_id} accepted")
    # 11.6 configure bit timing: what the EDS supports accepted, the rest refused; back at the bus's rate
    problems = []
    supported = _supported_rates(session, node_id)
    for index, rate in cia.BIT_TIMING.items():
        try:
            lss.configure_bit_timing(index)
            accepted = True
        except LssError:
            accepted = False
        if accepted != (rate in supported):
            problems.append(
                f"{rate} kbit/s {'accepted' if accepted else 'refused'}, the EDS says "
                f"{'supported' if rate in supported else 'not'}"
            )
    mark = session.recorder.mark()
    session.network.send_message(cia.LSS_REQUEST, _frame(cia.LSS_CONFIGURE_BIT_TIMING, 1, 0))  # another table
    session.recorder.wait(
        lambda f: bool(_responses(session, mark, cia.LSS_CONFIGURE_BIT_TIMING)), mark, session.timing.sdo
    )
    answer = _responses(session, mark, cia.LSS_CONFIGURE_BIT_TIMING)
    if not answer or answer[0][1] == 0:
        problems.append("bit timing table 1 (not CiA's) " + ("accepted" if answer else "unanswered"))
    bus_rate = session.target.bitrate // 1000
    own = next(index for index, rate in cia.BIT_TIMING.items() if rate == bus_rate)
    try:
        lss.configure_bit_timing(own)
    except LssError as exc:
        problems.append(f"the bus's {bus_rate} kbit/s refused: {exc}")
    results["11.6"][node_id] = judge(problems, f"{sorted(supported)} kbit/s accepted, the others refused (error 1)")
    # 11.7 store configuration
    try:
        lss.store_configuration()
        results["11.7"][node_id] = passed("stored (error 0); used at power-up: see 8.6")
    except LssError as exc:
        results["11.7"][node_id] = failed(f"store configuration: {exc}")
    # 11.8 back to waiting: a non-configured drive with a node-ID boots
    mark = session.recorder.mark()
    lss.send_switch_state_global(lss.WAITING_STATE)
    booted = session.recorder.wait(
        lambda frames: any(f.can_id == cia.heartbeat(node_id) and f.data == b"\x00" for f in frames),
        mark,
        session.timing.boot,
    )
    if not booted:
        results["11.8"][node_id] = failed(f"no boot-up message from node {node_id} after switching to waiting")
        return
    time.sleep(0.02)
    identity = tuple(session.nodes[node_id].sdo[0x1018][sub].raw for sub in (1, 2, 3, 4))
    results["11.8"][node_id] = judge(
        [] if identity == address else [f"0x1018 reads {identity}, its LSS address was {address}"],
        f"boot-up from node {node_id}; 0x1018 by SDO = its LSS address",
    )


def _noted(case: str):
    def run(session: Session) -> dict[int, Finding]:
        if (skip := _skip_if_configured(session)) is not None:
            return skip
        return session.notes[_NOTE][case]

    return run


LSS.case("11.4", "inquire identity and node-ID (5Ah-5Eh) in the configuration state")(_noted("11.4"))
LSS.case("11.5", "configure node-ID (11h): 1-127 accepted, others refused with error 1")(_noted("11.5"))
LSS.case("11.6", "configure bit timing (13h): the EDS's bit rates accepted, others and other tables refused")(
    _noted("11.6")
)
LSS.case("11.7", "store configuration (17h)")(_noted("11.7"))
LSS.case("11.8", "back to waiting, a configured drive boots with its node-ID; 0x1018 is its LSS address")(
    _noted("11.8")
)


@LSS.case("11.9", "the fast scan finds nobody once every drive is configured")
def nobody_left(session: Session) -> dict[int, Finding]:
    if (skip := _skip_if_configured(session)) is not None:
        return skip
    found, address = session.fast_scan()
    if found:
        session.network.lss.send_switch_state_global(session.network.lss.WAITING_STATE)
    return every(session.ids, judge([f"found {address}"] if found else [], "no answer to the fast scan's first step"))


@LSS.case("11.10", "switch state selective (40h-43h) by the whole LSS address, answered 44h")
def selective(session: Session) -> dict[int, Finding]:
    if (skip := _skip_if_configured(session)) is not None:
        return skip
    lss = session.network.lss
    out = {}
    for node_id in session.ids:
        address = _identity(session, node_id)
        mark = session.recorder.mark()
        for cs, part in zip(cia.LSS_SWITCH_SELECTIVE, address, strict=True):
            session.network.send_message(cia.LSS_REQUEST, _u32(cs, part))
        session.recorder.wait(
            lambda f, m=mark: bool(_responses(session, m, cia.LSS_SELECTED)), mark, session.timing.sdo
        )
        problems = [] if _responses(session, mark, cia.LSS_SELECTED) else ["no 44h answer"]
        try:
            current = lss.inquire_node_id()
            if current != node_id:
                problems.append(f"the selected drive says node-ID {current}")
        except LssError as exc:
            problems.append(f"inquire node-ID: {exc}")
        lss.send_switch_state_global(lss.WAITING_STATE)
        out[node_id] = judge(problems, f"selected; inquire node-ID = {node_id}")
    return out


@LSS.case("11.11", "identify remote slave (46h-4Bh) answers for an address range, not outside it")
def identify_remote(session: Session) -> dict[int, Finding]:
    if (skip := _skip_if_configured(session)) is not None:
        return skip
    out = {}
    for node_id in session.ids:
        vendor, product, revision, serial = _identity(session, node_id)
        answers = []
        for low, high in ((serial, serial), (serial + 1, 0xFFFFFFFF)):
            mark = session.recorder.mark()
            for cs, part in zip(cia.LSS_IDENTIFY_REMOTE, (vendor, product, revision, revision, low, high), strict=True):
                session.network.send_message(cia.LSS_REQUEST, _u32(cs, part))
            time.sleep(session.timing.silence if low > serial else 0)
            session.recorder.wait(  # its own range: an answer expected, as long as an SDO answer may take
                lambda f, m=mark: bool(_responses(session, m, cia.LSS_IDENTIFIED)),
                mark,
                session.timing.silence if low > serial else session.timing.sdo,
            )
            answers.append(len(_responses(session, mark, cia.LSS_IDENTIFIED)))
        problems = []
        if not answers[0]:
            problems.append(f"no answer for serial range [{serial}, {serial}]")
        others = [n for n in session.ids if _identity(session, n)[3] > serial]
        if answers[1] != len(others) and not (others and answers[1]):
            problems.append(f"{answers[1]} answers for serials above {serial}, {len(others)} drives have one")
        out[node_id] = judge(problems, f"answered 4Fh for its serial {serial}; {answers[1]} for serials above it")
    return out


@LSS.case("11.12", "activate bit timing (15h): silent for twice the switch delay, then back")
def activate_bit_timing(session: Session) -> dict[int, Finding]:
    if (skip := _skip_if_configured(session)) is not None:
        return skip
    lss = session.network.lss
    delay = 0.2
    session.set_heartbeat(20)
    time.sleep(0.1)
    lss.send_switch_state_global(lss.CONFIGURATION_STATE)
    start, sent = time.monotonic(), time.time()
    mark = session.recorder.mark()
    lss.activate_bit_timing(round(delay * 1000))
    quiet_until = start + 2 * delay
    session.recorder.wait(
        lambda frames: all(
            any(f.can_id == cia.heartbeat(n) and f.received > quiet_until for f in frames) for n in session.ids
        ),
        mark,
        2 * delay + 1.0,
    )
    lss.send_switch_state_global(lss.WAITING_STATE)
    frames = session.recorder.since(mark)
    out = {}
    for node_id in session.ids:
        own = [f for f in frames if f.can_id in (cia.heartbeat(node_id), cia.emcy(node_id))]
        # by the drive's send times: from its taking the command (a few ms after it went) to the delays' end
        inside = [f for f in own if sent + 0.03 < f.sent < sent + 2 * delay - 0.005]
        after = [f for f in own if f.received >= quiet_until - 0.03]
        problems = [f"{len(inside)} frames inside the switch delays"] if inside else []
        if not after:
            problems.append("no heartbeat after the switch")
        gap = (after[0].received - start) if after else float("nan")
        out[node_id] = judge(problems, f"silent {gap * 1000:.0f} ms (2 x {delay * 1000:.0f} ms delay), then heartbeats")
    session.set_heartbeat(0)
    return out
