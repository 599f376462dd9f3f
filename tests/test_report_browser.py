"""report.html and the live view in a real headless browser (Debian's chromium through Playwright).

Every number the page reports is checked against an independent source: the scene file read by the
tests, result.json, the stored roadmaps read with numpy, closed forms of the mesh; and what it draws
against a screenshot's pixels. One browser for the module.
"""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from browser_support import (
    Browser,
    canvas_pixels,
    drawn_fraction,
    feed_url,
    offsite,
    red_pixels,
    start_view,
    wait_for,
)
from conftest import CONFIGS
from pipeline_support import point_robot_pipeline
from surgiplan import registry

SURGIPLAN = [sys.executable, "-m", "surgiplan.cli"]


@pytest.fixture(scope="module")
def browser():
    b = Browser()
    yield b
    b.close()


def _run(path: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*SURGIPLAN, "run", str(path), "--quiet", *extra], capture_output=True, text=True, timeout=600
    )


@pytest.fixture(scope="module")
def main_job(tmp_path_factory):
    """The main job (configs/block_world_proficiency.yaml) as `make run` runs it, its files in a temporary dir."""
    tmp = tmp_path_factory.mktemp("main-job")
    data = yaml.safe_load((CONFIGS / "block_world_proficiency.yaml").read_text())
    data["scene"] = str(CONFIGS / data["scene"])
    for stage in data["pipeline"]:
        stage["artifact"] = str(tmp / Path(stage["artifact"]).name)
    data["output"] = {"dir": str(tmp / "out")}
    path = tmp / "main.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    result = _run(path)
    assert result.returncode == 0, result.stderr
    return tmp / "out", data


def _example_env():
    return {**os.environ, "SURGIPLAN_PLUGIN_PACKAGES": "surgiplan,surgiplan-hello"}


def robot_pipeline(tmp: Path, name: str, realtime: bool, speed: float = 60.0) -> Path:
    robot = {"speed": speed, "lag": 0.05, "rate": 200, "tool_radius": 0.5, "realtime": realtime}
    return point_robot_pipeline(tmp / f"{name}.yaml", name, tmp / "out", robot, output={"dir": str(tmp / "out")})


@pytest.fixture(scope="module")
def robot_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("robot")
    path = robot_pipeline(tmp, "robot", realtime=False)
    result = subprocess.run(
        [*SURGIPLAN, "run", str(path), "--quiet"], capture_output=True, text=True, timeout=300, env=_example_env()
    )
    assert result.returncode == 0, result.stderr
    return tmp / "out"


FLAP_DIVISIONS = [6, 6, 1]


@pytest.fixture(scope="module")
def flap_run(tmp_path_factory):
    """A small flap lifted in 3 quasi-static steps by stvk: a .pvd sequence of 4 states."""
    tmp = tmp_path_factory.mktemp("flap")
    data = yaml.safe_load((CONFIGS / "flap_simulate.yaml").read_text())
    settings = data["pipeline"][0]["settings"]
    settings["mesh"]["box"]["divisions"] = FLAP_DIVISIONS
    settings["steps"] = 3
    settings["grasp"]["region"] = {"min": [41, 16, 0], "max": [50, 34, 2.5]}
    data["output"] = {"dir": str(tmp / "out")}
    path = tmp / "flap.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    result = _run(path)
    assert result.returncode == 0, result.stderr
    return tmp / "out"


def open_report(browser, out: Path):
    page = browser.page((out / "report.html").resolve().as_uri())
    page.wait_for_timeout(200)  # a few frames
    return page


def assert_clean(page):
    assert page.problems == [], page.problems
    assert page.evaluate("surgiplan.errors") == []
    assert offsite(page.requests, allowed=("file://",)) == [], "the report fetched something not beside it"


# ----------------------------------------------------------------------------- the main job's report


def test_the_main_jobs_report_opens_from_the_file_system_with_no_request_and_no_error(browser, main_job):
    out, _ = main_job
    document = json.loads((out / "result.json").read_text())
    assert "report.html" in document["files"]
    page = open_report(browser, out)
    assert_clean(page)
    assert page.requests[0].startswith("file://")
    # everything but the page itself is a figure listed in result.json, beside it
    fetched = {Path(u.removeprefix("file://")).name for u in page.requests[1:]}
    assert fetched <= set(document["files"]), fetched
    assert page.evaluate("surgiplan.revision") == "187"
    page.close()


def test_the_canvas_shows_the_scene_and_the_below_threshold_stretches(browser, main_job):
    out, _ = main_job
    page = open_report(browser, out)
    page.evaluate("surgiplan.setView('top')")
    page.wait_for_timeout(200)
    pixels = canvas_pixels(page)
    drawn = drawn_fraction(pixels)
    red = red_pixels(pixels)
    page.screenshot(path=str(out / "screenshot-top.png"))
    # blocks cover about 18 % of the floor seen from above; the paths and bounds more
    assert drawn > 0.10, f"the canvas is nearly blank: {drawn:.1%} of it drawn"
    assert red > 20, "no below-threshold (red) stretch is visible"
    # hiding the obstacles changes what is drawn: the pixels come from the scene, not from a static image
    page.check("#show-obstacles")
    page.uncheck("#show-obstacles")
    page.wait_for_timeout(200)
    assert drawn_fraction(canvas_pixels(page)) < drawn - 0.05
    page.close()


def test_the_page_reports_what_it_drew_and_it_matches_result_json(browser, main_job):
    from surgiplan import load_scene

    out, data = main_job
    document = json.loads((out / "result.json").read_text())
    scene = load_scene(CONFIGS / "scenes" / "block_world.yaml")
    page = open_report(browser, out)
    counts = page.evaluate("surgiplan.counts")
    stages_with_paths = [s for s in document["stages"] if len(s["path"]) >= 2]
    regions = sum(len(s.get("annotations", {}).get("critical_regions", [])) for s in document["stages"])
    edges = 0
    for stage in data["pipeline"]:
        with np.load(stage["artifact"]) as stored:
            edges += len(stored["edges"])
    assert counts["obstacles"] == len(scene.obstacles) == 6
    assert counts["obstacle_outlines"] == 6  # a few obstacles: each outlined (a merged mesh of many is not)
    assert counts["paths"] == len(stages_with_paths) == 4
    assert counts["critical_regions"] == regions == 2
    assert counts["points"] == len(scene.points)
    assert counts["roadmaps"] == 4 and counts["roadmap_edges"] == edges
    text = page.inner_text("#counts")
    assert text.startswith(f"drew {len(scene.obstacles)} obstacles, {len(stages_with_paths)} paths"), text
    # per stage: its metrics table (one row a metric) and its figure, loaded from beside the page
    for stage in document["stages"]:
        panel = page.locator(f'details.stage[data-stage="{stage["name"]}"]')
        assert panel.locator("table.metrics tr").count() == len(stage["metrics"])
        length = stage["metrics"]["length_m"] * 1000
        assert f"{length:.4g} mm".replace(".0 mm", " mm") in panel.inner_text() or f"{length:.4g}" in panel.inner_text()
        figures = [f for f in stage["files"] if f.endswith(".png")]
        assert figures
        for figure in figures:
            img = panel.locator(f'img[src="{figure}"]')
            img.scroll_into_view_if_needed()
            deadline = time.monotonic() + 30
            while not img.evaluate("img => img.complete && img.naturalWidth > 0") and time.monotonic() < deadline:
                page.wait_for_timeout(50)
            assert img.evaluate("img => img.naturalWidth") > 100, f"{figure} did not load"
    page.close()


def test_hovering_an_obstacle_names_it(browser, main_job):
    from surgiplan import load_scene

    out, _ = main_job
    scene = load_scene(CONFIGS / "scenes" / "block_world.yaml")
    page = open_report(browser, out)
    for stage in page.evaluate("Array.from(document.querySelectorAll('details.stage')).map(d => d.dataset.stage)"):
        for layer in ("path", "critical"):
            page.evaluate(f"surgiplan.show({json.dumps(stage)}, '{layer}', false)")
    page.evaluate("surgiplan.setView('top')")
    page.wait_for_timeout(150)
    for obstacle in scene.obstacles:
        lo, hi = obstacle.aabb()
        top = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2]]  # the middle of its top face
        at = page.evaluate(f"surgiplan.screenOf({json.dumps(top)})")
        assert at["inside"]
        page.mouse.move(at["x"], at["y"])
        wait_for(page, "document.getElementById('tooltip').style.display === 'block'")
        assert page.inner_text("#tooltip") == f"obstacle {obstacle.name} (box)"
    # and away from everything, nothing is named
    corner = page.evaluate("surgiplan.screenOf([0.001, 0.001, -0.05])")
    page.mouse.move(corner["x"], corner["y"])
    assert page.evaluate("surgiplan.hovered") is None
    page.close()


def test_a_roadmap_is_drawn_when_asked(browser, main_job):
    out, _data = main_job
    page = open_report(browser, out)
    page.evaluate("surgiplan.setView('top')")
    page.wait_for_timeout(150)
    before = drawn_fraction(canvas_pixels(page))
    page.check('input[data-stage="expert"][data-layer="roadmap"]')
    page.wait_for_timeout(200)
    after = drawn_fraction(canvas_pixels(page))
    assert after > before + 0.05, (before, after)  # 34,706 edges cover the free space
    page.close()


# ----------------------------------------------------------------------------- an execution, over time


def test_the_time_slider_replays_an_execution(browser, robot_run):
    document = json.loads((robot_run / "result.json").read_text())
    execute = document["stages"][1]
    timeline = execute["annotations"]["timeline"]
    t = np.asarray(timeline["t"])
    tips = np.asarray(timeline["tip"])
    page = open_report(browser, robot_run)
    assert_clean(page)
    assert page.evaluate("surgiplan.timeStages()") == [{"name": "robot", "kind": "timeline", "count": len(t)}]
    assert page.evaluate("surgiplan.counts.timelines") == 1
    # the events on the timeline: as recorded
    assert page.locator("#events div").count() == len(timeline["events"]) == 3
    first = page.evaluate("surgiplan.state()")
    shots = [canvas_pixels(page)]
    for fraction in (0.35, 1.0):
        index = round(fraction * (len(t) - 1))
        page.locator("#slider").fill(str(index))  # as a user drags it: an input event
        page.wait_for_timeout(150)
        state = page.evaluate("surgiplan.state()")
        assert state["index"] == index
        assert state["t"] == pytest.approx(t[index], abs=1e-6)
        np.testing.assert_allclose(state["tip"], tips[index], atol=1e-7)  # float32 in the page
        np.testing.assert_allclose(state["commanded"], timeline["commanded"][index], atol=1e-7)
        assert state["clearance"] == pytest.approx(timeline["clearance"][index], abs=1e-7)
        assert f"t = {t[index]:.3f} s" in page.inner_text("#timelabel")
        shots.append(canvas_pixels(page))
    assert first["index"] == 0
    np.testing.assert_allclose(first["tip"], tips[0], atol=1e-7)
    # the instrument moved on the screen
    for a, b in itertools.pairwise(shots):
        assert np.count_nonzero(np.any(a != b, axis=2)) > 50
    # the executed path ends at the recorded end, not where it started
    assert np.linalg.norm(tips[-1] - tips[0]) > 0.1
    page.close()


# ----------------------------------------------------------------------------- tissue under stress, over time


def test_the_tissue_mesh_is_coloured_by_stress_over_the_sequence(browser, flap_run):
    document = json.loads((flap_run / "result.json").read_text())
    metrics = document["stages"][0]["metrics"]
    nx, ny, nz = FLAP_DIVISIONS
    page = open_report(browser, flap_run)
    assert_clean(page)
    counts = page.evaluate("surgiplan.counts")
    assert counts["meshes"] == 1
    # a box of nx x ny x nz cells whose faces are each split in two triangles
    assert counts["mesh_triangles"] == 2 * 2 * (nx * ny + nx * nz + ny * nz)
    stages = page.evaluate("surgiplan.timeStages()")
    assert stages == [{"name": "flap", "kind": "mesh", "count": metrics["steps"] + 1}]
    shots = []
    for index in range(metrics["steps"] + 1):
        page.locator("#slider").fill(str(index))
        page.wait_for_timeout(120)
        state = page.evaluate("surgiplan.state()")
        assert state["frame"] == index
        assert state["t"] == pytest.approx(metrics["step_fraction"][index])
        assert state["max_stress"] == pytest.approx(metrics["step_max_stress_Pa"][index], rel=1e-6)
        shots.append(canvas_pixels(page))
    # the flap is lifted: what is drawn changes from state to state
    for a, b in itertools.pairwise(shots):
        assert np.count_nonzero(np.any(a != b, axis=2)) > 200
    assert page.is_visible("#colourbar")
    page.screenshot(path=str(flap_run / "screenshot-flap.png"))
    page.close()


# ----------------------------------------------------------------------------- surgiplan view


def _start(args: list[str], env=None) -> tuple[subprocess.Popen, str]:
    """Start a `surgiplan view` process; its URL (the first http:// line it prints)."""
    return start_view(args, env=env)


def test_view_serves_the_report_on_loopback(browser, main_job):
    out, _ = main_job
    process, url = _start([str(out), "--port", "0"])
    try:
        assert "/report.html?token=" in url
        page = browser.page(url)
        assert page.problems == []
        assert offsite(page.requests, allowed=("http://127.0.0.1:",)) == []
        assert page.evaluate("surgiplan.counts.obstacles") == 6
        page.close()
    finally:
        process.terminate()
        process.wait(10)


def test_the_live_view_receives_a_device_in_the_loop_run_as_it_happens(browser, tmp_path):
    process, url = _start(["--live", "--port", "0"])
    try:
        page = browser.page(url, ready="window.surgiplan && surgiplan.ready && surgiplan.live.connected")
        feed = feed_url(url)
        path = robot_pipeline(tmp_path, "live", realtime=True, speed=60.0)  # about 2.4 s of motion
        run = subprocess.Popen(
            [*SURGIPLAN, "run", str(path), "--quiet", "--live", feed],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=_example_env(),
        )
        # during the run: samples arrive while the stage is still running
        wait_for(page, "surgiplan.live.tips > 20", 60_000)
        during = page.evaluate("({tips: surgiplan.live.tips, status: surgiplan.live.status})")
        assert run.poll() is None and during["status"] is None, "the run ended before the page saw it running"
        _, err = run.communicate(timeout=300)
        assert run.returncode == 0, err
        wait_for(page, "surgiplan.live.status !== null", 30_000)
        page.wait_for_timeout(300)
        live = page.evaluate(
            "({tips: surgiplan.live.tips, last: surgiplan.live.last, status: surgiplan.live.status,"
            " events: surgiplan.live.events, stage: surgiplan.live.stage, updates: surgiplan.live.updates,"
            " obstacles: surgiplan.counts.obstacles, drops: surgiplan.live.drops,"
            " dropsShown: document.getElementById('live-drops').textContent})"
        )
        assert page.problems == [] and page.evaluate("surgiplan.errors") == []
        assert offsite(page.requests) == []
    finally:
        process.terminate()
        process.wait(10)
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    execute = document["stages"][1]
    timeline = execute["annotations"]["timeline"]
    samples = len(timeline["t"])
    assert live["obstacles"] == 6
    assert live["stage"]["name"] == "robot" and len(live["stage"]["recommended"]) == len(document["stages"][0]["path"])
    assert live["status"] == {"status": "completed"}
    # every sample the page got is one the device recorded, and the last one is the end of the motion
    assert during["tips"] < live["tips"] <= samples
    assert live["tips"] >= 0.5 * samples, f"only {live['tips']} of {samples} samples reached the page"
    assert live["last"]["t"] == pytest.approx(timeline["t"][-1])
    np.testing.assert_allclose(live["last"]["tip"], timeline["tip"][-1], atol=1e-12)
    assert [e["kind"] for e in live["events"]] == [e["kind"] for e in timeline["events"]]
    assert live["updates"] > 10  # the scene was redrawn as samples arrived
    assert live["drops"] == {"feed": 0, "page": 0} and live["dropsShown"] == "samples dropped: 0"
    registry.reset_default_registry()


def test_the_live_page_shows_the_samples_the_feed_dropped(browser):
    """A feed whose queue overflows before it connects: the page says how many samples it will never see."""
    from surgiplan.live import WebSocketFeed

    process, url = _start(["--live", "--port", "0"])
    try:
        page = browser.page(url, ready="window.surgiplan && surgiplan.ready && surgiplan.live.connected")
        feed = WebSocketFeed(feed_url(url), queue_size=50, retry_for=10)
        feed.publish("stage", {"name": "s", "kind": "execute", "recommended": [[0, 0, 0], [0.1, 0, 0]]})
        for i in range(500):  # faster than any connection: the oldest are dropped
            feed.publish("tip", {"t": i / 100, "tip": [i / 5000, 0.0, 0.0]})
        feed.publish("status", {"status": "completed"})  # the newest: kept (the oldest go first)
        feed.close()
        dropped = feed.dropped
        wait_for(page, "surgiplan.live.status !== null", 30_000)
        got = page.evaluate(
            "({drops: surgiplan.live.drops, tips: surgiplan.live.tips,"
            " shown: document.getElementById('live-drops').textContent})"
        )
        assert page.problems == [] and page.evaluate("surgiplan.errors") == []
        page.close()
    finally:
        process.terminate()
        process.wait(10)
    assert dropped >= 400
    assert got["drops"] == {"feed": dropped, "page": 0}
    assert 500 - dropped <= got["tips"] <= 501 - dropped  # the page got every sample that was not dropped
    assert got["shown"] == f"samples dropped: {dropped} (by the run's feed {dropped}, by the viewer for this page 0)"


@pytest.mark.parametrize(("fps", "budget"), [(None, 30), ("10", 10), ("0", 0)])
def test_the_live_view_draws_within_its_frame_budget_and_shows_the_newest_sample(browser, fps, budget):
    """Without a GPU (SwiftShader here) the live page draws at most 30 frames a second, each with the newest sample;
    ``--fps`` sets the budget, 0 lifts it. Samples paced at 100 a second for 1.5 s."""
    from surgiplan.live import WebSocketFeed

    process, url = _start(["--live", "--port", "0", *(["--fps", fps] if fps else [])])
    try:
        page = browser.page(url, ready="window.surgiplan && surgiplan.ready && surgiplan.live.connected")
        feed = WebSocketFeed(feed_url(url))
        feed.publish("stage", {"name": "s", "kind": "execute", "recommended": [[0, 0, 0], [0.1, 0, 0]]})
        wait_for(page, "surgiplan.live.stage !== null", 30_000)
        page.wait_for_timeout(300)  # the stage's frames drawn
        counting = time.monotonic()  # frames are counted from here to the last evaluate below
        before = page.evaluate("surgiplan.live.frames")
        started = time.monotonic()
        for i in range(150):
            feed.publish("tip", {"t": i / 100, "tip": [i / 1500, 0.0, 0.0], "wall": time.time()})
            time.sleep(max(0.0, started + (i + 1) / 100 - time.monotonic()))
        wait_for(page, "surgiplan.live.tips === 150 && surgiplan.live.pending.length === 0", 30_000)
        feed.close()
        got = page.evaluate(
            "({frames: surgiplan.live.frames, fps: surgiplan.live.fps, renderer: surgiplan.live.renderer,"
            " last: surgiplan.live.last.t, shown: surgiplan.live.cueLatency.length})"
        )
        elapsed = time.monotonic() - counting
        assert page.problems == [] and page.evaluate("surgiplan.errors") == []
        page.close()
    finally:
        process.terminate()
        process.wait(10)
    frames = got["frames"] - before
    assert "SwiftShader" in got["renderer"] and got["fps"] == budget
    # every sample reached a drawn frame (its cue latency counted), the last one last
    assert got["last"] == pytest.approx(1.49) and got["shown"] == 150
    if budget:
        assert 0.25 * budget * elapsed <= frames <= budget * elapsed + 2
    else:  # no budget: more frames than 10 a second could hold
        assert frames > 10 * elapsed + 2


def test_many_obstacles_are_one_translucent_mesh_of_front_faces_without_outlines(browser, tmp_path):
    """configs/scanned_trainer.yaml's 117 boxes (more than outputs.merged.MAX_SEPARATE): one merged mesh, drawn
    front faces only and writing depth (no blending of every box along a pixel's ray), not outlined."""
    from surgiplan import load_scene

    run = subprocess.run(
        [*SURGIPLAN, "run", str(CONFIGS / "scanned_trainer.yaml"), "--quiet", "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    scene = load_scene(CONFIGS / "scenes" / "scanned_trainer.yaml")
    page = open_report(browser, tmp_path / "out")
    assert_clean(page)
    counts = page.evaluate("surgiplan.counts")
    assert counts["obstacles"] == len(scene.obstacles) == 117 and counts["obstacle_outlines"] == 0
    assert page.evaluate("surgiplan.obstacleMaterials()") == [
        {"count": 117, "side": "front", "depthWrite": True, "transparent": True}
    ]
