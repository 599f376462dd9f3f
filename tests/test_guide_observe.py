"""The CAST gimbal as a pose source in observe mode: nothing commanded on the bus, the encoder positions are
where the (simulated) hand put the axes, and the whole shaft's clearance matches coal."""

from __future__ import annotations

import json
import struct

import coal
import numpy as np
import pytest
import yaml
from gimbal_guide_support import gimbal_guide_pipeline, open_source
from surgiplan import load_pipeline, run_pipeline


def gimbal_pipeline(tmp_path, guide_settings=None):
    settings = guide_settings or {"hand": {"level": "intermediate", "seed": 2}, "control_rate": 100}
    return gimbal_guide_pipeline(tmp_path, "observe", settings)


@pytest.fixture(scope="module")
def observed(tmp_path_factory):
    """The source driven directly (as the guide stage does), so that its bus log can be read before closing."""
    tmp = tmp_path_factory.mktemp("observe")
    pipeline = load_pipeline(gimbal_pipeline(tmp))
    plan_only = load_pipeline(gimbal_pipeline(tmp))
    plan_only.stages = plan_only.stages[:1]
    plan = run_pipeline(plan_only).results[0]
    spec = pipeline.stages[1]
    space = pipeline.stages[0].space
    source = open_source(tmp, plan, space, spec, plan.clearance_threshold)
    truth = source.device.simulator
    samples, hand = [], []
    for sample in source.samples():
        samples.append(sample)
        hand.append(truth.hand(source.origin + sample.t))  # where the hand held the axes at that SYNC
    frames = list(source.device.bus.frames)
    node_ids = [a.node_id for a in source.device.master.axes]
    cpu = source.cpu.copy()
    source.close()
    return space, samples, np.array(hand), frames, node_ids, cpu


def test_observe_mode_sends_no_motion_command(observed):
    _, samples, _, frames, node_ids, _ = observed
    ids = [f[1] for f in frames]
    # no RPDO at all (controlword, target position): 0x200 + node id
    assert not [i for i in ids if i in {0x200 + n for n in node_ids}]
    # no SDO download to the controlword or any target object (0x6040, 0x607A, 0x60FF, 0x6071)
    written = []
    for _, cob, data in frames:
        if cob in {0x600 + n for n in node_ids} and len(data) >= 4 and data[0] >> 5 == 1:  # download initiate
            written.append(struct.unpack_from("<H", data, 1)[0])
    assert not {0x6040, 0x607A, 0x60FF, 0x6071} & set(written)
    assert written, "the start-up configures the drives by SDO"
    # the standard start-up happened (reset communication, start), then SYNCs and one TPDO per drive per SYNC
    assert (0x000, bytes([0x82, node_ids[0]])) in [(f[1], f[2]) for f in frames]
    syncs = ids.count(0x080)
    assert syncs >= len(samples)
    for n in node_ids:
        assert ids.count(0x180 + n) >= len(samples)


def test_the_samples_are_where_the_hand_held_the_axes(observed):
    _, samples, hand, _, _, cpu = observed
    q = np.array([s.q for s in samples])
    assert len(samples) > 300
    # the encoders quantise to 1/counts_per_unit; each sample is the position latched at its SYNC
    counts = np.abs(q - hand) * cpu
    assert counts.max() <= 0.5 + 1e-6, np.argwhere(counts > 0.5 + 1e-6)[:10]
    assert np.all(np.diff([s.t for s in samples]) > 0)


def test_the_whole_shafts_clearance_matches_coal(observed, block_world):
    space, samples, _, _, _, _ = observed
    boxes = [(coal.Box(*o.size), coal.Transform3s(o.pose.rotation, o.pose.translation)) for o in block_world.obstacles]
    request, result = coal.DistanceRequest(), coal.DistanceResult()
    radius = space.shaft_radius
    for sample in samples[::25]:
        q = sample.q
        tip = space.tip(q[None])[0]
        axis = tip - space.fulcrum
        length = float(np.linalg.norm(axis))
        z = axis / length
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
        rotation = np.column_stack([x, np.cross(z, x), z])
        shaft = coal.Capsule(radius, length)
        pose = coal.Transform3s(rotation, space.fulcrum + axis / 2)
        distances = []
        for box, where in boxes:
            result.clear()
            distances.append(coal.distance(shaft, pose, box, where, request, result))
        reference = min(distances)
        mine = float(space.clearance(q[None])[0])
        if reference > 1e-4:  # coal's penetration depths are estimates; positive distances are exact
            assert mine == pytest.approx(reference, abs=1e-6)
        else:
            assert mine <= 1e-4


def test_the_guide_stage_follows_the_gimbal_and_records_it(tmp_path, cli):
    path = gimbal_pipeline(tmp_path)
    data = yaml.safe_load(path.read_text())
    data["pipeline"][1]["trainee"] = {"name": "dana", "task": "gimbal"}
    path.write_text(yaml.safe_dump(data))
    code, _, err = cli("run", path, "--quiet")
    stage = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][1]
    assert stage["plugin"] == "cast_gimbal" and stage["status"] in ("completed", "incomplete"), stage["message"]
    assert stage["metrics"]["samples"] > 300 and stage["metrics"]["record"]["trainee"] == "dana"
    assert code in (0, 1), err


def test_a_hand_on_real_drives_is_refused(tmp_path, cli):
    path = gimbal_pipeline(
        tmp_path, {"bus": {"interface": "socketcan", "channel": "can0"}, "hand": {"level": "beginner"}}
    )
    code, _, err = cli("validate", path)
    assert code == 2 and "hand: moves simulated drives" in err and "pipeline[1].settings" in err


@pytest.mark.parametrize(
    ("fault", "reason"),
    [
        ({"kind": "dead_node", "node": 2, "at_s": 1.0}, "no TPDO from CAN node 2"),
        ({"kind": "bus_off", "at_s": 1.0}, "the CAN bus failed"),
    ],
)
def test_a_drive_or_bus_that_stops_answering_stops_the_attempt_with_the_reason(tmp_path, cli, fault, reason):
    path = gimbal_pipeline(
        tmp_path, {"hand": {"level": "intermediate", "seed": 2}, "control_rate": 100, "bus": {"faults": [fault]}}
    )
    code, _, _ = cli("run", path, "--quiet")
    stage = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][1]
    assert code == 1
    assert stage["status"] == "stopped" and reason in stage["message"], stage["message"]
    # what arrived before the fault is still scored: about a second of samples at 100 Hz
    assert 80 <= stage["metrics"]["samples"] <= 120, stage["metrics"]["samples"]
