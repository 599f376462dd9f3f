"""SDO (CiA 301 §7.2.4): expedited, segmented and block transfers both ways (block with and without the
CRC), and the abort code of every refused case: unknown command, toggle bit, wrong length, value outside
the EDS's limits, unknown object and sub-index, invalid block size and sequence number, CRC error, and a
change the drive refuses in its NMT state. The CTT's SDO family (2.x) and OD 4.6.

Transfers go through canopen's ``SdoClient`` (upload, download, ``open`` with block transfer); where a
case must break the protocol on purpose it sends the frames CiA 301 defines through the same client.
"""

from __future__ import annotations

import binascii
import struct

from canopen import objectdictionary as od
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from . import standard as cia
from .cases import Family, Finding, failed, judge, not_applicable, passed
from .objects import name, signature_object, variables
from .session import Session, abort_of, hexcode

SDO = Family("SDO")


def _request(command: int, index: int, subindex: int, payload: bytes = b"") -> bytes:
    return struct.pack("<BHB", command, index, subindex) + payload.ljust(4, b"\x00")[:4]


def _strings(session: Session, node_id: int) -> list[od.ODVariable]:
    """Readable objects longer than 4 bytes (segmented and block transfers of several segments); found once."""
    found = session.notes.setdefault("long objects", {})
    if node_id not in found:
        found[node_id] = []
        for var in variables(session.drive(node_id).dictionary):
            value = session.upload(node_id, var.index, var.subindex) if var.readable else 0
            if isinstance(value, bytes) and len(value) > 4:
                found[node_id].append(var)
    return found[node_id]


def _numbers(session: Session, node_id: int, writable: bool = True):
    for var in variables(session.drive(node_id).dictionary):
        if var.data_type in cia.INTEGERS and var.readable and (var.writable or not writable):
            if not signature_object(var) and not 0x1600 <= var.index <= 0x1BFF and var.index != 0x1003:
                yield var


@SDO.case("2.1", "expedited upload and download (device type, heartbeat time)", ctt="2.1, 2.2")
def expedited(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        problems = []
        response = session.request(node_id, _request(0x40, 0x1000, 0))
        device_type = session.drive(node_id).dictionary[0x1000].default
        if response is None or response[0] & 0xE3 != 0x43:
            problems.append(f"0x1000 upload answered {response.hex() if response else 'nothing'}, not expedited")
        elif int.from_bytes(response[4:8], "little") != device_type:
            problems.append(f"0x1000 = 0x{int.from_bytes(response[4:8], 'little'):08X}")
        response = session.request(node_id, _request(0x2B, 0x1017, 0, struct.pack("<H", 100)))
        if response is None or response[0] != 0x60:
            problems.append(f"0x1017 expedited download answered {response.hex() if response else 'nothing'}")
        elif session.nodes[node_id].sdo[0x1017].raw != 100:
            problems.append("0x1017 did not take 100")
        session.set_heartbeat(0, [node_id])
        out[node_id] = judge(problems, f"0x1000 = 0x{device_type:08X} (43h); 0x1017 = 100 written (60h) and read")
    return out


@SDO.case("2.2", "segmented upload of every object longer than 4 bytes", ctt="2.16, 2.18")
def segmented_upload(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        strings = _strings(session, node_id)
        if not strings:
            out[node_id] = not_applicable("the EDS has no readable object longer than 4 bytes")
            continue
        problems = []
        for var in strings:
            response = session.request(node_id, _request(0x40, var.index, var.subindex))
            if response is None or response[0] & 0xE3 != 0x41:
                problems.append(f"{name(var)}: initiate answered {response.hex() if response else 'nothing'}")
                session.request(node_id, struct.pack("<BHBL", 0x80, var.index, var.subindex, cia.GENERAL), 0.05)
                continue
            size = int.from_bytes(response[4:8], "little")
            data, toggle = b"", 0
            for _ in range(size // 7 + 2):
                segment = session.request(node_id, bytes([0x60 | toggle << 4]) + bytes(7))
                if segment is None or segment[0] & 0xE0 != 0 or segment[0] & 0x10 != toggle << 4:
                    problems.append(f"{name(var)}: segment {segment.hex() if segment else 'missing'}")
                    break
                data += segment[1 : 8 - ((segment[0] >> 1) & 0x7)]
                toggle ^= 1
                if segment[0] & 0x01:
                    break
            if len(data) != size or (var.default is not None and data != var.encode_raw(var.default)):
                problems.append(f"{name(var)}: {data!r} ({len(data)} of {size} bytes)")
        out[node_id] = judge(problems, f"{len(strings)} objects ({', '.join(name(v) for v in strings)}) by segments")
    return out


@SDO.case("2.3", "segmented download (of an object of 4 bytes or less)", ctt="2.15")
def segmented_download(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        code = session.download(node_id, 0x1017, 0, struct.pack("<H", 123), force_segment=True)
        value = session.nodes[node_id].sdo[0x1017].raw if code is None else None
        session.set_heartbeat(0, [node_id])
        out[node_id] = judge(
            [] if value == 123 else [f"0x1017: {hexcode(code)}, reads {value}"],
            "0x1017 = 123 by a segmented download, read back",
        )
    return out


@SDO.case("2.4", "a segment with the wrong toggle bit is aborted 0x05030000", ctt="2.17")
def toggle(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        strings = _strings(session, node_id)
        if not strings:
            out[node_id] = not_applicable("no object needs a segmented upload")
            continue
        var = strings[0]
        session.request(node_id, _request(0x40, var.index, var.subindex))
        code = abort_of(session.request(node_id, bytes([0x70]) + bytes(7)))  # toggle 1 first: wrong
        out[node_id] = judge(
            [] if code in cia.ACCEPT["toggle"] else [f"{name(var)}: {hexcode(code)}"],
            f"{name(var)}: abort 0x{code or 0:08X}",
        )
    return out


@SDO.case("2.5", "an unknown command specifier is aborted 0x05040001", ctt="2.7")
def unknown_command(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        code = abort_of(session.request(node_id, _request(0xE0, 0x1000, 0)))
        out[node_id] = judge(
            [] if code in cia.ACCEPT["unknown command"] else [hexcode(code)], f"E0h: abort 0x{code or 0:08X}"
        )
    return out


@SDO.case("2.6", "data longer or shorter than the object is aborted (0x06070010/12/13)", ctt="2.8, 2.9")
def wrong_length(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        problems, tried = [], 0
        for var in _numbers(session, node_id):
            size = len(var) // 8
            value = session.upload(node_id, var.index, var.subindex)
            if isinstance(value, int):
                continue
            tried += 1
            code = session.download(node_id, var.index, var.subindex, value + b"\x00")
            if code not in cia.ACCEPT["too long"]:
                problems.append(f"{name(var)} with {size + 1} bytes: {hexcode(code)}")
            if size > 1:
                code = session.download(node_id, var.index, var.subindex, value[: size - 1])
                if code not in cia.ACCEPT["too short"]:
                    problems.append(f"{name(var)} with {size - 1} bytes: {hexcode(code)}")
        out[node_id] = judge(problems, f"{tried} writable numbers: one byte more and one less refused")
    return out


@SDO.case("2.7", "values outside the EDS's LowLimit/HighLimit are aborted, the limits accepted", ctt="2.10, 2.11, 4.6")
def limits(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        limited = [v for v in _numbers(session, node_id) if v.min is not None or v.max is not None]
        if not limited:
            out[node_id] = not_applicable("the EDS states no LowLimit/HighLimit")
            continue
        problems = []
        for var in limited:
            lo, hi = cia.integer_range(var.data_type)
            before = session.upload(node_id, var.index, var.subindex)
            for limit, step, refusal in ((var.max, 1, "too high"), (var.min, -1, "too low")):
                if limit is None:
                    continue
                code = session.download(node_id, var.index, var.subindex, var.encode_raw(limit))
                if code is not None:
                    problems.append(f"{name(var)} = {limit} (its limit) refused: {hexcode(code)}")
                if lo <= limit + step <= hi:
                    code = session.download(node_id, var.index, var.subindex, var.encode_raw(limit + step))
                    if code not in cia.ACCEPT[refusal]:
                        problems.append(f"{name(var)} = {limit + step}: {hexcode(code)}")
            if isinstance(before, bytes):
                session.download(node_id, var.index, var.subindex, before)
        out[node_id] = judge(problems, f"{len(limited)} limited objects: limits accepted, one past refused")
    return out


@SDO.case("2.8", "unknown objects and sub-indices are aborted, both ways (0x06020000, 0x06090011)", ctt="2.5, 2.6")
def unknown(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        dictionary = session.drive(node_id).dictionary
        missing = next(i for i in range(0x1001, 0x2000) if i not in dictionary.indices)
        record = next(dictionary[i] for i in sorted(dictionary.indices) if not isinstance(dictionary[i], od.ODVariable))
        past = max(record.subindices) + 1
        problems = []
        for what, code, accept in (
            (f"upload 0x{missing:04X}", session.upload(node_id, missing, 0), "no object"),
            (f"download 0x{missing:04X}", session.download(node_id, missing, 0, b"\x00"), "no object"),
            (f"upload 0x{record.index:04X}:{past}", session.upload(node_id, record.index, past), "no sub-index"),
            (
                f"download 0x{record.index:04X}:{past}",
                session.download(node_id, record.index, past, b"\x00"),
                "no sub-index",
            ),
        ):
            if isinstance(code, bytes) or code not in cia.ACCEPT[accept]:
                problems.append(f"{what}: {'answered' if isinstance(code, bytes) else hexcode(code)}")
        out[node_id] = judge(problems, f"0x{missing:04X} and 0x{record.index:04X}:{past} refused both ways")
    return out


def _block_read(session: Session, node_id: int, var: od.ODVariable, crc: bool) -> bytes:
    with session.nodes[node_id].sdo.open(
        var.index, var.subindex, "rb", block_transfer=True, request_crc_support=crc
    ) as stream:
        return stream.read()


@SDO.case("2.9", "block upload with and without the CRC", ctt="2.19, 2.22, 2.23")
def block_upload(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        objects = [session.drive(node_id).dictionary[0x1000], *_strings(session, node_id)]
        problems = []
        for var in objects:
            expected = session.upload(node_id, var.index, var.subindex)
            for crc in (True, False):
                try:
                    data = _block_read(session, node_id, var, crc)
                except (SdoAbortedError, SdoCommunicationError) as exc:
                    problems.append(f"{name(var)} {'with' if crc else 'without'} CRC: {exc}")
                    continue
                if data != expected:
                    problems.append(f"{name(var)} by block: {data!r}, by segments {expected!r}")
        out[node_id] = judge(problems, f"{', '.join(name(v) for v in objects)}: with and without CRC, as uploaded")
    return out


@SDO.case("2.10", "block download with and without the CRC", ctt="2.21, 2.25")
def block_download(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        problems = []
        for crc, value in ((True, 77), (False, 88)):
            try:
                with session.nodes[node_id].sdo.open(
                    0x1017, 0, "wb", block_transfer=True, size=2, request_crc_support=crc
                ) as stream:
                    stream.write(struct.pack("<H", value))
            except (SdoAbortedError, SdoCommunicationError) as exc:
                problems.append(f"0x1017 {'with' if crc else 'without'} CRC: {exc}")
                continue
            read = session.nodes[node_id].sdo[0x1017].raw
            if read != value:
                problems.append(f"0x1017 = {read} after a block download of {value}")
        session.set_heartbeat(0, [node_id])
        out[node_id] = judge(problems, "0x1017 = 77 (CRC) and 88 (no CRC) by block, read back")
    return out


@SDO.case("2.11", "a block download with a wrong CRC is aborted 0x05040004")
def block_crc(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        payload = struct.pack("<H", 55)
        answer = session.request(node_id, struct.pack("<BHBL", 0xC6, 0x1017, 0, len(payload)))  # CRC, size given
        if answer is None or answer[0] & 0xE3 != 0xA0:
            out[node_id] = failed(f"initiate block download answered {answer.hex() if answer else 'nothing'}")
            continue
        session.request(node_id, bytes([0x81]) + payload.ljust(7, b"\x00"))  # the only segment; acknowledged
        wrong = binascii.crc_hqx(payload, 0) ^ 0xFFFF
        code = abort_of(session.request(node_id, struct.pack("<BH", 0xC1 | (5 << 2), wrong) + bytes(5)))
        value = session.nodes[node_id].sdo[0x1017].raw
        problems = [] if code in cia.ACCEPT["crc"] else [f"end with a wrong CRC: {hexcode(code)}"]
        if value == 55:
            problems.append("0x1017 took the value anyway")
        out[node_id] = judge(problems, f"abort 0x{code or 0:08X}; 0x1017 unchanged ({value})")
    return out


@SDO.case("2.12", "a block upload with an invalid block size (0, 128) is aborted", ctt="2.26")
def block_size(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        problems = []
        for size in (0, 128):
            code = abort_of(session.request(node_id, struct.pack("<BHBBB", 0xA4, 0x1000, 0, size, 0) + bytes(2)))
            if code not in cia.ACCEPT["block size"]:
                problems.append(f"block size {size}: {hexcode(code)}")
        out[node_id] = judge(problems, "block sizes 0 and 128 refused (0x05040002)")
    return out


@SDO.case("2.13", "a block upload acknowledged with a sequence number never sent is aborted", ctt="2.27")
def block_sequence(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        var = ([*_strings(session, node_id)] or [session.drive(node_id).dictionary[0x1000]])[0]
        answer = session.request(node_id, struct.pack("<BHBBB", 0xA4, var.index, var.subindex, 127, 0) + bytes(2))
        if answer is None or answer[0] & 0xE3 != 0xC2:
            out[node_id] = failed(f"initiate block upload answered {answer.hex() if answer else 'nothing'}")
            continue
        session.send_raw(node_id, bytes([0xA3]) + bytes(7))
        segments = 0
        for _ in range(128):
            segment = session.read_frame(node_id)
            if segment is None:
                break
            segments += 1
            if segment[0] & 0x80:
                break
        code = abort_of(session.request(node_id, bytes([0xA2, 128, 127]) + bytes(5)))
        out[node_id] = judge(
            [] if code in cia.ACCEPT["block sequence"] else [f"ack 128: {hexcode(code)}"],
            f"{segments} segments of {name(var)}, acknowledged as 128: abort 0x{code or 0:08X}",
        )
    return out


@SDO.case("2.14", "PDO parameters in OPERATIONAL: accepted, or refused 0x08000022 (device state)")
def device_state(session: Session) -> dict[int, Finding]:
    out = {}
    for node_id in session.ids:
        session.nmt(cia.START, node_id)
    for node_id in session.ids:
        index = next((i for i in (0x1801, 0x1800) if i in session.drive(node_id).dictionary.indices), None)
        if index is None:
            out[node_id] = not_applicable("the EDS has no TPDO")
            continue
        code = session.download(node_id, index, 2, bytes([1]))
        if code is None:
            out[node_id] = passed(f"0x{index:04X}:2 written in OPERATIONAL (CiA 301 allows it)")
        else:
            out[node_id] = judge(
                [] if code in cia.ACCEPT["device state"] else [hexcode(code)],
                f"0x{index:04X}:2 in OPERATIONAL: abort 0x{code:08X}",
            )
    session.reset()
    return out
