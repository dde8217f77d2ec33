import threading

import numpy as np
import pytest

from rtsid.link.ring import RingBuffer


def fill(ring: RingBuffer, n: int) -> None:
    for _ in range(n):
        k = ring.newest_index + 1
        ring.append(float(k), -float(k), k % 16, 1.0, 2.0)


def test_latest_and_wraparound():
    ring = RingBuffer(10)
    assert ring.latest(3) is None
    ring.start_at(100)
    fill(ring, 2)
    assert ring.latest(3) is None
    fill(ring, 25)
    snap = ring.latest(9)
    assert snap.sample_index.tolist() == list(range(118, 127))
    assert np.array_equal(snap.position_rad, snap.sample_index.astype(float))
    assert snap.valid.all() and ring.oldest_index == 117
    with pytest.raises(ValueError, match="capacity"):
        ring.latest(10)


def test_gaps_are_invalid_rows_and_indices_stay_contiguous():
    ring = RingBuffer(16)
    fill(ring, 3)
    ring.append_gap(4, host_time_s=5.0)
    fill(ring, 2)
    snap = ring.latest(9)
    assert snap.sample_index.tolist() == list(range(9))
    assert snap.valid.tolist() == [True] * 3 + [False] * 4 + [True] * 2
    assert np.all(snap.position_rad[3:7] == 0) and np.all(np.isnan(snap.bus_time_s[3:7]))
    assert ring.is_valid(4) is False and ring.is_valid(2) is True and ring.is_valid(99) is None


def test_gap_longer_than_the_ring():
    ring = RingBuffer(8)
    fill(ring, 2)
    ring.append_gap(100, host_time_s=1.0)
    fill(ring, 1)
    snap = ring.latest(7)
    assert snap.sample_index.tolist() == list(range(96, 103))
    assert snap.valid.tolist() == [False] * 6 + [True]


def test_read_since_reports_overwritten_rows_and_continues():
    ring = RingBuffer(10)
    fill(ring, 5)
    first = ring.read_since(0, 100)
    assert first.sample_index.tolist() == list(range(5)) and first.overwritten == 0
    fill(ring, 20)  # rows 5..24; the ring holds 15..24
    second = ring.read_since(first.next_index, 100)
    assert second.sample_index[0] == 15  # rows 5..14 were overwritten
    assert second.overwritten == 10 and ring.reader_overruns == 10
    assert second.sample_index[-1] == 23  # at most capacity - 1 rows per read
    third = ring.read_since(second.next_index, 100)
    assert third.sample_index.tolist() == [24] and third.overwritten == 0
    empty = ring.read_since(third.next_index, 100)
    assert len(empty) == 0 and empty.overwritten == 0
    limited = ring.read_since(20, 3)
    assert limited.sample_index.tolist() == [20, 21, 22]


def test_readers_always_see_consistent_rows_while_the_writer_runs():
    ring = RingBuffer(64)
    stop = threading.Event()
    written = 200_000

    def writer() -> None:
        for _ in range(written):
            k = ring.newest_index + 1
            ring.append(float(k), 2.0 * k, 0, float(k), float(k))
            if k % 997 == 0:
                ring.append_gap(3, host_time_s=0.0)
        stop.set()

    thread = threading.Thread(target=writer, name="ring-writer")
    thread.start()
    checked = 0
    try:
        cursor = 0
        while not stop.is_set() or cursor <= ring.newest_index:
            snap = ring.latest(40)
            if snap is not None:
                idx = snap.sample_index
                assert np.array_equal(idx, np.arange(idx[0], idx[0] + 40))
                ok = snap.valid
                assert np.array_equal(snap.position_rad[ok], idx[ok].astype(float))
                assert np.array_equal(snap.torque_nm[ok], 2.0 * idx[ok])
                checked += 1
            batch = ring.read_since(cursor, 50)
            if len(batch):
                assert batch.sample_index[0] == cursor + batch.overwritten
                ok = batch.valid
                assert np.array_equal(batch.position_rad[ok], batch.sample_index[ok].astype(float))
                cursor = batch.next_index
            else:
                cursor += batch.overwritten
    finally:
        thread.join(timeout=30)
    assert checked > 0 and cursor == ring.newest_index + 1


def test_wake_at_sets_the_event_when_the_row_is_published():
    ring = RingBuffer(16)
    event = threading.Event()
    ring.wake_at(2, event)
    ring.append(0.0, 0.0, 0, 0.0, 0.0)
    ring.append(0.0, 0.0, 0, 0.0, 0.0)
    assert not event.is_set()  # rows 0 and 1: not yet
    ring.append(0.0, 0.0, 0, 0.0, 0.0)
    assert event.is_set()
    event.clear()
    ring.wake_at(6, event)
    ring.append_gap(2, 0.0)  # rows 3-4
    assert not event.is_set()
    ring.append_gap(3, 0.0)  # rows 5-7: a gap publishes row 6 too
    assert event.is_set()
    event.clear()
    ring.wake_at(7, event)  # already published: set at once
    assert event.is_set()


def test_every_column_of_every_span_comes_out_in_index_order_across_the_wrap():
    ring = RingBuffer(16)
    fill(ring, 20)
    ring.append_gap(2, 5.0)  # rows 20, 21: lost
    fill(ring, 5)  # newest 26; the ring holds 11 .. 26, its slots wrap after 15
    for lo in range(11, 27):
        for n in range(1, min(27 - lo, ring.capacity - 1) + 1):  # read_since: < capacity
            snap = ring.read_since(lo, n)
            index = np.arange(lo, lo + n)
            lost = (index == 20) | (index == 21)
            assert snap.sample_index.tolist() == index.tolist()
            assert np.array_equal(snap.valid, ~lost)
            assert np.array_equal(snap.position_rad, np.where(lost, 0.0, index))
            assert np.array_equal(snap.torque_nm, np.where(lost, 0.0, -index))
            assert np.array_equal(snap.status, np.where(lost, 0, index % 16))
            assert np.array_equal(snap.host_time_s, np.where(lost, 5.0, 1.0))
            assert np.array_equal(np.isnan(snap.bus_time_s), lost)


@pytest.mark.parametrize("as_array", [False, True])
def test_append_block_writes_the_rows_appends_would_and_wakes_a_waiter(as_array):
    blocks, one_by_one = RingBuffer(50), RingBuffer(50)
    rng = np.random.default_rng(7)
    woken = threading.Event()
    blocks.wake_at(60, woken)
    for size in (3, 17, 1, 16, 40, 2, 30):  # small (element by element) and large, wrapping
        pos, trq = rng.normal(size=size), rng.normal(size=size)
        status, bus = rng.integers(0, 16, size=size), rng.uniform(0, 1e9, size=size)
        args = (pos, trq, status.astype(np.uint8), 5.0, bus)
        if not as_array:
            args = (pos.tolist(), trq.tolist(), status.tolist(), 5.0, bus.tolist())
        newest = blocks.append_block(*args)
        for k in range(size):
            one_by_one.append(pos[k], trq[k], int(status[k]), 5.0, bus[k])
        assert newest == one_by_one.newest_index == blocks.newest_index
    assert woken.is_set()
    a, b = blocks.latest(49), one_by_one.latest(49)
    for column in ("sample_index", "position_rad", "torque_nm", "valid", "status", "bus_time_s"):
        assert np.array_equal(getattr(a, column), getattr(b, column)), column
