"""The expert ghost in report.html and the trainee's cues in the live view, in headless chromium: what the page
reports is checked against result.json and what was fed to it, and what it draws against a screenshot's pixels."""

from __future__ import annotations

import io
import json
import time

import numpy as np
import pytest
from browser_support import Browser, canvas_pixels, feed_url, offsite, start_live_view, wait_for

GHOST = (0x17, 0xBE, 0xCF)
CUES = {
    "clear": (0x2C, 0xA0, 0x2C),
    "critical": (0xF2, 0xB0, 0x1E),
    "below": (0xD6, 0x27, 0x28),
    "contact": (0x7F, 0, 0),
}
ARROW = (0x94, 0x67, 0xBD)


@pytest.fixture(scope="module")
def browser():
    b = Browser()
    yield b
    b.close()


def near(pixels: np.ndarray, x: float, y: float, rgb, radius: int = 2, tolerance: int = 40) -> bool:
    """Whether a pixel within ``radius`` of (x, y) has the colour ``rgb`` (each channel within ``tolerance``)."""
    x, y = round(x), round(y)
    window = pixels[max(0, y - radius) : y + radius + 1, max(0, x - radius) : x + radius + 1].astype(int)
    return bool(np.any(np.all(np.abs(window - np.array(rgb)) <= tolerance, axis=2)))


def screen(page, box, point) -> tuple[float, float]:
    """Where the page draws ``point`` (m), in the pixels of a screenshot of the element at ``box``."""
    at = page.evaluate(f"surgiplan.screenOf({json.dumps(point)})")
    return at["x"] - box["x"], at["y"] - box["y"]


def teal(pixels: np.ndarray) -> np.ndarray:
    p = pixels.astype(int)
    return (p[..., 0] < 120) & (p[..., 1] > 130) & (p[..., 2] > 150) & (p[..., 2] - p[..., 0] > 60)


def test_the_report_shows_the_expert_ghost_beside_the_trainee_over_time(browser, ghosted):
    tmp, _, document = ghosted
    out = tmp / "beginner"
    timeline = document["stages"][1]["annotations"]["timeline"]
    page = browser.page((out / "report.html").resolve().as_uri())
    assert page.problems == [] and page.evaluate("surgiplan.errors") == []
    assert offsite(page.requests, allowed=("file://",)) == []
    assert page.evaluate("surgiplan.counts.ghosts") == 1
    assert "expert ghost" in page.inner_text("#legend")
    for layer in ("path",):  # only the ghost and the instrument, seen from above
        page.evaluate(f"surgiplan.show('recommended', '{layer}', false); surgiplan.show('attempt', '{layer}', false)")
    page.evaluate("surgiplan.setView('top')")
    seen = []
    for fraction in (0.3, 0.7):
        index = round(fraction * (len(timeline["t"]) - 1))
        page.locator("#slider").fill(str(index))
        page.wait_for_timeout(150)
        state = page.evaluate("surgiplan.state()")
        np.testing.assert_allclose(state["ghost"], timeline["ghost"][index], atol=1e-7)  # float32 in the page
        np.testing.assert_allclose(state["tip"], timeline["tip"][index], atol=1e-7)
        at = page.evaluate(f"surgiplan.screenOf({json.dumps(state['ghost'])})")
        box = page.locator("#view > canvas").bounding_box()
        pixels = canvas_pixels(page)
        x, y = at["x"] - box["x"], at["y"] - box["y"]
        assert teal(pixels[int(y) - 6 : int(y) + 7, int(x) - 6 : int(x) + 7]).sum() > 20, (
            f"no ghost at {x:.0f}, {y:.0f}"
        )
        seen.append((x, y))
    # the ghost moved with the slider, and hiding its layer (the ghost and its path) takes it off the screen
    assert np.hypot(seen[1][0] - seen[0][0], seen[1][1] - seen[0][1]) > 20
    page.evaluate("surgiplan.show('attempt', 'ghost', false)")
    page.wait_for_timeout(150)
    pixels = canvas_pixels(page)
    assert teal(pixels[int(y) - 6 : int(y) + 7, int(x) - 6 : int(x) + 7]).sum() == 0
    page.close()


# ----------------------------------------------------------------------------- the live view's cues


@pytest.fixture
def live_view():
    process, url = start_live_view()
    yield url
    process.terminate()
    process.wait(10)


def test_the_live_view_shows_the_cues_a_trainee_needs_in_pixels(browser, live_view, block_world):
    from PIL import Image
    from surgiplan.live import WebSocketFeed
    from surgiplan.outputs.report import scene_data

    page = browser.page(live_view + "#latency", ready="window.surgiplan && surgiplan.ready && surgiplan.live.connected")
    feed = WebSocketFeed(feed_url(live_view), retry_for=10)
    path = [[0.010, 0.050, 0.020], [0.140, 0.050, 0.020]]
    feed.publish("run", {"name": "cues", "length_unit": "mm", "unit_scale": 1e-3})
    feed.publish("scene", scene_data(block_world))
    feed.publish(
        "stage",
        {
            "name": "attempt",
            "kind": "guide",
            "plugin": "probe",
            "recommended": path,
            "threshold": 0.004,
            "critical": [[0.020, 0.040]],
            "deviation_tolerance": 0.005,
            "ghost": {"trainee": "ann", "attempt": 2, "score": 91.0},
            "ghost_path": path,
        },
    )
    wait_for(page, "surgiplan.live.stage !== null", 30_000)
    page.evaluate("surgiplan.setView('top')")
    samples = {
        # 12 mm beside the path (y 62 mm), clear of everything: green, the arrow back to (100, 50), the ghost behind
        "clear": {
            "tip": [0.100, 0.062, 0.020],
            "closest": [0.100, 0.050, 0.020],
            "deviation": 0.012,
            "clearance": 0.010,
        },
        # 2 mm from a block outside a critical region: red
        "below": {
            "tip": [0.100, 0.058, 0.020],
            "closest": [0.100, 0.050, 0.020],
            "deviation": 0.008,
            "clearance": 0.002,
        },
        # in the critical region: amber, and the banner says so
        "critical": {
            "tip": [0.030, 0.050, 0.020],
            "closest": [0.030, 0.050, 0.020],
            "deviation": 0.0,
            "clearance": 0.003,
            "critical": True,
        },
        "contact": {
            "tip": [0.120, 0.062, 0.020],
            "closest": [0.120, 0.050, 0.020],
            "deviation": 0.012,
            "clearance": -0.001,
        },
    }
    banners = {
        "clear": "off the path by 12 mm (tolerance 5 mm)",
        "below": "too close: clearance 2 mm below d_thresh 4 mm",
        "critical": "entering a critical region",
        "contact": "CONTACT",
    }
    for i, (kind, sample) in enumerate(samples.items()):
        ghost = [0.060 + 0.005 * i, 0.050, 0.020]
        feed.publish("tip", {"t": 0.5 * i, "critical": False, "ghost": ghost, "wall": time.time(), **sample})
        wait_for(
            page,
            f"surgiplan.live.tips === {i + 1} && surgiplan.live.cue !== null && surgiplan.live.pending.length === 0",
        )
        page.wait_for_timeout(100)
        cue = page.evaluate("surgiplan.live.cue")
        assert cue["clearance"] == kind and banners[kind] in cue["banner"], cue
        shot = np.asarray(Image.open(io.BytesIO(page.locator("#view").screenshot())).convert("RGB"))
        box = page.locator("#view").bounding_box()
        tip, closest, ghost_at = (screen(page, box, p) for p in (sample["tip"], sample["closest"], ghost))
        assert near(shot, *tip, CUES[kind], radius=2, tolerance=30), f"{kind}: the instrument is not {CUES[kind]}"
        assert near(shot, *ghost_at, GHOST, radius=2, tolerance=30), "no ghost where the expert is"
        if sample["deviation"] > 0:
            # the arrow's shaft, two thirds of the way from the instrument to the closest path point
            mid = (tip[0] + 0.66 * (closest[0] - tip[0]), tip[1] + 0.66 * (closest[1] - tip[1]))
            assert near(shot, *mid, ARROW, radius=2, tolerance=40), "no deviation arrow"
        # the banner is on the screen in its colour
        banner = page.locator("#cue-banner").bounding_box()
        colour = {"clear": ARROW, "below": CUES["below"], "critical": CUES["critical"], "contact": CUES["contact"]}[
            kind
        ]
        assert near(
            shot,
            banner["x"] - box["x"] + 4,
            banner["y"] - box["y"] + banner["height"] / 2,
            colour,
            radius=1,
            tolerance=12,
        )
    # every sample's latency from its wall time to a frame drawn after it was measured (values: bench_cues.py), and
    # to the page's handling of its message, which comes first
    shown, arrived = page.evaluate("[surgiplan.live.cueLatency, surgiplan.live.arrivalLatency]")
    assert len(shown) == len(arrived) == len(samples)
    assert all(a <= s + 1e-6 for a, s in zip(arrived, shown, strict=True)), (arrived, shown)
    assert page.problems == [] and page.evaluate("surgiplan.errors") == []
    assert offsite(page.requests) == []
    feed.close()
    page.close()
