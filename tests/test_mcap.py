"""A run as MCAP, read back with the mcap reader and Foxglove's protobuf schemas (mcap-protobuf-support): every
channel, its schema, its message count and time range, and the values against the run's own CSV files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from gimbal_guide_support import FULCRUM
from pipeline_support import block_world_pipeline, safe_prm_stage

mcap_reader = pytest.importorskip("mcap.reader", reason="the mcap extra")
decoder = pytest.importorskip("mcap_protobuf.decoder", reason="the mcap extra")
pytest.importorskip("foxglove", reason="the mcap extra")


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    """One run for the module: a plan in the gimbal's space, the gimbal executing it, an attempt following it."""
    from surgiplan import load_pipeline, run_pipeline

    tmp_path = tmp_path_factory.mktemp("mcap")
    stages = [
        safe_prm_stage(
            "plan", 1500, "intermediate", start=[60, 50, 20], space={"kind": "cast_gimbal", "fulcrum": FULCRUM}
        ),
        {"stage": "execute", "name": "gimbal", "plugin": "cast_gimbal", "settings": {"control_rate": 100}},
        {"stage": "guide", "name": "attempt", "plugin": "synthetic_trainee", "settings": {"seed": 3, "pace": 0}},
    ]
    path = block_world_pipeline(tmp_path / "p.yaml", "mcap-probe", stages, tmp_path / "out")
    assert run_pipeline(load_pipeline(path)).ok
    return tmp_path / "out"


class JsonDecoders:
    """The mcap reader's decoder factory for JSON channels (protobuf ones: mcap-protobuf-support's)."""

    def decoder_for(self, message_encoding, schema):
        return json.loads if message_encoding == "json" else None


def read(path):
    with open(path, "rb") as f:
        reader = mcap_reader.make_reader(f, decoder_factories=[decoder.DecoderFactory(), JsonDecoders()])
        summary = reader.get_summary()
        channels = {
            c.topic: (
                summary.schemas[c.schema_id].name,
                c.message_encoding,
                summary.statistics.channel_message_counts[i],
            )
            for i, c in summary.channels.items()
        }
        messages: dict[str, list] = {}
        for _, channel, message, decoded in reader.iter_decoded_messages():
            messages.setdefault(channel.topic, []).append((message.log_time, decoded))
    return channels, messages


def test_a_run_exports_as_mcap_that_the_mcap_reader_and_foxglove_schemas_read_back(cli, out):
    code, stdout, err = cli("export", "mcap", out)
    assert code == 0, err
    channels, messages = read(out / "mcap-probe.mcap")
    samples = np.genfromtxt(out / "attempt-samples.csv", delimiter=",", names=True)
    execution = np.genfromtxt(out / "gimbal-execution.csv", delimiter=",", names=True)
    n_attempt, n_gimbal = len(samples), len(execution)
    assert channels == {
        "/scene": ("foxglove.SceneUpdate", "protobuf", 1),
        "/plan/plan": ("foxglove.SceneUpdate", "protobuf", 1),
        "/gimbal/reference": ("foxglove.SceneUpdate", "protobuf", 1),
        "/gimbal/tip": ("foxglove.PoseInFrame", "protobuf", n_gimbal),
        "/gimbal/joints": ("foxglove.JointStates", "protobuf", n_gimbal),
        "/attempt/reference": ("foxglove.SceneUpdate", "protobuf", 1),
        "/attempt/tip": ("foxglove.PoseInFrame", "protobuf", n_attempt),
        "/attempt/measures": ("surgiplan.Measures", "json", n_attempt),
        **(
            {"/attempt/events": ("foxglove.Log", "protobuf", channels["/attempt/events"][2])}
            if "/attempt/events" in channels
            else {}
        ),
    }
    # the scene: the six blocks as triangle meshes (12 triangles a box) and the bounds
    [(_, scene)] = messages["/scene"]
    blocks = [e for e in scene.entities if e.id.startswith("obstacle:")]
    assert sorted(e.id for e in blocks) == [f"obstacle:{n}" for n in ("A1", "A2", "B1", "B2", "C1", "C2")]
    assert all(len(e.triangles[0].indices) == 36 for e in blocks)
    # the gimbal's samples: tips and joints as its CSV has them, on one clock after the plan (1 s gap)
    times = np.array([t for t, _ in messages["/gimbal/tip"]]) * 1e-9
    np.testing.assert_allclose(times, 1.0 + execution["t_s"] - execution["t_s"][0], atol=1e-9)
    tips = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for _, m in messages["/gimbal/tip"]])
    np.testing.assert_allclose(tips, np.column_stack([execution[f"tip_{a}_m"] for a in "xyz"]), atol=1e-12)
    first = messages["/gimbal/joints"][0][1]
    names = [j.name for j in first.joints]
    assert names == ["yaw", "pitch", "insertion", "roll"]
    np.testing.assert_allclose([j.position for j in first.joints], [execution[f"measured_{n}"][0] for n in names])
    # the attempt: after the gimbal's last sample and a 1 s gap; deviation and clearance as its CSV
    attempt_times = np.array([t for t, _ in messages["/attempt/tip"]]) * 1e-9
    assert attempt_times[0] == pytest.approx(times[-1] + 1.0, abs=1e-9)
    measures = [m for _, m in messages["/attempt/measures"]]
    np.testing.assert_allclose([m["deviation_m"] for m in measures], samples["deviation_m"], atol=1e-12)
    np.testing.assert_allclose([m["clearance_m"] for m in measures], samples["clearance_m"], atol=1e-12)
    assert "/attempt/tip: " in stdout


def test_one_attempt_alone_and_a_bad_directory(cli, out, tmp_path):
    code, _, err = cli("export", "mcap", out, "--stage", "attempt")
    assert code == 0, err
    channels, _ = read(out / "attempt.mcap")
    assert {t for t in channels} >= {"/scene", "/attempt/tip", "/attempt/measures"}
    assert not any(t.startswith("/gimbal") or t.startswith("/plan") for t in channels)
    code, _, err = cli("export", "mcap", out, "--stage", "atempt")
    assert code == 2 and "no stage named 'atempt'; did you mean 'attempt'?" in err
    assert not list(out.glob(".*.tmp")), "no half-written file"
    code, _, err = cli("export", "mcap", tmp_path)
    assert code == 2 and "has no result.json" in err
