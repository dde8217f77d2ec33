"""The torque-sign judgement (rtsid.ident.sign): one rule for identify, the daemon and replay."""

from __future__ import annotations

from rtsid.ident.sign import (
    INVERTED_SHARE,
    MIN_WINDOWS,
    SignCount,
    reads_inverted,
    torque_sign_inverted,
)


def test_a_window_reads_inverted_only_with_k_b_and_a_fitted_i_negative():
    assert reads_inverted(-100.0, -1.3, -0.015)
    assert not reads_inverted(-100.0, -1.3, 0.015)  # a fitted I > 0: not an inverted joint
    assert reads_inverted(-100.0, -1.3, 0.015, I_held=True)  # a held I is not this window's
    assert not reads_inverted(-100.0, 1.3, -0.015)
    assert not reads_inverted(100.0, -1.3, -0.015)


def test_the_sign_is_judged_only_after_enough_windows_and_by_a_majority():
    assert not torque_sign_inverted(MIN_WINDOWS - 1, MIN_WINDOWS - 1)
    assert torque_sign_inverted(MIN_WINDOWS, MIN_WINDOWS)
    majority = round(INVERTED_SHARE * 100)
    assert torque_sign_inverted(majority, 100) and not torque_sign_inverted(majority - 1, 100)


def test_the_running_count_fires_at_the_minimum_on_an_inverted_stream():
    count = SignCount()
    fired = [count.add(-100.0, -1.3, -0.015) for _ in range(MIN_WINDOWS)]
    assert fired == [False] * (MIN_WINDOWS - 1) + [True]
    correct = SignCount()
    assert not any(correct.add(100.0, 1.3, 0.015) for _ in range(10 * MIN_WINDOWS))
