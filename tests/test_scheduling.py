"""surgiplan.scheduling.paced_section: what it changes for the body and that it gives everything back."""

from __future__ import annotations

import gc
import sys

import pytest
from surgiplan.scheduling import SWITCH_INTERVAL, paced_section


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
