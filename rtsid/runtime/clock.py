"""Fixed-rate scheduling against absolute monotonic deadlines.

Deadlines are ``start + k·period``: a slow iteration never shifts later ones (no drift), and
an iteration that overran skips the deadlines already past instead of running them in a
burst — stale work is dropped, and how much is reported (cf. openpilot's ``Ratekeeper``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from rtsid.errors import ConfigError

__all__ = ["Deadlines"]


class Deadlines:
    """Absolute deadlines every ``period_s`` on ``time.monotonic()``.

    Parameters
    ----------
    period_s : float
        Period, s (> 0).
    start_s : float, optional
        First deadline (default: one period from now).
    clock : callable
        Monotonic clock, s (tests may inject one).

    Attributes
    ----------
    skipped : int
        Deadlines passed over because an iteration ran past them.
    last_lateness_s : float
        How late the most recent wake-up was, s.
    """

    def __init__(
        self,
        period_s: float,
        start_s: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not period_s > 0:
            raise ConfigError(f"period {period_s!r} s must be > 0")
        self.period_s = float(period_s)
        self._clock = clock
        self._next = (clock() + period_s) if start_s is None else float(start_s)
        self.skipped = 0
        self.last_lateness_s = 0.0

    @property
    def next_deadline_s(self) -> float:
        """The deadline :meth:`wait` sleeps until."""
        return self._next

    def wait(self, stop: threading.Event | None = None) -> bool:
        """Sleep until the next deadline (or until ``stop`` is set); then advance.

        Returns
        -------
        bool
            False when ``stop`` was set (the caller should end its loop).
        """
        delay = self._next - self._clock()
        if delay > 0:
            if stop is not None:
                if stop.wait(delay):
                    return False
            else:
                time.sleep(delay)
        elif stop is not None and stop.is_set():
            return False
        now = self._clock()
        self.last_lateness_s = max(0.0, now - self._next)
        self._advance(now)
        return True

    def _advance(self, now: float) -> None:
        self._next += self.period_s
        if self._next <= now:
            missed = int((now - self._next) // self.period_s) + 1
            self.skipped += missed
            self._next += missed * self.period_s
