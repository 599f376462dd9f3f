"""python-can's own interface tests, run against surgiplan's ``loopback`` interface.

Vendored from the python-can 4.6.1 sdist (``python_can-4.6.1.tar.gz`` on PyPI, directory ``test/``), the
version pinned in the venv when they were taken; python-can is licensed LGPL-3.0 (``LICENSE.txt`` here).
Taken unchanged except where python-can's tests select the interface (each file says where in its header):

* ``back2back_test.py``: ``Back2BackTestCase`` and ``TestThreadSafeBus`` open ``loopback`` buses on a fresh
  port per test instead of ``virtual`` on ``virtual_channel_0``; the subclasses for other interfaces
  (socketcan, udp_multicast, etas) and ``SocketCanBroadcastChannel`` are left out (udp_multicast would
  send to a multicast group: loopback only here);
* ``test_interface.py``: the interface fixture takes ``loopback`` only (python-can's: every backend);
* ``contextmanager_test.py``, ``notifier_test.py``, ``test_message_filtering.py``, ``test_bus.py``:
  ``interface="virtual"`` is ``interface="loopback"`` and the channels (``"test"``, ``0``, ``1``,
  ``"testy"``, none) are ports on 127.0.0.1.

``config.py`` and ``data/`` are python-can's, unchanged. The variant with ``receive_own_messages=True`` (the
loopback docstring's promise) is ``tests/interop/test_python_can_loopback.py``, ours.
"""

from __future__ import annotations

import socket

#: the python-can version these files were taken from
PYTHON_CAN_VERSION = "4.6.1"


def free_ports(count: int = 1) -> list[int]:
    """``count`` distinct free TCP ports on 127.0.0.1: the channels of loopback buses."""
    socks = [socket.socket(socket.AF_INET, socket.SOCK_STREAM) for _ in range(count)]
    try:
        for sock in socks:
            sock.bind(("127.0.0.1", 0))
        return [sock.getsockname()[1] for sock in socks]
    finally:
        for sock in socks:
            sock.close()


def free_port() -> int:
    return free_ports(1)[0]
