import os
import resource
import sys
import time

import numpy as np
import pytest

from rtsid.ident.excitation import filtered_noise
from rtsid.ident.reflex import stream_taps
from rtsid.ident.reflex_lane import ReflexModels, SlowLaneSettings
from rtsid.ident.window import EstimatorOptions
from rtsid.io.schemas import ESTIMATE_FIELDS
from rtsid.link.protocol import STATUS_TORQUE_SATURATED
from rtsid.link.ring import RingBuffer
from rtsid.runtime.worker import WindowEvaluator, WindowWorker, WorkerConfig
from rtsid.sim.joint import JointParameters, simulate_impedance

FS = 2500.0


def filled_ring(n=1500, *, gap_at=None, gap_len=3, saturate_at=None, age_s=0.0, seed=0):
    theta = filtered_noise(n, FS, 30.0, peak=0.03, seed=seed)
    tau = simulate_impedance(
        theta, FS, JointParameters(0.015, 0.8, 150.0), noise_percent=5.0, seed=seed
    )
    ring = RingBuffer(5000)
    now = time.monotonic() - age_s
    for k in range(n):
        if gap_at is not None and k == gap_at:
            ring.append_gap(gap_len, now)
            continue
        status = STATUS_TORQUE_SATURATED if k == saturate_at else 0
        ring.append(theta[k], tau[k], status, now - (n - k) / FS, k / FS)
    return ring


def make_worker(ring, published, **cfg):
    evaluator = WindowEvaluator(
        FS, WorkerConfig(**cfg), EstimatorOptions(), published.append, robot="r1", joint="ankle"
    )
    return WindowWorker(ring, evaluator)


def test_windows_end_on_a_grid_of_sample_indices():
    worker = make_worker(filled_ring(), [], hop_s=0.02)  # 50 samples
    assert worker.first_window_end(0) == 749
    assert worker.first_window_end(1) == 799
    assert worker.first_window_end(700) == 1449
    assert all((worker.first_window_end(k) + 1) % 50 == 0 for k in range(0, 200, 7))


def test_a_4_ms_hop_puts_a_window_end_every_10_samples():
    worker = make_worker(filled_ring(), [], hop_s=0.004)
    assert worker.hop_samples == 10
    ends = [worker.first_window_end(k) for k in range(0, 100, 3)]
    assert all((end + 1) % 10 == 0 for end in ends)
    assert worker.first_window_end(0) == 749 and worker.first_window_end(1) == 759


def test_compute_is_counted_as_wall_time_and_as_the_threads_cpu_time(monkeypatch):
    # A window whose estimate waits (here: sleeps, as when the GIL or the CPU is elsewhere)
    # costs wall time but little CPU: the counters tell the two apart.
    published = []
    worker = make_worker(filled_ring(), published)
    busy = worker.process_window(1449)
    after_busy = worker.counters()
    assert after_busy.compute_cpu_ms_last > 0
    assert after_busy.compute_s == pytest.approx(busy["compute_ms"] / 1e3)
    estimate = worker.evaluator.stream.estimate

    def waits_then_estimates(*args, **kwargs):
        time.sleep(0.05)
        return estimate(*args, **kwargs)

    monkeypatch.setattr(worker.evaluator.stream, "estimate", waits_then_estimates)
    waited = worker.process_window(1499)
    c = worker.counters()
    assert waited["ok"] and c.compute_ms_last >= 50.0
    assert c.compute_cpu_ms_last < 0.5 * c.compute_ms_last  # the sleep is not CPU
    assert c.compute_s == pytest.approx((busy["compute_ms"] + waited["compute_ms"]) / 1e3)
    assert c.compute_cpu_s == pytest.approx(after_busy.compute_cpu_s + c.compute_cpu_ms_last / 1e3)


def test_process_window_publishes_a_complete_estimate_message():
    published = []
    msg = make_worker(filled_ring(), published).process_window(1449)
    assert published == [msg]
    assert set(msg) == set(ESTIMATE_FIELDS)
    assert msg["ok"] and msg["reason"] is None
    assert msg["K"] == pytest.approx(150.0, rel=0.1)
    assert (msg["window_start_index"], msg["window_end_index"]) == (700, 1449)
    assert msg["t_end_s"] == pytest.approx(msg["window_end_index"] / FS)
    assert msg["robot"] == "r1" and msg["seq"] == 0
    assert msg["compute_ms"] > 0 and msg["latency_ms"] >= 0


def test_a_few_lost_samples_are_bridged_and_counted_never_interpolated():
    published = []
    msg = make_worker(filled_ring(gap_at=1400, gap_len=3), published).process_window(1449)
    assert msg["ok"] and msg["lost_samples"] == 3
    assert msg["K"] == pytest.approx(150.0, rel=0.1)
    clean = make_worker(filled_ring(), []).process_window(1449)
    assert clean["lost_samples"] == 0


@pytest.mark.parametrize(
    "ring_kwargs,reason",
    [
        ({"gap_at": 1400, "gap_len": 30}, "gap"),  # 12 ms lost: beyond max_gap_s
        ({"saturate_at": 1200}, "saturated"),
        ({"age_s": 1.0}, "stale"),
    ],
)
def test_bad_windows_are_withheld_with_the_reason(ring_kwargs, reason):
    published = []
    worker = make_worker(filled_ring(**ring_kwargs), published)
    msg = worker.process_window(1499)
    assert not msg["ok"] and msg["reason"] == reason
    assert msg["K"] is None and msg["I_se"] is None
    assert worker.counters().withheld == {reason: 1}


def test_windows_not_in_the_ring_are_skipped_and_counted():
    published = []
    worker = make_worker(filled_ring(n=1000), published)
    assert worker.process_window(1099) is None  # not yet arrived
    assert worker.process_window(600) is None  # starts before the first sample
    assert published == [] and worker.counters().overruns == 2
    assert worker.counters().overrun_causes == {"rows not in the ring": 2}


def test_over_budget_is_counted_and_flagged():
    published = []
    worker = make_worker(filled_ring(), published, budget_s=1e-6)
    msg = worker.process_window(1449)
    assert "over_budget" in msg["flags"]
    assert worker.counters().deadline_misses == 1


def test_a_miss_is_set_against_the_stall_journal():
    from rtsid.runtime.stalls import RunQueueClock, StallJournal

    published = []
    worker = make_worker(filled_ring(), published, budget_s=1e-6)
    worker.stalls = StallJournal()
    with worker.stalls.step("housekeeping: status"):
        worker.process_window(1449)  # the step still runs when the window misses
    worker.process_window(1499)
    (first, second) = worker.stalls.drain_misses()
    assert (first.window_end_index, second.window_end_index) == (1449, 1499)
    assert [s.name for s in first.overlapped] == ["housekeeping: status (still running)"]
    assert [s.name for s in second.overlapped] == []  # the step had ended
    (unseen,) = set(worker.counters().miss_causes) - {"housekeeping: status"}
    assert unseen.startswith("nothing seen: ")  # split by where its time went
    assert unseen.removeprefix("nothing seen: ") == second.dominant_wait()
    assert sum(worker.counters().miss_waits.values()) == 2  # every miss, overlapped or not
    assert first.cpu_ms is not None and 0.0 < first.cpu_ms  # the worker's CPU, in the log line
    assert f"(of it on CPU {first.cpu_ms:.2f} ms" in first.describe()
    if os.path.exists(RunQueueClock.PATH):  # Linux: the run-queue wait over the window too
        assert first.cpu_wait_ms is not None and 0.0 <= first.cpu_wait_ms
        assert f"waiting for a CPU {first.cpu_wait_ms:.2f} ms" in first.describe()
    if hasattr(resource, "RUSAGE_THREAD"):  # Linux: the worker's counters over the window
        usage = first.stages.usage if first.stages is not None else None
        assert usage is not None and usage.faults >= 0 and usage.user_us >= 0
        assert f"; the window: {usage.describe()}" in first.describe()


def test_thread_starts_at_the_newest_window_then_reports_stale(wait_for):
    published = []
    ring = filled_ring()  # 1500 samples already there, nothing more arrives
    worker = make_worker(ring, published, hop_s=0.02, max_sample_age_s=0.5)
    with worker:
        wait_for(lambda: len(published) >= 3, 10.0, "three messages")
    assert worker.stop(timeout_s=1.0)
    first = published[0]
    assert first["ok"] and first["window_end_index"] == 1499  # starts at the newest window
    assert worker.counters().overruns == 0  # what was in the ring at start is history
    assert all(m["reason"] == "stale" and m["window_end_index"] == 1549 for m in published[1:])
    assert [m["seq"] for m in published] == list(range(len(published)))


def test_falling_behind_skips_to_the_newest_window_and_counts_the_rest(wait_for):
    published = []
    ring = filled_ring()
    worker = make_worker(ring, published, hop_s=0.02, max_sample_age_s=30.0)
    with worker:
        wait_for(lambda: any(m["window_end_index"] == 1499 for m in published), 5.0, "first")
        now = time.monotonic()
        switch = sys.getswitchinterval()
        sys.setswitchinterval(1.0)  # all ten hops land before the worker wakes
        try:
            for k in range(500):  # ten hops arrive at once, e.g. after a stall
                ring.append(0.01 * np.sin(k / 5.0), 1.0 * np.cos(k / 7.0), 0, now, 0.0)
        finally:
            sys.setswitchinterval(switch)
        wait_for(lambda: any(m["window_end_index"] == 1999 for m in published), 5.0, "newest")
    assert worker.stop(timeout_s=1.0)
    ends = [m["window_end_index"] for m in published]
    assert 1549 not in ends and ends[-1] == 1999
    assert worker.counters().overruns == 9  # windows ending 1549 … 1949 were skipped
    # one write carried them all: the link's burst, not a slow worker
    assert worker.counters().overrun_causes == {"samples came in one burst": 9}


def test_a_stale_message_does_not_step_the_tracker_that_its_window_will_step():
    """Live, a window can be said stale (no samples yet) and then evaluated when its samples
    come; a replay evaluates it once. The track must not depend on the stale message."""
    ring = filled_ring(n=3000, seed=3)
    plain, stale_first = [], []
    quiet = make_worker(ring, plain, hop_s=0.02, max_sample_age_s=60.0)
    told = make_worker(ring, stale_first, hop_s=0.02, max_sample_age_s=60.0)
    for end in range(749, 3000, 50):
        quiet.process_window(end)
        told.evaluator.publish_stale(end)
        told.evaluator.publish_stale(end)  # once per hop while the samples are late
        told.process_window(end)
    stale, evaluated = stale_first[0::3] + stale_first[1::3], stale_first[2::3]
    assert all(m["reason"] == "stale" for m in stale) and all(m["ok"] for m in evaluated)
    keys = ("K_track", "K_track_se")
    assert [[m[k] for k in keys] for m in evaluated] == [[m[k] for k in keys] for m in plain]
    # a stale message carries the latest track (the previous window's), unchanged
    assert stale_first[3]["K_track"] == evaluated[0]["K_track"] is not None


def test_skipped_windows_whose_samples_came_apart_blame_the_worker():
    worker = make_worker(filled_ring(), [])  # each sample arrived at its own time
    # window 1449's last sample and the newest (1499) were not written together
    assert worker._overrun_cause(1449, 1499, after_window=True) == (
        "previous window still computing"
    )
    assert worker._overrun_cause(1449, 1499, after_window=False) == "worker woke late"


def test_a_slow_lane_evaluator_forms_the_reflex_stream_taps_before_its_first_window():
    # issue 22: with the slow lane in its own process, the first window to take up a model
    # formed the streamed decimator's taps (a filter design, ≈ 3 ms of CPU) inside its
    # deadline (the misses at windows ending 12 499 / 17 499 at a 4 ms hop); the evaluator
    # now forms them when it is built, so that window forms nothing new
    settings = SlowLaneSettings(enabled=True, horizon_s=10.0, update_s=2.0, apply_after_s=1.0)
    factor = round(FS / settings.cascade().fs_out_hz)
    stream_taps.cache_clear()
    WindowEvaluator(
        FS,
        WorkerConfig(hop_s=0.004),
        EstimatorOptions(),
        [].append,
        reflex=ReflexModels(FS, settings),
    )
    formed = stream_taps.cache_info()
    assert formed.currsize == 1  # formed at construction …
    stream_taps(factor)  # … for the rate the first model's window asks for
    assert stream_taps.cache_info().misses == formed.misses
    assert stream_taps.cache_info().hits == formed.hits + 1
