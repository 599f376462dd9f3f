"""The simulated drive's SDO server (CiA 301 §7.2.4): expedited, segmented and block transfer, with the
standard abort codes.

canopen's ``SdoServer`` serves expedited and segmented transfers; it answers a block upload with a normal
one and aborts a block download. :class:`DriveSdoServer` adds both block transfers, with the CRC
(CRC-16/XMODEM: polynomial 0x1021, initial value 0, ``binascii.crc_hqx``) when the client asks for it, and
the aborts a certified server gives:

* 0x05040001 command specifier unknown, 0x05030000 toggle bit not alternated (segmented);
* block transfer: 0x05040002 invalid block size (0 or above 127), 0x05040003 invalid sequence number (an
  acknowledgement beyond the segments sent), 0x05040004 CRC error;
* 0x05040000 SDO protocol timed out: a segmented or block transfer the client leaves for
  :data:`PROTOCOL_TIMEOUT` s is aborted;
* 0x06070012/0x06070013 data longer/shorter than the object (canopen's server says 0x06070010 for both).

Silent in STOPPED and INITIALISING (CiA 301's NMT rules) and while the drive is off the bus.
"""

from __future__ import annotations

import binascii
import logging
import struct

from canopen import objectdictionary as od_types
from canopen.sdo import SdoAbortedError, SdoServer
from canopen.sdo.constants import SDO_STRUCT

from ..cia402 import NMT_INITIALISING, NMT_STOPPED

log = logging.getLogger(__name__)

#: a segmented or block transfer left by its client for this long is aborted 0x05040000 (s)
PROTOCOL_TIMEOUT = 1.0
#: the largest block (segments) the server asks for and accepts
MAX_BLOCK = 127

TOGGLE_NOT_ALTERNATED = 0x05030000
TIMED_OUT = 0x05040000
UNKNOWN_COMMAND = 0x05040001
INVALID_BLOCK_SIZE = 0x05040002
INVALID_SEQUENCE = 0x05040003
CRC_ERROR = 0x05040004
LENGTH_TOO_HIGH = 0x06070012
LENGTH_TOO_LOW = 0x06070013


def crc16(data: bytes, value: int = 0) -> int:
    """The SDO block transfer's CRC (CiA 301: CRC-16 CCITT, polynomial 0x1021, initial value 0)."""
    return binascii.crc_hqx(bytes(data), value)


class DriveSdoServer(SdoServer):
    """canopen's SDO server with block transfer, the protocol time-out and CiA 301's NMT gating."""

    def __init__(self, rx_cobid: int, tx_cobid: int, node) -> None:
        super().__init__(rx_cobid, tx_cobid, node)
        #: the transfer in progress: None, "upload", "download", "block upload", "block download"
        self._transfer: str | None = None
        self._timer = None
        self._block: dict = {}

    # ------------------------------------------------------------------ dispatch
    def on_request(self, can_id, data, timestamp):
        node = self._node
        if node.nmt._state in (NMT_STOPPED, NMT_INITIALISING) or not node.talking:
            return
        if len(data) != 8:
            return  # not an SDO request (CiA 301: always 8 bytes)
        data = bytes(data)
        try:
            if self._transfer == "block download" and self._block.get("receiving") and data[0] != 0x80:
                self._block_segment(data)
            elif self._transfer == "block upload" and data[0] >> 5 == 5:
                self._block_upload_step(data)
            elif self._transfer == "block download" and data[0] >> 5 == 6 and data[0] & 0x03 == 1:
                self._block_download_end(data)
            else:
                self._dispatch(data, can_id, timestamp)
        except SdoAbortedError as exc:
            self._finish()
            self.abort(exc.code)

    def _dispatch(self, data: bytes, can_id, timestamp) -> None:
        ccs = data[0] >> 5
        if ccs in (0, 3) and self._transfer not in ("upload", "download"):
            self._index, self._subindex = 0, 0
            raise SdoAbortedError(UNKNOWN_COMMAND)  # a segment outside a transfer
        if ccs == 4:  # the client aborts: whatever was going on ends
            self._finish()
            super().on_request(can_id, data, timestamp)
            return
        if ccs in (1, 2, 5, 6):  # a new transfer replaces one left unfinished
            self._finish()
        if ccs == 5:
            self._block_upload_initiate(data)
            return
        if ccs == 6:
            self._block_download_initiate(data)
            return
        if ccs == 1:
            self._check_download_size(data)
        if ccs not in (0, 1, 2, 3):
            _, self._index, self._subindex = SDO_STRUCT.unpack_from(data)
            raise SdoAbortedError(UNKNOWN_COMMAND)
        # expedited and segmented: canopen's server, which reports its own aborts (and ends the transfer)
        if ccs in (1, 2):
            self._transfer, self._buffer = ("download" if ccs == 1 else "upload"), None
        super().on_request(can_id, data, timestamp)
        if self._transfer is None:
            return  # aborted
        last_segment = (ccs == 0 and data[0] & 0x01) or (ccs == 3 and not self._buffer)
        expedited = (ccs == 1 and data[0] & 0x02) or (ccs == 2 and not self._buffer)
        if last_segment or expedited:
            self._finish()
        else:
            self._arm_timer()

    def abort(self, abort_code=0x08000000):
        self._finish()
        super().abort(abort_code)

    # ------------------------------------------------------------------ protocol time-out
    def _arm_timer(self) -> None:
        scheduler = getattr(self._node.simulator, "scheduler", None)
        if scheduler is None:
            return
        if self._timer is not None:
            self._timer.stop()
        self._timer = scheduler.call_at(self._node.simulator.clock.now() + PROTOCOL_TIMEOUT, self._timed_out)

    def _timed_out(self) -> None:
        self._timer = None
        if self._transfer is not None and self._node.talking:
            log.info("node %d: SDO %s of 0x%04X timed out", self._node.id, self._transfer, self._index or 0)
            self.abort(TIMED_OUT)

    def _finish(self) -> None:
        self._transfer = None
        self._block = {}
        if self._timer is not None:
            self._timer.stop()
            self._timer = None

    # ------------------------------------------------------------------ lengths
    def _check_download_size(self, data: bytes) -> None:
        """A download whose size the client states is checked against the object at once (as the
        segmented download's end would be)."""
        command, index, subindex = SDO_STRUCT.unpack_from(data)
        self._index, self._subindex = index, subindex
        if command & 0x02:
            size = 4 - ((command >> 2) & 0x3) if command & 0x01 else 4
        elif command & 0x01:
            (size,) = struct.unpack_from("<L", data, 4)
        else:
            return
        self._check_size(index, subindex, size)

    def _check_size(self, index: int, subindex: int, size: int) -> None:
        obj = self._node._find_object(index, subindex)
        if not obj.writable:
            raise SdoAbortedError(0x06010002)
        if obj.data_type in od_types.NUMBER_TYPES:
            expected = len(obj) // 8
            if size > expected:
                raise SdoAbortedError(LENGTH_TOO_HIGH)
            if size < expected:
                raise SdoAbortedError(LENGTH_TOO_LOW)

    # ------------------------------------------------------------------ block upload
    def _block_upload_initiate(self, data: bytes) -> None:
        command, index, subindex, blksize, _pst = struct.unpack_from("<BHBBB", data)
        self._index, self._subindex = index, subindex
        if command & 0x03 != 0:
            raise SdoAbortedError(UNKNOWN_COMMAND)
        if not 1 <= blksize <= MAX_BLOCK:
            raise SdoAbortedError(INVALID_BLOCK_SIZE)
        payload = bytes(self._node.get_data(index, subindex, check_readable=True))
        crc = bool(command & 0x04)
        self._transfer = "block upload"
        self._block = {"data": payload, "crc": crc, "blksize": blksize, "offset": 0, "sent": [], "started": False}
        response = bytearray(8)
        struct.pack_into("<BHBL", response, 0, 0xC0 | (0x04 if crc else 0) | 0x02, index, subindex, len(payload))
        self.send_response(response)
        self._arm_timer()

    def _block_upload_step(self, data: bytes) -> None:
        block = self._block
        cs = data[0] & 0x03
        if cs == 3 and not block["started"]:  # start upload
            block["started"] = True
            self._send_block()
        elif cs == 2 and block["started"]:  # block acknowledged
            ackseq, blksize = data[1], data[2]
            sent = block["sent"]
            if ackseq > len(sent):
                raise SdoAbortedError(INVALID_SEQUENCE)
            if not 1 <= blksize <= MAX_BLOCK:
                raise SdoAbortedError(INVALID_BLOCK_SIZE)
            # the segments after ackseq are sent again in the next block
            block["offset"] -= sum(len(chunk) for chunk in sent[ackseq:])
            block["blksize"] = blksize
            if block["offset"] >= len(block["data"]) and ackseq == len(sent) and block.get("last"):
                self._end_block_upload()
            else:
                self._send_block()
        elif cs == 1 and block.get("ended"):  # the client confirms the end
            self._finish()
        else:
            raise SdoAbortedError(UNKNOWN_COMMAND)
        if self._transfer is not None:
            self._arm_timer()

    def _send_block(self) -> None:
        block = self._block
        payload, offset = block["data"], block["offset"]
        block["sent"], block["last"] = [], False
        for seqno in range(1, block["blksize"] + 1):
            chunk = payload[offset : offset + 7]
            offset += len(chunk)
            last = offset >= len(payload)
            frame = bytearray(8)
            frame[0] = seqno | (0x80 if last else 0)
            frame[1 : 1 + len(chunk)] = chunk
            self.send_response(frame)
            block["sent"].append(chunk)
            if last:
                block["last"] = True
                break
        block["offset"] = offset

    def _end_block_upload(self) -> None:
        block = self._block
        payload = block["data"]
        tail = len(payload) % 7 or (7 if payload else 0)
        unused = 7 - tail
        response = bytearray(8)
        crc = crc16(payload) if block["crc"] else 0
        struct.pack_into("<BH", response, 0, 0xC1 | (unused << 2), crc)
        block["ended"] = True
        self.send_response(response)

    # ------------------------------------------------------------------ block download
    def _block_download_initiate(self, data: bytes) -> None:
        command, index, subindex = SDO_STRUCT.unpack_from(data)
        self._index, self._subindex = index, subindex
        if command & 0x01 != 0:
            raise SdoAbortedError(UNKNOWN_COMMAND)  # an end request without a transfer
        size = struct.unpack_from("<L", data, 4)[0] if command & 0x02 else None
        if size is not None:
            self._check_size(index, subindex, size)
        else:
            obj = self._node._find_object(index, subindex)
            if not obj.writable:
                raise SdoAbortedError(0x06010002)
        crc = bool(command & 0x04)
        self._transfer = "block download"
        self._block = {
            "crc": crc,
            "size": size,
            "received": bytearray(),
            "seqno": 0,
            "receiving": True,
            "blksize": MAX_BLOCK,
            "last": False,
        }
        response = bytearray(8)
        struct.pack_into("<BHBB", response, 0, 0xA0 | (0x04 if crc else 0), index, subindex, MAX_BLOCK)
        self.send_response(response)
        self._arm_timer()

    def _block_segment(self, data: bytes) -> None:
        block = self._block
        seqno, last = data[0] & 0x7F, bool(data[0] & 0x80)
        if seqno == block["seqno"] + 1:
            block["seqno"] = seqno
            block["received"] += data[1:8]
            block["last"] = last
        if last or seqno >= block["blksize"]:
            # acknowledge what arrived in order; the client repeats the rest
            acknowledged = block["seqno"]
            response = bytearray(8)
            response[0:3] = bytes([0xA2, acknowledged, MAX_BLOCK])
            block["seqno"] = 0
            if block["last"]:
                block["receiving"] = False
            self.send_response(response)
        self._arm_timer()

    def _block_download_end(self, data: bytes) -> None:
        block = self._block
        if block.get("receiving", True):
            raise SdoAbortedError(UNKNOWN_COMMAND)
        unused = (data[0] >> 2) & 0x07
        received = bytes(block["received"])
        payload = received[: len(received) - unused] if unused else received
        if block["size"] is not None and len(payload) != block["size"]:
            raise SdoAbortedError(LENGTH_TOO_HIGH if len(payload) > block["size"] else LENGTH_TOO_LOW)
        if block["crc"]:
            (crc,) = struct.unpack_from("<H", data, 1)
            if crc != crc16(payload):
                raise SdoAbortedError(CRC_ERROR)
        self._check_size(self._index, self._subindex, len(payload))
        self._node.set_data(self._index, self._subindex, payload, check_writable=True)
        response = bytearray(8)
        response[0] = 0xA1
        self._finish()
        self.send_response(response)
