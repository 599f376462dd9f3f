"""The live view never slows the stage it watches: a paced attempt with a page and a stalled client attached, and
the same attempt with no viewer.

A guide stage follows a synthetic beginner paced in real time at 100 samples/s (``--seconds``, default 20 s per
attempt), run in this process with a recording feed: for every sample, the moment the stage is done with it
(its analysis and its publication) on ``time.perf_counter``. A sample's *lateness* is how far behind its own
time ``t`` that moment is, less the attempt's smallest such lag (the best any sample did). Two cases, alternated
``--runs`` times (default 3):

* **no viewer**: the stage publishes as it does when watched (the same payloads), but to nothing;
* **viewer**: the feed goes to ``surgiplan view --live`` (another process, with its token), watched by one
  headless chromium page (Debian's, software WebGL) and one *stalled* client: a raw socket that upgrades to
  ``/watch`` and then never reads (the viewer must drop it, not wait for it). The page is a trainer's: nothing
  automates it while the attempt runs (``benchmarks/unattended_page.py``; a page Playwright drives gets every
  websocket frame serialised for Playwright's driver, work no trainer's browser does).

Both with the stage's threads at ordinary priority (the shortest slice EEVDF grants) and under SCHED_FIFO 10
(``guidance.realtime_priority``, as a real-time control loop runs): on 2 cores, a page rendering WebGL in software
keeps both busy, and only a real-time policy wins every wake-up from it (a C probe at ordinary priority, with or
without the short slice, wakes more than 2 ms late ~50 times in 10 s beside the page; under SCHED_FIFO, never).

Each attempt runs beside a stall witness (``benchmarks/witness.py``: on each CPU a process pinned to it under
SCHED_FIFO 99 waking every millisecond, which nothing inside the machine can delay) and records the stolen time
(``steal_ticks_*``, /proc/stat, in 10 ms ticks): on this virtual machine the host sometimes runs other guests on our
cores, and then no scheduling inside it is on time. A late sample during which the witness was late too is counted apart
(``*_during_machine_stalls``): the machine stopped then, not the stage.

Each attempt itself also runs under the kernel's scheduler trace (``benchmarks/schedtrace.py``: ftrace's sched_waking,
sched_wakeup and sched_switch; root and tracefs, else ``sched_trace`` says it was not available) of the stage's
threads: the one that follows the samples (and publishes them) and the source's reader (``guide-source``, which
sleeps until each sample is due). For every sample more than 2 ms late, and every one the viewer delayed, the slowest
wake-up of those threads from the sample's due time (when it would have been done as quickly as the attempt's best,
the span the witness is asked about) to when the stage was done with it: its thread, its delivery (sched_waking to
sched_wakeup: on this virtual machine a halted CPU run again, the host's), its wait in a run queue (to sched_switch),
and what ``readme_blocks.formatting.wakeup_cause`` makes of it (``host``, ``queue`` or ``none``); per attempt, the
slowest wake-up of those threads overall (``schedtrace.summary``).

Counted: samples more than 2 ms late in each case; and paired, sample by sample (the same seed gives the same
samples), samples the viewer delayed by more than 2 ms over the same sample with no viewer. Target: 0. Also
recorded: when the stalled client was disconnected (its socket's TCP state, read without reading its data), and
what the page got and was told it lost. The machine is shared: the load average before and after is recorded.

    python benchmarks/bench_live_delay.py [--runs N] [--seconds S] [--quick]   (--quick: 1 run of 8 s, writes nothing)
"""

from __future__ import annotations

import gc
import os
import socket
import struct
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

from browser_support import feed_url, live_view, stalled_client, wait_for  # noqa: E402
from common import paced_run_arguments, save, table  # noqa: E402
from cyclictest import cyclictest_floor  # noqa: E402
from pipeline_support import block_world_pipeline, recommended_stage  # noqa: E402
from readme_blocks.formatting import wakeup_cause  # noqa: E402
from schedtrace import SchedTrace, benchmark_threads, slowest_during  # noqa: E402
from schedtrace import summary as schedtrace_summary  # noqa: E402
from unattended_page import UnattendedBrowser  # noqa: E402
from witness import Witness  # noqa: E402

PATH_MM = 190.0  # about the beginner's recommended path in the block world
LATE_MS = 2.0
#: the attempt's samples a second (the synthetic trainee's rate, paced in real time)
RATE = 100
#: the stage's threads at ordinary priority (the shortest slice, surgiplan.scheduling), then under SCHED_FIFO
#: (guidance.realtime_priority), as a real-time loop runs
SCHEDULING = (("ordinary", None), ("SCHED_FIFO 10", 10))
TCP_CLOSE, TCP_CLOSE_WAIT = 7, 8
TRACED = "ftrace sched_waking/wakeup/switch"
#: the late samples whose slowest wake-up a run's results list (all are counted)
LISTED = 20
#: a delayed sample during a collector pass this long (ms) or longer is counted as delayed during a collection
GC_MS = 0.5


class Recording:
    """A live feed that notes when the stage is done with each sample, and passes everything on (or not)."""

    active = True

    def __init__(self, inner=None) -> None:
        self.inner = inner
        self.done: list[tuple[float, float]] = []  # (the sample's t, perf_counter after its publication)
        self.traced: dict[int, str] = {}  # the stage's threads, taken at its first sample (stage_threads)
        #: the garbage collector's passes in this process while the feed is open: (start, end perf_counter s,
        #: generation); a pass holds the GIL, so every thread of the stage waits for it
        self.collections: list[tuple[float, float, int]] = []
        self._collecting: float | None = None
        gc.callbacks.append(self._collector)

    def _collector(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._collecting = time.perf_counter()
        elif self._collecting is not None:
            self.collections.append((self._collecting, time.perf_counter(), int(info["generation"])))
            self._collecting = None

    def publish(self, channel: str, payload) -> None:
        if self.inner is not None:
            self.inner.publish(channel, payload)
        if channel == "tip":
            self.done.append((float(payload["t"]), time.perf_counter()))
            if not self.traced:  # after the sample's time is taken: it costs that sample nothing
                self.traced = stage_threads()

    def threads(self) -> list[int]:
        return self.inner.threads() if self.inner is not None else []

    def close(self) -> None:
        if self._collector in gc.callbacks:
            gc.callbacks.remove(self._collector)
        if self.inner is not None:
            self.inner.close(timeout=10)

    def collection_during(self, start: float, end: float) -> tuple[float, int | None]:
        """The longest collector pass that overlapped ``start``-``end`` (perf_counter s): its length (s) and
        generation (None: none)."""
        longest, generation = 0.0, None
        for a, b, g in self.collections:
            if a < end and b > start and b - a > longest:
                longest, generation = b - a, g
        return longest, generation

    def lateness_ms(self) -> np.ndarray:
        t, done = np.asarray(self.done).T
        lag = done - t
        return 1000 * (lag - lag.min())

    def done_at(self) -> np.ndarray:
        """When the stage was done with each sample (perf_counter s)."""
        return np.asarray(self.done)[:, 1]


def stage_threads() -> dict[int, str]:
    """The guide stage's threads by id, called from the stage while it runs (it publishes from the thread that
    follows the samples): that one ("stage") and the source's reader ("guide-source", the stage's ``_Reader``)."""
    threads = {threading.get_native_id(): "stage"}
    threads.update({tid: name for tid, name in benchmark_threads().items() if name == "guide-source"})
    return threads


def slowest_wakeups(
    rows: dict[int, np.ndarray] | None,
    threads: dict[int, str],
    done: np.ndarray,
    lateness_ms: np.ndarray,
    which: np.ndarray,
    feed: Recording | None = None,
) -> list[dict]:
    """For each sample ``which`` picks: the slowest wake-up of the stage's ``threads`` (``rows``:
    :meth:`SchedTrace.wakeups`) from its due time (when it would have been done as quickly as the attempt's best:
    ``done`` less its lateness, the span :func:`during_stalls` asks the witness about) to ``done``: its thread, its
    delivery (the host's), its wait in a run queue, in all (ms), and its cause as ``wakeup_cause`` says it; with the
    ``feed``, also the longest garbage collector pass in that span (``gc_ms``, ``gc_generation``). None (no trace):
    none."""
    if rows is None:
        return []
    out = []
    for i in np.flatnonzero(which):
        wait, tid, delivery = slowest_during(rows, done[i] - lateness_ms[i] / 1000, done[i])
        wait, delivery = float(wait), float(delivery)
        row = {
            "sample": int(i),
            "late_ms": round(float(lateness_ms[i]), 3),
            "thread": threads.get(tid, str(tid)) if tid is not None else None,
            "delivery_ms": round(1e3 * delivery, 3),
            "run_queue_ms": round(1e3 * (wait - delivery), 3),
            "wakeup_ms": round(1e3 * wait, 3),
        }
        if feed is not None:
            collecting, generation = feed.collection_during(done[i] - lateness_ms[i] / 1000, done[i])
            row["gc_ms"], row["gc_generation"] = round(1e3 * collecting, 3), generation
        row["cause"] = wakeup_cause(row["wakeup_ms"], row["delivery_ms"])
        out.append(row)
    return out


def causes(samples: list[dict]) -> dict[str, int]:
    """How many of :func:`slowest_wakeups`' samples had each cause."""
    return {cause: sum(1 for s in samples if s["cause"] == cause) for cause in ("host", "queue", "none")}


def traced_attempt(trace: SchedTrace, threads: dict[int, str]) -> tuple[dict[int, np.ndarray] | None, dict]:
    """An attempt's wake-ups of the stage's threads (None without the trace) and its summary: whether the trace
    ran, the slowest wake-up (``schedtrace.summary``) and the events the trace's buffer lost (0: none)."""
    info = schedtrace_summary(trace, threads)
    if not trace.available:
        return None, info
    return trace.wakeups(threads), {"sched_trace": TRACED, **info, "trace_events_lost": trace.events_lost()}


def during_stalls(witness: Witness, done: np.ndarray, lateness_ms: np.ndarray) -> np.ndarray:
    """Which samples were late while the stall witness was late too: its late wake-up overlaps the time the
    sample waited beyond the best (from ``done`` less its lateness to ``done``)."""
    waited_from = done - lateness_ms / 1000
    return np.array([witness.late_during(a, b) > 0 for a, b in zip(waited_from, done, strict=True)], dtype=bool)


def pipeline(tmp: Path, seconds: float, priority: int | None) -> Path:
    guide = {
        "stage": "guide",
        "name": "attempt",
        "plugin": "synthetic_trainee",
        "path_from": "recommended",
        "settings": {"level": "beginner", "seed": 3, "pace": 1, "rate": RATE, "speed": PATH_MM / seconds},
        **({"guidance": {"realtime_priority": priority}} if priority else {}),
    }
    stages = [recommended_stage("beginner", 2000, k=15, artifact=tmp / "roadmap.npz"), guide]
    return block_world_pipeline(tmp / "live-delay.yaml", "live-delay", stages, tmp / "out")


def attempt(path: Path, feed: Recording) -> np.ndarray:
    """The attempt's lateness per sample (ms; ``feed.done_at()``: when each was done)."""
    from surgiplan import load_pipeline, run_pipeline
    from surgiplan.outputs.report import scene_data

    loaded = load_pipeline(path)
    feed.publish("run", {"name": loaded.name, "length_unit": "mm", "unit_scale": 1e-3})
    feed.publish("scene", scene_data(loaded.scene))
    outcome = run_pipeline(loaded, live=feed)
    feed.close()
    status = outcome.results[-1].status
    if status not in ("completed", "incomplete"):
        raise SystemExit(f"the attempt ended {status}")
    return feed.lateness_ms()


def tcp_state(sock: socket.socket) -> int:
    """The socket's TCP state (Linux ``tcp_info.tcpi_state``), read without taking any of its data."""
    return struct.unpack("B", sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 1))[0]


def watched_attempt(
    path: Path, browser: UnattendedBrowser, trace: SchedTrace
) -> tuple[np.ndarray, np.ndarray, dict, Recording]:
    """The watched attempt's lateness per sample (ms), when each was done (perf_counter s), what the page and
    the stalled client went through, and its recording feed (the stage's threads, the collector's passes);
    ``trace`` records the attempt itself (not the viewer's and the page's start)."""
    from surgiplan.live import WebSocketFeed

    with live_view(exit_after=600) as url:
        page = browser.page(url, ready="window.surgiplan && surgiplan.ready && surgiplan.live.connected")
        stalled = stalled_client(url)
        started = time.monotonic()
        cut: list[float] = []

        def watch_stalled() -> None:
            for _ in range(100_000):  # bounded: 0.05 s apart, far longer than an attempt
                if tcp_state(stalled) in (TCP_CLOSE, TCP_CLOSE_WAIT):
                    cut.append(time.monotonic() - started)
                    return
                if stop.wait(0.05):
                    return

        stop = threading.Event()
        watcher = threading.Thread(target=watch_stalled, daemon=True)
        watcher.start()
        feed = Recording(WebSocketFeed(feed_url(url)))
        with trace:
            lateness = attempt(path, feed)
        wait_for(page, "surgiplan.live.status !== null", 60_000)
        got = page.evaluate(
            "({tips: surgiplan.live.tips, drops: surgiplan.live.drops, frames: surgiplan.live.frames,"
            " fps: surgiplan.live.fps, renderer: surgiplan.live.renderer})"
        )
        problems = page.problems + page.evaluate("surgiplan.errors")
        page.close()
        for _ in range(200):  # the viewer drops a stalled page within seconds of its queue filling up
            if cut:
                break
            time.sleep(0.05)
        stop.set()
        watcher.join(5)
        stalled.close()
        if problems:
            raise SystemExit(f"the page reported problems: {problems}")
        return (
            lateness,
            feed.done_at(),
            {
                "page_samples": got["tips"],
                "page_drops": got["drops"]["page"],
                "feed_drops": got["drops"]["feed"],
                "stalled_cut_after_s": round(cut[0], 2) if cut else None,
                # the frames the page drew in its budget (report.js: 30 a second on a software renderer)
                "page_frames": got["frames"],
                "page_fps_budget": got["fps"],
                "page_renderer": got["renderer"],
            },
            feed,
        )


def summary(case: str, runs: list[np.ndarray], scheduling: str, **extra) -> dict:
    a = np.concatenate(runs)
    return {
        "scheduling": scheduling,
        "case": case,
        "runs": len(runs),
        "samples": int(a.size),
        "late_over_2ms": int(np.count_nonzero(a > LATE_MS)),
        "median_ms": round(float(np.median(a)), 3),
        "p99_ms": round(float(np.percentile(a, 99)), 3),
        "max_ms": round(float(a.max()), 3),
        **extra,
    }


def case_trace(attempts: list[dict], late: list[dict], delayed: list[dict] | None = None) -> dict:
    """A case's trace over its runs: whether it ran, its attempts' slowest wake-ups (``attempts``:
    :func:`traced_attempt`'s summaries) and the causes of its late samples (and of those the viewer delayed)."""
    if not all(a.get("sched_trace") == TRACED for a in attempts):
        return {"sched_trace": attempts[0]["sched_trace"] if attempts else "not run"}
    out = {
        "sched_trace": TRACED,
        "wakeups": sum(a["wakeups"] for a in attempts),
        "wakeups_over_1ms": sum(a["wakeups_over_1ms"] for a in attempts),
        "wakeup_max_ms": max(a["wakeup_max_ms"] for a in attempts),
        "delivery_max_ms": max(a["delivery_max_ms"] for a in attempts),
        "late_wakeup_causes": causes(late),
    }
    if delayed is not None:
        out["delayed_wakeup_causes"] = causes(delayed)
    return out


def collector(feed: Recording, case: str) -> dict:
    """The garbage collector's passes during an attempt: how many of each generation, and the longest (ms)."""
    passes = feed.collections
    counts = [sum(1 for *_, g in passes if g == generation) for generation in (0, 1, 2)]
    longest, generation = max(((b - a, g) for a, b, g in passes), default=(0.0, None))
    return {
        f"gc_passes_{case}": counts,
        f"gc_longest_ms_{case}": round(1e3 * longest, 3),
        f"gc_longest_generation_{case}": generation,
    }


def run_trace(alone: dict, watched: dict, late_alone: list[dict], late: list[dict], delayed: list[dict]) -> dict:
    """A run's trace fields: whether it ran, the slowest wake-up of each attempt, the causes of the late and the
    delayed samples, and the first :data:`LISTED` of each attempt's late samples (:func:`slowest_wakeups`)."""
    if alone.get("sched_trace") != TRACED or watched.get("sched_trace") != TRACED:
        return {"sched_trace": watched.get("sched_trace") or alone.get("sched_trace")}
    out = {"sched_trace": TRACED}
    for key in ("wakeups_over_1ms", "wakeup_max_ms", "delivery_max_ms", "trace_events_lost"):
        out[f"{key}_alone"], out[f"{key}_watched"] = alone[key], watched[key]
    out["delayed_wakeup_causes"] = causes(delayed)
    out["late_wakeup_causes"] = causes(late)
    out["late_alone_wakeup_causes"] = causes(late_alone)
    out["late_slowest_wakeups"] = late[:LISTED]
    out["late_alone_slowest_wakeups"] = late_alone[:LISTED]
    return out


def main() -> None:
    runs, seconds, quick = paced_run_arguments(__doc__.splitlines()[0])
    load = os.getloadavg()
    rows, viewer_runs = [], []
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        browser = UnattendedBrowser()
        try:
            for scheduling, priority in SCHEDULING:
                path = pipeline(tmp, seconds, priority)
                attempt(path, Recording())  # plans and stores the roadmap; a warm-up
                alone, watched, paired = [], [], []
                traces_alone, traces_watched = [], []  # per run: the attempt's trace summary (traced_attempt)
                late_alone_all, late_all, delayed_all = [], [], []  # the late samples' slowest wake-ups
                for i in range(runs):
                    with Witness() as witness_alone, SchedTrace() as trace:
                        feed = Recording()
                        alone.append(attempt(path, feed))
                    alone_stalled = during_stalls(witness_alone, feed.done_at(), alone[-1]) & (alone[-1] > LATE_MS)
                    wakeups, trace_alone = traced_attempt(trace, feed.traced)
                    late_alone = slowest_wakeups(
                        wakeups, feed.traced, feed.done_at(), alone[-1], alone[-1] > LATE_MS, feed
                    )
                    trace = SchedTrace()
                    with Witness() as witness_watched:
                        lateness, done, info, watched_feed = watched_attempt(path, browser, trace)
                    watched.append(lateness)
                    n = min(lateness.size, alone[-1].size)
                    paired.append(lateness[:n] - alone[-1][:n])
                    delayed = paired[-1] > LATE_MS
                    stalled_delays = during_stalls(witness_watched, done[:n], lateness[:n]) & delayed
                    late = int(np.count_nonzero(lateness > LATE_MS))
                    wakeups, trace_watched = traced_attempt(trace, watched_feed.traced)
                    late_watched = slowest_wakeups(
                        wakeups, watched_feed.traced, done, lateness, lateness > LATE_MS, watched_feed
                    )
                    for s in late_watched:  # a sample the viewer delayed is late (it is no earlier alone)
                        if s["sample"] < n:
                            s["delayed_ms"] = round(float(paired[-1][s["sample"]]), 3)
                    late_delayed = [s for s in late_watched if s["sample"] < n and delayed[s["sample"]]]
                    traces_alone.append(trace_alone)
                    traces_watched.append(trace_watched)
                    late_alone_all += late_alone
                    late_all += late_watched
                    delayed_all += late_delayed
                    viewer_runs.append({
                        "scheduling": scheduling,
                        "run": i + 1,
                        "late_over_2ms": late,
                        "delayed_by_viewer_over_2ms": int(np.count_nonzero(delayed)),
                        "delayed_during_machine_stalls": int(np.count_nonzero(stalled_delays)),
                        "late_alone_over_2ms": int(np.count_nonzero(alone[-1] > LATE_MS)),
                        "late_alone_during_machine_stalls": int(np.count_nonzero(alone_stalled)),
                        **info,
                        "steal_ticks_alone": witness_alone.steal,
                        "steal_ticks_watched": witness_watched.steal,
                        "witness_late_max_ms_alone": witness_alone.summary()["witness_late_max_ms"],
                        "witness_late_max_ms_watched": witness_watched.summary()["witness_late_max_ms"],
                        "witness": witness_watched.policy,
                        **run_trace(trace_alone, trace_watched, late_alone, late_watched, late_delayed),
                        **collector(feed, "alone"),
                        **collector(watched_feed, "watched"),
                        "delayed_during_collections": sum(1 for d in late_delayed if d.get("gc_ms", 0) >= GC_MS),
                    })  # fmt: skip
                    print({k: v for k, v in viewer_runs[-1].items() if not isinstance(v, list)}, flush=True)
                    for s in late_delayed[:LISTED]:
                        print(f"  delayed by the viewer: {s}", flush=True)
                    if len(late_delayed) > LISTED:
                        print(f"  ... and {len(late_delayed) - LISTED} more delayed samples", flush=True)
                delayed = int(sum(np.count_nonzero(p > LATE_MS) for p in paired))
                rows += [
                    summary("no viewer", alone, scheduling, **case_trace(traces_alone, late_alone_all)),
                    summary(
                        "viewer: a page and a stalled client",
                        watched,
                        scheduling,
                        delayed_by_viewer_over_2ms=delayed,
                        paired_p99_ms=round(float(np.percentile(np.concatenate(paired), 99)), 3),
                        paired_max_ms=round(float(np.concatenate(paired).max()), 3),
                        **case_trace(traces_watched, late_all, delayed_all),
                    ),
                ]
        finally:
            browser.close()
    print(table(rows, list(rows[1])))
    print(table(viewer_runs, [k for k, v in viewer_runs[0].items() if not isinstance(v, list)]))
    # the machine's floor for the same deadline, measured by rt-tests' cyclictest in the same session: the stage's
    # rate and priority under SCHED_FIFO, a wake-up later than LATE_MS a lapse, as many runs as attempts, as long
    fifo = next(p for _, p in SCHEDULING if p)
    floor = cyclictest_floor(
        2 * runs, seconds, False, priority=fifo, interval_us=round(1e6 / RATE), late_us=round(1000 * LATE_MS)
    )
    print(floor, flush=True)
    if quick:
        return
    after = os.getloadavg()
    notes = (
        f"load average before {load[0]:.2f}/{load[1]:.2f}/{load[2]:.2f} and after {after[0]:.2f}/{after[1]:.2f}/"
        f"{after[2]:.2f} (1/5/15 min; 2 cores, shared); {RATE} samples/s, {seconds:g} s attempts; target: 0 samples "
        f"delayed by more than {LATE_MS:g} ms by the viewer"
    )
    chromium = subprocess.run(["chromium", "--version"], capture_output=True, text=True).stdout.strip()
    print(
        "wrote",
        save(
            "live_delay",
            rows,
            notes,
            peers={
                "chromium": {
                    "version": chromium,
                    "configuration": "headless, SwiftShader (no GPU), the flags of tests/browser_support.py; no "
                    "automation attached during the attempt (benchmarks/unattended_page.py)",
                }
            },
            extra={"viewer_runs": viewer_runs, "seconds": seconds, "late_ms": LATE_MS, "floor": floor},
        ),
    )


if __name__ == "__main__":
    main()
