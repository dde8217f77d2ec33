"""One life cycle for every component that owns a thread: start → running → stop → error.

::

    owner = Component(...)          # nothing runs yet
    owner.start()                   # opens what it needs (may raise), starts the thread
    owner.running                   # True while the thread lives
    owner.failure                   # None, or one line saying why the thread died
    owner.stop(timeout_s=2.0)       # bounded; True only if it ended in time *and* cleanly
    owner.check()                   # re-raises a thread's error as ServiceError

Modelled on python-can's ``Notifier``: the thread's exception is kept (``error``) and logged
once, never lost. It is *not* re-raised on the thread (that would only print a traceback
nobody acts on); whoever owns the component sees it through :attr:`ThreadOwner.failure`,
:meth:`ThreadOwner.check` or the result of :meth:`ThreadOwner.stop`. The daemon polls
``failure`` of every component and exits non-zero when one is set.

Subclasses implement :meth:`ThreadOwner._run` (loop ``while not self._stop.is_set()``, each
wait bounded) and may override the hooks :meth:`_before_start`, :meth:`_interrupt` and
:meth:`_after_stop`.
"""

from __future__ import annotations

import logging
import threading
from typing import Self

from rtsid.errors import ServiceError

__all__ = ["ThreadOwner"]

log = logging.getLogger("rtsid.lifecycle")


class ThreadOwner:
    """Base of components that own one thread (a context manager).

    Parameters
    ----------
    thread_name : str
        Name of the thread (shows in tracebacks, ``top -H`` and leak reports).
    ends_by_itself : bool
        Whether the thread may finish on its own (a player that reaches the end of its
        recording); otherwise a thread that ends before :meth:`stop` is a failure.
    """

    def __init__(self, thread_name: str, *, ends_by_itself: bool = False) -> None:
        self.thread_name = thread_name
        self._ends_by_itself = ends_by_itself
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None

    # ------------------------------------------------------------------ for subclasses
    def _run(self) -> None:
        """The thread's body; return when ``self._stop`` is set."""
        raise NotImplementedError

    def _before_start(self) -> None:
        """Open what the thread needs (on the caller's thread; may raise)."""

    def _interrupt(self) -> None:
        """Wake the thread from a wait :attr:`_stop` does not interrupt."""

    def _after_stop(self, ended: bool) -> None:
        """Release resources once the thread is joined (``ended``) or given up on."""

    # ------------------------------------------------------------------ life cycle
    def start(self) -> Self:
        """Start the thread (idempotent); errors opening resources propagate."""
        if self._thread is not None:
            return self
        self._before_start()
        self._thread = threading.Thread(target=self._main, name=self.thread_name, daemon=True)
        self._thread.start()
        return self

    def _main(self) -> None:
        try:
            self._run()
        except BaseException as exc:  # kept and reported; the owner decides what to do
            self.error = exc
            log.error("thread %s failed: %r", self.thread_name, exc, exc_info=exc)

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Ask the thread to stop and wait at most ``timeout_s`` seconds.

        Returns
        -------
        bool
            True when the thread has ended and no error ended it (a clean stop).
        """
        self._stop.set()
        self._interrupt()
        ended = True
        if self._thread is not None:
            if self._thread is not threading.current_thread():
                self._thread.join(timeout_s)
            ended = not self._thread.is_alive()
            if not ended:
                log.error("thread %s did not stop within %.1f s", self.thread_name, timeout_s)
        self._after_stop(ended)
        return ended and self.error is None

    @property
    def native_id(self) -> int | None:
        """The thread's kernel id once started (for scheduling it; None before)."""
        return None if self._thread is None else self._thread.native_id

    @property
    def running(self) -> bool:
        """Whether the thread is alive."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def failure(self) -> str | None:
        """Why the thread died (its error, or an end nobody asked for); None while healthy."""
        if self.error is not None:
            return f"thread {self.thread_name} failed: {type(self.error).__name__}: {self.error}"
        if self._thread is None or self._ends_by_itself or self._stop.is_set():
            return None
        if not self._thread.is_alive():
            return f"thread {self.thread_name} ended although nobody stopped it"
        return None

    def check(self) -> None:
        """Raise :class:`~rtsid.errors.ServiceError` if the thread failed."""
        failure = self.failure
        if failure is not None:
            raise ServiceError(failure) from self.error

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
