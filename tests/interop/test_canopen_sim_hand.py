"""``surgiplan-sim-drives --hand``: the trainee's hand in the drives' own process (the assist loop's drives in a
process of their own, benchmarks/bench_assist.py), checked from outside with canopen's own SDO client and python-can.

The hand's time 0 is the first SYNC; an unpowered axis goes where the hand is, so the position actual value 0x6064
the drive reports follows the hand's path, in encoder counts of the device's joints."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest
from canopen_support import drives_process, master
from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice

INITIAL = [0.0, 0.6, 0.12, 0.0]


def counts_per_unit() -> np.ndarray:
    device = CastGimbalDevice(CastGimbalDevice.Settings.model_validate({}))
    device.model = device.build_model()
    return np.asarray(device.joints().counts_per_unit, dtype=float)


def test_an_unpowered_axis_follows_the_hand_from_the_first_sync(tmp_path):
    hand = tmp_path / "hand.npz"
    times = np.array([0.0, 0.4, 100.0])
    joints = np.array([INITIAL, [0.2, 0.6, 0.12, 0.0], [0.2, 0.6, 0.12, 0.0]])  # yaw 0 -> 0.2 rad in 0.4 s
    np.savez(hand, times=times, joints=joints)
    cpu = counts_per_unit()
    with drives_process(initial=INITIAL, extra=["--hand", str(hand)]) as port, master(port) as network:
        import canopen

        node = canopen.RemoteNode(1, None)
        network.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 1.0

        def yaw() -> int:  # position actual value 0x6064 (INTEGER32, counts), read by canopen's SDO client
            return int.from_bytes(node.sdo.upload(0x6064, 0)[:4], "little", signed=True)

        time.sleep(0.3)
        assert yaw() == round(INITIAL[0] * cpu[0])  # no SYNC yet: the hand has not started
        network.send_message(0x080, b"")  # the first SYNC: the hand's time 0
        sent = time.monotonic()
        time.sleep(1.0)
        after = yaw() / cpu[0]
        assert time.monotonic() - sent > 0.4
        assert after == pytest.approx(0.2, abs=1.5 / cpu[0])  # where the hand is (within an encoder count)


@pytest.mark.parametrize(
    "arrays, message",
    [
        ({"times": np.array([0.0, 1.0]), "joints": np.zeros((2, 3))}, "'joints' (2, 4) for the device's 4 axes"),
        ({"times": np.array([1.0, 0.0]), "joints": np.zeros((2, 4))}, "'times' must be increasing"),
        ({"t": np.array([0.0, 1.0])}, "not an .npz file with arrays 'times' and 'joints'"),
    ],
)
def test_a_bad_hand_file_is_refused_with_its_name_before_the_bus_opens(tmp_path, arrays, message):
    hand = tmp_path / "bad.npz"
    np.savez(hand, **arrays)
    command = [sys.executable, "-m", "surgiplan.plugins.devices.canopen.sim.process", "--channel", "1"]
    done = subprocess.run([*command, "--hand", str(hand)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert str(hand) in done.stderr and message in done.stderr and "Traceback" not in done.stderr
