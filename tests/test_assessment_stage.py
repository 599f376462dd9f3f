"""A guide stage with an expert ghost and a task benchmark: the ghost keeps pace by progress (checked against the
record read with sqlite3), the stage reports its gate, the live feed carries the cues, and bad keys are errors."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest
import yaml
from assessment_support import guide_stage, pipeline
from surgiplan.guidance import TraineeRecord


def test_the_ghost_is_the_experts_best_attempt_keeping_pace_by_progress(ghosted):
    _, record, document = ghosted
    stage = document["stages"][1]
    db = sqlite3.connect(record)
    attempts = db.execute(
        "SELECT attempts.id, score, status, recommended_length_m FROM attempts JOIN trainees ON trainees.id = "
        "trainee_id WHERE name = 'ann' ORDER BY attempts.id"
    ).fetchall()
    best = max((a for a in attempts if a[2] == "completed"), key=lambda a: a[1])
    assert stage["metrics"]["ghost"] == {
        "trainee": "ann",
        "task": "bw",
        "attempt": attempts.index(best) + 1,
        "id": best[0],
        "score": best[1],
    }
    rows = np.array(
        db.execute("SELECT x, y, z, progress_m FROM samples WHERE attempt_id = ? ORDER BY i", (best[0],)).fetchall()
    )
    db.close()
    tips, reached = rows[:, :3], np.maximum.accumulate(rows[:, 3] / best[3])
    timeline = stage["annotations"]["timeline"]
    length = stage["metrics"]["recommended_length_m"]
    assert length != pytest.approx(best[3])  # the expert's path is another (shorter) one
    for progress, ghost in zip(timeline["progress"], timeline["ghost"], strict=True):
        # where ann was when she first covered the fraction of her path that eve has covered of hers
        f = progress / length
        j = int(np.argmax(reached >= f)) if reached[-1] >= f else len(reached)
        if j == 0:
            expected = tips[0]
        elif j == len(reached):
            expected = tips[-1]
        else:
            expected = tips[j - 1] + (f - reached[j - 1]) / (reached[j] - reached[j - 1]) * (tips[j] - tips[j - 1])
        np.testing.assert_allclose(ghost, expected, atol=1e-12)
    # the whole of the ghost's path goes to the report
    assert len(stage["annotations"]["ghost"]["tips"]) == len(tips)
    assert np.allclose(timeline["ghost"][0], tips[0]) and np.allclose(timeline["ghost"][-1], tips[-1], atol=1e-9)


def test_the_stage_reports_the_trainees_standing_at_the_tasks_gate(ghosted):
    _, record, document = ghosted
    gate = document["stages"][1]["metrics"]["gate"]
    with TraineeRecord(record) as r:
        benchmark = r.benchmark("bw")
        (attempt,) = r.history("eve", "bw")
        levels = r.levels()
    assert {k: levels[k] for k in ("ann", "ben", "eve")} == {"ann": "expert", "ben": "expert", "eve": "beginner"}
    assert set(benchmark.thresholds) == {"score", "duration_s"}
    assert gate["within"] == [benchmark.within(attempt["metrics"])] and gate["passed_at"] is None
    assert gate["last"]["score"]["value"] == document["stages"][1]["metrics"]["score"] == attempt["score"]


def test_the_live_feed_carries_the_cues_of_every_sample(tmp_path, ghosted):
    from surgiplan import load_pipeline, run_pipeline
    from surgiplan.live import LiveFeed

    _, record, _ = ghosted

    class Recorder(LiveFeed):
        active = True

        def __init__(self):
            self.messages = []

        def publish(self, channel, payload):
            self.messages.append((channel, dict(payload)))

    stage = guide_stage("attempt", "intermediate", 5, {"name": "cy", "task": "bw"}, ghost={"trainee": "ben"})
    path = pipeline(tmp_path, "live", "intermediate", [stage])
    data = yaml.safe_load(path.read_text())
    data["record"] = str(record)
    path.write_text(yaml.safe_dump(data))
    feed = Recorder()
    import surgiplan.runner as runner

    original = runner.StageContext
    runner.StageContext = lambda *a, **k: original(*a, **{**k, "live": feed})
    try:
        outcome = run_pipeline(load_pipeline(path))
    finally:
        runner.StageContext = original
    started = next(p for c, p in feed.messages if c == "stage")
    assert started["ghost"]["trainee"] == "ben" and len(started["ghost_path"]) > 100
    assert started["deviation_tolerance"] == pytest.approx(0.005)
    tips = [p for c, p in feed.messages if c == "tip"]
    assert len(tips) == outcome.results[1].metrics["samples"]
    for p in tips[::25]:
        # the closest path point is the deviation away, the ghost a point of ben's path
        assert np.linalg.norm(np.subtract(p["tip"], p["closest"])) == pytest.approx(p["deviation"], abs=1e-12)
        assert p["wall"] > 1e9 and len(p["ghost"]) == 3


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"ghost": {"trainee": "zed"}}, "pipeline[1].ghost: no trainee 'zed' in the record"),
        ({"ghost": {"trainee": "ann", "task": "suturing"}}, "pipeline[1].ghost: trainee 'ann' has no recorded attempt"),
        ({"ghost": {"trainee": "ann", "attempt": 9}}, "pipeline[1].ghost: trainee 'ann' has 2 attempt(s) at task 'bw'"),
        ({"ghost": {"trainee": "ann", "attempt": "worst"}}, "pipeline[1].ghost.attempt"),
        ({"assessment": {"idle_sped": 2}}, "pipeline[1].assessment.idle_sped: unknown key"),
        ({"assessment": {"port": "trocar"}}, "pipeline[1].assessment.port: no point named 'trocar' in the scene"),
        ({"assessment": {"weights": {"safety": -1}}}, "pipeline[1].assessment.weights.safety"),
    ],
)
def test_ghost_and_assessment_keys_are_checked_at_validation(tmp_path, cli, ghosted, change, message):
    _, record, _ = ghosted
    stage = guide_stage("attempt", "beginner", 7, {"name": "eve", "task": "bw"}, **change)
    path = pipeline(tmp_path, "bad", "beginner", [stage])
    data = yaml.safe_load(path.read_text())
    data["record"] = str(record)
    path.write_text(yaml.safe_dump(data))
    code, _, err = cli("validate", path)
    assert code == 2 and message in err and "Traceback" not in err, err
