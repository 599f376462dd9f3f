#!/usr/bin/env python

"""
This module tests the context manager of Bus and Notifier classes
"""

# Vendored from python-can 4.6.1 (test/contextmanager_test.py), LGPL-3.0: see __init__.py and LICENSE.txt.
# Adapted only where the interface is selected, marked "surgiplan:": interface="loopback" (was "virtual")
# with a fresh port as the channel (python-can's opens both on virtual's default channel).

import unittest

import can

from . import free_port  # surgiplan


class ContextManagerTest(unittest.TestCase):
    def setUp(self):
        data = [0, 1, 2, 3, 4, 5, 6, 7]
        self.msg_send = can.Message(
            is_extended_id=False, arbitration_id=0x100, data=data
        )

    def test_open_buses(self):
        channel = free_port()  # surgiplan
        with (
            can.Bus(channel, interface="loopback") as bus_send,  # surgiplan: was interface="virtual"
            can.Bus(channel, interface="loopback") as bus_recv,  # surgiplan: was interface="virtual"
        ):
            bus_send.send(self.msg_send)
            msg_recv = bus_recv.recv()

            # Receiving a frame with data should evaluate msg_recv to True
            self.assertTrue(msg_recv)

    def test_use_closed_bus(self):
        channel = free_port()  # surgiplan
        with (
            can.Bus(channel, interface="loopback") as bus_send,  # surgiplan: was interface="virtual"
            can.Bus(channel, interface="loopback") as bus_recv,  # surgiplan: was interface="virtual"
        ):
            bus_send.send(self.msg_send)

        # Receiving a frame after bus has been closed should raise a CanException
        self.assertRaises(can.CanError, bus_recv.recv)
        self.assertRaises(can.CanError, bus_send.send, self.msg_send)


if __name__ == "__main__":
    unittest.main()
