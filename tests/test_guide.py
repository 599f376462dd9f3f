"""Trainee guidance (the guide stage): per-sample measures against independent references, exact events,
the attempt report, the trainee record (crash-safe, proficiency), and bad input."""

from __future__ import annotations

import csv
import itertools
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import coal
import numpy as np
import pytest
import yaml
from conftest import CONFIGS, ROOT
from surgiplan import load_scene
from surgiplan.guidance import GuidanceSettings, Guide, PoseSample, TraineeRecord
from surgiplan.spaces import R3Space

SCENE = CONFIGS / "scenes" / "block_world.yaml"


def guide_pipeline(tmp_path, source="synthetic_trainee", settings=None, guidance=None, trainee=None, **extra):
    stages = [
        {
            "stage": "plan",
            "name": "recommended",
            "plugin": "safe_prm",
            "settings": {"proficiency": "beginner", "milestones": 800, "seed": 1},
            "start": "entry",
            "goal": "target",
        },
        {
            "stage": "guide",
            "name": "attempt",
            "plugin": source,
            "path_from": "recommended",
            "settings": settings if settings is not None else {"level": "beginner", "seed": 7, "pace": 0},
            **({"guidance": guidance} if guidance else {}),
            **({"trainee": trainee} if trainee else {}),
        },
    ]
    data = {
        "name": "guide-probe",
        "length_unit": "mm",
        "scene": str(SCENE),
        "pipeline": stages,
        "output": {"dir": str(tmp_path / "out"), "gltf": False},
        "record": str(tmp_path / "record.sqlite"),
        **extra,
    }
    path = tmp_path / "guide.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def attempt(tmp_path_factory):
    """One synthetic beginner's attempt, run from the command line (CSV, figure, record)."""
    from surgiplan.cli import main

    tmp = tmp_path_factory.mktemp("attempt")
    code = main(["run", str(guide_pipeline(tmp, trainee={"name": "alice", "task": "block-world"})), "--quiet"])
    assert code == 0
    document = json.loads((tmp / "out" / "result.json").read_text())
    return tmp, document


def read_samples(path: Path) -> dict[str, np.ndarray]:
    with path.open() as handle:
        rows = list(csv.DictReader(handle))
    return {key: np.array([float(r[key]) for r in rows]) for key in rows[0]}


def test_every_samples_deviation_and_clearance_re_measured_independently(attempt):
    tmp, document = attempt
    plan, guide = document["stages"]
    assert guide["status"] == "completed" and guide["metrics"]["reached_goal"]
    samples = read_samples(tmp / "out" / "attempt-samples.csv")
    tips = np.column_stack([samples["x_m"], samples["y_m"], samples["z_m"]])
    assert len(tips) == guide["metrics"]["samples"] > 500
    # deviation: brute force, the recommended polyline sampled every 2 micrometres, nearest sample
    path = np.asarray(plan["path"])
    dense = np.concatenate(
        [
            np.linspace(a, b, max(2, int(np.ceil(np.linalg.norm(b - a) / 2e-6))), endpoint=False)
            for a, b in itertools.pairwise(path)
        ]
        + [path[-1:]]
    )
    from scipy.spatial import cKDTree

    brute, _ = cKDTree(dense).query(tips)
    np.testing.assert_allclose(samples["deviation_m"], brute, atol=1.5e-6)
    # clearance: coal's distance from the tip (a point) to each box, where the tip is outside every box
    scene = load_scene(SCENE)
    boxes = []
    for o in scene.obstacles:
        shape = coal.Box(*o.size)
        boxes.append((shape, coal.Transform3s(o.pose.rotation, o.pose.translation)))
    point = coal.Sphere(1e-12)
    request, result = coal.DistanceRequest(), coal.DistanceResult()
    outside = samples["clearance_m"] > 1e-6
    assert outside.sum() > 0.9 * len(tips)
    for tip, mine in zip(tips[outside][::7], samples["clearance_m"][outside][::7], strict=True):
        distances = []
        for shape, pose in boxes:
            result.clear()
            distances.append(coal.distance(point, coal.Transform3s(np.eye(3), tip), shape, pose, request, result))
        assert mine == pytest.approx(min(distances), abs=1e-9)
    # inside a block (the beginner's contacts): negative, and the tip is inside that box
    for tip in tips[samples["clearance_m"] < 0]:
        assert any(np.all(np.abs(tip - o.pose.translation) < np.asarray(o.size) / 2) for o in scene.obstacles)


def test_the_attempts_metrics_follow_from_its_samples(attempt):
    tmp, document = attempt
    guide = document["stages"][1]
    m = guide["metrics"]
    samples = read_samples(tmp / "out" / "attempt-samples.csv")
    tips = np.column_stack([samples["x_m"], samples["y_m"], samples["z_m"]])
    assert m["path_length_m"] == pytest.approx(np.linalg.norm(np.diff(tips, axis=0), axis=1).sum(), rel=1e-7)
    assert m["deviation_rms_m"] == pytest.approx(np.sqrt(np.mean(samples["deviation_m"] ** 2)), rel=1e-6)
    assert m["deviation_max_m"] == pytest.approx(samples["deviation_m"].max(), rel=1e-6)
    assert m["min_clearance_m"] == pytest.approx(samples["clearance_m"].min(), rel=1e-6)
    low = (samples["clearance_m"] < 0.008) & (samples["critical"] == 0)
    both = low[:-1] & low[1:]
    assert m["below_threshold_s"] == pytest.approx(np.diff(samples["t_s"])[both].sum(), abs=1e-6)
    events = guide["annotations"]["events"]
    assert m["contacts"] == sum(e["kind"] == "contact" for e in events)
    # the score: the documented terms (docs/assessment.md), from the samples, weighted by the default weights
    length, duration = m["recommended_length_m"], samples["t_s"][-1] - samples["t_s"][0]
    steps = np.linalg.norm(np.diff(tips, axis=0), axis=1)
    idle = np.diff(samples["t_s"])[steps < 0.002 * np.diff(samples["t_s"])].sum()
    assert m["idle_s"] == pytest.approx(idle, abs=1e-9) and m["economy"] == pytest.approx(steps.sum() / length)
    expected = {
        "safety": max(0.0, 1 - m["below_threshold_m"] / length - 0.25 * m["contacts"]),
        "accuracy": np.exp(-m["deviation_rms_m"] / 0.005),
        "economy": min(1.0, length / steps.sum()),
        "time": min(1.0, length / 0.025 / duration),
        "idle": 1 - idle / duration,
        "smoothness": min(1.0, np.exp(-(abs(m["sparc"]) - 1) / 4)),
        "corrections": 1 / (1 + m["corrections"] / (100 * length)),
    }
    weights = {"safety": 0.3, "accuracy": 0.2, "economy": 0.1, "time": 0.1, "idle": 0.05, "smoothness": 0.1}
    weights["corrections"] = 0.1  # no depth term: an r3 source without a port measures no insertion
    assert m["score_terms"] == pytest.approx(expected) and m["score_weights"] == pytest.approx(weights)
    mean = sum(weights[k] * expected[k] for k in expected) / sum(weights.values())
    assert m["score"] == pytest.approx(100 * m["completion"] * mean)
    assert {"attempt.png", "attempt-samples.csv"} <= set(guide["files"])
    assert m["latency_median_ms"] < m["latency_max_ms"]  # measured, per sample (values: benchmarks/bench_guide.py)


# ----------------------------------------------------------------------------- events, exactly


@pytest.fixture
def straight(block_world):
    """The straight recommended path entry -> target (y 50, z 20) through the three gaps."""
    space = R3Space(block_world)
    path = np.array([[0.010, 0.050, 0.020], [0.140, 0.050, 0.020]])
    return space, path


def walk(times, y_offset=lambda x: 0.0, speed=0.02, x0=0.010, x1=0.140, stop=None, back=None):
    """Samples at 100 Hz along y = 50 mm, with y_offset(x) (m) added; optional stop/back behaviour."""
    out, x = [], x0
    for t in times:
        out.append(PoseSample(t, tip=np.array([x, 0.050 + y_offset(x), 0.020])))
        if stop and stop[0] <= t < stop[1]:
            continue
        if back and back[0] <= t < back[1]:
            x -= speed * 0.01
            continue
        x = min(x1, x + speed * 0.01)
    return out


def run_guide(space, path, scene, samples, critical, threshold=0.004, **settings):
    guide = Guide(space, path, scene, threshold, critical, GuidanceSettings(**settings), unit="mm")
    for s in samples:
        guide.measure(s)
    return guide, guide.finish()


def critical_interval(scene, path, threshold, x_max):
    """Where the straight path keeps less than the threshold before x_max: what safe_prm reports as the
    critical region of a gap with no detour (arc-length interval, m)."""
    x = np.linspace(path[0, 0], x_max, 20001)
    tips = np.column_stack([x, np.full_like(x, path[0, 1]), np.full_like(x, path[0, 2])])
    low = x[scene.clearance(tips) < threshold]
    return (float(low.min() - path[0, 0]), float(low.max() - path[0, 0]))


def stretches(times, mask):
    """(first, last) time of each run of True."""
    out, start, last = [], None, None
    for t, m in zip(times, mask, strict=True):
        if m and start is None:
            start = t
        if not m and start is not None:
            out.append((start, last))
            start = None
        last = t
    if start is not None:
        out.append((start, last))
    return out


def test_an_excursion_below_d_thresh_outside_a_critical_region_is_flagged_with_its_start_and_end(straight, block_world):
    space, path = straight
    times = np.arange(0, 8, 0.01)
    # move 3 mm towards B2 while x is between 72 and 78 mm: 3 mm from B2's face (y 56), below the 4 mm threshold
    samples = walk(times, lambda x: 0.003 if 0.072 <= x <= 0.078 else 0.0)
    # the left gap (6 mm, no way around) is the recommended path's critical region
    critical = critical_interval(block_world, path, 0.004, 0.060)
    _, events = run_guide(space, path, block_world, samples, critical=[critical], deviation_tolerance=0.005)
    below = [e for e in events if e.kind == "below_threshold"]
    # expected, measured independently: coal-checked scene clearances of the samples, outside the left gap
    tips = np.array([s.tip for s in samples])
    clearance = block_world.clearance(tips)
    progress = tips[:, 0] - path[0, 0]
    outside = ~((progress >= critical[0]) & (progress <= critical[1]))
    expected = stretches([s.t for s in samples], (clearance < 0.004) & outside)
    # the excursion by B2, and the right gap (7 mm: the straight path keeps 3.5 mm there, and it is not critical)
    assert len(expected) == 2 and [(e.start_t, e.end_t) for e in below] == expected
    inside_excursion = [s.t for s in samples if 0.072 <= s.tip[0] <= 0.078]
    assert expected[0] == (inside_excursion[0], inside_excursion[-1])
    assert below[0].worst == pytest.approx(0.003, abs=1e-12)
    assert "closer than d_thresh 4 mm outside a critical region (down to 3 mm)" in below[0].message
    # in the left gap the path is at 3 mm too, but there no detour exists: no event there
    assert not [e for e in events if e.start_progress_m <= critical[1]]
    assert not [e for e in events if e.kind in ("deviation", "contact", "wrong_way", "stalled")]


def test_the_same_excursion_inside_the_critical_region_is_not_flagged(straight, block_world):
    space, path = straight
    times = np.arange(0, 8, 0.01)
    samples = walk(times, lambda x: 0.001 if 0.037 <= x <= 0.043 else 0.0)  # 2 mm from A2 in the left gap
    critical = critical_interval(block_world, path, 0.004, 0.060)
    guide, events = run_guide(space, path, block_world, samples, critical=[critical])
    assert not [e for e in events if e.kind == "below_threshold" and e.start_progress_m <= critical[1]]
    in_gap = [m for m in guide.measurements if 0.037 <= m.tip[0] <= 0.043]
    assert all(m.critical for m in in_gap) and min(m.clearance for m in in_gap) == pytest.approx(0.002, abs=1e-12)
    # the very same excursion with no critical region there is flagged
    _, events = run_guide(space, path, block_world, samples, critical=[])
    assert [e for e in events if e.kind == "below_threshold" and e.start_progress_m <= critical[1]]


def test_contact_deviation_wrong_way_and_stall_events(straight, block_world):
    space, path = straight
    times = np.arange(0, 12, 0.01)
    # 4.5 mm into A1's side of the gap (contact), then 2 s standing still, then 10 mm backwards
    samples = walk(times, lambda x: -0.0045 if 0.038 <= x <= 0.040 else 0.0, stop=(3.0, 5.5), back=(6.0, 6.6))
    guide, events = run_guide(
        space,
        path,
        block_world,
        samples,
        critical=[(0.024, 0.036)],
        deviation_tolerance=0.004,
        stall_time=2.0,
        stall_distance=0.001,
        wrong_way=0.005,
    )
    kinds = {e.kind: e for e in events}
    contact = [s.t for s in samples if 0.038 <= s.tip[0] <= 0.040 and s.tip[1] < 0.047]
    assert (kinds["contact"].start_t, kinds["contact"].end_t) == (contact[0], contact[-1])
    assert kinds["contact"].worst == pytest.approx(-0.0015, abs=1e-12)
    assert kinds["deviation"].worst == pytest.approx(0.0045, abs=1e-12)
    # stalled from the moment 2 s of standing still have passed until the tip moves again
    stalled = [e for e in events if e.kind == "stalled"]
    assert len(stalled) == 1  # not while going the wrong way
    # standing from t = 3.0 (20 mm/s, so 1 mm is 0.05 s of motion): less than 1 mm in 2 s from t = 4.96 on
    assert stalled[0].start_t == pytest.approx(4.96, abs=1e-9) and 5.5 < stalled[0].end_t < 5.6
    # backwards at 20 mm/s from t = 6.0: more than 5 mm behind after 0.25 s
    assert kinds["wrong_way"].start_t == pytest.approx(6.26, abs=0.011)
    assert kinds["wrong_way"].worst == pytest.approx(0.012, abs=2e-4)
    assert guide.reached_goal


# ----------------------------------------------------------------------------- the record


def test_proficiency_from_the_record_is_the_percentile_by_hand(attempt, tmp_path):
    tmp, _ = attempt
    samples = read_samples(tmp / "out" / "attempt-samples.csv")
    with TraineeRecord(tmp / "record.sqlite") as record:
        p = record.proficiency("alice", "block-world", percentile=90)
        assert p.attempts == 1 and p.samples == len(samples["t_s"])
        assert p.d_thresh == pytest.approx(np.percentile(samples["deviation_m"], 90), rel=1e-7)
        stored = record.samples(record.attempts("alice")[0]["id"])
        np.testing.assert_allclose(stored["deviation"], samples["deviation_m"], rtol=1e-8)
        assert record.attempts("alice")[0]["status"] == "completed"
        with pytest.raises(Exception, match=r"no trainee 'bob' in the record .*choose one of: alice"):
            record.proficiency("bob", "block-world")
        with pytest.raises(
            Exception, match=r"has no recorded attempt at task 'suturing' in .*; recorded tasks: block-world"
        ):
            record.proficiency("alice", "suturing")


def test_surgiplan_trainee_prints_the_history_and_writes_a_progression_figure(attempt, cli):
    tmp, _ = attempt
    code, out, err = cli("trainee", "alice", "--record", tmp / "record.sqlite", "--json")
    assert code == 0, err
    report = json.loads(out)
    assert len(report["attempts"]) == 1 and report["attempts"][0]["task"] == "block-world"
    assert Path(report["figure"]).is_file() and Path(report["figure"]).stat().st_size > 20_000
    code, _, err = cli("trainee", "bob", "--record", tmp / "record.sqlite")
    assert code == 2 and "no trainee 'bob'" in err and "alice" in err and "Traceback" not in err
    code, _, err = cli("trainee", "alice", "--record", tmp / "none.sqlite")
    assert code == 2 and "no trainee record at" in err


@pytest.mark.slow
def test_the_record_survives_kill_9_mid_attempt_with_every_committed_attempt_intact(tmp_path):
    trainee = {"name": "alice", "task": "block-world"}
    output = {"dir": str(tmp_path / "out"), "gltf": False, "figures": False}  # the record is what is checked
    first = guide_pipeline(tmp_path, trainee=trainee, output=output)
    done = subprocess.run(
        [sys.executable, "-m", "surgiplan.cli", "run", str(first), "--quiet"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    with TraineeRecord(tmp_path / "record.sqlite") as record:
        before = record.attempts("alice")
        samples_before = len(record.samples(before[0]["id"])["t"])
    # the next attempt in real time (pace 1: about 18 s), killed a second into it
    slow = guide_pipeline(
        tmp_path,
        settings={"level": "beginner", "seed": 8, "pace": 1},
        trainee=trainee,
        output={**output, "dir": str(tmp_path / "out2")},
    )
    process = subprocess.Popen(
        [sys.executable, "-m", "surgiplan.cli", "run", str(slow), "--quiet"],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    # mid-attempt: the run's marker lists the plan stage as done (the guide stage is running), a second later
    marker, stages = tmp_path / "out2" / ".in-progress.json", []
    deadline = time.monotonic() + 120
    while stages != ["recommended"] and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
        try:
            stages = [s["name"] for s in json.loads(marker.read_text())["stages_so_far"]]
        except (OSError, ValueError):  # not written yet (it is replaced atomically)
            pass
    assert stages == ["recommended"], stages
    time.sleep(1)
    assert process.poll() is None
    os.kill(process.pid, signal.SIGKILL)
    process.wait(timeout=10)
    db = sqlite3.connect(tmp_path / "record.sqlite")
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    db.close()
    with TraineeRecord(tmp_path / "record.sqlite") as record:
        after = record.attempts("alice")
        assert [a["id"] for a in after] == [a["id"] for a in before]  # the killed attempt left nothing
        assert len(record.samples(after[0]["id"])["t"]) == samples_before


# ----------------------------------------------------------------------------- sources and bad input


def test_a_recorded_attempt_replays_and_measures_the_same_as_live(attempt, tmp_path, cli):
    tmp, document = attempt
    replay = guide_pipeline(
        tmp_path, source="recorded_attempt", settings={"file": str(tmp / "out" / "attempt-samples.csv"), "speed": 0}
    )
    code, _, err = cli("run", replay, "--quiet")
    assert code == 0, err
    again = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][1]
    first = document["stages"][1]
    for key in ("deviation_rms_m", "min_clearance_m", "path_length_m", "below_threshold_s", "score"):
        assert again["metrics"][key] == pytest.approx(first["metrics"][key], rel=1e-6, abs=1e-9), key
    assert [e["kind"] for e in again["annotations"]["events"]] == [e["kind"] for e in first["annotations"]["events"]]


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("t,x,y\n0,1,2\n", "the header needs t and either x, y, z or yaw, pitch, insertion, roll; missing z"),
        ("time,x,y,z\n0,1,2,3\n", "no time column 't'"),
        ("t,x,y,z\n0,10,50,20\n0.2,11,50,20\n0.1,12,50,20\n", "attempt.csv:4: time 0.1 s does not increase"),
        ("t,x,y,z\n0,10,50,20\n0.1,eleven,50,20\n", "attempt.csv:3: expected numbers in columns t, x, y, z"),
        ("t,x_in,y,z\n0,1,2,3\n", "unknown unit 'in' in column 'x_in'"),
        ("t,x,y,z\n0,10,50,20\n", "an attempt needs at least 2 samples, found 1"),
    ],
    ids=["missing-column", "no-time", "time-backwards", "not-a-number", "unknown-unit", "one-sample"],
)
def test_a_bad_attempt_file_is_a_clear_error_at_validation(tmp_path, cli, content, message):
    (tmp_path / "attempt.csv").write_text(content)
    path = guide_pipeline(tmp_path, source="recorded_attempt", settings={"file": "attempt.csv"})
    code, _, err = cli("validate", path)
    assert code == 2 and message in err and "pipeline[1].settings" in err and "Traceback" not in err


@pytest.fixture
def hostile_source(tmp_path, monkeypatch):
    plugins = Path(__file__).resolve().parent / "plugins"
    site = tmp_path / "site"
    info = site / "surgiplan_hostile-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: surgiplan-hostile\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[surgiplan]\nhostile = surgiplan_hostile\n")
    monkeypatch.syspath_prepend(str(plugins))
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setenv("SURGIPLAN_PLUGIN_PACKAGES", "surgiplan,surgiplan-hostile")
    from surgiplan import registry

    registry.reset_default_registry()


@pytest.mark.parametrize(
    ("mode", "status", "message"),
    [
        ("silent", "stopped", "source 'hostile_source' sent no pose for 0.5 s (guidance.silence_timeout)"),
        ("stops", "stopped", "source 'hostile_source' stopped: the tracker lost the instrument"),
        ("backwards", "invalid_result", "sample time 0.05 s is before the previous sample's 0.2 s"),
    ],
)
def test_a_source_that_stops_or_misbehaves_ends_the_attempt_with_the_reason(
    tmp_path, cli, hostile_source, mode, status, message
):
    path = guide_pipeline(tmp_path, source="hostile_source", settings={"mode": mode}, guidance={"silence_timeout": 0.5})
    code, _, err = cli("run", path, "--quiet")
    assert code == 1 and "Traceback" not in err
    stage = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][1]
    assert stage["status"] == status and message in stage["message"], stage["message"]


def test_guide_stage_keys_are_checked(tmp_path, cli):
    path = guide_pipeline(tmp_path, guidance={"deviation_tolerence": 4})
    code, _, err = cli("validate", path)
    assert code == 2 and "pipeline[1].guidance.deviation_tolerence: unknown key" in err
    data = yaml.safe_load(path.read_text())
    data["pipeline"][0]["trainee"] = {"name": "a", "task": "b"}
    data["pipeline"][1].pop("guidance")
    path.write_text(yaml.safe_dump(data))
    code, _, err = cli("validate", path)
    assert code == 2 and "trainee applies to guide stages only, not to plan stages" in err


def test_live_feed_gets_every_sample_and_each_event(block_world, tmp_path):
    from surgiplan import load_pipeline, run_pipeline
    from surgiplan.live import LiveFeed

    class Recorder(LiveFeed):
        active = True

        def __init__(self):
            self.messages = []

        def publish(self, channel, payload):
            self.messages.append((channel, dict(payload)))

    feed = Recorder()
    pipeline = load_pipeline(guide_pipeline(tmp_path))
    import surgiplan.runner as runner

    original = runner.StageContext

    def with_feed(*args, **kwargs):
        return original(*args, **{**kwargs, "live": feed})

    runner.StageContext = with_feed
    try:
        outcome = run_pipeline(pipeline)
    finally:
        runner.StageContext = original
    guide = outcome.results[1]
    channels = [c for c, _ in feed.messages]
    assert channels[0] == "stage" and channels[-1] == "status"
    assert channels.count("tip") == guide.metrics["samples"]
    starts = [p for c, p in feed.messages if c == "event" and p["change"] == "start"]
    assert len(starts) == len(guide.annotations["events"])
    assert feed.messages[0][1]["recommended"] == guide.annotations["recommended_tips"]


def test_the_next_recommended_path_adapts_to_the_recorded_trainee(attempt, tmp_path, cli):
    """proficiency: {trainee, task, percentile}: d_thresh is the percentile of the trainee's recorded deviations."""
    tmp, _ = attempt
    samples = read_samples(tmp / "out" / "attempt-samples.csv")
    data = yaml.safe_load(guide_pipeline(tmp_path).read_text())
    data["record"] = str(tmp / "record.sqlite")
    data["pipeline"] = data["pipeline"][:1]
    data["pipeline"][0]["settings"]["proficiency"] = {"trainee": "alice", "task": "block-world", "percentile": 80}
    path = tmp_path / "next.yaml"
    path.write_text(yaml.safe_dump(data))
    code, _, err = cli("run", path, "--quiet")
    assert code == 0, err
    plan = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][0]
    assert plan["metrics"]["d_thresh_m"] == pytest.approx(np.percentile(samples["deviation_m"], 80), rel=1e-7)
    assert plan["metrics"]["trainee"]["attempts"] == 1
    assert plan["metrics"]["clearance_threshold_m"] == plan["metrics"]["d_thresh_m"]
    data["pipeline"][0]["settings"]["proficiency"]["trainee"] = "bob"
    path.write_text(yaml.safe_dump(data))
    code, _, err = cli("validate", path)
    assert code == 2 and "pipeline[0].settings.proficiency" in err and "no trainee 'bob'" in err


def test_the_synthetic_hand_stays_inside_the_trainer_box():
    """A recommended path along the box's lid: the drift would carry half of the beginner's samples through it
    (a run of bench_cues ended invalid_result, a sample 0.1 mm above the lid); the box's walls stop the tip."""
    from surgiplan.guidance import TraineeModel, synthetic_attempt

    lo, hi = np.zeros(3), np.array([0.15, 0.10, 0.04])
    tips = np.array([[0.01, 0.05, 0.04], [0.14, 0.05, 0.04]])
    model = TraineeModel(level="beginner", seed=3)
    _, free = synthetic_attempt(tips, model)
    times, held = synthetic_attempt(tips, model, (lo, hi))
    assert (free[:, 2] > hi[2] + 1e-4).mean() > 0.2, "without the walls the drift leaves the box"
    assert np.all(held >= lo) and np.all(held <= hi)
    inside = np.all((free >= lo) & (free <= hi), axis=1)
    np.testing.assert_array_equal(held[inside], free[inside])  # the walls change nothing inside the box
    np.testing.assert_allclose(held[:, 2], np.minimum(free[:, 2], hi[2]))
    assert len(times) == len(held)
