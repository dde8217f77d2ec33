"""The daemon's slow lane: the reflex pathway re-fitted over the last tens of seconds.

Every ``update_s`` of samples it cuts the scheduled horizon out of the ring
(:class:`rtsid.ident.reflex_lane.ReflexModels` decides which samples, by index only) and fits
the parallel cascade, either in a spawned worker process (``mode = "process"``: it never holds
the daemon's GIL) or on this low-priority thread (``mode = "thread"``). Finished fits go into
the shared :class:`~rtsid.ident.reflex_lane.ReflexModels`, where the fast lane picks the one
its window is due; each is published on ``/reflex``. A fit that fails (bad data, numerics, a
crashed worker process) is counted and reported in the status; it never stops the fast lane.
"""

from __future__ import annotations

import concurrent.futures as futures
import logging
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rtsid.ident.reflex_lane import (
    ReflexModels,
    ReflexUpdate,
    SlowLaneSettings,
    fit_reflex_update,
    warm_up,
)
from rtsid.lifecycle import ThreadOwner
from rtsid.link.ring import RingBuffer, Snapshot

__all__ = ["SlowLane", "SlowLaneCounters", "TorqueOf"]

log = logging.getLogger("rtsid.slow_lane")

#: Sign-corrected torque of a snapshot with the robot's own dynamics removed.
TorqueOf = Callable[[Snapshot], np.ndarray]
#: Niceness of the slow lane's process or thread (higher: lower priority).
NICENESS = 10


@dataclass
class SlowLaneCounters:
    """Totals since start (the ``slow_lane`` object of the status message)."""

    mode: str
    fits: int = 0
    applied: int = 0
    failed: int = 0
    worker_restarts: int = 0
    last_seq: int | None = None
    last_fit_ms: float | None = None
    last_error: str | None = None


def _lower_priority() -> None:
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), NICENESS)
    except OSError:  # not permitted or not Linux: run at the normal priority
        pass


def _exit_with(parent_pid: int) -> None:
    """End this worker process when the daemon that started it is gone (killed with SIGKILL,
    say): a worker blocked on its task queue would otherwise outlive it."""
    while os.getppid() == parent_pid:
        time.sleep(1.0)
    os._exit(0)


def _init_worker_process(parent_pid: int) -> None:
    """Initializer of the slow lane's worker process: low priority, gone with its parent, deaf
    to Ctrl-C (the terminal sends SIGINT to the whole process group: the daemon stops the pool
    itself, and a worker interrupted in its queue read printed a traceback)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _lower_priority()
    threading.Thread(target=_exit_with, args=(parent_pid,), daemon=True).start()


def _end_pool(pool: futures.ProcessPoolExecutor, timeout_s: float = 5.0) -> None:
    """Shut ``pool`` down without waiting for a fit in progress: its worker process is ended.

    Waiting for it (``shutdown(wait=True)``) has no bound: at low priority on a machine at
    load 15 a fit ran for tens of seconds, and the daemon, which stops the slow lane before
    it forwards the last samples to the recording, lost to the ring 8 001 samples its live
    windows had used (the replay then withheld them). Python 3.14's
    ``ProcessPoolExecutor.terminate_workers`` does the same.
    """
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    for process in processes:
        process.join(timeout_s)
        if process.is_alive():  # frozen (SIGSTOP) or ignoring SIGTERM
            process.kill()
            process.join(timeout_s)


class SlowLane(ThreadOwner):
    """Fit the reflex pathway on schedule from the ring (a context manager).

    Parameters
    ----------
    ring : RingBuffer
        The acquisition's ring (it must hold ``horizon_s`` plus ``update_s``).
    models : ReflexModels
        Where fits go; the fast lane reads them.
    torque_of : callable
        Snapshot → sign-corrected torque without the robot's own dynamics (N·m).
    publish : callable
        Called with each finished :class:`ReflexUpdate` and its fit time (ms).
    """

    def __init__(
        self,
        ring: RingBuffer,
        models: ReflexModels,
        torque_of: TorqueOf,
        publish: Callable[[ReflexUpdate, float], None],
    ) -> None:
        super().__init__("rtsid-slow-lane")
        self.ring = ring
        self.models = models
        self.settings: SlowLaneSettings = models.settings
        self.torque_of = torque_of
        self.publish = publish
        self._counters = SlowLaneCounters(mode=self.settings.mode)
        self._lock = threading.Lock()
        self._pool: futures.ProcessPoolExecutor | None = None
        self._warming: futures.Future[bool] | None = None  # the process's first task

    def counters(self) -> SlowLaneCounters:
        """A copy of the totals."""
        with self._lock:
            return SlowLaneCounters(**vars(self._counters))

    # ------------------------------------------------------------------ life cycle
    def _before_start(self) -> None:
        if self.settings.mode == "process":
            self._pool = self._new_pool()
            self._warming = self._pool.submit(warm_up, self.models.fs_hz, self.settings)

    def _new_pool(self) -> futures.ProcessPoolExecutor:
        return futures.ProcessPoolExecutor(
            max_workers=1,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_worker_process,
            initargs=(os.getpid(),),
        )

    def _after_stop(self, ended: bool) -> None:
        if self._pool is not None:
            _end_pool(self._pool)
            self._pool = None

    # ------------------------------------------------------------------ the loop
    def _run(self) -> None:
        if self.settings.mode == "thread":
            _lower_priority()
            warm_up(self.models.fs_hz, self.settings)
        first: int | None = None
        seq = 0
        while not self._stop.is_set():
            if first is None:
                if self.ring.newest_index < 0:
                    self._stop.wait(0.05)
                    continue
                # the data's first sample, not the oldest still held: a lane that starts
                # late (a long warm-up under load) keeps the schedule a replay re-derives
                first = self.ring.first_index
                seq = self.models.first_seq(first)
            span = self.models.fit_span(seq, first)
            if span is None or self.ring.newest_index < span[1] - 1:
                self._stop.wait(0.05)
                continue
            self._fit(seq, span)
            seq += 1

    def _fit(self, seq: int, span: tuple[int, int]) -> None:
        start, end = span
        snap = self.ring.read_since(start, end - start)
        started = time.perf_counter()
        if len(snap) != end - start or int(snap.sample_index[0]) != start:
            update = ReflexUpdate.failed(seq, start, end, "the ring no longer holds the horizon")
        else:
            try:
                update = self._run_fit(seq, snap)
            except Exception as exc:  # counted and reported; the fast lane goes on without it
                update = ReflexUpdate.failed(seq, start, end, f"{type(exc).__name__}: {exc}")
        if self._stop.is_set() and update.error == "stopped":
            return
        fit_ms = (time.perf_counter() - started) * 1e3
        self.models.add(update)
        self._count(update, fit_ms)
        self.publish(update, fit_ms)

    def _run_fit(self, seq: int, snap: Snapshot) -> ReflexUpdate:
        start, end = int(snap.sample_index[0]), int(snap.sample_index[-1]) + 1
        valid = None if snap.valid.all() else snap.valid
        args = (seq, start, snap.position_rad, self.torque_of(snap), valid, self.models.fs_hz)
        if self._pool is None:
            return fit_reflex_update(*args, self.settings)
        try:
            future = self._pool.submit(fit_reflex_update, *args, self.settings)
            while not self._stop.is_set():
                try:
                    return future.result(timeout=0.1)
                except futures.TimeoutError:
                    continue
            future.cancel()
            return ReflexUpdate.failed(seq, start, end, "stopped")
        except futures.process.BrokenProcessPool as exc:
            self._restart_pool()
            return ReflexUpdate.failed(seq, start, end, f"the slow-lane process died: {exc}")

    def _restart_pool(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
        self._pool = self._new_pool()
        self._warming = self._pool.submit(warm_up, self.models.fs_hz, self.settings)
        with self._lock:
            self._counters.worker_restarts += 1

    def _count(self, update: ReflexUpdate, fit_ms: float) -> None:
        with self._lock:
            c = self._counters
            c.last_seq = update.seq
            c.last_fit_ms = fit_ms
            if update.pathway is None:
                c.failed += 1
                if c.last_error != update.error:
                    log.warning(
                        "slow-lane fit %d gave no reflex model: %s", update.seq, update.error
                    )
                c.last_error = update.error
            else:
                c.fits += 1
                c.applied += int(update.applied)
