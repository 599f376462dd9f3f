"""EDS: each drive's EDS parses with canopen and is consistent (CiA 306), and it *is* the drive's object
dictionary: every object of the EDS is in the drive with its access type and default, and the drive has
no object the EDS lacks (CTT 1.0 and the OD family 4.x).

Every expectation comes from the EDS (its objects, access types, defaults and PDO mapping flags), so an
object added to the drives and their EDS files is checked without changing this module. The defaults are
compared after an NMT reset node; the drive's process inputs (read-only, PDO-mappable: the statusword, the
position actual value, ...) are its state, not parameters, and are only read.
"""

from __future__ import annotations

import canopen
from canopen import objectdictionary as od

from . import standard as cia
from .cases import Family, Finding, Verdict, failed, judge, passed
from .eds_check import check_eds
from .objects import name, process_input, signature_object, variables
from .session import Session, hexcode

EDS = Family("EDS")


@EDS.case("1.1", "the EDS parses with canopen", ctt="1.0")
def parses(session: Session) -> dict[int, Finding]:
    out = {}
    for drive in session.drives:
        try:
            dictionary = canopen.import_od(str(drive.eds), drive.node_id)
        except Exception as exc:  # any error in a file canopen cannot read is the finding
            out[drive.node_id] = failed(f"canopen cannot read {drive.eds.name}: {type(exc).__name__}: {exc}")
            continue
        count = sum(1 for _ in variables(dictionary))
        out[drive.node_id] = passed(f"{drive.eds.name}: {len(dictionary.indices)} objects, {count} variables")
    return out


@EDS.case("1.2", "the EDS is consistent (CiA 306: sections, types, access, mapping, sub-index 0, lists)", ctt="1.0")
def consistent(session: Session) -> dict[int, Finding]:
    out = {}
    for drive in session.drives:
        report = check_eds(drive.eds_text, drive.eds.name)
        evidence = f"{report.objects} objects, {report.variables} variables checked"
        if report.errors:
            out[drive.node_id] = judge(report.errors, evidence)
        elif report.warnings:
            out[drive.node_id] = Finding(Verdict.WARN, "; ".join(report.warnings[:3]))
        else:
            out[drive.node_id] = passed(evidence + ", no warning")
    return out


@EDS.case("1.3", "after reset node: device type, identity and supported modes are the EDS's", ctt="2.1, 4.2")
def identity(session: Session) -> dict[int, Finding]:
    booted = session.reset()
    out = {}
    for drive in session.drives:
        if not booted[drive.node_id]:
            out[drive.node_id] = failed("no boot-up message after NMT reset node")
            continue
        problems = []
        for index, sub in ((0x1000, 0), (0x1018, 1), (0x1018, 2), (0x1018, 3), (0x1018, 4), (0x6502, 0)):
            var = _var(drive.dictionary, index, sub)
            if var is None:
                if index in (0x1000, 0x1018):
                    problems.append(f"the EDS has no 0x{index:04X}:{sub}")
                continue
            value = session.upload(drive.node_id, index, sub)
            if isinstance(value, int):
                problems.append(f"0x{index:04X}:{sub}: {hexcode(value)}")
            elif var.decode_raw(value) != var.default:
                problems.append(f"0x{index:04X}:{sub} = 0x{var.decode_raw(value):X}, the EDS says 0x{var.default:X}")
        device_type = drive.dictionary[0x1000].default
        if device_type & 0xFFFF != 402:
            problems.append(f"device type 0x{device_type:08X}: not a CiA 402 device")
        out[drive.node_id] = judge(problems, f"device type 0x{device_type:08X}, identity and 0x6502 as the EDS says")
    return out


def _var(dictionary, index: int, sub: int):
    try:
        obj = dictionary[index]
    except KeyError:
        return None
    if isinstance(obj, od.ODVariable):
        return obj if sub == 0 else None
    return obj[sub] if sub in obj.subindices else None


@EDS.case("4.1", "every object of the EDS is there: read with its size, no sub-index past the highest", ctt="4.1, 2.5")
def present(session: Session) -> dict[int, Finding]:
    out = {}
    for drive in session.drives:
        problems, read = [], 0
        for var in variables(drive.dictionary):
            if not var.readable:
                continue
            value = session.upload(drive.node_id, var.index, var.subindex)
            if isinstance(value, int):
                if var.index == 0x1003 and var.subindex > 0 and value in cia.ACCEPT["no error"]:
                    continue  # no error at this depth of the history: CiA 301 aborts the read
                problems.append(f"{name(var)}: {hexcode(value)}")
                continue
            read += 1
            size = cia.DATA_TYPES.get(var.data_type, ("", None))[1]
            if size is not None and len(value) * 8 != size:
                problems.append(f"{name(var)}: {len(value)} bytes, a {cia.DATA_TYPES[var.data_type][0]}")
        for index in sorted(drive.dictionary.indices):
            obj = drive.dictionary[index]
            sub = 1 if isinstance(obj, od.ODVariable) else max(obj.subindices) + 1
            if sub > 0xFF:
                continue
            code = session.upload(drive.node_id, index, sub)
            if code not in cia.ACCEPT["no sub-index"]:
                problems.append(f"0x{index:04X}:{sub} (past the highest sub-index): {hexcode(code)}")
        out[drive.node_id] = judge(problems, f"{read} variables read; past-the-end sub-indices refused 0x06090011")
    return out


@EDS.case("4.2", "every value read after reset node is the EDS's default (process inputs excepted)", ctt="4.2, 4.8")
def defaults(session: Session) -> dict[int, Finding]:
    out = {}
    for drive in session.drives:
        problems, compared = [], 0
        for var in variables(drive.dictionary):
            if not var.readable or process_input(var) or var.default is None:
                continue
            value = session.upload(drive.node_id, var.index, var.subindex)
            if isinstance(value, int):
                continue  # refused reads are 4.1's
            compared += 1
            if value != var.encode_raw(var.default):
                problems.append(f"{name(var)} = {var.decode_raw(value)!r}, the EDS says {var.default!r}")
        out[drive.node_id] = judge(problems, f"{compared} defaults equal the EDS's")
    return out


@EDS.case("4.3", "read-only and constant objects refuse writes", ctt="2.3, 4.3")
def read_only(session: Session) -> dict[int, Finding]:
    out = {}
    for drive in session.drives:
        problems, tried = [], 0
        for var in variables(drive.dictionary):
            if var.writable:
                continue
            value = session.upload(drive.node_id, var.index, var.subindex)
            if isinstance(value, int):
                value = var.encode_raw(var.default) if var.default is not None else b"\x00"
            tried += 1
            code = session.download(drive.node_id, var.index, var.subindex, value)
            if code not in cia.ACCEPT["write read-only"]:
                problems.append(f"{name(var)} ({var.access_type}): {hexcode(code)}")
        out[drive.node_id] = judge(problems, f"{tried} ro/const objects refused (0x06010002)")
    return out


@EDS.case("4.4", "write-only objects refuse reads", ctt="2.4, 4.4")
def write_only(session: Session) -> dict[int, Finding]:
    out = {}
    for drive in session.drives:
        candidates = [var for var in variables(drive.dictionary) if var.access_type == "wo"]
        if not candidates:
            out[drive.node_id] = Finding(Verdict.NOT_APPLICABLE, "the EDS declares no write-only object")
            continue
        problems = []
        for var in candidates:
            code = session.upload(drive.node_id, var.index, var.subindex)
            if isinstance(code, bytes) or code not in cia.ACCEPT["read write-only"]:
                problems.append(f"{name(var)}: {'read' if isinstance(code, bytes) else hexcode(code)}")
        out[drive.node_id] = judge(problems, f"{len(candidates)} wo objects refused reads")
    return out


@EDS.case("4.9", "every writable object takes its own value back", ctt="2.2, 4.9")
def write_back(session: Session) -> dict[int, Finding]:
    out = {}
    for drive in session.drives:
        problems, written = [], 0
        for var in variables(drive.dictionary):
            if not (var.writable and var.readable) or signature_object(var) or 0x1600 <= var.index <= 0x1BFF:
                continue  # the mapping parameters change only with the mapping procedure (the PDO family's)
            value = session.upload(drive.node_id, var.index, var.subindex)
            if isinstance(value, int):
                continue
            written += 1
            code = session.download(drive.node_id, var.index, var.subindex, value)
            if code is not None:
                problems.append(f"{name(var)} = {var.decode_raw(value)!r} written back: {hexcode(code)}")
        out[drive.node_id] = judge(problems, f"{written} rw objects accepted their own value")
    return out


@EDS.case("4.10", "the drive has no object the EDS lacks (every other index of the scanned areas refused)")
def no_other(session: Session) -> dict[int, Finding]:
    out = {}
    ranges = ", ".join(f"0x{lo:04X}-0x{hi:04X}" for lo, hi in session.scan)
    requests = {
        drive.node_id: [
            (index, 0)
            for lo, hi in session.scan
            for index in range(lo, hi + 1)
            if index not in drive.dictionary.indices
        ]
        for drive in session.drives
    }
    answers = session.upload_many(requests)
    for node_id, found in answers.items():
        problems = []
        for (index, _), code in found.items():
            if isinstance(code, bytes) or code not in cia.ACCEPT["no object"]:
                what = "answers" if isinstance(code, bytes) else ("no answer" if code == -1 else hexcode(code))
                problems.append(f"0x{index:04X}: {what}")
        out[node_id] = judge(problems, f"{len(found)} indices of {ranges} outside the EDS refused 0x06020000")
    return out
