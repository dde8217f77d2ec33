import time

import pytest

from rtsid.ident.excitation import filtered_noise
from rtsid.ident.window import EstimatorOptions
from rtsid.io.schemas import ESTIMATE_FIELDS
from rtsid.link.protocol import STATUS_TORQUE_SATURATED
from rtsid.link.ring import RingBuffer
from rtsid.runtime.worker import WindowWorker, WorkerConfig
from rtsid.sim.joint import JointParameters, simulate_impedance

FS = 2500.0


def filled_ring(n=1500, *, gap_at=None, saturate_at=None, age_s=0.0, seed=0):
    theta = filtered_noise(n, FS, 30.0, peak=0.03, seed=seed)
    tau = simulate_impedance(
        theta, FS, JointParameters(0.015, 0.8, 150.0), noise_percent=5.0, seed=seed
    )
    ring = RingBuffer(5000)
    now = time.monotonic() - age_s
    for k in range(n):
        if gap_at is not None and k == gap_at:
            ring.append_gap(3, now)
            continue
        status = STATUS_TORQUE_SATURATED if k == saturate_at else 0
        ring.append(theta[k], tau[k], status, now - (n - k) / FS, k / FS)
    return ring


def make_worker(ring, published, **cfg):
    return WindowWorker(
        ring,
        FS,
        WorkerConfig(**cfg),
        EstimatorOptions(),
        published.append,
        robot="r1",
        joint="ankle",
    )


def test_step_publishes_a_complete_estimate_message():
    published = []
    msg = make_worker(filled_ring(), published).step()
    assert published == [msg]
    assert set(msg) == set(ESTIMATE_FIELDS)
    assert msg["ok"] and msg["reason"] is None
    assert msg["K"] == pytest.approx(150.0, rel=0.1)
    assert msg["window_end_index"] - msg["window_start_index"] == 749
    assert msg["t_end_s"] == pytest.approx(msg["window_end_index"] / FS)
    assert msg["robot"] == "r1" and msg["seq"] == 0
    assert msg["compute_ms"] > 0 and msg["latency_ms"] >= 0


@pytest.mark.parametrize(
    "ring_kwargs,reason",
    [
        ({"gap_at": 1400}, "gap"),
        ({"saturate_at": 1200}, "saturated"),
        ({"age_s": 1.0}, "stale"),
    ],
)
def test_bad_windows_are_withheld_with_the_reason(ring_kwargs, reason):
    published = []
    worker = make_worker(filled_ring(**ring_kwargs), published)
    msg = worker.step()
    assert not msg["ok"] and msg["reason"] == reason
    assert msg["K"] is None and msg["I_se"] is None
    assert worker.counters().withheld == {reason: 1}


def test_same_window_twice_is_stale_and_short_ring_waits():
    published = []
    worker = make_worker(filled_ring(), published)
    assert worker.step()["ok"]
    assert worker.step()["reason"] == "stale"  # nothing new arrived
    assert make_worker(filled_ring(n=100), published).step() is None  # warming up


def test_over_budget_is_counted_and_flagged():
    published = []
    worker = make_worker(filled_ring(), published, budget_s=1e-6)
    msg = worker.step()
    assert "over_budget" in msg["flags"]
    assert worker.counters().deadline_misses == 1


def test_thread_runs_on_its_hop_and_stops_within_bound():
    published = []
    ring = filled_ring()
    worker = make_worker(ring, published, hop_s=0.01, max_sample_age_s=30.0)
    with worker:
        deadline = time.monotonic() + 5.0
        while len(published) < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
    assert worker.stop(timeout_s=1.0)
    assert len(published) >= 3
    assert [m["seq"] for m in published] == list(range(len(published)))
    assert published[0]["ok"] and all(m["reason"] == "stale" for m in published[1:])
