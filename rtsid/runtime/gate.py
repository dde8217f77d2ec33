"""When the window worker is between windows: the moment for the daemon's other work.

At a 4 ms hop a window takes about 1 ms of CPU and the housekeeping tick (estimates and
samples handed to the MCAP writer, the history deflated, every 0.5 s the status built,
encoded and published) up to another. Run at the same time, the two share the GIL: each is
slowed to the pace of both, and the tick's 1 ms of CPU spread over 2–6 ms of wall made the
window it overlapped miss its deadline (issue 22; most misses on a quiet machine fell on a
status tick). Run when the worker has published a window and gone to wait for the next
window's last sample, the tick has the rest of the hop to itself.

:class:`WindowGate` is that meeting point. The worker calls :meth:`~WindowGate.window_started`
and :meth:`~WindowGate.window_finished` around each window and
:meth:`~WindowGate.worker_waiting` as it begins to wait for a sample (a lock, a flag and a
counter: it never waits here). Waiting, not finishing, is the moment: a worker that has fallen
behind starts the next window at once, and a tick begun then would share it. The housekeeping
thread calls :meth:`~WindowGate.after_next_window` when a tick falls due, and again before each
half of the status (its build; its encoding and publication), so each piece of work starts
where the worker has just gone to sleep. The wait is bounded: with no windows (a stale link, a
stopped worker) or a worker that never catches up, the tick runs when its bound is out, late
by at most that bound, so the status period stays 0.5 s on average (the ticks keep their
absolute deadlines, :class:`~rtsid.runtime.clock.Deadlines`).
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
    idle : int
        Times the worker began to wait for a sample (after a window, or while none came).
    waits, waited_out : int
        Calls of :meth:`after_next_window`, and those whose bound ran out before a window
        finished (the tick then ran anyway).
    """

    def __init__(self) -> None:
        self._changed = threading.Condition(threading.Lock())
        self._computing = False
        self.finished = 0
        self.idle = 0
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

    def worker_waiting(self) -> None:
        """The worker begins to wait for the next window's last sample: the hop's quiet part."""
        with self._changed:
            self.idle += 1
            self._changed.notify_all()

    # ------------------------------------------------------------------ the others' side
    @property
    def computing(self) -> bool:
        """A window is being computed now."""
        return self._computing

    def after_next_window(self, timeout_s: float) -> bool:
        """Wait until the worker next goes to wait for a sample (after the window it is
        computing, if any), at most ``timeout_s``.

        Returns
        -------
        bool
            True when the worker went to wait (the caller runs right after it); False when
            the bound ran out first.
        """
        deadline = time.monotonic() + timeout_s
        with self._changed:
            self.waits += 1
            seen = self.idle
            while self.idle == seen:
                left = deadline - time.monotonic()
                if left <= 0 or not self._changed.wait(left):
                    if self.idle == seen:
                        self.waited_out += 1
                        return False
            return True
