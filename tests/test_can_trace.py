"""CAN traces (``record: {can: blf | asc | log}``) read back by python-can's own readers, replayed by
``python -m can.player``, and decoded by ``surgiplan can-decode`` against the simulated drives' ground truth.

Independent measures: python-can's ``LogReader`` (the readers CAN tools' formats are read with), the frames
the master logged while it ran, the positions the control loop measured, and the CiA 402 state transitions
the simulated drives made (their own record, not the bus).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
import time

import can
import numpy as np
import pytest
from devices_support import FULCRUM, GAP_TIPS, execute, gimbal_path, gimbal_space
from surgiplan.cli import main
from surgiplan.outputs.candecode import decode_trace, load_nodes
from test_can_loopback import free_port

SETTINGS = {"fulcrum": FULCRUM, "control_rate": 100}


def _run(block_world, tmp_path, fmt):
    from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice

    space = gimbal_space(block_world)
    report, truth = execute(
        CastGimbalDevice,
        {**SETTINGS, "record": {"can": fmt}},
        gimbal_path(space, GAP_TIPS),
        space,
        block_world,
        tmp_path,
    )
    assert report.status == "completed", report.message
    return tmp_path / f"execute.can.{fmt}", truth


@pytest.fixture(scope="module")
def blf_run(tmp_path_factory):
    from conftest import CONFIGS
    from surgiplan import load_scene

    tmp = tmp_path_factory.mktemp("trace")
    return _run(load_scene(CONFIGS / "scenes" / "block_world.yaml"), tmp, "blf")


@pytest.mark.parametrize("fmt", ["blf", "asc", "log"])
def test_the_trace_holds_every_frame_the_master_saw_read_back_by_python_can(block_world, tmp_path, fmt, blf_run):
    path, truth = blf_run if fmt == "blf" else _run(block_world, tmp_path, fmt)
    # an ASC trace's times are relative to its "Begin Triggerblock" date unless asked for absolute ones
    messages = list(can.LogReader(str(path), **({"relative_timestamp": False} if fmt == "asc" else {})))
    frames = truth["frames"]  # what the master logged up to the end of the trajectory
    # the trace goes on to the bus's release (disable, NMT pre-operational): the master's log is its start
    assert len(frames) > 500 and len(messages) > len(frames)
    assert [(m.arbitration_id, bytes(m.data)) for m in messages[: len(frames)]] == [(f[1], f[2]) for f in frames]
    # time stamps: the stage's clock, placed at the wall-clock time of the run (to the format's resolution)
    offsets = np.array([m.timestamp for m in messages[: len(frames)]]) - np.array([f[0] for f in frames])
    assert np.ptp(offsets) < (2e-3 if fmt == "asc" else 2e-6)  # ASC's trigger block date is to the ms
    assert abs(offsets[0] - time.time()) < 600
    if fmt != "log":  # candump's format has no direction
        sent = {0x000, 0x080, 0x77F} | {base + n for n in truth["node_ids"] for base in (0x200, 0x600)}
        assert all(m.is_rx == (m.arbitration_id not in sent) for m in messages)


def test_the_decoder_follows_the_pdo_mapping_and_sees_the_drives_states_and_positions(blf_run):
    from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice

    path, truth = blf_run
    device = CastGimbalDevice(CastGimbalDevice.Settings.model_validate(SETTINGS))
    drives = device.can_nodes()
    assert [n for n, _, _ in drives] == truth["node_ids"]
    frames = list(decode_trace(path, load_nodes({n: eds for n, _, eds in drives}, {n: j for n, j, _ in drives})))
    # the CiA 402 transitions the drives made (their own record) are the decoder's, in order, per node
    statusword = re.compile(r"Statusword(?: \[0x6041\.0\])? ?= ?0x[0-9A-F]{4} \(([A-Z ]+)\)")
    for node in truth["node_ids"]:
        # NOT READY TO SWITCH ON passes at power-up, before any frame could show it
        made = [to for _, n, _, to in truth["transitions"] if n == node and to != "NOT READY TO SWITCH ON"]
        seen = [
            statusword.search(f.text).group(1) for f in frames if f.node == node and f.event and "Statusword" in f.text
        ]
        assert len(made) >= 4 and seen[: len(made)] == made, (node, seen, made)
        assert seen[len(made) :] == ["READY TO SWITCH ON"]  # deactivate: shutdown (transition 8), after the truth
    # every position the control loop measured is a TPDO's position actual value, as the decoder reads it
    log, cpu = truth["log"], truth["counts_per_unit"]
    for k, node in enumerate(truth["node_ids"]):
        decoded = {
            int(f.text.split("Position actual value=")[1])
            for f in frames
            if f.node == node and f.kind == "TPDO1" and "Position actual value=" in f.text
        }
        measured = {round(v) for v in log.measured[:, k] * cpu[k]}
        assert measured <= decoded, node
    # the configuration: written by SDO, by name, and confirmed
    texts = [f.text for f in frames]
    assert any("write Modes of operation [0x6060.0] = 8" in t for t in texts)
    assert any("written TPDO1 mapping parameter.Mapped object 2 [0x1A00.2]" in t for t in texts)
    assert not [f for f in frames if f.kind == "other"]


def test_can_decode_command_by_device_name(blf_run, capsys):
    path, _ = blf_run
    assert main(["can-decode", str(path), "--device", "cast_gimbal", "--events"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert any("NMT" in line and "start -> node 1 (yaw)" in line for line in out)
    assert sum("OPERATION ENABLED" in line for line in out) == 4  # one per drive
    total = int(out[-1].split()[0])
    assert total == len(list(can.LogReader(str(path))))


@pytest.mark.parametrize(
    "args, message",
    [
        (["missing.blf"], "no such trace"),
        (["TRACE", "--device", "no_such_device"], "no_such_device"),
        (["TRACE", "--eds", "x=missing.eds"], "NODE=FILE"),
        (["TRACE", "--eds", "3=missing.eds"], "no such EDS file"),
    ],
)
def test_can_decode_refuses_bad_input_with_a_message(blf_run, capsys, args, message):
    args = [str(blf_run[0]) if a == "TRACE" else a for a in args]
    assert main(["can-decode", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


@pytest.mark.parametrize(
    "name, content",
    [
        ("bad.asc", b"date Thu Nov 26\nbase hex timestamps absolute\n  0.1 1 xyz Rx d 9 00\n"),  # no frame
        ("bad.blf", b"LOGG" + bytes(range(200))),  # a BLF header that is not one
        ("bad.log", b"(1.0) can0 12G#00\n"),
    ],
)
def test_a_file_that_is_not_a_trace_is_refused(tmp_path, capsys, name, content):
    bad = tmp_path / name
    bad.write_bytes(content)
    assert main(["can-decode", str(bad)]) == 2
    err = capsys.readouterr().err
    assert name in err and "Traceback" not in err


def test_can_player_replays_the_trace_onto_a_bus(blf_run):
    path, _ = blf_run
    expected = [(m.arbitration_id, bytes(m.data)) for m in can.LogReader(str(path))]
    port = free_port()
    received = []
    with can.Bus(interface="loopback", channel=str(port)) as bus:
        done = threading.Event()

        def collect():
            deadline = time.monotonic() + 60
            while not done.is_set() and time.monotonic() < deadline and len(received) < len(expected):
                msg = bus.recv(0.2)
                if msg is not None:
                    received.append((msg.arbitration_id, bytes(msg.data)))

        thread = threading.Thread(target=collect, daemon=True)
        thread.start()
        env = {**os.environ, "PYTHONWARNINGS": "ignore"}
        result = subprocess.run(
            [sys.executable, "-m", "can.player", "-i", "loopback", "-c", str(port), str(path)],
            capture_output=True,
            text=True,
            timeout=60,
            env=env,
        )
        assert result.returncode == 0, result.stderr
        thread.join(10)
        done.set()
    assert received == expected
