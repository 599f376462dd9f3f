"""The trainee's cues in the live view: latency from a sample to the pixels that show it, in headless chromium.

A guide stage follows a synthetic beginner paced in real time at 100 samples/s (a 20 s attempt) with an
expert ghost, fed with ``surgiplan run --live`` into ``surgiplan view --live``; a headless chromium page
(Debian's, software WebGL: no GPU) watches with ``#latency``. Every sample carries the wall-clock time at
which it reached the stage from its source; the page records, for every sample, the time from then to the
end of the first frame it drew after getting it, read back from the canvas (``getImageData``: the pixels
exist), so each figure is sample to pixels: the stage's analysis, the feed, the viewer's relay, the
page's handling and the drawing of the cues. Target: p99 under 50 ms.

For scale, the same run with a websocket client in Python in place of the page: sample to arrival at a
watcher (the stage, feed and relay alone). Medians and percentiles over every sample of ``--runs`` runs
(default 3) and per run; the load average before and after is recorded (the machine is shared).

    python benchmarks/bench_cues.py [--runs N] [--seconds S] [--quick]   (--quick: 1 run of 8 s, writes nothing)
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT / "tests"))

from browser_support import Browser, feed_url, live_view, wait_for, watch_live  # noqa: E402
from common import paced_run_arguments, save, table  # noqa: E402
from pipeline_support import block_world_pipeline, recommended_stage  # noqa: E402

SURGIPLAN = [sys.executable, "-m", "surgiplan.cli"]
PATH_MM = 190.0  # about the beginner's recommended path in the block world


def pipeline(tmp: Path, name: str, guide: dict) -> Path:
    stages = [
        recommended_stage("beginner", 2000, k=15, artifact=tmp / "roadmap.npz"),
        {"stage": "guide", "name": "attempt", "plugin": "synthetic_trainee", "path_from": "recommended", **guide},
    ]
    return block_world_pipeline(tmp / f"{name}.yaml", name, stages, tmp / name, record=str(tmp / "record.sqlite"))


def run(path: Path, *extra: str) -> None:
    done = subprocess.run([*SURGIPLAN, "run", str(path), "--quiet", *extra], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{path}: {done.stderr}")


def page_run(browser: Browser, attempt: Path) -> tuple[list[float], list[float]]:
    """Sample-to-pixels latencies (ms) of one attempt watched by a page, and sample to the page's handling of it."""
    with live_view(exit_after=600) as url:
        page = browser.page(url + "#latency", ready="window.surgiplan && surgiplan.ready && surgiplan.live.connected")
        run(attempt, "--live", feed_url(url))
        wait_for(page, "surgiplan.live.status !== null && surgiplan.live.pending.length === 0", 60_000)
        latencies = page.evaluate("surgiplan.live.cueLatency")
        arrivals = page.evaluate("surgiplan.live.arrivalLatency")
        problems = page.problems + page.evaluate("surgiplan.errors")
        page.close()
        if problems:
            raise SystemExit(f"the page reported problems: {problems}")
        return latencies, arrivals


def transport_run(attempt: Path) -> list[float]:
    """Sample-to-arrival latencies (ms) at a websocket watcher in Python: the stage, the feed and the relay."""
    latencies: list[float] = []

    def arrived(item: dict, now: float) -> None:
        if item["channel"] == "tip" and "wall" in item["payload"]:
            latencies.append(1000 * (now - item["payload"]["wall"]))

    with live_view(exit_after=600) as url:
        thread = threading.Thread(target=watch_live, args=(url, arrived), daemon=True)
        thread.start()
        time.sleep(1.0)
        run(attempt, "--live", feed_url(url))
        thread.join(60)
        return latencies


def summary(case: str, values: list[float], runs: int) -> dict:
    a = np.asarray(values, float)
    return {
        "case": case,
        "runs": runs,
        "samples": len(a),
        "median_ms": round(float(np.median(a)), 2),
        "p95_ms": round(float(np.percentile(a, 95)), 2),
        "p99_ms": round(float(np.percentile(a, 99)), 2),
        "max_ms": round(float(a.max()), 2),
    }


def main() -> None:
    runs, seconds, quick = paced_run_arguments(__doc__.splitlines()[0])
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        expert = {"settings": {"level": "expert", "seed": 1, "pace": 0}, "trainee": {"name": "ann", "task": "bw"}}
        run(pipeline(tmp, "expert", expert))  # the ghost's attempt, and the roadmap stored for the runs below
        guide = {
            "settings": {"level": "beginner", "seed": 3, "pace": 1, "rate": 100, "speed": PATH_MM / seconds},
            "trainee": {"name": "eve", "task": "bw"},
            "ghost": {"trainee": "ann"},
        }
        attempt = pipeline(tmp, "attempt", guide)
        browser = Browser()
        pooled, arrived, per_run = [], [], []
        try:
            for i in range(runs):
                latencies, arrivals = page_run(browser, attempt)
                pooled += latencies
                arrived += arrivals
                per_run.append(summary(f"page, run {i + 1}", latencies, 1))
                print(table(per_run[-1:], list(per_run[-1])), flush=True)
        finally:
            browser.close()
        transport = []
        for _ in range(runs):
            transport += transport_run(attempt)
    rows = [
        summary("sample to pixels (headless chromium, software WebGL)", pooled, runs),
        summary("sample to the page's handling of its message (stage, feed, relay, page's queue)", arrived, runs),
        summary("sample to a watcher in Python (stage, feed, relay)", transport, runs),
        *per_run,
    ]
    print(table(rows, list(rows[0])))
    if quick:
        return
    after = os.getloadavg()
    notes = (
        f"load average before {load[0]:.2f}/{load[1]:.2f}/{load[2]:.2f} and after {after[0]:.2f}/{after[1]:.2f}/"
        f"{after[2]:.2f} (1/5/15 min; 2 cores, shared); 100 samples/s, {seconds:g} s attempts; target p99 < 50 ms"
    )
    chromium = subprocess.run(["chromium", "--version"], capture_output=True, text=True).stdout.strip()
    print(
        "wrote",
        save(
            "cues",
            rows,
            notes,
            peers={
                "chromium": {
                    "version": chromium,
                    "configuration": "headless, SwiftShader (no GPU), tests/browser_support.py",
                }
            },
        ),
    )


if __name__ == "__main__":
    main()
