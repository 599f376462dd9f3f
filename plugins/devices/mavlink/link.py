"""MAVLink 2 links: pymavlink connections, message signing, injected packet loss, errors.

Everything protocol-level (encoding, CRCs, sequence numbers, MAVLink 2
signing, serial/UDP/TCP transports) is pymavlink's; this module opens a
``mavutil`` connection in the form users know from MAVProxy and QGroundControl
(``udpin:127.0.0.1:14550``, ``udpout:127.0.0.1:14560``, ``tcp:127.0.0.1:5760``,
``/dev/ttyACM0``), makes sure MAVLink 2 is spoken, and adds what both ends of
surgiplan's links need: signing set up from a key in the settings, and (for
the simulated vehicle) packet loss injected in both directions.

MAVLink 2 signing (mavlink.io "Message Signing"): a 32-byte secret key shared
by both ends; every frame carries a 48-bit timestamp and a 48-bit SHA-256
signature. A key is given as 64 hexadecimal digits or as a passphrase, which
is hashed with SHA-256 as MAVProxy's ``signing setup`` does.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import select
import socket
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np
from surgiplan.errors import SurgiplanError

# pymavlink picks its wire protocol and dialect from the environment when mavutil is first
# imported; surgiplan needs MAVLink 2 (mission_type fields, signing). "common" is enough.
os.environ.setdefault("MAVLINK20", "1")
os.environ.setdefault("MAVLINK_DIALECT", "common")
from pymavlink import mavutil

if mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0":  # imported earlier by someone else for MAVLink 1
    os.environ["MAVLINK20"] = "1"
    mavutil.set_dialect(mavutil.current_dialect)

#: the generated dialect module (message classes, enums, constants)
mavlink = mavutil.mavlink

#: socket receive buffer asked for (bytes)
RECEIVE_BUFFER = 4 * 1024 * 1024

#: connection strings mavutil understands, as users write them
_CONNECTION = re.compile(r"^(?:(?:udpin|udpout|udp|udpbcast|tcp|tcpin|mcast):[^:\s]+:\d{1,5}|/\S+|COM\d+)$")


class VehicleError(SurgiplanError):
    """The vehicle cannot be reached, does not answer, or refuses; the message names the step.

    Attributes:
        step: what surgiplan was doing (``connect``, ``mission upload``, ``arming``, ...).
    """

    def __init__(self, message: str, *, step: str = "", **kwargs) -> None:
        self.step = step
        #: the message without the step
        self.detail = message
        super().__init__(f"{step}: {message}" if step else message, **kwargs)


def check_connection_string(text: str) -> str:
    """Validate a pymavlink connection string; ``ValueError`` lists the accepted forms."""
    if not _CONNECTION.match(text.strip()):
        raise ValueError(
            f"'{text}' is not a MAVLink connection string; use udpin:HOST:PORT (listen), udpout:HOST:PORT "
            "(send to), tcp:HOST:PORT, tcpin:HOST:PORT, or a serial device such as /dev/ttyACM0"
        )
    return text.strip()


def signing_key(text: str) -> bytes:
    """The 32-byte secret key: 64 hex digits as they are, anything else hashed (SHA-256) as a passphrase."""
    text = text.strip()
    if re.fullmatch(r"[0-9a-fA-F]{64}", text):
        return bytes.fromhex(text)
    if not text:
        raise ValueError("the signing key is empty")
    return hashlib.sha256(text.encode("utf-8")).digest()


def enum_name(enum: str, value: int) -> str:
    """``MAV_MISSION_NO_SPACE`` for ``("MAV_MISSION_RESULT", 4)``; the number when it is unknown."""
    entry = mavlink.enums.get(enum, {}).get(int(value))
    return entry.name if entry is not None else f"{enum}({int(value)})"


def enum_description(enum: str, value: int) -> str:
    entry = mavlink.enums.get(enum, {}).get(int(value))
    return (entry.description or "").strip().rstrip(".") if entry is not None else ""


def enum_value(enum: str, name: str | int) -> int:
    """The value of ``name`` (``"MAV_MISSION_DENIED"`` or ``"DENIED"``) in ``enum``; ``ValueError`` lists choices."""
    table = mavlink.enums[enum]
    if isinstance(name, int):
        if name in table:
            return name
        raise ValueError(f"{name} is not a {enum} value")
    wanted = name.strip().upper()
    for value, entry in table.items():
        if entry.name in (wanted, f"{enum}_{wanted}", f"MAV_MISSION_{wanted}", f"MAV_RESULT_{wanted}"):
            return int(value)
    names = ", ".join(e.name for v, e in sorted(table.items()) if not e.name.endswith("_ENUM_END"))
    raise ValueError(f"unknown {enum} '{name}'; choose one of: {names}")


@dataclass
class LinkStatistics:
    """What went over a link, per message type."""

    sent: Counter
    received: Counter
    dropped_out: int = 0
    dropped_in: int = 0
    #: frames pymavlink could not accept (bad CRC, bad or missing signature)
    rejected: int = 0

    def to_json(self) -> dict[str, Any]:
        return {
            "messages_sent": int(sum(self.sent.values())),
            "messages_received": int(sum(self.received.values())),
            "messages_dropped_out": self.dropped_out,
            "messages_dropped_in": self.dropped_in,
            "frames_rejected": self.rejected,
        }


class Endpoint:
    """One end of a MAVLink 2 link over a pymavlink ``mavutil`` connection.

    ``loss`` drops that fraction of the messages in *each* direction (seeded,
    independent draws): the simulated vehicle uses it to rehearse a poor radio
    link. Signing, when a key is given, signs everything sent and rejects
    every frame that is unsigned or signed with another key.
    """

    def __init__(
        self,
        connection: str,
        *,
        system_id: int,
        component_id: int,
        baud: int = 57600,
        key: bytes | None = None,
        link_id: int = 0,
        loss: float = 0.0,
        seed: int | None = None,
    ) -> None:
        self.connection = connection
        try:
            self.conn = mavutil.mavlink_connection(
                connection, baud=baud, source_system=system_id, source_component=component_id, input=False
            )
        except (OSError, ValueError) as exc:
            raise VehicleError(f"cannot open MAVLink connection '{connection}': {exc}", step="connect") from None
        self.mav = self.conn.mav
        self._bind_loopback(connection)
        self._enlarge_receive_buffer()
        self.stats = LinkStatistics(Counter(), Counter())
        self.loss = float(loss)
        self._rng = np.random.default_rng(seed)
        self._write = self.conn.write
        self.conn.write = self._lossy_write  # every send (pymavlink's mav.send) goes through here
        self.signed = key is not None
        #: the telemetry log being written (:mod:`.tlog`), if any: what is sent and what arrives
        self.tlog = None
        if key is not None:
            # no allow_unsigned_callback: an unsigned frame or a wrong signature is rejected
            self.conn.setup_signing(key, sign_outgoing=True, link_id=link_id)

    def _bind_loopback(self, connection: str) -> None:
        """``udpout`` to a loopback address: bind the socket to loopback too.

        pymavlink leaves a ``udpout`` socket unbound, and the kernel binds it to the wildcard address
        (every interface) at the first send; bound to 127.0.0.1 (or ::1) the link is loopback at both ends.
        """
        kind, _, rest = connection.partition(":")
        host = rest.rpartition(":")[0].strip("[]")
        sock = getattr(self.conn, "port", None)
        if kind != "udpout" or not isinstance(sock, socket.socket) or host not in ("127.0.0.1", "localhost", "::1"):
            return
        with contextlib.suppress(OSError):
            sock.bind(("::1" if host == "::1" else "127.0.0.1", 0))

    def _enlarge_receive_buffer(self) -> None:
        """Ask for a 4 MB socket receive buffer (the kernel caps it at net.core.rmem_max).

        The default (~200 kB, some 200 datagrams) overflows within a second when a busy
        machine delays the reader while a vehicle streams telemetry, and the kernel then
        drops datagrams silently, heartbeats among them.
        """
        sock = getattr(self.conn, "port", None)
        if isinstance(sock, socket.socket):
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)

    # ------------------------------------------------------------------ sending
    def _lossy_write(self, buf) -> None:
        if self.tlog is not None:  # what this end sent (a loss on the way is the link's)
            self.tlog.write(buf)
        if self.loss > 0 and self._rng.random() < self.loss:
            self.stats.dropped_out += 1
            return
        self._write(buf)

    def send(self, message) -> None:
        """Encode (and sign) ``message`` with pymavlink and send it."""
        self.stats.sent[message.get_type()] += 1
        self.mav.send(message)

    # ------------------------------------------------------------------ receiving
    @property
    def port(self) -> int | None:
        """The local UDP/TCP port (a ``udpin:...:0`` connection binds a free one)."""
        sock = getattr(self.conn, "port", None)
        try:
            return int(sock.getsockname()[1]) if sock is not None else None
        except (OSError, AttributeError):
            return None

    def wait(self, timeout: float) -> None:
        """Sleep until data arrives or ``timeout`` seconds pass."""
        fd = getattr(self.conn, "fd", None)
        if timeout <= 0:
            return
        if fd is None:
            time.sleep(min(timeout, 0.01))
            return
        try:
            select.select([fd], [], [], timeout)
        except (OSError, ValueError):
            time.sleep(min(timeout, 0.01))

    def receive(self, limit: int = 1000) -> list:
        """Every message that has arrived (at most ``limit``), without waiting."""
        out = []
        while len(out) < limit:
            try:
                message = self.conn.recv_msg()
            except (OSError, ValueError):
                break
            if message is None:
                break
            kind = message.get_type()
            if kind == "BAD_DATA":
                self.stats.rejected += 1
                continue
            if self.loss > 0 and self._rng.random() < self.loss:
                self.stats.dropped_in += 1
                continue
            self.stats.received[kind] += 1
            if self.tlog is not None:
                self.tlog.write(message.get_msgbuf())
            out.append(message)
        return out

    @property
    def lost_in(self) -> int:
        """Messages of the peer that never arrived, by the gaps in its MAVLink sequence numbers (pymavlink)."""
        return int(getattr(self.conn, "mav_loss", 0))

    @property
    def counted_in(self) -> int:
        """Messages that arrived and were counted for :attr:`lost_in`."""
        return int(getattr(self.conn, "mav_count", 0))

    @property
    def signature_rejections(self) -> int:
        signing = self.mav.signing
        return int(signing.reject_count + signing.badsig_count)

    def note(self, text: str) -> None:
        """A STATUSTEXT of this end written in the telemetry log only (never sent): a mark for a replay."""
        if self.tlog is not None:
            message = mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, text.encode()[:50])
            self.tlog.write(message.pack(self.mav))

    def close(self) -> None:
        try:
            self.conn.close()
        except Exception:  # closing must never hide the error that brought us here
            pass


def is_mavlink2(message) -> bool:
    """Whether a received message came in a MAVLink 2 frame."""
    buf = message.get_msgbuf()
    return bool(buf) and buf[0] == mavlink.PROTOCOL_MARKER_V2
