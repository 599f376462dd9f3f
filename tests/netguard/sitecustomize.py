"""Loopback-only network guard for the test suite and every Python process it starts.

The suite's conftest installs :func:`install` in the test process and puts
this directory first on ``PYTHONPATH``, so every Python subprocess the tests
start (simulated drives, the simulated vehicle, executor workers) imports it
as ``sitecustomize`` and is guarded too. An audit hook (PEP 578) sees every
``socket.bind``, ``socket.connect``, ``socket.sendto`` and ``socket.sendmsg``
before it happens; an address that is not loopback (127.0.0.0/8, ::1,
``localhost``), including a wildcard bind (all interfaces) and any multicast
group, is refused (the call raises) and recorded in the file named by
``SURGIPLAN_NETGUARD_LOG``, which the conftest reads after each test and
fails the test with.

UNIX, netlink and CAN sockets (local by nature) pass.
"""

from __future__ import annotations

import ipaddress
import os
import socket
import sys
import traceback

_installed = False


class NetworkPolicyError(RuntimeError):
    """A test tried to send or listen on a non-loopback address."""


def loopback(host) -> bool:
    if isinstance(host, bytes):
        host = host.decode(errors="replace")
    if not isinstance(host, str):
        return False
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.split("%")[0]).is_loopback
    except ValueError:
        return False


def _check(event: str, args: tuple) -> None:
    if event not in ("socket.bind", "socket.connect", "socket.sendto", "socket.sendmsg"):
        return
    sock, address = args[0], args[1]
    family = getattr(sock, "family", None)
    if family not in (socket.AF_INET, socket.AF_INET6) or address is None:
        return
    host = address[0] if isinstance(address, tuple) and address else address
    if loopback(host):
        return
    message = f"{event} to {address!r} from pid {os.getpid()} ({' '.join(sys.argv)[:200]})"
    log = os.environ.get("SURGIPLAN_NETGUARD_LOG")
    if log:
        stack = "".join(traceback.format_stack(limit=12)[:-2])
        with open(log, "a") as handle:
            handle.write(f"{message}\n{stack}\n---\n")
    raise NetworkPolicyError(f"network guard: {message}: tests send only to 127.0.0.1 / ::1")


def install() -> None:
    global _installed
    if not _installed:
        sys.addaudithook(_check)
        _installed = True


if os.environ.get("SURGIPLAN_NETGUARD_LOG"):
    install()
