"""Skill assessment: every metric against a hand computation on a trajectory with a known answer, the score's
composition, benchmark thresholds and the gate on a constructed history, the CUSUM against a hand-computed
series, and the construct-validity statistics against brute force (docs/assessment.md)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from surgiplan.guidance import GuidanceSettings, Guide, PoseSample
from surgiplan.guidance.benchmark import Benchmark, BenchmarkSettings, gate, thresholds
from surgiplan.guidance.cusum import CusumSettings, cusum
from surgiplan.guidance.metrics import (
    AssessmentSettings,
    dimensionless_jerk,
    idle_time,
    reversals,
    runs,
    sparc,
)
from surgiplan.guidance.validity import separation
from surgiplan.spaces import R3Space

#: the straight recommended path of the block world, entry (10, 50, 20) mm to target (140, 50, 20) mm
PATH = np.array([[0.010, 0.050, 0.020], [0.140, 0.050, 0.020]])


def attempt(block_world, tips, rate=100.0, port=None, **assessment):
    """A Guide fed tip positions at ``rate`` Hz along the straight path (no threshold: clearance is not judged)."""
    guide = Guide(
        R3Space(block_world),
        PATH,
        block_world,
        0.0,
        [],
        GuidanceSettings(),
        unit="mm",
        assessment=AssessmentSettings(**assessment),
        port=port,
    )
    for i, tip in enumerate(tips):
        guide.measure(PoseSample(i / rate, tip=np.asarray(tip, float)))
    guide.finish()
    return guide, guide.metrics()


def along(x, y=0.0, z=0.0):
    """Tips at x (m) on the straight path, offset by y and z (m)."""
    x = np.asarray(x, float)
    return np.column_stack([x, 0.050 + np.broadcast_to(y, x.shape), 0.020 + np.broadcast_to(z, x.shape)])


# ----------------------------------------------------------------------------- metrics with known answers


def test_a_straight_line_at_constant_speed_has_no_jerk_no_correction_no_idle_time_and_economy_1(block_world):
    # 20 mm/s from entry to target: 130 mm in 6.5 s, a sample every 10 ms
    t = np.arange(651) / 100.0
    _, m = attempt(block_world, along(0.010 + 0.020 * t), port=(0.0, 0.050, 0.020))
    assert m["jerk"] == pytest.approx(0.0, abs=1e-9)
    assert m["corrections"] == 0 and m["depth_reversals"] == 0 and m["idle_s"] == 0.0
    assert m["duration_s"] == pytest.approx(6.5)
    assert m["path_length_m"] == pytest.approx(0.130, rel=1e-12) and m["economy"] == pytest.approx(1.0, rel=1e-12)
    assert m["deviation_rms_m"] == pytest.approx(0.0, abs=1e-12) and m["completion"] == 1.0
    # the score's terms as docs/assessment.md defines them: the time term is 130 mm at 25 mm/s over 6.5 s
    terms = m["score_terms"]
    assert terms["time"] == pytest.approx(0.130 / 0.025 / 6.5)
    assert terms["economy"] == terms["idle"] == terms["corrections"] == terms["depth"] == terms["accuracy"] == 1.0


def test_a_known_pause_gives_its_idle_time(block_world):
    # 20 mm/s, then 1.5 s standing at x = 70 mm (t 3.0 to 4.5 s), then on to the target
    t = np.arange(801) / 100.0
    x = 0.010 + 0.020 * np.minimum(t, 3.0) + 0.020 * np.clip(t - 4.5, 0.0, None)
    assert x[-1] == pytest.approx(0.140)
    _, m = attempt(block_world, along(x))
    assert m["idle_s"] == pytest.approx(1.5, abs=1e-9)
    assert idle_time(t[:451], along(x[:451]), 0.002) == pytest.approx(1.5, abs=1e-9)
    # a slow crawl is idle only below idle_speed: 1 mm/s is, 3 mm/s is not (idle_speed 2 mm/s)
    crawl = along(0.070 + 0.001 * t[:101])
    assert idle_time(t[:101], crawl, 0.002) == pytest.approx(1.0) and idle_time(t[:101], crawl, 0.0009) == 0.0
    # smoothed positions (Savitzky-Golay over 0.1 s) blur the pause by at most half a window
    _, smoothed = attempt(block_world, along(x), smoothing_window=0.1)
    assert abs(smoothed["idle_s"] - m["idle_s"]) <= 0.05


def test_dimensionless_jerk_and_sparc_against_closed_forms_and_their_authors_values():
    # a minimum-jerk movement: v = 30 t^2 - 60 t^3 + 30 t^4 over 1 s; D^3 / v_peak^2 * int (v'')^2 = 720 / 1.875^2
    fs = 1000.0
    tau = np.arange(0, 1 + 1e-12, 1 / fs)
    assert dimensionless_jerk(30 * tau**2 - 60 * tau**3 + 30 * tau**4, fs) == pytest.approx(720 / 1.875**2, rel=5e-3)
    assert dimensionless_jerk(np.full(500, 0.02), 100.0) == 0.0
    # the Gaussian speed profile of Balasubramanian et al.'s reference (github.com/siva82kb/SPARC, docstrings):
    # SPARC -1.41403 and dimensionless jerk -335.74684 (their sign)
    t = np.arange(-1, 1, 0.01)
    speed = np.exp(-5 * t**2)
    assert sparc(speed, 100.0) == pytest.approx(-1.41403, abs=5e-6)
    assert dimensionless_jerk(speed, 100.0) == pytest.approx(335.74684, abs=5e-5)
    # less smooth, more negative: two bumps
    assert sparc(np.exp(-20 * (t - 0.4) ** 2) + np.exp(-20 * (t + 0.4) ** 2), 100.0) < -2.0


def test_corrections_count_the_reversals_of_the_lateral_offset(block_world):
    # a zig-zag of 2 mm amplitude sideways (y), 5 periods over the path: 10 turns back towards the other side
    x = np.linspace(0.010, 0.140, 1301)
    guide, m = attempt(block_world, along(x, y=0.002 * np.sin(2 * np.pi * 5 * (x - 0.010) / 0.130)))
    assert m["corrections"] == 10
    lateral = guide.samples().lateral
    assert np.abs(lateral[:, 0]).max() < 1e-12  # along +z: nothing
    np.testing.assert_allclose(
        np.abs(lateral[:, 1]), np.abs(0.002 * np.sin(2 * np.pi * 5 * (x - 0.010) / 0.130)), atol=1e-12
    )
    # the same zig-zag, 0.4 mm: below correction_distance (1 mm), never a correction
    _, small = attempt(block_world, along(x, y=0.0004 * np.sin(2 * np.pi * 5 * (x - 0.010) / 0.130)))
    assert small["corrections"] == 0


def test_depth_reversals_count_in_and_out_along_the_insertion_axis(block_world):
    # the port on the path's line behind the entry: insertion is x; forward, 3 mm back, forward, 3 mm back, to the end
    x = np.concatenate(
        [
            np.linspace(0.010, 0.060, 500),
            np.linspace(0.060, 0.057, 30),
            np.linspace(0.057, 0.100, 430),
            np.linspace(0.100, 0.097, 30),
            np.linspace(0.097, 0.140, 430),
        ]
    )
    _, m = attempt(block_world, along(x), port=(0.0, 0.050, 0.020))
    assert m["depth_reversals"] == 4
    _, none = attempt(block_world, along(x))  # r3 without a port: not measured, no depth term in the score
    assert none["depth_reversals"] is None and "depth" not in none["score_terms"]


def test_reversals_follow_their_hysteresis():
    assert reversals([0, 2, 0], 1.0) == 1
    assert reversals([0, 0.9, 0, 0.9, 0], 1.0) == 0
    assert reversals([0, -2, 0, -2], 1.0) == 2
    assert reversals(np.r_[np.linspace(0, 3, 30), np.linspace(3, 2.2, 10)], 1.0) == 0  # back 0.8 < 1
    assert runs([True, True, False, True, False, False, True]) == 3 and runs([False]) == 0


def test_the_score_is_the_weighted_mean_of_its_terms_times_completion(block_world):
    t = np.arange(651) / 100.0
    tips = along(0.010 + 0.020 * t)
    _, only_time = attempt(block_world, tips, weights={k: 0.0 for k in ("safety", "accuracy", "economy", "idle")})
    terms = only_time["score_terms"]
    weights = {"smoothness": 0.1, "corrections": 0.1, "time": 0.1}
    expected = sum(weights[k] * terms[k] for k in weights) / 0.3
    assert only_time["score"] == pytest.approx(100 * expected)
    # half the way: completion 0.5 halves the score
    _, half = attempt(block_world, tips[:326])
    assert half["completion"] == pytest.approx(0.5, abs=1e-9)
    mean = sum(half["score_weights"][k] * half["score_terms"][k] for k in half["score_terms"])
    assert half["score"] == pytest.approx(100 * 0.5 * mean / sum(half["score_weights"].values()))


# ----------------------------------------------------------------------------- the benchmark and the gate


EXPERTS = [
    {"duration_s": 10.0, "score": 90.0, "contacts": 0},
    {"duration_s": 12.0, "score": 80.0, "contacts": 0},
    {"duration_s": 14.0, "score": 70.0, "contacts": 0},
]


def test_thresholds_are_the_expert_mean_plus_or_minus_k_sd_or_a_percentile():
    settings = BenchmarkSettings(metrics=["duration_s", "score", "contacts", "corrections"])
    found = thresholds(EXPERTS, settings)
    # mean 12 s, sample SD 2 s: lower is better, so mean + SD; score: mean 80, SD 10, higher is better
    assert found["duration_s"].value == pytest.approx(14.0) and found["duration_s"].sd == pytest.approx(2.0)
    assert found["score"].value == pytest.approx(70.0) and found["score"].better == "higher"
    assert found["contacts"].value == 0.0
    assert "corrections" not in found  # no expert attempt has it
    two = thresholds(EXPERTS, settings.model_copy(update={"k": 2.0}))
    assert two["duration_s"].value == pytest.approx(16.0) and two["score"].value == pytest.approx(60.0)
    # the 90th percentile (linear) of 10, 12, 14 is 13.6; for the score, the 10th of 70, 80, 90 is 72
    p90 = thresholds(EXPERTS, settings.model_copy(update={"method": "percentile", "percentile": 90.0}))
    assert p90["duration_s"].value == pytest.approx(13.6) and p90["score"].value == pytest.approx(72.0)
    with pytest.raises(ValueError, match=r"unknown metric.*durations"):
        BenchmarkSettings(metrics=["durations"])


def test_the_gate_passes_at_the_attempt_that_completes_n_in_a_row():
    settings = BenchmarkSettings(metrics=["duration_s", "score"])
    benchmark = Benchmark("t", "mean_sd", 1.0, None, 2, ["a"], 3, thresholds(EXPERTS, settings))
    history = [
        {"duration_s": 15.0, "score": 75.0},  # too slow
        {"duration_s": 13.0, "score": 71.0},  # within
        {"duration_s": 13.0, "score": 60.0},  # score too low
        {"duration_s": 12.0, "score": 80.0},  # within
        {"duration_s": 11.0, "score": 85.0},  # within: 2 in a row
        {"duration_s": 10.0, "score": 90.0},  # within: 3 in a row
        {"duration_s": 10.0},  # no score: not within (never passed on what was not measured)
    ]
    result = gate(history, benchmark)
    assert result.within == [False, True, False, True, True, True, False]
    assert result.passed_at == 5 and result.streak == 0
    benchmark.consecutive = 3
    assert gate(history, benchmark).passed_at == 6
    benchmark.consecutive = 4
    assert gate(history, benchmark).passed_at is None and gate(history[:6], benchmark).streak == 3


# ----------------------------------------------------------------------------- CUSUM


def test_cusum_against_a_hand_computed_series():
    # p0 0.1, p1 0.3, alpha = beta = 0.1: P = ln 3, Q = ln(9/7), s = Q / (P + Q) = 0.1861689,
    # h0 = h1 = ln 9 / (P + Q) = 1.6276621 (by hand, Bolsin & Colson 2000)
    chart = cusum([True, False, True, True] + [False] * 21, CusumSettings())
    assert chart.s == pytest.approx(0.1861689, abs=1e-7)
    assert chart.h0 == pytest.approx(1.6276621, abs=1e-7) and chart.h1 == pytest.approx(1.6276621, abs=1e-7)
    expected = [0.8138311, 0.6276621, 1.4414932, 2.2553242, 2.0691553, 1.8829863, 1.6968174, 1.5106485]
    expected += [1.3244795, 1.1383106, 0.9521416, 0.7659727, 0.5798038, 0.3936348, 0.2074659, 0.0212969]
    expected += [-0.164872, -0.351041, -0.5372099, -0.7233788, -0.9095478, -1.0957167, -1.2818857, -1.4680546]
    expected += [-1.6542235]
    np.testing.assert_allclose(chart.values, expected, atol=1e-7)
    # unacceptable: 2.2553242 is h1 above the lowest point so far (0, the start); acceptable: 13 attempts in,
    # 0.5798038 is h0 below the highest so far (2.2553242 - 1.6276621 = 0.6276621)
    assert chart.unacceptable_at == 4 and chart.acceptable_at == 13
    assert chart.acceptable_line[12] == pytest.approx(0.6276621, abs=1e-7)
    assert chart.unacceptable_line[0] == pytest.approx(1.6276621, abs=1e-7)
    # two failures in a row: 2 (1 - s) = 2 ln 3 / (P + Q) = h1 exactly, which reaches the line
    assert cusum([True, True], CusumSettings()).unacceptable_at == 2
    # other rates: p0 0.05, p1 0.2, alpha 0.05, beta 0.2: s = ln(0.95/0.8) / ln(0.2 * 0.95 / (0.05 * 0.8))
    other = CusumSettings(p0=0.05, p1=0.2, alpha=0.05, beta=0.2)
    s = math.log(0.95 / 0.8) / math.log(0.2 * 0.95 / (0.05 * 0.8))
    assert cusum([False], other).values == pytest.approx([-s])
    with pytest.raises(ValueError, match=r"p1 .* must exceed the acceptable p0"):
        CusumSettings(p0=0.3, p1=0.1)


# ----------------------------------------------------------------------------- construct validity


def test_auc_and_p_value_against_brute_force():
    experts, novices = [3.0, 4.0, 5.5, 2.0], [6.0, 4.5, 9.0, 7.0, 5.0]
    row = separation("duration_s", ("expert", experts), ("novice", novices))  # lower is better
    better = sum(1.0 if a < b else 0.5 if a == b else 0.0 for a, b in itertools.product(experts, novices))
    assert row.auc == pytest.approx(better / 20) and row.median_higher == 3.5 and row.median_lower == 6.0
    # the exact two-sided p-value: every split of the nine values into groups of 4 and 5
    values = experts + novices
    observed = sum(a < b for a, b in itertools.product(experts, novices))
    count = [
        sum(a < b for a, b in itertools.product(g, [v for i, v in enumerate(values) if i not in c]))
        for c in itertools.combinations(range(9), 4)
        for g in [[values[i] for i in c]]
    ]
    extreme = sum(1 for u in count if abs(u - 10) >= abs(observed - 10))
    assert row.p == pytest.approx(extreme / len(count))
    # higher is better: the score
    row = separation("score", ("expert", [90, 85, 80]), ("novice", [60, 82, 70]))
    assert row.auc == pytest.approx(8 / 9)
    assert separation("score", ("a", [1.0]), ("b", [2.0, 3.0])).auc is None  # too few to say
