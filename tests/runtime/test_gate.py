"""The window gate: the housekeeping tick waits for the worker to go to sleep, never the
worker for the tick."""

from __future__ import annotations

import threading

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
