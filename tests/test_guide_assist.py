"""Haptic guidance (``cast_gimbal`` source ``mode: assist``): cyclic synchronous torque in the simulated drives,
τ = Jᵀ F against a hand computation, the wall at the threshold, the fade schedule, and the safety rules asserted
on the captured bus traffic."""

from __future__ import annotations

import json
import struct
import warnings

import coal
import numpy as np
import pytest
import yaml
from conftest import CONFIGS
from gimbal_guide_support import gimbal_guide_pipeline, open_source
from surgiplan import load_pipeline, run_pipeline
from surgiplan.guidance import SourceStopped
from surgiplan.guidance.fixture import FixtureSettings, VirtualFixture, assistance_level
from surgiplan.plugins.devices.canopen.sim.statemachine import SOD
from surgiplan.plugins.devices.cast_gimbal import CastGimbalDevice, CastGimbalDeviceSettings
from surgiplan.plugins.devices.cast_gimbal.assist import TorqueLaw

RATE = 250.0  # Hz: small tests


def assist_pipeline(tmp_path, settings=None, trainee=None):
    guide = {
        "hand": {"level": "beginner", "seed": 2},
        "control_rate": RATE,
        "mode": "assist",
        "max_duration": 1.6,  # s: the attempt's first part is enough here (small tests)
        **(settings or {}),
    }
    # the roadmap built once per test, loaded by a second run
    return gimbal_guide_pipeline(tmp_path, "assist", guide, trainee, artifact=tmp_path / "roadmap.npz")


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("assist-plan")
    plan_only = load_pipeline(assist_pipeline(tmp))
    plan_only.stages = plan_only.stages[:1]
    return run_pipeline(plan_only).results[0], plan_only.stages[0].space


def run_source(tmp, planned, settings=None, during=None):
    """The assist source driven as the guide stage drives it; ``during(source, k)`` at each sample. Returns the
    source's samples, the captured frames, the node ids, the simulator and the source (closed)."""
    plan, space = planned
    pipeline = load_pipeline(assist_pipeline(tmp, settings))
    spec = pipeline.stages[1]
    from surgiplan.clearance import intervals, threshold_value

    critical = intervals(list(plan.critical_regions))
    source = open_source(tmp, plan, space, spec, threshold_value(plan.clearance_threshold), critical)
    truth = source.device.simulator
    node_ids = [a.node_id for a in source.device.master.axes]
    device, bus = source.device, source.device.bus
    samples = []
    try:
        for k, sample in enumerate(source.samples()):
            samples.append(sample)
            if during is not None:
                during(source, k)
    except SourceStopped as exc:  # the attempt stops (a drive gone silent for pdo_timeout_cycles)
        source.stopped = str(exc)
    finally:
        source.close()
    return samples, list(bus.frames), node_ids, truth, source, device


def rpdos(frames, node_ids):
    """(time, node, controlword, target torque) of every RPDO1 on the bus."""
    out = []
    for t, cob, data in frames:
        if cob - 0x200 in node_ids and len(data) == 4:
            cw, torque = struct.unpack("<Hh", bytes(data))
            out.append((t, cob - 0x200, cw, torque))
    return out


def sdo_downloads(frames, node_ids):
    """(node, index, sub, value) of every expedited SDO download the master sent."""
    out = []
    for _, cob, data in frames:
        if cob - 0x600 in node_ids and len(data) == 8 and data[0] >> 5 == 1 and data[0] & 0x02:
            size = 4 - ((data[0] >> 2) & 0x3) if data[0] & 0x1 else 4
            value = int.from_bytes(bytes(data[4 : 4 + size]), "little")
            out.append((cob - 0x600, struct.unpack_from("<H", bytes(data), 1)[0], data[3], value))
    return out


# ----------------------------------------------------------------------------- the motor model in torque mode
def test_a_constant_torque_accelerates_the_axis_as_inertia_and_friction_say():
    """CST on one simulated axis against the closed form of J v' = τ − b v − c (from rest, τ > c)."""
    import can
    from surgiplan.plugins.devices.canopen.bus import ArmedFaults
    from surgiplan.plugins.devices.canopen.clock import SimulatedClock
    from surgiplan.plugins.devices.canopen.sim.drives import AxisHardware, DriveSimulator
    from surgiplan.plugins.devices.canopen.sim.motor import MotorModel
    from surgiplan.plugins.devices.canopen.sim.statemachine import OE

    clock = SimulatedClock()
    bus = can.Bus(interface="virtual", channel="cst-motor-test")
    axis = AxisHardware(1, 1e4, 100.0, 50.0, rated_torque=0.1, gear_ratio=10.0, inertia=0.01, viscous_friction=0.02,
                        coulomb_friction=0.05)  # fmt: skip
    sim = DriveSimulator(bus, [axis], MotorModel(sync_timeout=10.0), clock, ArmedFaults([], clock.now), None)
    try:
        sim.mode[0], sim.state[0] = 10, OE
        sim.target_torque[0] = 300  # 0.3 of the rated 0.1 N·m, times 10: 0.3 N·m at the joint
        sim.advance(clock.now() + 1.0)
        tau, b, c, inertia = 0.3, 0.02, 0.05, 0.01
        expected = (tau - c) / b * (1 - np.exp(-b * 1.0 / inertia))
        assert sim.vel[0] == pytest.approx(expected, rel=2e-3)
        assert sim.torque_actual[0] == 300
        sim.target_torque[0] = 5000  # above the max torque (0x6072 = the peak 3000): clipped to it
        sim.advance(clock.now() + 1.001)
        assert sim.torque_actual[0] == 3000
        sim.target_torque[0] = 40  # 0.04 N·m below the Coulomb friction: a still axis stays still
        sim.vel[0] = 0.0
        p = sim.pos[0]
        sim.advance(clock.now() + 1.5)
        assert sim.vel[0] == 0.0 and sim.pos[0] == p
    finally:
        sim.close()


# ----------------------------------------------------------------------------- τ = Jᵀ F by hand
def _gimbal(space):
    from scipy.spatial.transform import Rotation

    with warnings.catch_warnings():  # at pitch +-90 deg any split of roll and yaw is the same frame
        warnings.simplefilter("ignore", UserWarning)
        rpy = Rotation.from_matrix(space.frame).as_euler("xyz")
    settings = CastGimbalDeviceSettings.model_validate(
        {"fulcrum": {"xyz": space.fulcrum.tolist(), "rpy": rpy.tolist()}}
    )
    device = CastGimbalDevice(settings)
    device.model = device.build_model()
    return device


def _jacobian_by_differences(space, q, h=1e-7):
    """∂tip/∂q of the gimbal's closed-form kinematics (surgiplan.spaces.CastGimbalSpace.tip), not Pinocchio's."""
    columns = []
    for j in range(4):
        step = np.zeros(4)
        step[j] = h
        columns.append((space.tip((q + step)[None])[0] - space.tip((q - step)[None])[0]) / (2 * h))
    return np.stack(columns, axis=1)


def test_a_known_offset_from_the_path_gives_the_hand_computed_joint_torques(planned):
    _, space = planned
    device = _gimbal(space)
    q = np.array([0.3, 0.9, 0.14, 0.2])
    tip = space.tip(q[None])[0]
    # a straight path 4 mm beside the tip, perpendicular to the offset
    offset = np.array([0.0, 0.0, 1.0])
    along = np.array([1.0, 0.0, 0.0])
    centre = tip + 0.004 * offset
    tips = centre + np.linspace(-0.05, 0.05, 201)[:, None] * along
    settings = FixtureSettings(stiffness=200.0, damping=5.0, max_force=10.0)
    fixture = VirtualFixture(tips, [], None, settings)
    motors = device.joints().motors
    unit = motors["rated_torque"] * motors["gear_ratio"] / 1000.0
    law = TorqueLaw(device.model, fixture, space.scene, space.fulcrum, space.shaft_radius, unit, cap=3000)
    tau, info = law.joint_torque(q, np.zeros(4))
    force = 200.0 * 0.004 * offset  # k times the offset, toward the path: 0.8 N
    assert info["guide"] == pytest.approx(force, abs=1e-9)
    expected = _jacobian_by_differences(space, q).T @ force
    assert tau == pytest.approx(expected, rel=1e-5, abs=1e-9)
    # the drives' units: thousandths of 0.1 N·m rated through 10:1 (yaw, pitch), 100 N/N·m (insertion), 5:1 (roll)
    per_mille = law.per_mille(tau)
    assert per_mille[:3] == pytest.approx(np.rint(expected[:3] / np.array([1e-3, 1e-3, 1e-2])), abs=0)
    # the damper brakes motion across the path only: a velocity along the path adds nothing
    qd = np.linalg.lstsq(_jacobian_by_differences(space, q), 0.05 * along, rcond=None)[0]
    tau_moving, _ = law.joint_torque(q, qd)
    assert tau_moving == pytest.approx(expected, rel=1e-4, abs=1e-6)
    # ... a velocity across it is damped: F = k e - b v_perp
    qd = np.linalg.lstsq(_jacobian_by_differences(space, q), 0.02 * offset, rcond=None)[0]
    _tau_across, info = law.joint_torque(q, qd)
    assert info["guide"] == pytest.approx(force - 5.0 * 0.02 * offset, abs=1e-6)


def test_the_wall_engages_exactly_below_the_threshold_and_pushes_the_shaft_away(planned, block_world):
    _, space = planned
    device = _gimbal(space)
    q = np.array([0.03, 0.7, 0.15, 0.0])  # the shaft nearer one block of a pair than the other
    tip = space.tip(q[None])[0]
    clearance = float(space.clearance(q[None])[0])
    assert 0.0 < clearance < 0.05
    tips = tip + np.linspace(0.0, 0.01, 11)[:, None] * np.array([1.0, 0.0, 0.0])  # the tip is on the path
    settings = FixtureSettings(wall_stiffness=1000.0)
    law = lambda threshold: TorqueLaw(  # noqa: E731
        device.model, VirtualFixture(tips, [], threshold, settings), space.scene, space.fulcrum, space.shaft_radius,
        np.ones(4), cap=3000,
    )  # fmt: skip
    _, above = law(clearance - 1e-6).joint_torque(q, np.zeros(4))
    assert not above["wall"].any()  # clearance above d_thresh: no wall
    _, exact = law(clearance).joint_torque(q, np.zeros(4))
    assert not exact["wall"].any()  # at d_thresh: not below it
    tau, below = law(clearance + 0.002).joint_torque(q, np.zeros(4))
    assert np.linalg.norm(below["wall"]) == pytest.approx(1000.0 * 0.002, rel=1e-6)
    # its direction: from coal's nearest points, the obstacle's toward the shaft's (independent of our distances)
    radius = space.shaft_radius
    axis = tip - space.fulcrum
    length = float(np.linalg.norm(axis))
    z = axis / length
    x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    pose = coal.Transform3s(np.column_stack([x, np.cross(z, x), z]), space.fulcrum + axis / 2)
    best = None
    for o in block_world.obstacles:
        request, result = coal.DistanceRequest(), coal.DistanceResult()
        d = coal.distance(coal.Capsule(radius, length), pose, coal.Box(*o.size),
                          coal.Transform3s(o.pose.rotation, o.pose.translation), request, result)  # fmt: skip
        if best is None or d < best[0]:
            best = (d, np.array(result.getNearestPoint1()), np.array(result.getNearestPoint2()))
    d, on_shaft, on_box = best
    assert d == pytest.approx(clearance, abs=1e-6)
    away = (on_shaft - on_box) / np.linalg.norm(on_shaft - on_box)
    assert float(np.dot(below["wall"] / np.linalg.norm(below["wall"]), away)) > 0.995
    # and the torques move the shaft away: a small step along τ increases the clearance
    step = 1e-4 * tau / np.linalg.norm(tau)
    assert float(space.clearance((q + step)[None])[0]) > clearance


def test_inside_a_critical_region_the_wall_keeps_the_critical_clearance():
    tips = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    fixture = VirtualFixture(tips, [(0.02, 0.05)], 0.006, FixtureSettings(critical_clearance=0.001))
    assert fixture.wall_limit(0.01) == 0.006
    assert fixture.wall_limit(0.03) == 0.001
    assert fixture.wall_limit(0.07) == 0.006


def test_the_assistance_fades_on_the_documented_schedule():
    s = FixtureSettings(full_at=0.008, none_at=0.002, minimum=0.2)
    assert assistance_level(None, s) == 1.0  # no recorded attempt: full help
    assert assistance_level(0.010, s) == 1.0
    assert assistance_level(0.008, s) == 1.0
    assert assistance_level(0.005, s) == pytest.approx(0.5)
    assert assistance_level(0.0035, s) == pytest.approx(0.25)
    assert assistance_level(0.0025, s) == pytest.approx(0.2)  # the floor
    assert assistance_level(0.001, s) == pytest.approx(0.2)
    assert assistance_level(0.001, FixtureSettings(fade="none")) == 1.0
    fixture = VirtualFixture(np.eye(3)[:2], [], None, FixtureSettings(stiffness=100.0, damping=4.0), level=0.5)
    assert (fixture.k, fixture.c) == (50.0, 2.0)


# ----------------------------------------------------------------------------- safety on the bus traffic
@pytest.fixture(scope="module")
def assisted(tmp_path_factory, planned):
    return run_source(tmp_path_factory.mktemp("assisted"), planned, {"assist": {"torque_cap": 800}})


def test_every_torque_on_the_bus_is_within_the_cap_and_the_drives_end_switch_on_disabled(assisted):
    samples, frames, node_ids, truth, source, _ = assisted
    assert len(samples) > 200
    sent = rpdos(frames, node_ids)
    torques = np.array([r[3] for r in sent])
    assert np.abs(torques).max() <= 800
    assert np.count_nonzero(torques) > 100  # it did push
    # the cap went to max torque 0x6072, and mode CST (10) to 0x6060, by SDO at start-up
    downloads = sdo_downloads(frames, node_ids)
    for n in node_ids:
        assert (n, 0x6072, 0, 800) in downloads
        assert (n, 0x6060, 0, 10) in downloads
    # enabled with zero torque, through the state machine
    pushing = min(r[0] for r in sent if r[3] != 0)
    for n in node_ids:
        before = [r for r in sent if r[1] == n and r[0] < pushing]
        words = [r[2] for k, r in enumerate(before) if k == 0 or r[2] != before[k - 1][2]]
        assert words == [0x06, 0x07, 0x0F] and all(r[3] == 0 for r in before)
    # the end: zero torque, DISABLE VOLTAGE, a SYNC after it, every drive in SWITCH ON DISABLED
    for n in node_ids:
        last = [r for r in sent if r[1] == n][-1]
        assert (last[2], last[3]) == (0x00, 0)
    last_rpdo = max(r[0] for r in sent)
    assert any(cob == 0x080 and t >= last_rpdo for t, cob, _ in frames)
    assert all(s == SOD for s in truth.state)
    assert source.assistance["mode"] == "assist" and source.assistance["ended"] is None
    assert source.assistance["level"] == 1.0


def _ends_within_one_period(frames, node_ids, truth, detectable: float, period: float):
    """The first RPDO after ``detectable`` carries zero torque and DISABLE VOLTAGE for every drive, sent within one
    SYNC period; no torque after it; the drives are disabled at the next SYNC."""
    sent = rpdos(frames, node_ids)
    after = [r for r in sent if r[0] >= detectable - 1e-9]
    assert after, "no RPDO after the fault"
    stop_time = after[0][0]
    assert stop_time - detectable <= period + 1e-9
    for n in node_ids:
        mine = [r for r in after if r[1] == n]
        assert (mine[0][2], mine[0][3]) == (0x00, 0)
        assert all(r[3] == 0 for r in mine)
    sync_after = min(t for t, cob, _ in frames if cob == 0x080 and t > stop_time)
    assert sync_after - stop_time <= period + 1e-9
    disabled = {node: t for t, node, old, new in truth.transitions if t >= stop_time and new == "SWITCH ON DISABLED"}
    assert set(disabled) == set(node_ids)
    assert max(disabled.values()) <= sync_after + 1e-9
    return stop_time


def test_a_heartbeat_loss_sets_zero_torque_within_one_sync_period_and_drops_to_observe(tmp_path, planned):
    settings = {"bus": {"faults": [{"kind": "heartbeat_loss", "node": 2, "at_s": 0.8}]}, "heartbeat_period": 0.05}
    samples, frames, node_ids, truth, source, _ = run_source(tmp_path, planned, settings)
    beats = [t for t, cob, _ in frames if cob == 0x702]
    gap = np.flatnonzero(np.diff(beats) > 1.5 * 0.05)
    last_beat = beats[int(gap[0])] if gap.size else beats[-1]
    stop = _ends_within_one_period(frames, node_ids, truth, last_beat + 1.5 * 0.05, 1 / RATE)
    assert "heartbeat lost from CAN node 2" in source.assistance["ended"]
    assert source.assistance["ended_at_s"] == pytest.approx(stop - source.origin, abs=1e-9)
    # observe from then on: SYNCs and samples go on, no RPDO
    assert samples[-1].t + source.origin > stop + 0.2


def test_a_missed_tpdo_ends_the_assistance(tmp_path, planned):
    settings = {"bus": {"faults": [{"kind": "dead_node", "node": 3, "at_s": 0.6}]}, "pdo_timeout_cycles": 50}
    _samples, frames, node_ids, truth, source, _ = run_source(tmp_path, planned, settings)
    answered = [t for t, cob, _ in frames if cob == 0x183]
    syncs = [t for t, cob, _ in frames if cob == 0x080]
    unanswered = min(t for t in syncs if t > answered[-1])  # the first SYNC node 3 did not answer
    sent = rpdos(frames, node_ids)
    stop = next(r for r in sent if r[0] > unanswered and r[2] == 0)[0]
    assert stop - unanswered <= 1 / RATE + 1e-9
    assert "missed TPDO from CAN node 3" in source.assistance["ended"]
    assert all(r[3] == 0 for r in sent if r[0] >= stop)
    alive = [n for n in node_ids if n != 3]
    assert all(truth.state[node_ids.index(n)] == SOD for n in alive)


def test_an_emcy_ends_the_assistance(tmp_path, planned):
    def emcy(source, k):
        if k == 150:
            source.device.simulator.nodes[4].emcy.send(0x5000, 0x01)  # a device-hardware error, from the drive

    _samples, frames, node_ids, truth, source, _ = run_source(tmp_path, planned, during=emcy)
    emcy_time = min(t for t, cob, _ in frames if cob == 0x084)
    _ends_within_one_period(frames, node_ids, truth, emcy_time, 1 / RATE)
    assert "EMCY 0x5000 from CAN node 4" in source.assistance["ended"]


def test_an_old_sample_ends_the_assistance(tmp_path, planned):
    def stall(source, k):
        if k == 120:  # the loop falls 20 ms behind (descheduled)
            clock = source.device.clock
            clock.sleep_until(clock.now() + 0.02)

    _samples, frames, node_ids, truth, source, _ = run_source(tmp_path, planned, during=stall)
    assert "old (max_sample_age)" in source.assistance["ended"]
    sent = rpdos(frames, node_ids)
    stop = next(r for r in sent if r[2] == 0 and r[0] > 0.3)[0]
    assert all(r[3] == 0 for r in sent if r[0] >= stop)
    assert all(s == SOD for s in truth.state)


# ----------------------------------------------------------------------------- validation, the stage, the record
@pytest.mark.parametrize(
    "settings, key, message",
    [
        ({"assist": {"stiffness": -5}}, "pipeline[1].settings.assist.stiffness", "greater than or equal to 0"),
        ({"assist": {"torque_cap": 3500}}, "pipeline[1].settings", "above the drives' peak torque 3000"),
        ({"assist": {"max_sample_age": 0.001}}, "pipeline[1].settings", "shorter than one SYNC period"),
    ],
)
def test_bad_assist_settings_are_refused_at_validation_with_file_line_and_key(tmp_path, cli, settings, key, message):
    path = assist_pipeline(tmp_path, settings)
    code, out, err = cli("validate", path)
    assert code == 2, out + err
    assert "assist.yaml" in err and key in err and message in err, err
    assert "line" in err and "Traceback" not in err


def test_assist_on_a_plan_without_a_path_is_refused_at_validation(tmp_path, cli):
    """A retraction plan (no goal: the planner chooses where its motion ends) recommends no path to pull toward."""
    data = yaml.safe_load((CONFIGS / "retraction_incision.yaml").read_text())
    guide = yaml.safe_load(assist_pipeline(tmp_path).read_text())["pipeline"][1]
    guide["path_from"] = data["pipeline"][0]["name"]
    guide["settings"]["fulcrum"] = {"xyz": [50, 25, 80], "rpy": [0, "90 deg", 0]}
    data["pipeline"] = [data["pipeline"][0], guide]
    data["pipeline"][0].pop("artifact", None)
    path = tmp_path / "assist.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    code, out, err = cli("validate", path)
    assert code == 2, out + err
    assert "has no goal: no recommended path" in err and "pipeline[1].settings.mode" in err, err
    assert "assist.yaml:" in err and "Traceback" not in err


def test_the_attempt_record_keeps_the_assistance_level_from_the_trainees_proficiency(tmp_path, cli):
    from surgiplan.guidance.record import TraineeRecord

    path = assist_pipeline(tmp_path, trainee={"name": "bea", "task": "gimbal"})
    code, out, err = cli("run", path)  # 1.6 s of the attempt: incomplete (exit 1), recorded all the same
    assert code in (0, 1) and "Traceback" not in out + err, out + err
    with TraineeRecord(tmp_path / "record.sqlite") as record:
        first = record.attempts("bea", "gimbal")[0]["id"]
        deviation = record.samples(first)["deviation"]
        proficiency = record.proficiency("bea", "gimbal", last=5).d_thresh
    # the proficiency is the 95th percentile of the recorded deviations (computed here from the samples)
    assert proficiency == pytest.approx(float(np.percentile(deviation, 95)), rel=1e-9)
    code, out, err = cli("run", path)
    assert code in (0, 1) and "Traceback" not in out + err, out + err
    with TraineeRecord(tmp_path / "record.sqlite") as record:
        levels = [
            json.loads(record.db.execute("SELECT assessment FROM attempts WHERE id = ?", (a["id"],)).fetchone()[0])
            for a in record.attempts("bea", "gimbal")
        ]
    assert levels[0]["assistance"]["level"] == 1.0  # no attempt before: full assistance
    expected = assistance_level(proficiency, FixtureSettings())
    assert levels[1]["assistance"]["level"] == pytest.approx(expected, abs=1e-12)
    assert levels[1]["assistance"]["stiffness_n_per_m"] == pytest.approx(150.0 * expected)
