"""``rtsid bench service`` prints each phase's misses by cause and its longest collection."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest

from rtsid.benchmarks.service import (
    Phase,
    gc_pauses,
    longest_gc_ms,
    print_miss_causes,
    rss_growth_mib_per_min,
)
from rtsid.runtime.stages import CPU_CAUSES


def test_the_phase_prints_misses_by_cause_and_the_longest_collection_with_its_generation(capsys):
    worker = {
        "miss_causes": {"nothing seen: the window's own CPU": 2},
        "miss_cpu_causes": {CPU_CAUSES[1]: 1, CPU_CAUSES[6]: 1},
        "costly_causes": {CPU_CAUSES[6]: 7, CPU_CAUSES[5]: 2},
        "gc_collections": [40, 3, 1],
        "gc_ms": [8.0, 1.5, 2.2],
        "gc_longest": [2, 2.2, 2.05],
        "gc_longest_startup": [2, 41.5, 40.9],
        "gc_frozen": 91234,
        "estimates": 15000,
        "faulted_windows": 3,
        "window_faults": 41,
        "faulted_calls": 1,
        "call_faults": 12,
    }
    phase = Phase("idle machine", status=[{"worker": worker}])
    print_miss_causes(phase)
    out = capsys.readouterr().out
    assert (
        "idle machine: misses by why the worker's CPU ran long (its getrusage counters over the "
        f"window and the compiled call): {CPU_CAUSES[1]}: 1, {CPU_CAUSES[6]}: 1" in out
    )
    assert "windows of over 3× by why the worker's CPU ran long" in out
    assert f"{CPU_CAUSES[5]}: 2, {CPU_CAUSES[6]}: 7" in out
    assert (
        "longest garbage collection while running windows: gen 2, 2.20 ms (CPU 2.05 ms); "
        "at start-up: gen 2, 41.50 ms (CPU 40.90 ms); objects frozen 91234" in out
    )
    assert longest_gc_ms(worker) == "2.20 (gen 2)"
    assert (
        "windows whose worker took page faults: 3 of 15000 estimates (41 faults); of them in the "
        "compiled call 1 (12 faults)" in out
    )


def test_a_daemon_that_reports_no_collection_prints_none():
    assert gc_pauses({}).startswith("longest garbage collection while running windows: none;")
    assert longest_gc_ms({"gc_longest": None}) == "—"


def statuses(rss_at: Callable[[float], float], seconds: float, period_s: float = 0.5) -> list:
    """Status messages every ``period_s`` with ``rss_mb = rss_at(t)``."""
    t0 = 1_700_000_000 * 10**9
    times = [k * period_s for k in range(int(seconds / period_s) + 1)]
    return [{"host_time_ns": t0 + int(t * 1e9), "rss_mb": rss_at(t)} for t in times]


def test_rss_growth_is_the_steady_minute_rate_past_a_one_time_step():
    def rss(t: float) -> float:  # start-up, then 4 MiB a minute, and a 27 MiB step at 42 s
        return (100.0 if t < 5 else 140.0) + 4.0 * t / 60.0 + (27.0 if t >= 42.0 else 0.0)

    assert rss_growth_mib_per_min(statuses(rss, 120.0)) == pytest.approx(4.0)
    assert rss_growth_mib_per_min(statuses(lambda t: 140.0, 120.0)) == 0.0
    assert math.isnan(rss_growth_mib_per_min(statuses(rss, 45.0)))  # one span past start-up
    assert math.isnan(rss_growth_mib_per_min([]))


def test_each_missed_window_is_set_beside_its_replay(capsys):
    """A miss whose window replays within the hop was not the code's own work: the bench
    says how many did, and prints each miss line with its replayed compute."""
    from rtsid.replay import ReplayResult

    lines = [
        "deadline miss: window ending 262509, compute 5.17 ms (of it on CPU 4.82 ms); tracker",
        "deadline miss: window ending 120839, compute 6.11 ms (of it on CPU 0.35 ms); waits",
        "deadline miss: window ending 999, compute 4.40 ms (of it on CPU 4.30 ms); not replayed",
    ]
    replay = ReplayResult(
        "rec.mcap",
        messages=[
            {"window_end_index": 262509, "compute_ms": 0.21},
            {"window_end_index": 120839, "compute_ms": 4.6},
            {"window_end_index": 7, "compute_ms": 0.2},
        ],
    )
    phase = Phase("idle", miss_lines=lines, replay=replay, hop_ms=4.0)
    print_miss_causes(phase)
    out = capsys.readouterr().out
    assert (
        "idle: missed windows replayed within the 4 ms hop on one thread: 1 of 2 found in the "
        "replay (3 logged); the longest 4.6 ms" in out
    )
    assert (
        "window ending 262509, compute 5.17 ms (of it on CPU 4.82 ms); tracker; replayed: 0.21 ms"
        in out
    )
    assert "window ending 999, compute 4.40 ms (of it on CPU 4.30 ms); not replayed\n" in out
