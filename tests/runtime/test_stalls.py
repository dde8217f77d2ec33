"""The stall journal: garbage collections and daemon steps set against missed windows."""

from __future__ import annotations

import gc
import mmap
import os
import resource
import time

import pytest

from rtsid.runtime.stages import Usage, thread_usage
from rtsid.runtime.stalls import (
    MISS_LINES_PER_MINUTE,
    HostCounters,
    HostReading,
    RunQueueClock,
    StallJournal,
    freeze_survivors,
    frozen_count,
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
def test_thread_usage_counts_the_pages_this_thread_touches_first_as_system_time():
    before = thread_usage()
    pages = mmap.mmap(-1, 256 * mmap.PAGESIZE)  # anonymous: each page faulted on first write
    try:
        for page in range(256):
            pages[page * mmap.PAGESIZE] = 1
        after = thread_usage()
    finally:
        pages.close()
    assert before is not None and after is not None
    taken = Usage.between(before, after)
    assert taken.faults >= 256 and taken.minor_faults >= 256
    assert taken.user_us >= 0 and taken.system_us >= 0 and taken.involuntary_switches >= 0
    assert f"{taken.faults} page faults" in taken.describe()


def test_a_miss_line_names_the_host_counters_since_the_tick_before_it():
    journal = StallJournal()
    far = time.perf_counter() + 1e3
    host = HostReading(0.06, 10.0, 312, 0, 2, 0)
    journal.miss(7, far, far + 0.006, cpu_ms=3.8, cpu_wait_ms=0.0, host=host)
    (miss,) = journal.drain_misses()
    assert miss.describe().endswith(
        "; host over 0.06 s: steal 10 ms, 312 interrupts, compact_stall 0, thp_fault_alloc 2, "
        "pgmajfault 0"
    )


@pytest.mark.skipif(not os.path.exists("/proc/vmstat"), reason="the host's counters: Linux")
def test_the_host_counters_only_grow_between_a_tick_and_a_miss():
    journal = StallJournal()
    assert journal.host_since_tick() is None  # no tick yet: nothing to take them since
    journal.note_host()
    sum(range(100_000))
    since = journal.host_since_tick()
    assert since is not None and since.at_s > 0.0
    assert min(since[1:]) >= 0  # steal, interrupts, compactions, huge pages, major faults
    missing = HostCounters()
    missing.VMSTAT = "/proc/no such file"  # type: ignore[misc]
    assert missing.read() is None


def test_the_longest_collection_is_kept_apart_from_the_start_ups():
    with StallJournal() as journal:
        gc.collect()  # start-up: the daemon collects all it built, then freezes it
        startup = journal.longest_startup_gc
        assert journal.longest_gc is None
        journal.running()
        gc.collect(0)
        gc.collect(0)
    assert startup is not None and startup.generation == 2 and startup.ms > 0.0
    assert startup.cpu_ms >= 0.0
    longest = journal.longest_gc
    assert longest is not None and longest.generation == 0
    counters = journal.gc_counters()
    assert counters["gc_longest"] == [0, round(longest.ms, 3), round(longest.cpu_ms, 3)]
    assert counters["gc_longest_startup"][0] == 2
    assert counters["gc_collections"][0] >= 2 and counters["gc_frozen"] == frozen_count()


def test_what_is_frozen_is_counted_as_it_is_frozen():
    """The status's frozen count follows ``gc.get_freeze_count`` without calling it (it walks
    every frozen object: milliseconds, the GIL held)."""
    kept = [[k] for k in range(5000)]  # containers the collector tracks
    gc.collect()
    before, counted = gc.get_freeze_count(), frozen_count()
    freeze_survivors()
    assert frozen_count() - counted == gc.get_freeze_count() - before >= len(kept)


def test_the_kept_spans_are_not_walked_by_later_collections():
    """Thousands of spans kept (a busy daemon's minutes) leave the collector's view at the
    first young collection: a full collection's work does not grow with them."""
    journal = StallJournal()
    gc.collect()
    tracked = len(gc.get_objects())
    for k in range(5000):
        with journal.step(f"housekeeping: step {k % 4}"):
            pass
    gc.collect(0)  # what CPython's young collections do to tuples of plain values
    assert len(journal.spans()) == 5000
    assert len(gc.get_objects()) - tracked < 100  # not one tracked object per span


def test_the_host_counters_are_read_from_the_proc_files_lines(tmp_path):
    stat = tmp_path / "stat"
    stat.write_text(
        "cpu  100 2 30 4000 5 0 6 37 0 0\ncpu0 50 1 15 2000 2 0 3 20 0 0\n"
        "intr 123456 7 8 9\nctxt 999\n"
    )
    vmstat = tmp_path / "vmstat"
    vmstat.write_text("nr_free_pages 1\npgmajfault 26\ncompact_stall 3\nthp_fault_alloc 228\n")
    counters = HostCounters()
    counters.STAT, counters.VMSTAT = str(stat), str(vmstat)  # type: ignore[misc]
    reading = counters.read()
    assert reading is not None
    tick_ms = 1e3 / os.sysconf("SC_CLK_TCK")
    assert reading[1:] == (37 * tick_ms, 123456, 3, 228, 26)
    vmstat.write_text("nr_free_pages 1\n")  # a kernel without the counters: 0, not a failure
    assert counters.read()[3:] == (0, 0, 0)  # type: ignore[index]
