"""The daemon's garbage collections between windows: a full collection's survivors frozen."""

from __future__ import annotations

import gc
from collections.abc import Iterator

import pytest

from rtsid.runtime.daemon import _collect_in_the_gap


@pytest.fixture
def collector_off() -> Iterator[None]:
    """Automatic collection off (as while the daemon runs); thresholds and frozen set back."""
    enabled, thresholds = gc.isenabled(), gc.get_threshold()
    gc.disable()
    try:
        yield
    finally:
        gc.unfreeze()
        gc.set_threshold(*thresholds)
        if enabled:
            gc.enable()


def _make_full_collection_due() -> None:
    gc.set_threshold(1, 1, 1)
    gc.collect(1)
    gc.collect(1)  # two middle collections counted: the oldest generation is past 1


def test_a_full_collection_in_the_gap_freezes_what_survived_it(collector_off):
    gc.collect()
    gc.freeze()  # the daemon's start-up
    kept = [[k] for k in range(3000)]  # built after the start-up, long-lived
    _make_full_collection_due()
    frozen = gc.get_freeze_count()
    assert _collect_in_the_gap() == 2
    assert gc.get_freeze_count() >= frozen + len(kept)  # out of the collector's view
    walked = {id(o) for o in gc.get_objects()}  # what the next full collection walks
    assert not any(id(row) in walked for row in kept)
    assert len(walked) < 100
    later = [[k] for k in range(500)]  # what came after the last full collection
    _make_full_collection_due()
    assert _collect_in_the_gap() == 2
    assert gc.get_freeze_count() >= frozen + len(kept) + len(later)
    assert len(kept) == 3000 and len(later) == 500


def test_young_collections_in_the_gap_freeze_nothing(collector_off):
    gc.collect()
    gc.set_threshold(1, 1000, 1000)
    young = [[k] for k in range(50)]
    frozen = gc.get_freeze_count()
    assert _collect_in_the_gap() == 0
    assert gc.get_freeze_count() == frozen and len(young) == 50
    gc.set_threshold(1000, 1000, 1000)
    gc.collect()
    assert _collect_in_the_gap() is None  # nothing due
