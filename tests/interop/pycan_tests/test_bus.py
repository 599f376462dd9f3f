# Vendored from python-can 4.6.1 (test/test_bus.py), LGPL-3.0: see __init__.py and LICENSE.txt.
# Adapted only where the interface is selected, marked "surgiplan:": interface="loopback" (was "virtual", whose
# channel has a default) on a fresh port.
import gc
from unittest.mock import patch

import can

from . import free_port  # surgiplan


def test_bus_ignore_config():
    with patch.object(
        target=can.util, attribute="load_config", side_effect=can.util.load_config
    ):
        _ = can.Bus(interface="loopback", channel=free_port(), ignore_config=True)  # surgiplan
        assert not can.util.load_config.called

        _ = can.Bus(interface="loopback", channel=free_port())  # surgiplan
        assert can.util.load_config.called


@patch.object(can.bus.BusABC, "shutdown")
def test_bus_attempts_self_cleanup(mock_shutdown):
    bus = can.Bus(interface="loopback", channel=free_port())  # surgiplan
    del bus
    gc.collect()
    mock_shutdown.assert_called()
