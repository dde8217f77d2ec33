"""When the window worker is between windows: the moment for the daemon's other work.

At a 4 ms hop a window takes about 1 ms of CPU and the housekeeping tick (estimates and
samples handed to the MCAP writer, the history deflated, every 0.5 s the status built,
encoded and published) up to another. Run at the same time, the two share the GIL: each is
slowed to the pace of both, and the tick's 1 ms of CPU spread over 2–6 ms of wall made the
window it overlapped miss its deadline (issue 22; most misses on a quiet machine fell on a
status tick). Run right after a window is published, the tick has the whole rest of the hop
before the next window's last sample arrives.

:class:`WindowGate` is that meeting point. The worker calls :meth:`~WindowGate.window_started`
and :meth:`~WindowGate.window_finished` around each window (a lock and a flag: it never waits
here); the housekeeping thread calls :meth:`~WindowGate.after_next_window` when a tick falls
due, and again before each half of the status (its build; its encoding and publication), so
each piece of work starts where a window has just ended. The wait is bounded:
with no windows (a stale link, a stopped worker) the tick runs when its bound is out, late by
at most that bound, so the status period stays 0.5 s on average (the ticks keep their absolute
deadlines, :class:`~rtsid.runtime.clock.Deadlines`).
"""

from __future__ import annotations

import threading
import time

__all__ = ["WindowGate"]


class WindowGate:
    """Whether a window is being computed, and a wait for the moment one has just finished.

    Attributes
    ----------
    finished : int
        Windows finished since start.
    waits, waited_out : int
        Calls of :meth:`after_next_window`, and those whose bound ran out before a window
        finished (the tick then ran anyway).
    """

    def __init__(self) -> None:
        self._changed = threading.Condition(threading.Lock())
        self._computing = False
        self.finished = 0
        self.waits = 0
        self.waited_out = 0

    # ------------------------------------------------------------------ the worker's side
    def window_started(self) -> None:
        """The worker begins a window (never blocks beyond a short lock)."""
        with self._changed:
            self._computing = True

    def window_finished(self) -> None:
        """The worker has published the window's message."""
        with self._changed:
            self._computing = False
            self.finished += 1
            self._changed.notify_all()

    # ------------------------------------------------------------------ the others' side
    @property
    def computing(self) -> bool:
        """A window is being computed now."""
        return self._computing

    def after_next_window(self, timeout_s: float) -> bool:
        """Wait until a window finishes (one finishing from now on), at most ``timeout_s``.

        Returns
        -------
        bool
            True when a window finished (the caller runs right after it); False when the
            bound ran out first.
        """
        deadline = time.monotonic() + timeout_s
        with self._changed:
            self.waits += 1
            seen = self.finished
            while self.finished == seen:
                left = deadline - time.monotonic()
                if left <= 0 or not self._changed.wait(left):
                    if self.finished == seen:
                        self.waited_out += 1
                        return False
            return True
