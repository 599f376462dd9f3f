"""surgiplan.scheduling.paced_section: what it changes for the body and that it gives everything back."""

from __future__ import annotations

import gc
import sys
import time
from pathlib import Path

import pytest
from surgiplan.errors import ConfigError
from surgiplan.scheduling import (
    CPU_LATENCY_ENV,
    CPU_LATENCY_US,
    SWITCH_INTERVAL,
    cpu_latency_now,
    cpu_latency_setting,
    paced_section,
)


@pytest.fixture
def unfrozen_collector():
    gc.unfreeze()
    enabled = gc.isenabled()
    gc.enable()
    yield
    gc.unfreeze()
    if not enabled:
        gc.disable()


def test_a_paced_section_pauses_the_collector_and_freezes_the_heap_then_gives_both_back(unfrozen_collector):
    switch = sys.getswitchinterval()
    with paced_section(pause_collector=True):
        assert not gc.isenabled()
        assert gc.get_freeze_count() > 0  # what existed at entry is out of the collector's sight
        assert sys.getswitchinterval() == pytest.approx(SWITCH_INTERVAL)
    assert gc.isenabled()
    assert gc.get_freeze_count() == 0
    assert sys.getswitchinterval() == pytest.approx(switch)


def test_a_heap_frozen_by_its_owner_stays_frozen_as_it_was(unfrozen_collector):
    gc.freeze()  # a device's heap, frozen at activation
    frozen = gc.get_freeze_count()
    kept = [[] for _ in range(1000)]  # made after: a paced section must not freeze these for good
    with paced_section(pause_collector=True, switch_interval=None):
        assert not gc.isenabled()
        assert gc.get_freeze_count() == frozen
    assert gc.isenabled()
    assert gc.get_freeze_count() == frozen
    assert len(kept) == 1000


def test_without_pausing_the_collector_keeps_running_and_nothing_is_frozen(unfrozen_collector):
    with paced_section(switch_interval=None):
        assert gc.isenabled()
        assert gc.get_freeze_count() == 0
    assert gc.isenabled()


def _slow_idle_entries() -> int | None:
    """How many times any CPU entered an idle state that takes time to leave (exit latency above 0), by the kernel's
    cpuidle counters (None where the machine has no such state)."""
    states = [
        d
        for d in Path("/sys/devices/system/cpu").glob("cpu[0-9]*/cpuidle/state[0-9]*")
        if int((d / "latency").read_text()) > 0
    ]
    return sum(int((d / "usage").read_text()) for d in states) if states else None


def _idle_entries_while_sleeping(seconds: float = 0.2) -> int | None:
    slow = _slow_idle_entries()
    time.sleep(seconds)  # both CPUs idle, but for this thread's timer
    return None if slow is None else _slow_idle_entries() - slow


def test_asked_to_a_paced_section_keeps_the_cpus_out_of_slow_idle_states_then_lets_them_go(monkeypatch):
    before = cpu_latency_now()
    if before is None:
        pytest.skip("no PM QoS CPU latency interface to read here (not Linux, or not root)")
    monkeypatch.setenv(CPU_LATENCY_ENV, "0")
    idle_outside = _idle_entries_while_sleeping()
    with paced_section(switch_interval=None):
        assert cpu_latency_now() == 0
        # a CPU halted before the request is woken by it, and counts that halt as it leaves: let it leave first
        time.sleep(0.05)
        idle_inside = _idle_entries_while_sleeping()  # polling, not halting
    assert cpu_latency_now() == before  # the request went with the section
    if idle_outside is not None:
        assert idle_outside > 0  # the counters see an idle machine halt: the check below can fail
        assert idle_inside == 0


def test_by_default_a_paced_section_asks_for_no_cpu_latency(monkeypatch):
    monkeypatch.delenv(CPU_LATENCY_ENV, raising=False)
    assert CPU_LATENCY_US is None and cpu_latency_setting() is None
    before = cpu_latency_now()
    with paced_section(switch_interval=None):
        assert cpu_latency_now() == before
        if before is not None:
            idle = _idle_entries_while_sleeping()
            assert idle is None or idle > 0  # idle CPUs halt as they would


def test_the_environment_sets_the_latency_a_paced_section_asks_for_or_turns_the_request_off(monkeypatch):
    monkeypatch.setenv(CPU_LATENCY_ENV, " 50 ")
    assert cpu_latency_setting() == 50
    monkeypatch.setenv(CPU_LATENCY_ENV, "OFF")
    assert cpu_latency_setting() is None
    before = cpu_latency_now()
    with paced_section(switch_interval=None):
        assert cpu_latency_now() == before  # no request: idle CPUs halt as they would
    if before is not None:
        monkeypatch.setenv(CPU_LATENCY_ENV, "50")
        with paced_section(switch_interval=None):
            assert cpu_latency_now() == min(50, before)


@pytest.mark.parametrize("bad", ["-1", "1.5", "fast", "3000000000", "²"])
def test_a_malformed_latency_setting_is_refused_by_name_before_anything_changes(monkeypatch, bad):
    monkeypatch.setenv(CPU_LATENCY_ENV, bad)
    switch = sys.getswitchinterval()
    collecting = gc.isenabled()
    with pytest.raises(ConfigError) as caught:
        with paced_section(pause_collector=True):
            pytest.fail("the body ran")
    assert f"{CPU_LATENCY_ENV}={bad!r}" in str(caught.value)
    assert "whole number of microseconds" in str(caught.value) and "'off'" in str(caught.value)
    assert sys.getswitchinterval() == switch and gc.isenabled() == collecting


# ----------------------------------------------------------------------------- SlackCollector


class _Passes:
    """The collector's passes while the ``with`` block runs, as gc.callbacks reports them: their generations."""

    def __enter__(self):
        self.generations: list[int] = []
        gc.callbacks.append(self._seen)
        return self

    def _seen(self, phase, info):
        if phase == "start":
            self.generations.append(info["generation"])

    def __exit__(self, *exc):
        gc.callbacks.remove(self._seen)


def _young_to(count: int, keep: list) -> None:
    """Tracked objects made (and kept) until the young generation's count is just above ``count``."""
    while gc.get_count()[0] <= count:
        keep.append([])


def test_the_slack_collector_runs_cpythons_pass_when_one_is_due_and_frees_cycles(unfrozen_collector):
    import weakref

    from surgiplan.scheduling import SlackCollector

    with paced_section(pause_collector=True, switch_interval=None):
        collect = SlackCollector()
        threshold, every, _ = gc.get_threshold()
        gc.collect(1)  # a known start: both young generations empty, no generation-0 pass since
        keep: list = []
        with _Passes() as seen:
            _young_to(threshold // 2, keep)
            assert collect() is None and seen.generations == []  # not due: nothing runs
            # a cycle that becomes garbage: only the collector can free it
            freed = []
            node = type("Node", (), {})()
            node.me = node
            probe = weakref.ref(node, lambda _: freed.append(True))
            del node
            _young_to(threshold, keep)
            assert gc.isenabled() is False and probe() is not None  # the automatic passes are off: still there
            assert collect() == 0 and seen.generations == [0]
            assert freed == [True] and probe() is None
            assert gc.get_count()[0] <= 1
        # once more than `every` generation-0 passes ran since the last generation-1 pass, the next is of 1
        with _Passes() as seen:
            for _ in range(every):
                _young_to(threshold, keep)
                assert collect() == 0
            _young_to(threshold, keep)
            assert collect() == 1
            assert seen.generations == [0] * every + [1] and collect.passes == [every + 1, 1]


def test_the_slack_collector_waits_while_work_is_waiting_up_to_a_bound(unfrozen_collector):
    from surgiplan.scheduling import BACKLOG_FACTOR, SlackCollector

    with paced_section(pause_collector=True, switch_interval=None):
        collect = SlackCollector()
        threshold = gc.get_threshold()[0]
        gc.collect(1)
        keep: list = []
        with _Passes() as seen:
            _young_to(threshold, keep)
            assert collect(idle=False) is None and seen.generations == []  # due, but a cycle's work is waiting
            _young_to(BACKLOG_FACTOR * threshold, keep)
            assert collect(idle=False) == 0 and seen.generations == [0]  # the bound: it runs anyway


def test_the_slack_collector_runs_nothing_where_collection_is_switched_off(unfrozen_collector):
    from surgiplan.scheduling import SlackCollector

    thresholds = gc.get_threshold()
    gc.set_threshold(0)
    try:
        with paced_section(pause_collector=True, switch_interval=None), _Passes() as seen:
            collect = SlackCollector()
            keep = [[] for _ in range(20_000)]
            assert collect() is None and collect(idle=False) is None and seen.generations == [] and keep
    finally:
        gc.set_threshold(*thresholds)
