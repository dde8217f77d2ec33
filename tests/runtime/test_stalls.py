"""The stall journal: garbage collections and daemon steps set against missed windows."""

from __future__ import annotations

import gc
import mmap
import os
import resource
import time

import pytest

from rtsid.runtime.stalls import (
    MISS_LINES_PER_MINUTE,
    RunQueueClock,
    Span,
    StallJournal,
    thread_page_faults,
)


def test_a_collection_during_a_missed_window_is_named_and_counted():
    with StallJournal() as journal:
        start = time.perf_counter()
        gc.collect()  # a generation-2 collection on this thread
        journal.miss(1234, start, time.perf_counter())
    assert journal.collections[2] >= 1 and journal.gc_ms[2] > 0
    (miss,) = journal.drain_misses()
    assert miss.window_end_index == 1234
    assert any(s.name.startswith("gc gen 2 (MainThread)") for s in miss.overlapped)
    assert journal.causes()["gc gen 2"] == 1
    assert "window ending 1234" in miss.describe() and "gc gen 2" in miss.describe()
    assert journal.drain_misses() == []
    assert journal._on_gc not in gc.callbacks  # the callback is gone after the block


def test_only_steps_that_overlap_a_miss_are_blamed():
    journal = StallJournal()
    with journal.step("housekeeping: history deflate"):
        pass
    after = time.perf_counter()
    journal.miss(7, after + 1.0, after + 2.0)  # a window long after the step
    with journal.step("housekeeping: status"):
        start = time.perf_counter()
        journal_end = time.perf_counter()
    journal.miss(8, start, journal_end)
    first, second = journal.drain_misses()
    assert first.overlapped == () and "nothing seen" in first.describe()
    assert [s.name for s in second.overlapped] == ["housekeeping: status"]
    assert journal.causes() == {"nothing seen": 1, "housekeeping: status": 1}


def test_miss_lines_are_limited_a_minute_and_the_rest_counted():
    journal = StallJournal()
    for k in range(MISS_LINES_PER_MINUTE + 5):
        journal.miss(k, 0.0, 0.001)
    lines = journal.miss_lines(now_s=100.0)
    assert len(lines) == MISS_LINES_PER_MINUTE
    assert all(line.startswith("deadline miss: window ending") for line in lines)
    journal.miss(99, 0.0, 0.001)
    assert journal.miss_lines(now_s=130.0) == []  # the same minute: counted, not logged
    journal.miss(100, 0.0, 0.001)
    summary, own = journal.miss_lines(now_s=160.5)  # a new minute: the count, then its own
    assert summary.startswith("6 more deadline misses in the last minute")
    assert own.startswith("deadline miss: window ending 100,")
    assert journal.miss_lines(now_s=161.0) == []
    assert journal.causes() == {"nothing seen": MISS_LINES_PER_MINUTE + 7}


def test_a_miss_that_overlapped_nothing_is_counted_under_where_its_time_went():
    journal = StallJournal()
    far = time.perf_counter() + 100.0  # no step near these windows
    journal.miss(1, far, far + 0.008, cpu_ms=1.0, cpu_wait_ms=6.0)  # runnable, no CPU
    journal.miss(2, far, far + 0.008, cpu_ms=1.0, cpu_wait_ms=0.5)  # asleep: the GIL
    journal.miss(3, far, far + 0.008, cpu_ms=7.0, cpu_wait_ms=0.5)  # the window itself
    journal.miss(4, far, far + 0.008, cpu_ms=1.0)  # no run-queue clock: the waits are one
    journal.miss(5, far, far + 0.008)  # no CPU time at all: not split
    assert journal.causes() == {
        "nothing seen: waiting for a CPU": 1,
        "nothing seen: waiting for the GIL": 1,
        "nothing seen: the window's own CPU": 1,
        "nothing seen: waiting for a CPU or the GIL": 1,
        "nothing seen": 1,
    }
    assert dict(journal.miss_waits) == {
        "waiting for a CPU": 1,
        "waiting for the GIL": 1,
        "the window's own CPU": 1,
        "waiting for a CPU or the GIL": 1,
    }
    first = journal.drain_misses()[0]
    assert "(of it on CPU 1.00 ms, waiting for a CPU 6.00 ms)" in first.describe()


def test_the_run_queue_clock_reads_this_threads_waits_for_a_cpu():
    clock = RunQueueClock()
    if not os.path.exists(RunQueueClock.PATH):  # not Linux: every read says so
        assert clock.read_ns() is None
        return
    first = clock.read_ns()
    sum(range(200_000))  # run a while: the delay never goes back
    second = clock.read_ns()
    clock.close()
    assert first is not None and second is not None and 0 <= first <= second
    missing = RunQueueClock()
    missing.PATH = "/proc/no such file"  # type: ignore[misc]
    assert missing.read_ns() is None and missing.read_ns() is None


@pytest.mark.skipif(not hasattr(resource, "RUSAGE_THREAD"), reason="per-thread counts: Linux")
def test_thread_page_faults_count_the_pages_this_thread_touches_first():
    before = thread_page_faults()
    pages = mmap.mmap(-1, 256 * mmap.PAGESIZE)  # anonymous: each page faulted on first write
    try:
        for page in range(256):
            pages[page * mmap.PAGESIZE] = 1
        after = thread_page_faults()
    finally:
        pages.close()
    assert before is not None and after is not None
    assert after - before >= 256


def test_a_miss_line_names_the_page_faults_the_worker_took():
    journal = StallJournal()
    far = time.perf_counter() + 1e3
    journal.miss(7, far, far + 0.006, cpu_ms=3.8, cpu_wait_ms=0.0, page_faults=412)
    (miss,) = journal.drain_misses()
    assert "(of it on CPU 3.80 ms, waiting for a CPU 0.00 ms, 412 page faults)" in miss.describe()


def test_misses_of_the_windows_own_cpu_have_their_own_quota_of_lines():
    journal = StallJournal()
    for k in range(MISS_LINES_PER_MINUTE + 5):  # waiting for a CPU: a loaded machine
        journal.miss(k, 0.0, 0.004, cpu_ms=0.5, cpu_wait_ms=3.5)
    journal.miss(1000, 0.0, 0.004, cpu_ms=3.8, cpu_wait_ms=0.1)  # the window's own CPU
    lines = journal.miss_lines(now_s=100.0)
    assert len(lines) == MISS_LINES_PER_MINUTE + 1
    assert any("window ending 1000," in line for line in lines)
    assert journal.miss_waits["the window's own CPU"] == 1


def test_a_miss_finds_its_overlapping_spans_among_many_and_one_appended_late():
    journal = StallJournal()
    for k in range(8000):  # a long daemon life of housekeeping steps, 1 ms each, 2 ms apart
        journal._spans.append(Span(f"step {k}", 0.002 * k, 0.002 * k + 0.001))
    journal._spans.append(Span("late append", 15.9905, 15.9915))  # ended before the last one
    journal.miss(1, 15.9905, 15.9945)
    (miss,) = journal.drain_misses()
    names = [s.name for s in miss.overlapped]
    assert names == ["step 7995", "step 7996", "step 7997", "late append"]
