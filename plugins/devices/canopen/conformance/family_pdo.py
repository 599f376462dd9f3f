"""PDO (CiA 301 §7.2.2, §7.5.2.35-38): the communication and mapping parameters, the dynamic mapping
procedure through canopen's ``PdoMap.save()`` and the refusal of every invalid mapping (the CTT's PDO
family, 3.x); the transmission types are :mod:`.family_pdo_timing`'s cases of this family.

Mappings are chosen from the EDS: process inputs (``ro``/``rwr``, mappable) go to TPDOs, outputs
(``rww``/``wo``) to RPDOs.
"""

from __future__ import annotations

import configparser
import struct

from canopen import objectdictionary as od

from . import standard as cia
from .cases import Family, Finding, judge, not_applicable
from .objects import variables
from .session import Frame, Session, hexcode

PDO = Family("PDO")
#: the statusword's state bits (CiA 402: mask 0x6F) in SWITCH ON DISABLED and READY TO SWITCH ON
SOD, READY = 0x40, 0x21
QUIET = 0.04


def _pdos(session: Session, node_id: int, receive: bool) -> list[int]:
    """The numbers (1-512) of the drive's RPDOs or TPDOs, from its EDS."""
    first = 0x1400 if receive else 0x1800
    return [i - first + 1 for i in session.drive(node_id).dictionary.indices if first <= i <= first + 0x1FF]


def _candidates(session: Session, node_id: int, kind: str) -> list[od.ODVariable]:
    """Mappable objects that are process inputs ("in"), outputs ("out"), or unmappable writable/readable ones."""
    out = []
    for var in variables(session.drive(node_id).dictionary):
        if kind == "in" and var.pdo_mappable and var.access_type in ("ro", "rwr"):
            out.append(var)
        elif kind == "out" and var.pdo_mappable and var.access_type in ("rww", "wo"):
            out.append(var)
        elif kind == "none" and not var.pdo_mappable and var.data_type in cia.INTEGERS and var.index >= 0x2000:
            out.append(var)
    return out


def _entry(var: od.ODVariable) -> int:
    return var.index << 16 | var.subindex << 8 | len(var)


def _frames(session: Session, mark: int, can_id: int) -> list[Frame]:
    return session.recorder.since(mark, can_id)


def _statusword(frame: Frame) -> int:
    return int.from_bytes(frame.data[:2], "little") & 0x6F


def _map(session: Session, node_id: int, receive: bool, n: int, objects, trans: int, **timing) -> None:
    """Map PDO n of a drive with canopen's procedure (``PdoMap.save()``): invalidate, 0 entries, entries,
    count, valid."""
    maps = session.nodes[node_id].rpdo if receive else session.nodes[node_id].tpdo
    pdo = maps[n]
    pdo.read()
    pdo.clear()
    for var in objects:
        pdo.add_variable(var.index, var.subindex)
    pdo.trans_type = trans
    for key, value in timing.items():
        setattr(pdo, key, value)
    pdo.enabled = True
    pdo.save()


def _configure_all(session: Session, receive: bool, n: int, objects_of, trans: int, **timing) -> dict[int, str]:
    """Map PDO n on every drive; returns the drives where it failed, with why."""
    problems = {}
    for node_id in session.ids:
        try:
            _map(session, node_id, receive, n, objects_of(node_id), trans, **timing)
        except Exception as exc:  # any refusal or time-out is this drive's finding
            problems[node_id] = f"mapping {'R' if receive else 'T'}PDO{n}: {type(exc).__name__}: {exc}"
    return problems


def _statusword_var(session: Session, node_id: int) -> od.ODVariable:
    return session.drive(node_id).dictionary[0x6041]


def _controlword(session: Session, word: int) -> None:
    for node_id in session.ids:
        session.nodes[node_id].sdo[0x6040].raw = word


def _tpdo_n(session: Session, node_id: int) -> int:
    tpdos = _pdos(session, node_id, False)
    return 2 if 2 in tpdos else tpdos[0]


@PDO.case(
    "3.1", "PDO communication parameters: predefined COB-IDs, no extended IDs, types not reserved", ctt="3.1, 3.2"
)
def communication(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        problems, rtr = [], []
        for receive in (True, False):
            for n in _pdos(session, node_id, receive):
                index = (0x1400 if receive else 0x1800) + n - 1
                cob = session.nodes[node_id].sdo[index][1].raw
                trans = session.nodes[node_id].sdo[index][2].raw
                predefined = cia.rpdo(n, node_id) if receive else cia.tpdo(n, node_id)
                if n <= 4 and cob & 0x7FF != predefined:
                    problems.append(f"0x{index:04X}:1 = 0x{cob:08X}, not the predefined 0x{predefined:03X}")
                if cob & (1 << 29):
                    problems.append(f"0x{index:04X}:1 = 0x{cob:08X}: an extended (29-bit) COB-ID")
                if 241 <= trans <= 251:
                    problems.append(f"0x{index:04X}:2 = {trans}: a reserved transmission type")
                if not receive and not cob & cia.PDO_NO_RTR:
                    rtr.append(n)
        note = f"; TPDO {rtr} allow RTR (not requested by this suite)" if rtr else "; no TPDO allows RTR (bit 30)"
        out[node_id] = judge(
            problems, f"{len(_pdos(session, node_id, True))} RPDOs, {len(_pdos(session, node_id, False))} TPDOs" + note
        )
    return out


@PDO.case("3.2", "the default mappings are the EDS's and map existing, mappable objects", ctt="3.21")
def default_mappings(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        dictionary = session.drive(node_id).dictionary
        problems, entries = [], 0
        for receive in (True, False):
            for n in _pdos(session, node_id, receive):
                index = (0x1600 if receive else 0x1A00) + n - 1
                count = session.nodes[node_id].sdo[index][0].raw
                if count != dictionary[index][0].default:
                    problems.append(f"0x{index:04X}:0 = {count}, the EDS says {dictionary[index][0].default}")
                for sub in range(1, count + 1):
                    entry = session.nodes[node_id].sdo[index][sub].raw
                    entries += 1
                    if entry != dictionary[index][sub].default:
                        problems.append(
                            f"0x{index:04X}:{sub} = 0x{entry:08X}, the EDS says 0x{dictionary[index][sub].default:08X}"
                        )
        out[node_id] = judge(problems, f"{entries} mapping entries as the EDS states")
    return out


def _new_mapping(session: Session, node_id: int, receive: bool, n: int) -> list[od.ODVariable]:
    """A mapping unlike the default: the drive's candidates of the PDO's direction, rotated by n, 64 bits at most."""
    pool = _candidates(session, node_id, "out" if receive else "in")
    if not pool:
        return []
    rotated = pool[n % len(pool) :] + pool[: n % len(pool)]
    chosen, bits = [], 0
    for var in rotated:
        if bits + len(var) <= 64 and len(chosen) < 3:
            chosen.append(var)
            bits += len(var)
    return chosen


@PDO.case("3.3", "the dynamic mapping procedure through canopen's PdoMap.save(), every PDO, read back", ctt="3.22")
def mapping_procedure(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        problems, mapped = [], 0
        for receive in (True, False):
            maps = session.nodes[node_id].rpdo if receive else session.nodes[node_id].tpdo
            for n in _pdos(session, node_id, receive):
                objects = _new_mapping(session, node_id, receive, n)
                if not objects:
                    continue
                try:
                    _map(session, node_id, receive, n, objects, 254 if receive else 1)
                except Exception as exc:  # the drive's refusal of a valid mapping is the finding
                    problems.append(f"{'R' if receive else 'T'}PDO{n}: {type(exc).__name__}: {exc}")
                    continue
                maps[n].read()
                got = [(v.index, v.subindex, v.length) for v in maps[n].map]
                want = [(v.index, v.subindex, len(v)) for v in objects]
                if got != want or not maps[n].enabled:
                    problems.append(f"{'R' if receive else 'T'}PDO{n} reads back {got}, valid={maps[n].enabled}")
                mapped += 1
        session.reset([node_id])
        out[node_id] = judge(problems, f"{mapped} PDOs remapped (invalidate, 0, entries, count, valid), read back")
    return out


def _invalid(session: Session, node_id: int, receive: bool, n: int) -> tuple[int, int]:
    """PDO n invalidated (its COB-ID's bit 31); returns its communication and mapping indices."""
    comm = (0x1400 if receive else 0x1800) + n - 1
    cob = session.nodes[node_id].sdo[comm][1].raw
    session.nodes[node_id].sdo[comm][1].raw = cob | cia.PDO_INVALID
    return comm, comm + 0x200


@PDO.case("3.4", "mapping entries written without the procedure are refused", ctt="3.23, 3.24")
def without_procedure(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        problems = []
        n = _pdos(session, node_id, False)[0]
        mapping = 0x1A00 + n - 1
        var = _candidates(session, node_id, "in")[0]
        valid = not session.nodes[node_id].sdo[0x1800 + n - 1][1].raw & cia.PDO_INVALID
        if valid:  # a valid PDO: neither the count nor an entry may change
            for sub, value in ((0, 0), (1, _entry(var))):
                code = session.download(node_id, mapping, sub, struct.pack("<B" if sub == 0 else "<L", value))
                if code not in cia.ACCEPT["mapping procedure"]:
                    problems.append(f"valid TPDO{n}: 0x{mapping:04X}:{sub} <- 0x{value:X}: {hexcode(code)}")
        _invalid(session, node_id, False, n)
        count = session.nodes[node_id].sdo[mapping][0].raw
        if count:
            code = session.download(node_id, mapping, 1, struct.pack("<L", _entry(var)))
            if code not in cia.ACCEPT["mapping procedure"]:
                problems.append(f"invalid TPDO{n} with {count} entries: 0x{mapping:04X}:1: {hexcode(code)}")
        session.reset([node_id])
        out[node_id] = judge(problems, f"TPDO{n}: {'valid PDO and ' if valid else ''}count not 0 refused (0x06010000)")
    return out


@PDO.case("3.5", "a mapping longer than 64 bits is refused when its count is written", ctt="3.25, 3.26")
def too_long(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        problems = []
        for receive in (True, False):
            n = _pdos(session, node_id, receive)[0]
            pool = sorted(_candidates(session, node_id, "out" if receive else "in"), key=len, reverse=True)
            if not pool:
                continue
            _, mapping = _invalid(session, node_id, receive, n)
            session.nodes[node_id].sdo[mapping][0].raw = 0
            subs = max(session.drive(node_id).dictionary[mapping].subindices)
            count = min(subs, 64 // len(pool[0]) + 1)
            for sub in range(1, count + 1):
                session.nodes[node_id].sdo[mapping][sub].raw = _entry(pool[0])
            code = session.download(node_id, mapping, 0, bytes([count]))
            if code not in cia.ACCEPT["mapping too long"]:
                problems.append(f"{count} x {len(pool[0])} bits in 0x{mapping:04X}: {hexcode(code)}")
        session.reset([node_id])
        out[node_id] = judge(problems, "RPDO and TPDO of more than 64 bits refused (0x06040042)")
    return out


@PDO.case("3.6", "each object maps only in its direction; unmappable objects never", ctt="3.27-3.32")
def directions(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        inputs, outputs = _candidates(session, node_id, "in"), _candidates(session, node_id, "out")
        unmappable = _candidates(session, node_id, "none")
        problems, checked = [], []
        for receive in (True, False):
            n = _pdos(session, node_id, receive)[0]
            _, mapping = _invalid(session, node_id, receive, n)
            session.nodes[node_id].sdo[mapping][0].raw = 0
            right, wrong = (outputs, inputs) if receive else (inputs, outputs)
            kind = "RPDO" if receive else "TPDO"
            for var, accepted in [(v, True) for v in right[:1]] + [(v, False) for v in (wrong[:1] + unmappable[:1])]:
                code = session.download(node_id, mapping, 1, struct.pack("<L", _entry(var)))
                checked.append(f"{var.access_type} {kind}")
                if accepted and code is not None:
                    problems.append(f"0x{var.index:04X} ({var.access_type}) to a {kind}: {hexcode(code)}")
                if not accepted and code not in cia.ACCEPT["cannot map"]:
                    problems.append(
                        f"0x{var.index:04X} ({var.access_type}, mappable={var.pdo_mappable}) to a "
                        f"{kind}: {hexcode(code)}"
                    )
        session.reset([node_id])
        out[node_id] = judge(problems, f"{len(checked)} mappings tried: outputs to RPDOs, inputs to TPDOs only")
    return out


@PDO.case("3.7", "dummy entries map as [DummyUsage] says", ctt="3.33")
def dummies(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        parser = configparser.ConfigParser(interpolation=None, strict=False)
        parser.read_string(session.drive(node_id).eds_text)
        section = next((s for s in parser.sections() if s.lower() == "dummyusage"), None)
        if section is None:
            out[node_id] = not_applicable("the EDS has no [DummyUsage]")
            continue
        _, mapping = _invalid(session, node_id, True, _pdos(session, node_id, True)[0])
        session.nodes[node_id].sdo[mapping][0].raw = 0
        problems, allowed = [], []
        for index, (_, size) in (
            (2, ("", 8)),
            (3, ("", 16)),
            (4, ("", 32)),
            (5, ("", 8)),
            (6, ("", 16)),
            (7, ("", 32)),
        ):
            used = parser.get(section, f"Dummy{index:04X}", fallback="0").strip() == "1"
            code = session.download(node_id, mapping, 1, struct.pack("<L", index << 16 | size))
            if used:
                allowed.append(f"0x{index:04X}")
                if code is not None:
                    problems.append(f"dummy 0x{index:04X} allowed by the EDS: {hexcode(code)}")
            elif code not in cia.ACCEPT["cannot map"]:
                problems.append(f"dummy 0x{index:04X} not allowed by the EDS: {hexcode(code)}")
        session.reset([node_id])
        out[node_id] = judge(problems, f"dummies {', '.join(allowed) or 'none'} allowed; the others refused")
    return out


@PDO.case("3.8", "no PDO takes a restricted CAN-ID as its COB-ID (CiA 301 §7.3.5)", ctt="8.10")
def restricted(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        problems, tried = [], 0
        for receive in (True, False):
            n = _pdos(session, node_id, receive)[0]
            comm, _ = _invalid(session, node_id, receive, n)
            flags = cia.PDO_INVALID | (0 if receive else cia.PDO_NO_RTR)
            for can_id in cia.RESTRICTED_IDS:
                tried += 1
                code = session.download(node_id, comm, 1, struct.pack("<L", flags | can_id))
                if code not in cia.ACCEPT["restricted CAN-ID"]:
                    problems.append(f"0x{comm:04X}:1 <- 0x{flags | can_id:08X}: {hexcode(code)}")
        session.reset([node_id])
        out[node_id] = judge(problems, f"{tried} restricted CAN-IDs refused for RPDO and TPDO COB-IDs (0x06090030)")
    return out
