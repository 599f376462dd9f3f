"""Store and restore (CiA 301 §7.5.2.13/14, 0x1010 and 0x1011): the capabilities, the signatures ("save",
"load"; anything else aborted 0x08000020), what each sub-index covers (1 all, 2 communication, 3
application), that a reset brings back what was stored, and that stored values and restored defaults
survive a power cycle (the drives' process restarted: their memory is a file in their state folder). The
CTT's "Testing other" family (8.1-8.8).

It changes what the drives keep over a power cycle: on a real bus it runs only when allowed, and the last
case leaves every drive at its EDS defaults. The parameters it changes are found in the EDS (a writable
setting of each area the drive accepts another value for).
"""

from __future__ import annotations

from . import standard as cia
from .cases import Family, Finding, every, failed, judge, not_applicable, skipped
from .objects import pick_parameter, process_input, variables
from .session import Session, hexcode

STORE = Family("store and restore")
AREAS = {"communication": (0x1000, 0x1FFF), "application": (0x6000, 0x9FFF), "manufacturer": (0x2000, 0x5FFF)}


def _skip(session: Session) -> dict[int, Finding] | None:
    if not session.target.may_store:
        return every(session.ids, skipped("changes what the drives keep over a power cycle: allow it to run"))
    missing = [n for n in session.ids if not {0x1010, 0x1011} <= set(session.drive(n).dictionary.indices)]
    if missing:  # the family runs on drives that all store (it power-cycles them together)
        others = skipped(f"node {missing[0]}'s EDS has no 0x1010/0x1011: the family needs every drive to store")
        return {n: not_applicable("the EDS has no 0x1010/0x1011") if n in missing else others for n in session.ids}
    return None


#: how long a store or restore command may take to be confirmed (s): the drive writes its non-volatile memory
#: first (flash or EEPROM on real drives, a file on the simulated ones; either can take long on a busy device)
STORE_TIMEOUT = 3.0


def _signature(session: Session, node_id: int, index: int, sub: int, value: int) -> int | None:
    sdo = session.nodes[node_id].sdo
    patient, sdo.RESPONSE_TIMEOUT = sdo.RESPONSE_TIMEOUT, max(sdo.RESPONSE_TIMEOUT, STORE_TIMEOUT)
    try:
        return session.download(node_id, index, sub, value.to_bytes(4, "little"))
    finally:
        sdo.RESPONSE_TIMEOUT = patient


def _change(session: Session, node_id: int) -> dict[str, tuple]:
    """A new value in each area's first setting the drive accepts one for: {area: (var, old, new)}."""
    out = {}
    for area, (lo, hi) in AREAS.items():
        picked = pick_parameter(session, node_id, lo, hi, exclude=(0x1017,))
        if picked is not None:
            out[area] = picked
    return out


def _values(session: Session, node_id: int, changed: dict[str, tuple]) -> dict[str, int]:
    return {
        area: var.decode_raw(session.upload(node_id, var.index, var.subindex)) for area, (var, _, _) in changed.items()
    }


def _expect(found: dict[str, int], changed: dict[str, tuple], kept: set[str], when: str) -> list[str]:
    problems = []
    for area, (var, old, new) in changed.items():
        want = new if area in kept else old
        if found[area] != want:
            problems.append(
                f"{when}: 0x{var.index:04X}:{var.subindex} ({area}) = {found[area]}, expected {want} "
                f"({'stored' if area in kept else 'default'})"
            )
    return problems


@STORE.case("8.1", "0x1010/0x1011 say the drive saves and restores on command (bit 0)", ctt="8.1-8.8")
def capabilities(session: Session) -> dict[int, Finding]:
    if (skip := _skip(session)) is not None:
        return skip
    out = {}
    for node_id in session.ids:
        problems, subs = [], []
        for index in (0x1010, 0x1011):
            for sub in sorted(session.drive(node_id).dictionary[index].subindices):
                if sub == 0:
                    continue
                value = session.nodes[node_id].sdo[index][sub].raw
                subs.append(f"0x{index:04X}:{sub}")
                if not value & 1:
                    problems.append(f"0x{index:04X}:{sub} = 0x{value:08X}: does not save on command")
        out[node_id] = judge(problems, f"{', '.join(subs)} read 1")
    return out


@STORE.case(
    "8.2",
    "a wrong signature ('wron') to 0x1010 or 0x1011 is aborted 0x08000020, nothing stored",
    ctt="8.1, 8.3, 8.5, 8.7",
)
def wrong_signature(session: Session) -> dict[int, Finding]:
    if (skip := _skip(session)) is not None:
        return skip
    session.reset()
    out = {}
    for node_id in session.ids:
        changed = _change(session, node_id)
        problems = []
        for index in (0x1010, 0x1011):
            for sub in sorted(s for s in session.drive(node_id).dictionary[index].subindices if s):
                code = _signature(session, node_id, index, sub, cia.WRONG)
                if code not in cia.ACCEPT["signature"]:
                    problems.append(f"0x{index:04X}:{sub} <- 'wron': {hexcode(code)}")
        session.reset([node_id])
        problems += _expect(_values(session, node_id, changed), changed, set(), "after reset node")
        out[node_id] = judge(problems, "'wron' refused on every sub-index; nothing was stored")
    return out


@STORE.case("8.3", "save all (0x1010:1): what was written is back after reset node", ctt="8.2")
def save_all(session: Session) -> dict[int, Finding]:
    if (skip := _skip(session)) is not None:
        return skip
    out = {}
    for node_id in session.ids:
        changed = _change(session, node_id)
        code = _signature(session, node_id, 0x1010, 1, cia.SAVE)
        session.reset([node_id])
        problems = [f"'save' to 0x1010:1: {hexcode(code)}"] if code is not None else []
        problems += _expect(_values(session, node_id, changed), changed, set(changed), "after reset node")
        _signature(session, node_id, 0x1011, 1, cia.LOAD)
        session.reset([node_id])
        out[node_id] = judge(problems, f"{', '.join(_describe(changed))} kept over reset node")
    return out


def _describe(changed: dict[str, tuple]) -> list[str]:
    return [f"0x{var.index:04X}:{var.subindex} = {new} ({area})" for area, (var, _, new) in changed.items()]


@STORE.case("8.4", "save communication (0x1010:2) and application (0x1010:3) each keep only their area", ctt="8.5, 8.6")
def save_areas(session: Session) -> dict[int, Finding]:
    if (skip := _skip(session)) is not None:
        return skip
    out = {}
    stored = {}
    for node_id in session.ids:
        subs = session.drive(node_id).dictionary[0x1010].subindices
        if not {2, 3} <= set(subs):
            out[node_id] = not_applicable("0x1010 has no sub-indices 2 and 3")
            continue
        problems = []
        changed = _change(session, node_id)
        if not {"communication", "application"} <= set(changed):
            out[node_id] = failed(f"no communication and application setting to change found ({sorted(changed)})")
            continue
        _signature(session, node_id, 0x1010, 2, cia.SAVE)
        session.reset([node_id])
        problems += _expect(_values(session, node_id, changed), changed, {"communication"}, "communication saved")
        session.download(node_id, *_key(changed["application"]))
        _signature(session, node_id, 0x1010, 3, cia.SAVE)
        session.reset([node_id])
        problems += _expect(
            _values(session, node_id, changed), changed, {"communication", "application"}, "application saved too"
        )
        stored[node_id] = changed
        out[node_id] = judge(problems, "0x1010:2 kept the communication value only, 0x1010:3 the application's")
    session.notes["stored"] = stored
    return out


def _key(entry: tuple) -> tuple:
    var, _, new = entry
    return var.index, var.subindex, var.encode_raw(new)


@STORE.case("8.5", "restore communication (0x1011:2): its defaults after reset communication", ctt="8.8")
def restore_communication(session: Session) -> dict[int, Finding]:
    if (skip := _skip(session)) is not None:
        return skip
    stored = session.notes.get("stored", {})
    out = {}
    for node_id in session.ids:
        if node_id not in stored:
            out[node_id] = not_applicable("nothing stored by 8.4")
            continue
        code = _signature(session, node_id, 0x1011, 2, cia.LOAD)
        session.reset([node_id], cia.RESET_COMMUNICATION)
        changed = stored[node_id]
        problems = [f"'load' to 0x1011:2: {hexcode(code)}"] if code is not None else []
        problems += _expect(_values(session, node_id, changed), changed, {"application"}, "after reset communication")
        out[node_id] = judge(problems, "communication default again, application still as stored")
    return out


@STORE.case("8.6", "a power cycle keeps what was stored and what was restored; LSS node-IDs from memory")
def power_cycle(session: Session) -> dict[int, Finding]:
    if not session.target.can_power_cycle:
        return every(session.ids, skipped("a power cycle of these drives is the lab's to do"))
    if (skip := _skip(session)) is not None:
        return skip
    stored = session.notes.get("stored", {})
    mark = session.power_cycle()
    boots = {f.can_id - 0x700 for f in session.recorder.since(mark) if f.data == b"\x00" and 0x700 < f.can_id < 0x780}
    session.recorder.wait(
        lambda f: all(any(x.can_id == 0x700 + n and x.data == b"\x00" for x in f) for n in session.ids),
        mark,
        session.timing.boot,
    )
    boots = {f.can_id - 0x700 for f in session.recorder.since(mark) if f.data == b"\x00" and 0x700 < f.can_id < 0x780}
    out = {}
    for node_id in session.ids:
        problems = []
        if node_id not in boots:
            problems.append(
                f"no boot-up from node {node_id} at power-up"
                + (" (the LSS-stored node-ID)" if session.target.unconfigured else "")
            )
        if node_id in stored:
            problems += _expect(
                _values(session, node_id, stored[node_id]), stored[node_id], {"application"}, "after the power cycle"
            )
        lss = "its LSS-stored node-ID" if session.target.unconfigured else "its node-ID"
        out[node_id] = judge(
            problems, f"boot-up at power-up with {lss}; application value as stored, communication default (restored)"
        )
    return out


@STORE.case("8.7", "restore all (0x1011:1) then reset node: every value is the EDS's default again", ctt="8.4")
def restore_all(session: Session) -> dict[int, Finding]:
    if (skip := _skip(session)) is not None:
        return skip
    out = {}
    for node_id in session.ids:
        code = _signature(session, node_id, 0x1011, 1, cia.LOAD)
        session.reset([node_id])
        problems = [f"'load' to 0x1011:1: {hexcode(code)}"] if code is not None else []
        compared = 0
        for var in variables(session.drive(node_id).dictionary):
            if not var.readable or process_input(var) or var.default is None:
                continue
            value = session.upload(node_id, var.index, var.subindex)
            if isinstance(value, int):
                continue
            compared += 1
            if value != var.encode_raw(var.default):
                problems.append(
                    f"0x{var.index:04X}:{var.subindex} = {var.decode_raw(value)!r}, default {var.default!r}"
                )
        out[node_id] = judge(problems, f"{compared} values equal the EDS's defaults")
    return out
