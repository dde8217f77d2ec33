"""The window gate: the housekeeping tick waits for a window to finish, never the worker."""

from __future__ import annotations

import threading

from rtsid.runtime.gate import WindowGate


def waiting(gate: WindowGate, timeout_s: float) -> tuple[threading.Thread, list[bool]]:
    """A thread waiting on ``gate.after_next_window(timeout_s)``; its answer lands in the list."""
    answers: list[bool] = []
    thread = threading.Thread(target=lambda: answers.append(gate.after_next_window(timeout_s)))
    thread.start()
    return thread, answers


def test_a_tick_waits_for_the_window_being_computed_to_finish():
    gate = WindowGate()
    gate.window_started()
    assert gate.computing
    thread, answers = waiting(gate, 30.0)
    thread.join(0.2)
    assert thread.is_alive() and answers == []  # still computing: the tick has not begun
    gate.window_finished()
    thread.join(30.0)
    assert not thread.is_alive() and answers == [True]
    assert not gate.computing and gate.finished == 1
    assert (gate.waits, gate.waited_out) == (1, 0)


def test_a_window_finished_before_the_tick_fell_due_does_not_count():
    # the tick runs right after a window: one that ended earlier says nothing about how much
    # of the hop is left
    gate = WindowGate()
    gate.window_started()
    gate.window_finished()
    thread, answers = waiting(gate, 30.0)
    thread.join(0.2)
    assert thread.is_alive() and answers == []
    gate.window_started()  # the worker never waits on the gate
    gate.window_finished()
    thread.join(30.0)
    assert answers == [True] and gate.finished == 2


def test_with_no_windows_the_tick_runs_when_its_bound_is_out_and_counts_it():
    gate = WindowGate()
    assert gate.after_next_window(0.01) is False
    assert (gate.waits, gate.waited_out, gate.finished) == (1, 1, 0)
