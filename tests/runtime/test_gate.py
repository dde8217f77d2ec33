"""The window gate: the housekeeping tick waits for the worker to go to sleep, never the
worker for the tick."""

from __future__ import annotations

import contextlib
import json
import threading
from collections.abc import Iterator

import numpy as np

from rtsid.io import mcap_read
from rtsid.io.mcap_log import McapConfig, McapLogger
from rtsid.io.schemas import ESTIMATE_FIELDS, encode_estimate
from rtsid.runtime.gate import WindowGate


def waiting(gate: WindowGate, timeout_s: float) -> tuple[threading.Thread, list[bool]]:
    """A thread waiting on ``gate.after_next_window(timeout_s)``; its answer lands in the list."""
    answers: list[bool] = []
    thread = threading.Thread(target=lambda: answers.append(gate.after_next_window(timeout_s)))
    thread.start()
    return thread, answers


def test_a_tick_waits_for_the_window_being_computed_and_the_worker_to_sleep():
    gate = WindowGate()
    gate.window_started()
    assert gate.computing
    thread, answers = waiting(gate, 30.0)
    thread.join(0.2)
    assert thread.is_alive() and answers == []  # still computing: the tick has not begun
    gate.window_finished()
    assert not gate.computing and gate.finished == 1
    thread.join(0.2)
    # a worker behind its grid starts the next window at once: finishing one is not enough
    assert thread.is_alive() and answers == []
    gate.worker_waiting()  # it goes to wait for the next window's last sample
    thread.join(30.0)
    assert not thread.is_alive() and answers == [True]
    assert (gate.waits, gate.waited_out, gate.idle) == (1, 0, 1)


def test_a_sleep_begun_before_the_tick_fell_due_does_not_count():
    # the tick runs as the worker goes to sleep: a sleep begun earlier says nothing about
    # how much of the hop is left
    gate = WindowGate()
    gate.worker_waiting()
    thread, answers = waiting(gate, 30.0)
    thread.join(0.2)
    assert thread.is_alive() and answers == []
    gate.window_started()  # the worker never waits on the gate
    gate.window_finished()
    gate.worker_waiting()
    thread.join(30.0)
    assert answers == [True] and gate.idle == 2


def test_with_no_windows_the_tick_runs_when_its_bound_is_out_and_counts_it():
    gate = WindowGate()
    assert gate.after_next_window(0.01) is False
    assert (gate.waits, gate.waited_out, gate.idle) == (1, 1, 0)


# ---------------------------------------------------------------------- the MCAP writer
def writer_on_the_gate(
    tmp_path, gate: WindowGate, queue_size: int = 4096
) -> tuple[McapLogger, list[tuple[str, bool]]]:
    """A logger whose writer keeps to ``gate`` as the daemon wires it (but with a long bound,
    so only the gate lets it write), recording each write step and whether a window was
    computing as it began."""
    steps: list[tuple[str, bool]] = []

    @contextlib.contextmanager
    def timed(name: str) -> Iterator[None]:
        steps.append((name, gate.computing))
        yield

    config = McapConfig(
        directory=str(tmp_path), chunk_size=1024, flush_interval_s=10.0, queue_size=queue_size
    )
    logger = McapLogger(config, robot="r", joint="ankle", fs_hz=2500.0)
    logger.timed = timed
    logger.busy = lambda: gate.computing
    logger.wait_turn = lambda: gate.after_next_window(30.0)
    return logger, steps


def log_rows(logger: McapLogger, batches: range) -> None:
    for b in batches:
        logger.log_samples(100 * b, np.full(100, float(b)), np.zeros(100))


def test_the_mcap_writer_writes_and_compresses_only_while_no_window_computes(tmp_path, wait_for):
    """Issue 22: the writer thread's serialising and chunk compression begin as the worker
    goes to sleep and pause while a window computes; nothing is lost or reordered."""
    gate = WindowGate()
    logger, steps = writer_on_the_gate(tmp_path, gate)
    with logger:
        gate.window_started()
        log_rows(logger, range(20))
        wait_for(lambda: gate.waits == 1, 10.0, "the writer waiting for its turn")
        assert steps == [] and logger.stats()["written"] == 0  # not while the window computes
        gate.window_finished()
        gate.worker_waiting()  # the worker sleeps: the burst begins
        wait_for(lambda: logger.stats()["written"] == 20, 10.0, "the first burst")
        gate.window_started()  # a window while the writer idles: the next burst waits
        log_rows(logger, range(20, 40))
        wait_for(lambda: gate.waits == 2, 10.0, "the writer waiting for its next turn")
        assert logger.stats()["written"] == 20
        gate.window_finished()
        gate.worker_waiting()
        wait_for(lambda: logger.stats()["written"] == 40, 10.0, "the second burst")
    assert gate.waited_out == 0
    assert steps and not any(computing for _, computing in steps)
    names = {name for name, _ in steps}
    assert "mcap writer: chunk" in names  # full chunks closed by the writer, in its turn
    (path,) = logger.files
    firsts = [batch.first_index for batch in mcap_read.iter_sample_batches(path)]
    assert firsts == [100 * b for b in range(40)]


def test_a_window_begun_mid_burst_pauses_the_writer_until_the_worker_sleeps(tmp_path, wait_for):
    gate = WindowGate()
    logger, steps = writer_on_the_gate(tmp_path, gate)
    journal = logger.timed

    @contextlib.contextmanager
    def timed(name: str) -> Iterator[None]:
        with journal(name):
            yield
        if len(steps) == 1:  # the worker woke during the burst's first step
            gate.window_started()

    logger.timed = timed
    with logger:
        log_rows(logger, range(30))
        wait_for(lambda: gate.waits == 1, 10.0, "the writer waiting for its turn")
        gate.worker_waiting()  # the first burst's turn
        wait_for(lambda: gate.waits == 2, 10.0, "the writer pausing for the window")
        assert logger.stats()["written"] == 1 and len(steps) == 1  # the step begun, no more
        gate.window_finished()
        gate.worker_waiting()
        wait_for(lambda: logger.stats()["written"] == 30, 10.0, "the rest of the burst")
    assert not any(computing for _, computing in steps)
    (path,) = logger.files
    firsts = [batch.first_index for batch in mcap_read.iter_sample_batches(path)]
    assert firsts == [100 * b for b in range(30)]


def test_a_full_queue_still_drops_and_counts_while_the_writer_waits_for_its_turn(
    tmp_path, wait_for
):
    gate = WindowGate()
    logger, _ = writer_on_the_gate(tmp_path, gate, queue_size=16)
    with logger:
        gate.window_started()
        logger.log_samples(0, np.zeros(10), np.zeros(10))
        wait_for(lambda: gate.waits == 1, 10.0, "the writer waiting for its turn")
        accepted = [logger.log_samples(10 * (i + 1), np.zeros(10), np.zeros(10)) for i in range(40)]
        assert accepted.count(True) == 16 and accepted.count(False) == 24  # never blocks
        assert logger.stats()["dropped_by_kind"]["samples"] == 24
        gate.window_finished()
        gate.worker_waiting()
        wait_for(lambda: logger.stats()["written"] == 17, 10.0, "what was queued")


def test_a_writer_kept_waiting_by_a_busy_worker_still_flushes_on_time(tmp_path, wait_for):
    """A worker that never sleeps runs each of the writer's waits out (bounded): the writer
    still writes everything, and a long burst ends at the flush deadline, so the file is
    flushed while the queue drains, not only after it."""
    gate = WindowGate()
    steps: list[str] = []

    @contextlib.contextmanager
    def timed(name: str) -> Iterator[None]:
        steps.append(name)
        yield

    config = McapConfig(directory=str(tmp_path), chunk_size=1024, flush_interval_s=0.05)
    logger = McapLogger(config, robot="r", joint="ankle", fs_hz=2500.0)
    logger.timed = timed
    logger.busy = lambda: gate.computing
    logger.wait_turn = lambda: gate.after_next_window(0.01)
    gate.window_started()  # and never finished
    with logger:
        log_rows(logger, range(100))
        wait_for(lambda: logger.stats()["written"] == 100, 60.0, "every batch written")
    assert gate.waited_out >= 100  # each wait ran out
    writes = [i for i, name in enumerate(steps) if name == "mcap writer: write"]
    flushes = [i for i, name in enumerate(steps) if name == "mcap writer: flush"]
    assert flushes and flushes[0] < writes[-1]  # flushed mid-way, not after the last write
    (path,) = logger.files
    firsts = [batch.first_index for batch in mcap_read.iter_sample_batches(path)]
    assert firsts == [100 * b for b in range(100)]


def test_a_tick_of_estimates_pauses_between_two_when_a_window_begins(tmp_path, wait_for):
    """The batch of a tick's estimates is written one at a time while no window computes;
    a window begun after the third stops it there until the worker sleeps again."""
    gate = WindowGate()
    written: list[int] = []

    def tap(kind: str, log_time_ns: int, payload: bytes) -> None:
        written.append(json.loads(payload)["seq"])
        if len(written) == 3:
            gate.window_started()  # the worker woke

    config = McapConfig(directory=str(tmp_path), flush_interval_s=10.0)
    logger = McapLogger(config, robot="r", joint="ankle", fs_hz=2500.0, tap=tap)
    logger.busy = lambda: gate.computing
    logger.wait_turn = lambda: gate.after_next_window(30.0)
    messages = [estimate_message(seq) for seq in range(25)]
    with logger:
        logger.log_estimates([(encode_estimate(m), m["host_time_ns"], m) for m in messages])
        wait_for(lambda: gate.waits == 1, 10.0, "the writer waiting for its turn")
        gate.worker_waiting()
        wait_for(lambda: gate.waits == 2, 10.0, "the batch pausing for the window")
        assert written == [0, 1, 2]
        gate.window_finished()
        gate.worker_waiting()
        wait_for(lambda: len(written) == 25, 10.0, "the rest of the batch")
    assert written == list(range(25))
    (path,) = logger.files
    assert [e["seq"] for e in mcap_read.iter_estimates(path)] == list(range(25))


def estimate_message(seq: int) -> dict[str, object]:
    message: dict[str, object] = dict.fromkeys(ESTIMATE_FIELDS, 0.0)
    message.update(
        robot="r", joint="ankle", seq=seq, window_start_index=50 * seq,
        window_end_index=50 * seq + 749, ok=True, reason=None, flags=[],
        host_time_ns=1_000_000_000 + seq,
    )  # fmt: skip
    return message
