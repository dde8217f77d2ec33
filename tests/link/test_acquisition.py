"""The plant at full rate into the acquisition thread through python-can's virtual bus."""

from __future__ import annotations

import time

import can
import numpy as np
import pytest

from rtsid.errors import LinkError
from rtsid.link.acquisition import Acquisition
from rtsid.link.config import FaultConfig, PlantConfig
from rtsid.link.plant import VirtualPlant
from rtsid.link.protocol import STATE_ID, encode_state_block
from rtsid.link.ring import RingBuffer
from rtsid.link.sequence import MAX_STRAY_RUN

virtual_bus = None  # set by the autouse fixture below (conftest's helper)

WAIT_S = 30.0  # generous bound for loops waiting on the threads; tests never assert on time


@pytest.fixture(autouse=True)
def _bus_helper(vbus):
    global virtual_bus
    virtual_bus = vbus


def run_plant_into_acquisition(
    channel: str, cfg: PlantConfig, *, record: int = 0, ring_rows: int = 50_000
) -> tuple[Acquisition, VirtualPlant, RingBuffer]:
    """Stream ``cfg.max_samples`` through the virtual bus; return the stopped parts."""
    ring = RingBuffer(ring_rows)
    acq = Acquisition(lambda: virtual_bus(channel, rx_queue_size=20_000), ring)
    plant_bus = virtual_bus(channel)
    try:
        with acq, VirtualPlant(cfg, plant_bus, record_samples=record) as plant:
            plant.done.wait(WAIT_S)
            assert plant.error is None
            deadline = time.monotonic() + WAIT_S
            sent = plant.counters().frames_sent
            while acq.counters().frames < sent and time.monotonic() < deadline:
                time.sleep(0.01)
    finally:
        plant_bus.shutdown()
    return acq, plant, ring


def test_every_sample_arrives_in_order_with_exact_values(channel, fast_plant_cfg):
    n = fast_plant_cfg.max_samples
    acq, plant, ring = run_plant_into_acquisition(channel, fast_plant_cfg, record=n)
    c = acq.counters()
    assert c.samples == n and c.lost_samples == 0 and c.gaps == 0
    assert c.malformed == c.unknown_id == c.duplicates == c.out_of_order == 0
    snap = ring.read_since(0, n)
    assert snap.sample_index.tolist() == list(range(n)) and snap.valid.all()
    position, torque = plant.recorded()
    assert np.array_equal(snap.position_rad, position)  # bit-exact after scaling
    assert np.array_equal(snap.torque_nm, torque)
    assert np.std(position) > 0.005 and np.std(torque) > 0.5  # a real perturbation got through
    assert not acq.running and not c.stale


def test_injected_faults_are_counted_exactly_and_lost_samples_are_invalid_rows(channel):
    faults = FaultConfig(
        drop_rate=0.01,
        duplicate_rate=0.01,
        reorder_rate=0.01,
        corrupt_rate=0.005,
        short_rate=0.005,
        error_frame_rate=0.002,
        unknown_id_rate=0.002,
        seed=3,
    )
    cfg = PlantConfig(realtime=False, max_samples=12_000, diagnostics_hz=0.0, faults=faults)
    acq, plant, ring = run_plant_into_acquisition(channel, cfg)
    c, p = acq.counters(), plant.counters()
    snap = ring.read_since(0, 50_000)
    first, last = int(snap.sample_index[0]), int(snap.sample_index[-1])
    expected_lost = [k for k in plant.lost_indices().tolist() if first < k < last]
    assert snap.sample_index[~snap.valid].tolist() == expected_lost
    assert c.lost_samples == len(expected_lost) > 100
    assert c.malformed == p.corrupted + p.shortened > 0
    assert c.duplicates == p.duplicated > 0
    assert p.reordered > 0 and c.out_of_order == 0  # held jumps let late frames fill the gap
    assert c.error_frames == p.error_frames > 0 and c.unknown_id == p.unknown_frames > 0
    assert c.samples + c.lost_samples == last - first + 1


def test_silence_bursts_become_gaps_of_the_silenced_count(channel):
    faults = FaultConfig(silence_every_s=1.0, silence_s=0.4)  # 1000 samples every 2500
    cfg = PlantConfig(realtime=False, max_samples=10_000, diagnostics_hz=0.0, faults=faults)
    acq, plant, ring = run_plant_into_acquisition(channel, cfg)
    c = acq.counters()
    assert c.gaps == 3 and c.lost_samples == 3000 == plant.counters().silenced
    assert ring.newest_index == 9999


def send_states(bus: can.BusABC, counters: list[int], times: list[float]) -> None:
    n = len(counters)
    payload = encode_state_block(
        np.arange(n), np.arange(n), np.array(counters), np.zeros(n, dtype=np.int64)
    )
    for k in range(n):
        bus.send(
            can.Message(
                arbitration_id=STATE_ID,
                data=payload[k].tobytes(),
                is_extended_id=False,
                timestamp=times[k],
            )
        )


def wait_for(predicate, timeout=WAIT_S):
    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.005)
    return predicate()


def test_wraps_during_a_long_silence_are_counted_from_bus_timestamps(channel):
    ring = RingBuffer(40_000)
    fs = 25_000.0  # a wrap every 0.16 s, so the host clock can see a silence of many wraps
    silence = 20_000  # 4.9 wraps: the 8 s outage at 2500 Hz, scaled
    with virtual_bus(channel, preserve_timestamps=True) as tx:
        with Acquisition(lambda: virtual_bus(channel), ring, fs_hz=fs) as acq:
            t0 = 1000.0
            send_states(tx, list(range(10)), [t0 + k / fs for k in range(10)])
            assert wait_for(lambda: acq.counters().samples == 10)
            time.sleep(silence / fs)  # the sender is silent; the host sees the silence too
            idx = list(range(10 + silence, 20 + silence))
            send_states(tx, [k % 4096 for k in idx], [t0 + k / fs for k in idx])
            assert wait_for(lambda: acq.counters().samples == 20)
            c = acq.counters()
    assert c.gaps == 1 and c.lost_samples == silence
    assert ring.newest_index == silence + 19 and acq.sample_time_s(idx[-1]) > acq.sample_time_s(0)


def test_a_sender_clock_step_invents_no_lost_samples(channel):
    ring = RingBuffer(1000)
    with virtual_bus(channel, preserve_timestamps=True) as tx:
        with Acquisition(lambda: virtual_bus(channel), ring) as acq:
            times = [100.0 + k / 2500 for k in range(20)]
            times[10:] = [t + 3600.0 for t in times[10:]]  # the sender's clock jumps 1 h
            send_states(tx, list(range(20)), times)
            assert wait_for(lambda: acq.counters().samples == 20)
            c = acq.counters()
    assert c.lost_samples == 0 and c.gaps == 0 and ring.newest_index == 19


def test_a_stray_frame_with_a_valid_checksum_invents_no_lost_samples(channel):
    ring = RingBuffer(1000)
    counters = [*range(10), 3000, *range(10, 20)]  # one foreign frame, checksum valid
    with virtual_bus(channel, preserve_timestamps=True) as tx:
        with Acquisition(lambda: virtual_bus(channel), ring) as acq:
            send_states(tx, counters, [50.0 + k / 2500 for k in range(len(counters))])
            assert wait_for(lambda: acq.counters().samples == 20)
            c = acq.counters()
    assert c.strays == 1 and c.lost_samples == 0 and c.gaps == 0
    snap = ring.read_since(0, 100)
    assert snap.sample_index.tolist() == list(range(20)) and snap.valid.all()
    # send_states writes the frame's position in its row: the stray's (10) was never written
    assert (snap.position_rad * 1e6).round().tolist() == [*range(10), *range(11, 21)]


@pytest.mark.parametrize("k", [1, 2, 3, 5])
@pytest.mark.parametrize("offset", [1000, 40, 3000])
def test_consecutive_stray_frames_are_dropped_like_one_and_never_shift_the_index(
    channel, k, offset
):
    # issue 20: two strays (+1000, +1001) made 4094 phantom lost samples and shifted the
    # index (and t_s) by a counter wrap
    ring = RingBuffer(1000)
    strays = [(9 + offset + j) % 4096 for j in range(k)]
    counters = [*range(10), *strays, *range(10, 40)]
    with virtual_bus(channel, preserve_timestamps=True) as tx:
        with Acquisition(lambda: virtual_bus(channel), ring) as acq:
            send_states(tx, counters, [50.0 + n / 2500 for n in range(len(counters))])
            assert wait_for(lambda: acq.counters().samples == 40)
            c = acq.counters()
            t_s = [acq.sample_time_s(i) - acq.sample_time_s(0) for i in (10, 39)]
    assert c.strays == k and c.lost_samples == 0 and c.gaps == 0 and c.duplicates == 0
    snap = ring.read_since(0, 100)
    assert snap.sample_index.tolist() == list(range(40)) and snap.valid.all()
    assert t_s == pytest.approx([10 / 2500, 39 / 2500])
    # send_states writes the frame's position in its row: no stray's was ever written
    assert (snap.position_rad * 1e6).round().tolist() == [*range(10), *range(10 + k, 40 + k)]


@pytest.mark.parametrize("size", [1, 2, 3, 5, 1000])
def test_a_real_gap_the_size_of_a_stray_run_is_still_a_gap(channel, size):
    ring = RingBuffer(2000)
    counters = [*range(10), *range(10 + size, 40 + size)]
    with virtual_bus(channel, preserve_timestamps=True) as tx:
        with Acquisition(lambda: virtual_bus(channel), ring) as acq:
            send_states(tx, counters, [50.0 + n / 2500 for n in counters])
            assert wait_for(lambda: acq.counters().samples == 40)
            c = acq.counters()
    assert c.gaps == 1 and c.lost_samples == size and c.strays == 0
    snap = ring.read_since(0, 2000)
    assert snap.sample_index[~snap.valid].tolist() == list(range(10, 10 + size))
    assert ring.newest_index == 39 + size


@pytest.mark.parametrize("stamp", [float("inf"), float("nan"), None, -1.0])
def test_a_frame_with_a_bad_timestamp_is_counted_and_dropped(channel, stamp):
    ring = RingBuffer(1000)
    n = 6 + MAX_STRAY_RUN + 1  # the frames after the gap confirm it (strays are fewer)
    times: list = [20.0 + k / 2500 for k in range(n)]
    times[5] = stamp
    with virtual_bus(channel, preserve_timestamps=True) as tx:
        with Acquisition(lambda: virtual_bus(channel), ring) as acq:
            send_states(tx, list(range(n)), times)
            assert wait_for(lambda: acq.counters().samples == n - 1)
            c = acq.counters()
            assert acq.running and acq.failure is None
    assert c.rejected == 1 and c.lost_samples == 1 and ring.newest_index == n - 1
    assert acq.error is None


def test_an_absurd_but_finite_timestamp_invents_no_lost_samples(channel):
    ring = RingBuffer(1000)
    times = [20.0 + k / 2500 for k in range(10)]
    times[5] = 1e20
    with virtual_bus(channel, preserve_timestamps=True) as tx:
        with Acquisition(lambda: virtual_bus(channel), ring) as acq:
            send_states(tx, list(range(10)), times)
            assert wait_for(lambda: acq.counters().samples == 10)
            c = acq.counters()
    assert c.lost_samples == 0 and c.rejected == 0 and ring.newest_index == 9


class BrokenRing(RingBuffer):
    """A ring whose writes fail: every state frame fails to be handled."""

    def append(self, *args, **kwargs):
        raise RuntimeError("injected ring failure")


def test_a_frame_handler_failing_on_every_frame_ends_the_thread_with_an_error(channel):
    acq = Acquisition(lambda: virtual_bus(channel), BrokenRing(1000))
    with virtual_bus(channel) as tx:
        acq.start()
        try:
            send_states(tx, [k % 4096 for k in range(1000)], [0.0] * 1000)
            assert wait_for(lambda: acq.failure is not None)
        finally:
            clean = acq.stop(timeout_s=2.0)
    assert not clean and "rejected" in acq.failure and not acq.running
    assert isinstance(acq.error, LinkError) and acq.counters().rejected >= 256


def test_a_stalled_sender_catching_up_is_not_taken_for_lost_wraps(channel):
    ring = RingBuffer(1000)
    fs = 2500.0
    with virtual_bus(channel, preserve_timestamps=True) as tx:
        with Acquisition(lambda: virtual_bus(channel), ring, fs_hz=fs) as acq:
            # consecutive counters, but the sender stalled 1.3 s (0.8 of a wrap) in between
            send_states(tx, [0, 1, 2, 3], [10.0, 10.0004, 11.3, 11.3001])
            assert wait_for(lambda: acq.counters().samples == 4)
            c = acq.counters()
    assert c.lost_samples == 0 and ring.newest_index == 3


def test_malformed_frames_are_counted_and_never_written(channel):
    ring = RingBuffer(1000)
    with virtual_bus(channel) as tx:
        with Acquisition(lambda: virtual_bus(channel), ring) as acq:
            send_states(tx, [0, 1], [0.0, 0.0])
            good = encode_state_block(*(np.array([v]) for v in (5, 5, 2, 0)))[0].tobytes()
            bad = bytearray(good)
            bad[0] ^= 0x10
            for data, extra in (
                (good[:6], {}),  # short
                (bytes(bad), {}),  # checksum
                (good, {"is_remote_frame": True}),
                (good, {"is_extended_id": True}),  # 0x100 as a 29-bit ID is another frame
            ):
                tx.send(
                    can.Message(
                        arbitration_id=STATE_ID, data=data, **{"is_extended_id": False, **extra}
                    )
                )
            tx.send(can.Message(arbitration_id=0x123, data=good, is_extended_id=False))
            tx.send(can.Message(arbitration_id=0x4, is_error_frame=True, is_extended_id=False))
            send_states(tx, [2], [0.0])
            assert wait_for(lambda: acq.counters().samples == 3)
            c = acq.counters()
    assert c.malformed == 3 and c.unknown_id == 2 and c.error_frames == 1
    assert c.lost_samples == 0 and ring.newest_index == 2


def test_stop_returns_within_its_bound_without_frames(channel):
    acq = Acquisition(lambda: virtual_bus(channel), RingBuffer(100), receive_timeout_s=0.02)
    acq.start()
    assert wait_for(lambda: acq.counters().stale)
    assert acq.stop(timeout_s=2.0) is True
    assert not acq.running and acq.counters().stale_events == 1


class FlakyBus(can.interfaces.virtual.VirtualBus):
    """A virtual bus whose receive fails once (like a USB adapter unplugged)."""

    failures_left = 1

    def _recv_internal(self, timeout):
        if FlakyBus.failures_left:
            FlakyBus.failures_left -= 1
            raise can.CanOperationError("adapter gone")
        return super()._recv_internal(timeout)


def test_bus_errors_reopen_the_bus_with_backoff(channel):
    opened = []
    attempts = {"n": 0}

    def factory() -> can.BusABC:
        attempts["n"] += 1
        if attempts["n"] == 2:
            raise can.CanInitializationError("still gone")
        bus = FlakyBus(channel=channel)
        opened.append(bus)
        return bus

    ring = RingBuffer(1000)
    with virtual_bus(channel) as tx:
        with Acquisition(factory, ring, backoff_min_s=0.01) as acq:
            assert wait_for(lambda: acq.counters().reconnects == 1)
            send_states(tx, [0, 1, 2], [0.0] * 3)
            assert wait_for(lambda: acq.counters().samples == 3)
            c = acq.counters()
    assert c.bus_errors == 2 and c.reconnects == 1 and c.connected
    assert "still gone" in acq.last_error
    assert all(not b._open for b in opened)  # every bus it opened was shut down


def test_reconnect_after_stale(channel):
    opened = []

    def factory() -> can.BusABC:
        opened.append(virtual_bus(channel))
        return opened[-1]

    acq = Acquisition(
        factory,
        RingBuffer(100),
        reconnect_after_stale_s=0.05,
        backoff_min_s=0.01,
        receive_timeout_s=0.01,
    )
    with acq:
        assert wait_for(lambda: acq.counters().reconnects >= 2)
    assert all(not b._open for b in opened)


def test_first_open_failure_is_one_clear_link_error():
    def factory() -> can.BusABC:
        raise can.CanInitializationError("no such device can9")

    with pytest.raises(LinkError, match="cannot open the CAN bus: no such device can9; check"):
        Acquisition(factory, RingBuffer(100)).start()


def test_send_command_reaches_the_plant_and_changes_the_perturbation(channel):
    from rtsid.link.protocol import STATUS_PERTURBATION_ON, Command

    cfg = PlantConfig(realtime=False, max_samples=0, diagnostics_hz=0.0, block_s=0.05)
    ring = RingBuffer(20_000)
    plant_bus = virtual_bus(channel, rx_queue_size=100)
    try:
        with Acquisition(lambda: virtual_bus(channel, rx_queue_size=5000), ring) as acq:
            with VirtualPlant(cfg, plant_bus) as plant:
                assert wait_for(lambda: ring.newest_index > 1000)
                assert ring.latest(200).status[-1] & STATUS_PERTURBATION_ON
                acq.send_command(Command(enable=False))
                assert wait_for(lambda: plant.counters().commands == 1)
                start = plant.counters().samples + 2 * cfg.block_samples
                assert wait_for(lambda: ring.newest_index > start + 600)
                snap = ring.latest(500)
    finally:
        plant_bus.shutdown()
    assert not np.any(snap.status & STATUS_PERTURBATION_ON)
    assert np.max(np.abs(snap.position_rad)) < 1e-5  # the servo came to rest at zero


def test_windows_from_the_ring_identify_the_plants_true_joint(channel, fast_plant_cfg):
    import rtsid

    _, plant, ring = run_plant_into_acquisition(channel, fast_plant_cfg)
    truth = plant.truth
    estimates = []
    for end in (4000, 8000, 11_999):
        snap = ring.read_since(end - 749, 750)
        assert snap.valid.all() and len(snap) == 750
        est = rtsid.estimate_window(snap.position_rad, snap.torque_nm, 2500.0)
        estimates.append((est.I, est.B, est.K))
    inertia, damping, stiffness = np.median(np.array(estimates), axis=0)
    assert stiffness == pytest.approx(float(truth.stiffness_at(0.0)), rel=0.15)
    assert damping == pytest.approx(truth.damping, rel=0.15)
    assert inertia == pytest.approx(truth.inertia + truth.robot_inertia, rel=0.25)


def test_a_sender_catching_up_after_a_stall_is_not_a_wrong_rate(channel):
    # the embedded plant, stalled by the daemon's start-up, catches up in a burst: one 2 s
    # measurement read 2553.7 samples/s and the quick start told the user to change fs_hz
    fs, n = 2500.0, 17_500
    times = np.arange(n) / fs
    times[5000:7500] = np.linspace(2.6, 3.0, 2500)  # 0.6 s of silence, then a burst
    ring = RingBuffer(20_000)
    with virtual_bus(channel, preserve_timestamps=True) as tx:
        with Acquisition(lambda: virtual_bus(channel), ring, fs_hz=fs) as acq:
            send_states(tx, [k % 4096 for k in range(n)], (100.0 + times).tolist())
            assert wait_for(lambda: acq.counters().samples == n)
            c = acq.counters()
    assert c.lost_samples == 0
    assert not c.rate_mismatch and "link.fs_hz" not in (c.last_error or "")
