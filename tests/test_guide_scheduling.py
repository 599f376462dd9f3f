"""The guide stage's attempt as a paced loop (surgiplan.scheduling): the source's thread and the stage's ask the
scheduler for the shortest slice, or run under SCHED_FIFO at guidance.realtime_priority, and give the process back
as it was."""

from __future__ import annotations

import os
import sys

import pytest
from test_guide import guide_pipeline


def _at_the_sixth_sample(monkeypatch, probe) -> list:
    """What ``probe()`` returns in the synthetic trainee's thread as it yields its sixth sample (the attempt under
    way), appended to the list returned."""
    from surgiplan.plugins.guidance.synthetic import SyntheticTrainee

    seen = []
    original = SyntheticTrainee.samples

    def watched(self):
        for i, sample in enumerate(original(self)):
            if i == 5:
                seen.append(probe())
            yield sample

    monkeypatch.setattr(SyntheticTrainee, "samples", watched)
    return seen


def test_a_guide_attempt_runs_as_a_paced_loop_and_gives_the_process_back(tmp_path, monkeypatch):
    """While the attempt runs, the source's thread and the stage's ask the scheduler for the short slice
    (scheduling.LOOP_SLICE: a waking one preempts a busy viewer instead of waiting out its slice); Python's switch
    interval stays (a short one would hand the GIL to the feed's sender in the middle of a sample's analysis);
    afterwards the stage's thread is as it was."""
    import threading

    from surgiplan import load_pipeline, run_pipeline
    from surgiplan.scheduling import LOOP_SLICE, restore_priority, sched_attr, set_realtime_priority

    before = sched_attr()
    granted = sched_attr() if (asked := set_realtime_priority(None)) is not None else None
    restore_priority(asked)
    slice_ns = round(LOOP_SLICE * 1e9)
    stage_thread = threading.get_native_id()
    seen = _at_the_sixth_sample(monkeypatch, lambda: (sched_attr(), sched_attr(stage_thread), sys.getswitchinterval()))
    switch = sys.getswitchinterval()
    outcome = run_pipeline(load_pipeline(guide_pipeline(tmp_path)))
    assert outcome.results[1].status in ("completed", "incomplete")
    ((source_attr, stage_attr, interval),) = seen
    assert interval == switch == sys.getswitchinterval()
    if granted is None or granted.runtime != slice_ns:
        pytest.skip(f"this kernel grants no slice to an ordinary thread ({os.uname().release})")
    assert source_attr.policy == stage_attr.policy == os.SCHED_OTHER
    assert source_attr.runtime == stage_attr.runtime == slice_ns
    assert sched_attr() == before


def test_a_guide_attempt_with_a_realtime_priority_runs_under_sched_fifo(tmp_path, monkeypatch):
    """guidance.realtime_priority: the source's thread and the stage's run under SCHED_FIFO at it while the attempt
    runs (nothing at ordinary priority, such as a browser rendering the live view, can delay a sample); the stage's
    thread is ordinary again afterwards. Where SCHED_FIFO is not allowed, the stage fails with a message naming the
    key, before any sample is taken."""
    import threading

    from surgiplan import load_pipeline, run_pipeline

    stage_thread = threading.get_native_id()
    seen = _at_the_sixth_sample(
        monkeypatch,
        lambda: [(os.sched_getscheduler(t), os.sched_getparam(t).sched_priority) for t in (0, stage_thread)],
    )
    path = guide_pipeline(tmp_path, guidance={"realtime_priority": 7})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except OSError:
        allowed = False
    else:
        allowed = True
    if allowed:
        outcome = run_pipeline(load_pipeline(path))
        assert outcome.results[1].status in ("completed", "incomplete")
        assert seen == [[(os.SCHED_FIFO, 7), (os.SCHED_FIFO, 7)]]
        assert os.sched_getscheduler(0) == os.SCHED_OTHER
    seen.clear()

    def refuse(*args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    from surgiplan.errors import StageError
    from surgiplan.plugins.guidance.synthetic import SyntheticTrainee

    closed = []
    close = SyntheticTrainee.close
    monkeypatch.setattr(SyntheticTrainee, "close", lambda self: (closed.append(self), close(self))[1])
    with pytest.raises(StageError, match=r"guidance.realtime_priority 7 \(SCHED_FIFO\) is not allowed here \(Op"):
        run_pipeline(load_pipeline(path))
    assert seen == []
    assert len(closed) == 1  # the source made for the attempt is closed, though it never opened


def test_the_live_feeds_sender_runs_just_below_the_attempt_while_it_runs(tmp_path, monkeypatch):
    """A live feed's sender thread holds the GIL while it encodes; preempted then by an ordinary task (a browser
    rendering the page), it would hold up the stage's SCHED_FIFO thread until it ran again. While the attempt runs
    it is under SCHED_FIFO one below guidance.realtime_priority, and as it was afterwards."""
    import threading

    from surgiplan import load_pipeline, run_pipeline
    from surgiplan.live import LiveFeed

    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except OSError:
        pytest.skip("SCHED_FIFO is not allowed here")

    class Sending(LiveFeed):
        """A feed with a sender thread of its own, as WebSocketFeed has."""

        active = True

        def __init__(self):
            self.stop = threading.Event()
            self.sender = threading.Thread(target=self.stop.wait, args=(60,), daemon=True)
            self.sender.start()

        def threads(self):
            return [self.sender.native_id]

    feed = Sending()
    sender = feed.sender.native_id
    seen = _at_the_sixth_sample(monkeypatch, lambda: (os.sched_getscheduler(sender), os.sched_getparam(sender)))
    import surgiplan.runner as runner

    original = runner.StageContext
    monkeypatch.setattr(runner, "StageContext", lambda *a, **k: original(*a, **{**k, "live": feed}))
    try:
        outcome = run_pipeline(load_pipeline(guide_pipeline(tmp_path, guidance={"realtime_priority": 7})))
        assert outcome.results[1].status in ("completed", "incomplete")
        ((policy, param),) = seen
        assert (policy, param.sched_priority) == (os.SCHED_FIFO, 6)
        assert os.sched_getscheduler(sender) == os.SCHED_OTHER and os.sched_getparam(sender).sched_priority == 0
    finally:
        feed.stop.set()


def test_a_feed_names_its_sender_thread():
    """WebSocketFeed.threads: its sender's native id while it runs (here trying to reach a viewer nobody started),
    none once closed; the feed nobody watches has none."""
    from surgiplan.live import LiveFeed, WebSocketFeed

    assert LiveFeed().threads() == []
    feed = WebSocketFeed("ws://127.0.0.1:9/feed", retry_for=5.0, open_timeout=0.2)
    try:
        assert feed.threads() == [feed._thread.native_id] and feed.threads()[0] > 0
    finally:
        feed.close(timeout=3.0)
    assert feed.threads() == []


def test_a_guide_attempt_collects_garbage_between_samples_only(tmp_path, monkeypatch):
    """While the attempt runs, what existed before it is frozen out of the collector's sight (its passes, which
    hold the GIL, scan only what the attempt makes) and the automatic passes are off; the stage's thread runs the
    passes itself once a sample is done (scheduling.SlackCollector): every pass of the attempt falls between two
    samples' analyses, none inside one, and none in the source's thread. Afterwards the heap is as before."""
    import gc
    import threading
    import time

    from surgiplan import load_pipeline, run_pipeline
    from surgiplan.guidance.analysis import Guide
    from surgiplan.scheduling import BACKLOG_FACTOR

    before = gc.get_freeze_count()
    assert before == 0 and gc.isenabled()
    made: list = []

    def probe():  # in the source's thread: enough new objects that a pass is due even with samples waiting
        made.extend([] for _ in range(BACKLOG_FACTOR * gc.get_threshold()[0] + 1))
        return gc.get_freeze_count(), gc.isenabled()

    seen = _at_the_sixth_sample(monkeypatch, probe)
    analyses: list[tuple[float, float, int]] = []  # each sample's analysis: start, end, its thread
    passes: list[tuple[float, int, int]] = []  # each pass: its start, generation, thread
    measure = Guide.measure

    def timed(self, sample):
        start = time.perf_counter()
        try:
            return measure(self, sample)
        finally:
            analyses.append((start, time.perf_counter(), threading.get_native_id()))

    def noted(phase, info):
        if phase == "start":
            passes.append((time.perf_counter(), info["generation"], threading.get_native_id()))

    monkeypatch.setattr(Guide, "measure", timed)
    gc.callbacks.append(noted)
    try:
        outcome = run_pipeline(load_pipeline(guide_pipeline(tmp_path)))
    finally:
        gc.callbacks.remove(noted)
    assert outcome.results[1].status in ("completed", "incomplete")
    ((frozen, enabled),) = seen
    assert frozen > 10_000 and not enabled
    assert gc.get_freeze_count() == 0 and gc.isenabled()
    first, last = analyses[0][0], analyses[-1][1]
    during = [p for p in passes if first <= p[0] <= last]
    stage = analyses[0][2]
    assert len(analyses) > 100 and {a[2] for a in analyses} == {stage}
    assert len(during) >= 1 and {p[1] for p in during} <= {0, 1}, during  # young passes ran, in time
    assert all(thread == stage for _, _, thread in during)
    for start, _, _ in during:  # never inside an analysis
        assert not any(a <= start <= b for a, b, _ in analyses), start
