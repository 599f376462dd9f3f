"""report.html without a browser: written by every run (also on the error path), what it reads from a
run's files, `surgiplan view`'s answers to bad input, and the live feed's guarantees to the stage."""

from __future__ import annotations

import json
import re
import threading
from pathlib import Path

import numpy as np
import pytest
from conftest import CONFIGS, assert_error_record
from pipeline_support import point_robot_pipeline
from surgiplan.outputs.report import page, write_report
from surgiplan.outputs.report.data import report_data
from surgiplan.outputs.report.meshes import _surface, face_owner, pvd_entries, states_mesh
from surgiplan.outputs.report.packing import pack
from surgiplan.outputs.report.timeline import timeline_data
from surgiplan.storage import save_bundle


def _embedded(html: str) -> dict:
    start = html.index('<script type="application/json" id="surgiplan-data">') + len(
        '<script type="application/json" id="surgiplan-data">'
    )
    return json.loads(html[start : html.index("</script>", start)])


def _unpack(p) -> np.ndarray:
    import base64

    return np.frombuffer(base64.b64decode(p["b64"]), dtype="<f4" if p["dtype"] == "f32" else "<u4").reshape(p["shape"])


def robot_file(tmp_path: Path, **robot) -> Path:
    return point_robot_pipeline(tmp_path / "robot.yaml", "robot", tmp_path / "out", {"speed": 80, **robot})


def test_every_run_writes_its_report_before_its_record(cli, tmp_path, with_example_plugin):
    code, _, err = cli("run", robot_file(tmp_path), "--quiet")
    assert code == 0, err
    out = tmp_path / "out"
    document = json.loads((out / "result.json").read_text())
    assert "report.html" in document["files"]
    report = out / "report.html"
    assert report.stat().st_mtime_ns <= (out / "result.json").stat().st_mtime_ns  # last but one
    data = _embedded(report.read_text())
    assert [s["name"] for s in data["stages"]] == ["plan", "robot"]
    assert data["run"]["status"] == "succeeded" and len(data["scene"]["obstacles"]) == 6
    plan, robot = data["stages"]
    # the drawn path: on the planned path, and the segments below the 4 mm threshold marked
    tips = _unpack(plan["path"]["tips"])
    np.testing.assert_allclose(tips[[0, -1]], np.asarray(document["stages"][0]["path"])[[0, -1]], atol=1e-7)
    assert plan["path"]["low_count"] > 0
    below = document["stages"][0]["metrics"]["length_below_threshold_m"]
    low = _unpack(plan["path"]["low"]).astype(bool)
    drawn_below = np.linalg.norm(np.diff(tips, axis=0), axis=1)[low].sum()
    assert drawn_below == pytest.approx(below, rel=0.02)  # the same stretches the runner measured
    # the execution: its recorded timeline, the plan's path as reference
    timeline = document["stages"][1]["annotations"]["timeline"]
    assert robot["timeline"]["source"] == "timeline" and robot["timeline"]["samples"] == len(timeline["t"])
    np.testing.assert_allclose(_unpack(robot["timeline"]["tip"]), timeline["tip"], atol=1e-7)
    assert robot["reference"]["name"] == "plan"


def test_a_run_that_errors_still_has_its_report(cli, tmp_path, with_example_plugin, monkeypatch):
    from surgiplan_hello.point_robot import PointRobot

    def broken(self, trajectory):
        raise RuntimeError("the gantry's belt snapped")

    monkeypatch.setattr(PointRobot, "run", broken)
    code, _, _err = cli("run", robot_file(tmp_path), "--quiet")
    assert code == 1
    out = tmp_path / "out"
    document = assert_error_record(out, "the gantry's belt snapped", stage="robot")
    assert "report.html" in document["files"]
    data = _embedded((out / "report.html").read_text())
    assert data["run"]["status"] == "error"
    assert data["stages"][1]["status"] == "error" and "belt snapped" in data["stages"][1]["message"]


def test_a_report_that_cannot_be_written_costs_the_run_nothing(cli, tmp_path, with_example_plugin, monkeypatch):
    import surgiplan.outputs.report as report

    def broken(*args, **kwargs):
        raise MemoryError("no memory for the report")

    monkeypatch.setattr(report, "write_report", broken)
    code, _, err = cli("run", robot_file(tmp_path), "--quiet")
    assert code == 0, err
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    assert "report.html" not in document["files"] and not (tmp_path / "out" / "report.html").exists()
    assert "could not write" in err and "no memory for the report" in err


def test_the_page_is_self_contained_and_its_data_cannot_break_out_of_it():
    data = {
        "run": {"name": "x", "length_unit": "m", "unit_scale": 1.0},
        "scene": None,
        "stages": [{"name": "</script><script>alert(1)</script>", "message": "/*__APP__*/ __DATA__"}],
    }
    html = page(data, "a <b>title</b>")
    assert "<title>a &lt;b&gt;title&lt;/b&gt; · surgiplan report</title>" not in html  # the caller's title only
    assert "<title>a &lt;b&gt;title&lt;/b&gt;</title>" in html
    assert html.count("</script>") == 3  # the data, three.js and the viewer: nothing else closes a script
    assert _embedded(html)["stages"][0]["name"] == "</script><script>alert(1)</script>"
    assert _embedded(html)["stages"][0]["message"] == "/*__APP__*/ __DATA__"
    assert not re.search(r"<script[^>]*\bsrc=", html)  # no script is fetched
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)""", html)  # nor anything else from a server
    assert "Content-Security-Policy" in html and "default-src 'none'" in html


def test_files_outside_the_output_directory_are_not_read(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    secret = tmp_path / "secret.png"
    secret.write_bytes(b"\x89PNG not yours")
    document = {
        "name": "x",
        "status": "succeeded",
        "stages": [
            {
                "stage": "execute",
                "name": "e",
                "plugin": "p",
                "status": "completed",
                "path": [[0, 0, 0], [1, 0, 0]],
                "metrics": {},
                "files": ["../secret.png", "e-execution.csv", "../../etc/passwd-execution.csv"],
            }
        ],
    }
    data = report_data(out, document)
    stage = data["stages"][0]
    assert stage["images"] == []
    assert any("outside the output directory" in n for n in data["notes"])
    assert any("'e-execution.csv' is missing" in n for n in data["notes"])
    assert stage["timeline"]["source"] == "path"  # fell back to the executed path


def test_an_execution_csv_is_the_timeline_of_a_device_without_one(tmp_path):
    t = np.linspace(0, 2, 401)
    tip = np.column_stack([0.01 + 0.05 * t, np.full_like(t, 0.05), 0.02 + 0.001 * np.sin(t)])
    header = "t_s,measured_yaw,commanded_yaw,tip_x_m,tip_y_m,tip_z_m,tracked"
    rows = np.column_stack([t, t, t, tip, np.ones_like(t)])
    np.savetxt(tmp_path / "g-execution.csv", rows, delimiter=",", header=header, comments="", fmt="%.9g")
    entry = {
        "name": "g",
        "stage": "execute",
        "files": ["g.png", "g-execution.csv"],
        "path": tip[::10].tolist(),
        "metrics": {"faults": [{"kind": "heartbeat_loss", "node": 2, "t_s": 0.75, "action": "quick stop"}]},
    }
    timeline = timeline_data(tmp_path, entry, _notes())
    assert timeline["source"] == "g-execution.csv" and timeline["time_unit"] == "s"
    np.testing.assert_allclose(_unpack(timeline["t"]), t, atol=1e-6)
    np.testing.assert_allclose(_unpack(timeline["tip"]), tip, atol=1e-7)
    assert timeline["events"] == [{"t": 0.75, "kind": "heartbeat_loss", "message": "node 2, quick stop"}]


def _notes():
    from surgiplan.outputs.report.packing import Notes

    return Notes()


def test_the_surface_of_a_tetrahedral_box_and_the_owner_of_each_triangle():
    import meshio  # noqa: F401  (the reader the report uses for .vtu)
    from surgiplan.plugins.fem.mesh import box_mesh  # tests may use plugins; the report never does

    mesh = box_mesh([0.05, 0.05, 0.0025], [4, 3, 2], pattern="five")
    nodes, cells = mesh.nodes, mesh.tets
    surface = _surface(cells)
    assert len(surface) == 2 * 2 * (4 * 3 + 4 * 2 + 3 * 2)
    # outward: each triangle's normal points away from its element's centroid
    tri = nodes[surface[:, :3]]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centroid = nodes[cells[surface[:, 3]]].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", normal, tri.mean(axis=1) - centroid) > 0)
    np.testing.assert_array_equal(face_owner(cells, surface[:, :3]), surface[:, 3])
    # the same triangles, oriented alike, with the same owners as the FEM plugin's own boundary
    ours = {tuple(np.roll(f, -int(np.argmin(f)))): int(o) for f, o in zip(surface[:, :3], surface[:, 3], strict=True)}
    theirs = {
        tuple(np.roll(f, -int(np.argmin(f)))): int(o) for f, o in zip(mesh.surface, mesh.surface_elements, strict=True)
    }
    assert ours == theirs


def test_a_retraction_states_file_becomes_a_mesh_sequence(tmp_path):
    from surgiplan.plugins.fem.mesh import box_mesh

    box = box_mesh([0.05, 0.05, 0.0025], [4, 4, 1], pattern="five")
    nodes, cells = box.nodes, box.tets
    triangles = _surface(cells)[:, :3]
    states = 7
    lift = np.linspace(0, 0.01, states)
    positions = np.stack([nodes + [0, 0, 1] * (nodes[:, :1] / 0.05) * z for z in lift])
    stress = np.outer(np.arange(1, states + 1), np.arange(len(cells)) + 1.0)
    save_bundle(
        tmp_path / "r-states.npz",
        {
            "positions": positions,
            "stress": stress,
            "max_stress": stress.max(axis=1),
            "triangles": triangles,
            "elements": cells,
            "area_points": np.zeros((5, 3)),
            "visible": np.array([1, 0, 1, 1, 0], bool),
        },
    )
    mesh = states_mesh(tmp_path, "r-states.npz", _notes())
    assert mesh["frames"] == states and mesh["triangle_count"] == len(triangles)
    np.testing.assert_allclose(_unpack(mesh["positions"]), positions, atol=1e-9)
    owner = face_owner(cells, triangles)
    np.testing.assert_allclose(_unpack(mesh["stress"]), stress[:, owner])
    assert mesh["max_stress"] == pytest.approx(stress.max(axis=1).tolist())
    assert _unpack(mesh["area"]["visible"]).tolist() == [1, 0, 1, 1, 0]


def test_a_paraview_collection_is_read_as_written():
    text = (
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
        '    <DataSet timestep="0" part="0" file="flap/step_000.vtu"/>\n'
        '    <DataSet timestep="0.5" part="0" file="flap/step_001.vtu"/>\n  </Collection>\n</VTKFile>\n'
    )
    assert pvd_entries(text) == [(0.0, "flap/step_000.vtu"), (0.5, "flap/step_001.vtu")]


def test_pack_is_little_endian_and_exact():
    a = np.array([[1.5, -2.25, 3.0]])
    p = pack(a)
    assert p["shape"] == [1, 3] and p["dtype"] == "f32"
    np.testing.assert_array_equal(_unpack(p), a)


def test_write_report_without_a_pipeline_still_draws_the_paths(tmp_path):
    document = {
        "name": "old",
        "status": "succeeded",
        "length_unit": "mm",
        "stages": [
            {
                "stage": "plan",
                "name": "p",
                "plugin": "x",
                "status": "solved",
                "path": [[0, 0, 0], [0.1, 0, 0]],
                "metrics": {},
            }
        ],
    }
    write_report(tmp_path, document)
    data = _embedded((tmp_path / "report.html").read_text())
    assert data["scene"] is None and any("obstacles are not shown" in n for n in data["notes"])
    np.testing.assert_allclose(_unpack(data["stages"][0]["path"]["tips"])[[0, -1]], [[0, 0, 0], [0.1, 0, 0]])


# ----------------------------------------------------------------------------- surgiplan view: bad input


@pytest.mark.parametrize(
    ("setup", "fragment"),
    [
        (lambda d: d / "nowhere", "no such directory"),
        (lambda d: (d / "f.txt").write_text("x") and d / "f.txt", "is a file"),
        (lambda d: d, "has no result.json: not a surgiplan run's output directory"),
        (lambda d: (d / ".in-progress.json").write_text("{}") and d, "a run is still writing there"),
        (lambda d: (d / "result.json").write_text("{not json") and d, "is not a readable surgiplan record"),
    ],
)
def test_view_says_what_is_wrong_with_a_directory(cli, tmp_path, setup, fragment):
    code, _out, err = cli("view", setup(tmp_path), "--no-browser", "--exit-after", "0")
    assert code == 2
    assert fragment in err and "Traceback" not in err


def test_view_needs_a_directory_or_live(cli):
    code, _, err = cli("view")
    assert code == 2 and "surgiplan view OUT_DIR" in err
    code, _, err = cli("view", ".", "--live")
    assert code == 2 and "not both" in err


@pytest.mark.parametrize("fps", ["241", "0.5", "-1", "nan", "inf"])
def test_the_live_views_frame_budget_is_refused_outside_its_range(cli, fps):
    code, out, err = cli("view", "--live", "--fps", fps, "--no-browser", "--exit-after", "0", "--port", "0")
    assert code == 2 and f"--fps {float(fps):g}: give 0 (the display's rate) or 1 to 240" in err
    assert "Traceback" not in err and "http://" not in out  # refused before anything was served


def test_the_frame_budget_is_the_live_views_only(cli, tmp_path):
    code, _, err = cli("view", tmp_path, "--fps", "20", "--no-browser", "--exit-after", "0")
    assert code == 2 and "--fps is the live view's" in err


def test_view_writes_the_report_of_a_run_that_predates_reports(cli, tmp_path, with_example_plugin):
    code, _, err = cli("run", robot_file(tmp_path), "--quiet")
    assert code == 0, err
    out = tmp_path / "out"
    (out / "report.html").unlink()
    code, stdout, err = cli("view", out, "--no-browser", "--exit-after", "0.2", "--port", "0")
    assert code == 0, err
    assert "the run predates reports" in stdout and (out / "report.html").is_file()
    assert "http://127.0.0.1:" in stdout
    data = _embedded((out / "report.html").read_text())
    assert len(data["scene"]["obstacles"]) == 6  # the scene came back from the pipeline file


def test_a_run_feeds_only_a_viewer_on_this_machine(cli, tmp_path):
    for url in ("ws://10.0.0.1:8765/feed", "ws://example.org:8765/feed", "http://127.0.0.1:8765/feed"):
        code, _, err = cli("run", CONFIGS / "block_world_proficiency.yaml", "--live", url)
        assert code == 2, url
        assert "--live" in err


# ----------------------------------------------------------------------------- the live feed


def test_publishing_never_blocks_the_stage_without_a_viewer():
    """No viewer listening: publications are queued (the oldest dropped when full), never an error."""
    import socket

    from surgiplan.live import WebSocketFeed

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    feed = WebSocketFeed(f"ws://127.0.0.1:{port}/feed", queue_size=1000, retry_for=0.5)
    for i in range(5000):
        feed.publish("tip", {"t": i * 0.005, "tip": [0.0, 0.0, float(i)]})
    assert feed.dropped == 4000
    feed.close()
    assert not feed.active
    feed.publish("tip", {"t": 1.0, "tip": [0, 0, 0]})  # after close: dropped silently


def test_the_viewer_relays_a_feed_to_a_page_in_order_and_refuses_strangers():
    """The viewer end to end without a browser: a feed in, a watcher out, with websockets' own client."""
    import asyncio

    from surgiplan.live import WebSocketFeed
    from surgiplan.outputs.report.server import LiveViewer
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    viewer = LiveViewer(port=0)
    loop = asyncio.new_event_loop()
    done = threading.Event()

    async def serve():
        await viewer.serve(open_browser=False, exit_after=20, announce=lambda _: done.set())

    thread = threading.Thread(target=loop.run_until_complete, args=(serve(),), daemon=True)
    thread.start()
    assert done.wait(10)
    base = f"127.0.0.1:{viewer.bound}"
    origin = f"http://{base}"
    token = f"?token={viewer.token}"
    with pytest.raises(InvalidStatus):  # another site's page may not watch, even with the token
        connect(f"ws://{base}/watch{token}", origin="http://evil.example", open_timeout=5)
    with pytest.raises(InvalidStatus):  # nor pose as a stage
        connect(f"ws://{base}/feed{token}", origin=origin, open_timeout=5)
    with connect(f"ws://{base}/watch{token}", origin=origin, open_timeout=5) as watcher:
        assert json.loads(watcher.recv(timeout=5)) == []  # nothing yet
        feed = WebSocketFeed(f"ws://{base}/feed", token=viewer.token)
        feed.publish("stage", {"name": "s", "kind": "execute", "recommended": [[0, 0, 0], [1, 0, 0]]})
        for i in range(300):
            feed.publish("tip", {"t": i / 200, "tip": [i / 300, 0.0, 0.0]})
        feed.publish("status", {"status": "completed"})
        feed.close()
        got = []
        while not got or got[-1]["channel"] != "status":
            got += json.loads(watcher.recv(timeout=10))
    tips = [m["payload"]["t"] for m in got if m["channel"] == "tip"]
    assert got[0]["channel"] == "stage" and tips == [i / 200 for i in range(300)]
    assert feed.sent == 302 and feed.dropped == 0
    # a page that connects late gets the running stage and what it did so far
    with connect(f"ws://{base}/watch{token}", origin=origin, open_timeout=5) as late:
        snapshot = json.loads(late.recv(timeout=5))
    assert [m["channel"] for m in snapshot][:2] == ["stage", "tip"] and len(snapshot) == 302
    viewer.stop()
    thread.join(10)
    assert not thread.is_alive()


def test_a_guide_stage_shows_recommended_against_followed(tmp_path):
    """The guide stage's contract (issue 17): its timeline and the path it recommended, in its annotations."""
    t = np.linspace(0, 3, 61)
    followed = np.column_stack([0.01 + 0.04 * t, 0.05 + 0.002 * np.sin(3 * t), np.full_like(t, 0.02)])
    recommended = [[0.01, 0.05, 0.02], [0.13, 0.05, 0.02]]
    events = [{"t": 1.2, "kind": "below_threshold", "start_t": 1.2, "end_t": 1.5, "message": "3.1 mm from A2"}]
    document = {
        "name": "g",
        "status": "succeeded",
        "length_unit": "mm",
        "stages": [
            {"stage": "plan", "name": "beginner", "plugin": "safe_prm", "status": "solved", "path": recommended},
            {
                "stage": "guide",
                "name": "attempt",
                "plugin": "recorded",
                "status": "completed",
                "path": followed.tolist(),
                "metrics": {"score": 87.0},
                "annotations": {
                    "timeline": {
                        "t": t.tolist(),
                        "tip": followed.tolist(),
                        "deviation": np.abs(followed[:, 1] - 0.05).tolist(),
                        "clearance": np.full_like(t, 0.004).tolist(),
                        "progress": (0.04 * t).tolist(),
                        "events": events,
                    },
                    "events": events,
                    "path_from": "beginner",
                    "recommended_tips": recommended,
                },
            },
        ],
    }
    stage = report_data(tmp_path, document)["stages"][1]
    assert stage["reference"]["name"] == "beginner"
    np.testing.assert_allclose(_unpack(stage["reference"]["tips"]), recommended, atol=1e-8)
    timeline = stage["timeline"]
    assert timeline["source"] == "timeline" and timeline["samples"] == len(t)
    np.testing.assert_allclose(_unpack(timeline["deviation"]), np.abs(followed[:, 1] - 0.05), atol=1e-8)
    assert timeline["events"] == [{"t": 1.2, "kind": "below_threshold", "message": "3.1 mm from A2"}]
