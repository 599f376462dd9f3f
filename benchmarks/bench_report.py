"""report.html and the live view in the browser (Debian's chromium, headless, SwiftShader: no GPU).

1. Large results: how long a report takes to write (Python) and to load in the browser (navigation to the
   first frame with everything drawn, `#show=all`: roadmaps and stored paths too), for
   - a 5,000-milestone safe_prm roadmap (block world),
   - the 3,160-path optMIS repository (configs/hand_eye_offline.yaml's first stage),
   - a 4,000-element tissue mesh sequence of 20 states (the paper's flap, stvk, 19 steps);
   plus how long one step of the time slider takes to show (mesh recoloured and redrawn).
2. The live view: samples per second reaching the page and redraws per second showing a new sample, while
   a realtime point_robot (200 Hz) runs with `run --live` into `view --live`; and whether watching slows
   the stage: its lateness behind its clock and its wall time, with and without the viewer and a page,
   and the cost of one `publish` call.

Medians of repeated runs; the machine's load average is recorded (2 cores shared with other work).
Run: python benchmarks/bench_report.py  (results: benchmarks/results/report.json)
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
CONFIGS = ROOT / "configs"
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT / "tests"))

from browser_support import Browser, feed_url, live_view, wait_for  # noqa: E402
from common import package_version, save, table  # noqa: E402
from pipeline_support import point_robot_pipeline  # noqa: E402

SURGIPLAN = [sys.executable, "-m", "surgiplan.cli"]
ENV = {**os.environ, "SURGIPLAN_PLUGIN_PACKAGES": "surgiplan,surgiplan-hello"}
REPEAT = 5


def run(path: Path, *extra: str) -> None:
    result = subprocess.run([*SURGIPLAN, "run", str(path), "--quiet", *extra], capture_output=True, text=True, env=ENV)
    if result.returncode != 0:
        raise SystemExit(f"{path}: {result.stderr}")


def pipeline(tmp: Path, name: str, data: dict) -> Path:
    data = {**data, "output": {"dir": str(tmp / name), **data.get("output", {})}}
    data["output"]["dir"] = str(tmp / name)
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def large_runs(tmp: Path) -> dict[str, Path]:
    runs = {}
    roadmap = {
        "name": "roadmap-5000",
        "length_unit": "mm",
        "scene": str(CONFIGS / "scenes" / "block_world.yaml"),
        "pipeline": [
            {
                "stage": "plan",
                "name": "intermediate",
                "plugin": "safe_prm",
                "settings": {"proficiency": "intermediate", "milestones": 5000, "k": 15, "seed": 1},
                "start": "entry",
                "goal": "target",
                "artifact": str(tmp / "roadmap-5000.npz"),
            }
        ],
    }
    runs["5,000-milestone roadmap"] = pipeline(tmp, "roadmap-5000", roadmap)
    offline = yaml.safe_load((CONFIGS / "hand_eye_offline.yaml").read_text())
    offline["scene"] = str(CONFIGS / offline["scene"])
    offline["pipeline"] = offline["pipeline"][:1]
    offline["pipeline"][0]["artifact"] = str(tmp / "repository.npz")
    offline["executor"] = {"kind": "local", "workers": 2}
    runs["3,160-path repository"] = pipeline(tmp, "repository", offline)
    flap = yaml.safe_load((CONFIGS / "flap_simulate.yaml").read_text())
    flap["pipeline"][0]["settings"]["steps"] = 19
    runs["4,000-element mesh, 20 states"] = pipeline(tmp, "flap-20", flap)
    for label, path in runs.items():
        started = time.perf_counter()
        run(path)
        print(f"ran {label} in {time.perf_counter() - started:.1f} s", flush=True)
    return {label: Path(yaml.safe_load(p.read_text())["output"]["dir"]) for label, p in runs.items()}


def write_times(out: Path) -> list[float]:
    from surgiplan.outputs.report import write_report
    from surgiplan.pipeline import load_pipeline

    document = json.loads((out / "result.json").read_text())
    pipe = load_pipeline(document["pipeline_file"])
    times = []
    for _ in range(3):
        started = time.perf_counter()
        write_report(out, document, pipe)
        times.append(time.perf_counter() - started)
    return times


def load_times(browser: Browser, out: Path) -> dict:
    url = (out / "report.html").resolve().as_uri() + "#show=all"
    in_page, wall, counts = [], [], None
    for _ in range(REPEAT + 1):  # the first load warms the browser's caches
        started = time.perf_counter()
        page = browser.page(url, timeout=300_000)
        wall.append(time.perf_counter() - started)
        in_page.append(page.evaluate("surgiplan.loadMs") / 1000)
        counts = page.evaluate("surgiplan.counts")
        slider = None
        stages = page.evaluate("surgiplan.timeStages()")
        if stages:
            steps = []
            for i in range(min(stages[0]["count"], 20)):
                steps.append(
                    page.evaluate(
                        f"""new Promise(done => {{ const t0 = performance.now(); surgiplan.setIndex({i});
                        requestAnimationFrame(() => requestAnimationFrame(() => done(performance.now() - t0))); }})"""
                    )
                )
            slider = statistics.median(steps) / 1000
        page.close()
    return {
        "load_s": statistics.median(in_page[1:]),
        "load_s_runs": [round(v, 3) for v in in_page[1:]],
        "goto_to_ready_s": statistics.median(wall[1:]),
        "slider_step_s": slider,
        "counts": {k: v for k, v in counts.items() if v},
    }


# ----------------------------------------------------------------------------- the live view


def robot(tmp: Path, name: str) -> Path:
    settings = {"speed": 30, "lag": 0.05, "rate": 200, "tool_radius": 0.5, "realtime": True}
    return point_robot_pipeline(tmp / f"{name}.yaml", name, tmp / name, settings)


def stage_metrics(out: Path) -> dict:
    m = json.loads((out / "result.json").read_text())["stages"][1]["metrics"]
    return {
        "late_max_s": m["realtime_late_max_s"],
        "late_samples": m["realtime_late_samples"],
        "samples": m["samples"],
        "overrun_s": m["run_s"] - m["duration_s"],  # wall time beyond the motion's own duration
    }


def rates(page) -> dict:
    """Per whole second of the run: samples that reached the page, and redraws showing a new one."""
    times = page.evaluate("({tips: surgiplan.live.tipTimes, updates: surgiplan.live.updateTimes})")

    def per_second(stamps):
        if len(stamps) < 2:
            return []
        t0 = stamps[0]
        seconds = int((stamps[-1] - t0) // 1000)
        return [sum(1 for s in stamps if t0 + 1000 * k <= s < t0 + 1000 * (k + 1)) for k in range(seconds)]

    tips, updates = per_second(times["tips"]), per_second(times["updates"])
    return {"samples_per_s": statistics.median(tips), "redraws_per_s": statistics.median(updates)}


def live(browser: Browser, tmp: Path) -> dict:
    path = robot(tmp, "live")
    alone = []
    for i in range(3):
        run(robot(tmp, f"alone-{i}"))
        alone.append(stage_metrics(tmp / f"alone-{i}"))
    fed, watched, page_rates = [], [], []
    with live_view(exit_after=600, env=ENV) as url:
        for _ in range(3):  # fed to the viewer, no page watching: the feed's own cost
            run(path, "--live", feed_url(url))
            fed.append(stage_metrics(tmp / "live"))
        for i in range(3):
            page = browser.page(url, ready="window.surgiplan && surgiplan.ready && surgiplan.live.connected")
            run(path, "--live", feed_url(url))
            wait_for(page, "surgiplan.live.status !== null")
            watched.append(stage_metrics(tmp / "live"))
            page_rates.append(rates(page))
            page.close()
            print(f"live run {i + 1}: {page_rates[-1]}", flush=True)
    publish = publish_cost(tmp)

    def med(rows, key):
        return statistics.median(r[key] for r in rows)

    return {
        "samples_per_s": med(page_rates, "samples_per_s"),
        "redraws_per_s": med(page_rates, "redraws_per_s"),
        "runs": page_rates,
        "stage_alone": {k: med(alone, k) for k in alone[0]},
        "stage_fed_no_page": {k: med(fed, k) for k in fed[0]},
        "stage_watched": {k: med(watched, k) for k in watched[0]},
        "publish_us": publish,
    }


def publish_cost(tmp: Path) -> dict:
    """One publish() of a tip sample, with a viewer connected (median and 99th percentile, µs)."""
    import asyncio
    import threading

    from surgiplan.live import WebSocketFeed
    from surgiplan.outputs.report.server import LiveViewer

    viewer = LiveViewer(port=0)
    loop = asyncio.new_event_loop()
    ready = threading.Event()
    thread = threading.Thread(
        target=loop.run_until_complete,
        args=(viewer.serve(open_browser=False, exit_after=120, announce=lambda _: ready.set()),),
        daemon=True,
    )
    thread.start()
    ready.wait(10)
    feed = WebSocketFeed(viewer.feed_url, token=viewer.token)
    costs = []
    for i in range(20_000):
        sample = {"t": i / 200, "tip": [0.01, 0.05, 0.02], "commanded": [0.01, 0.05, 0.02], "clearance": 0.003}
        started = time.perf_counter_ns()
        feed.publish("tip", sample)
        costs.append(time.perf_counter_ns() - started)
        if i % 200 == 0:
            time.sleep(0.001)
    feed.close()
    viewer.stop()
    thread.join(10)
    costs.sort()
    return {"median": costs[len(costs) // 2] / 1000, "p99": costs[int(0.99 * len(costs))] / 1000}


def main() -> None:
    load_before = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-report-") as name:
        tmp = Path(name)
        outs = large_runs(tmp)
        browser = Browser()
        try:
            for label, out in outs.items():
                writes = write_times(out)
                measured = load_times(browser, out)
                rows.append(
                    {
                        "result": label,
                        "report_MB": round((out / "report.html").stat().st_size / 1e6, 2),
                        "write_s": round(statistics.median(writes), 3),
                        "load_s": round(measured["load_s"], 3),
                        "goto_to_ready_s": round(measured["goto_to_ready_s"], 3),
                        "slider_step_ms": None
                        if measured["slider_step_s"] is None
                        else round(1000 * measured["slider_step_s"], 1),
                        "load_s_runs": measured["load_s_runs"],
                        "drawn": measured["counts"],
                    }
                )
                print(rows[-1], flush=True)
            live_result = live(browser, tmp)
        finally:
            browser.close()
    load_after = os.getloadavg()
    print(table(rows, ["result", "report_MB", "write_s", "load_s", "goto_to_ready_s", "slider_step_ms"]))
    print(json.dumps(live_result, indent=2))
    save(
        "report",
        [
            *rows,
            {"result": "live view", **live_result},
            {"result": "load average", "before": load_before, "after": load_after},
        ],
        notes=f"load average (1, 5, 15 min) before {load_before}, after {load_after}; medians of {REPEAT} page loads "
        "(after one warm-up) and 3 live runs; headless chromium on SwiftShader (no GPU)",
        peers={
            "Chromium": {"version": chromium_version(), "configuration": "headless, SwiftShader (no GPU)"},
            "Playwright (client)": {"version": package_version("playwright")},
        },
    )


def chromium_version() -> str | None:
    """The browser's own version string (``chromium --version``), or None."""
    import subprocess

    from browser_support import chromium_path

    try:
        done = subprocess.run([chromium_path(), "--version"], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError, RuntimeError):
        return None
    return done.stdout.strip() or None


if __name__ == "__main__":
    main()
