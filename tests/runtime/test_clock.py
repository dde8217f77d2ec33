import threading

import pytest

from rtsid.errors import ConfigError
from rtsid.runtime.clock import Deadlines


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_deadlines_are_absolute_and_do_not_drift(monkeypatch):
    clock = FakeClock()
    sleeps = []
    monkeypatch.setattr(
        "time.sleep", lambda s: (sleeps.append(s), setattr(clock, "now", clock.now + s))
    )
    d = Deadlines(0.02, clock=clock)
    for _ in range(3):
        clock.now += 0.005  # work takes 5 ms
        assert d.wait()
    assert d.next_deadline_s == pytest.approx(100.08)
    assert sleeps == pytest.approx([0.015, 0.015, 0.015])
    assert d.skipped == 0


def test_an_overrun_skips_past_deadlines_instead_of_bursting():
    clock = FakeClock()
    d = Deadlines(0.02, clock=clock)
    clock.now += 0.075  # a 75 ms stall: deadlines at +20, +40, +60 ms have passed
    assert d.wait()
    assert d.last_lateness_s == pytest.approx(0.055)
    assert d.skipped == 2  # +40 and +60 ms are dropped; the next is +80 ms
    assert d.next_deadline_s == pytest.approx(100.08)


def test_wait_returns_false_when_stopped():
    stop = threading.Event()
    stop.set()
    assert not Deadlines(10.0).wait(stop)  # returns at once, not after 10 s


def test_period_must_be_positive():
    with pytest.raises(ConfigError):
        Deadlines(0.0)
