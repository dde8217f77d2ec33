"""The window worker: every hop, the latest window from the ring → one estimate message.

Runs on its own thread against absolute deadlines (:class:`~rtsid.runtime.clock.Deadlines`).
A window is estimated only from contiguous, valid, unsaturated, fresh samples; otherwise the
message says why (``ok: false`` and a ``reason``) — never a silent number. Work that overruns
its budget is counted, and the worker then takes the newest window rather than catching up on
stale ones.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rtsid.config import require_range, section_from_mapping
from rtsid.errors import NumericalError, WindowError
from rtsid.ident.window import EstimatorOptions, WindowEstimate, estimate_window
from rtsid.link.protocol import (
    STATUS_DISCONTINUITY,
    STATUS_POSITION_SATURATED,
    STATUS_TORQUE_SATURATED,
)
from rtsid.link.ring import RingBuffer, Snapshot
from rtsid.runtime.clock import Deadlines

__all__ = ["WindowWorker", "WorkerConfig", "WorkerCounters", "assess_window"]

_SATURATED = STATUS_POSITION_SATURATED | STATUS_TORQUE_SATURATED


@dataclass(frozen=True)
class WorkerConfig:
    """The ``[worker]`` config section.

    Attributes
    ----------
    window_s : float
        Window length, s.
    hop_s : float
        Time between estimates, s.
    budget_s : float
        Compute budget per window, s (0: the hop). Exceeding it counts a deadline miss.
    max_sample_age_s : float
        A window whose newest sample arrived longer ago than this is ``stale``.
    """

    window_s: float = 0.3
    hop_s: float = 0.02
    budget_s: float = 0.0
    max_sample_age_s: float = 0.1

    def __post_init__(self) -> None:
        require_range("window_s", self.window_s, 0.01, 60.0)
        require_range("hop_s", self.hop_s, 0.001, 60.0)
        require_range("budget_s", self.budget_s, 0.0, 60.0)
        require_range("max_sample_age_s", self.max_sample_age_s, 0.0, 60.0, low_inclusive=False)

    @classmethod
    def from_mapping(cls, mapping: Any) -> WorkerConfig:
        """Build from the ``[worker]`` TOML table."""
        return section_from_mapping(cls, mapping, "worker")

    @property
    def effective_budget_s(self) -> float:
        """The compute budget actually applied, s."""
        return self.budget_s or self.hop_s


@dataclass(frozen=True)
class WorkerCounters:
    """Totals since start (the ``worker`` object of the status message)."""

    estimates: int
    withheld: dict[str, int]
    overruns: int
    deadline_misses: int
    compute_ms_last: float


def assess_window(snap: Snapshot, now_s: float, max_age_s: float) -> str | None:
    """Why this window must not be estimated, or None when it may be.

    Parameters
    ----------
    snap : Snapshot
        The window's rows from the ring.
    now_s : float
        ``time.monotonic()`` now.
    max_age_s : float
        Largest acceptable age of the newest sample, s.

    Returns
    -------
    str or None
        ``"stale"``, ``"gap"`` (lost samples or a discontinuity in the signal),
        ``"saturated"`` or ``"nan"``; None when the window is usable.
    """
    if now_s - float(snap.host_time_s[-1]) > max_age_s:
        return "stale"
    if not bool(np.all(snap.valid)) or bool(np.any(snap.status & STATUS_DISCONTINUITY)):
        return "gap"
    if bool(np.any(snap.status & _SATURATED)):
        return "saturated"
    if not (np.all(np.isfinite(snap.position_rad)) and np.all(np.isfinite(snap.torque_nm))):
        return "nan"
    return None


class WindowWorker:
    """Estimate the latest window every hop on a named thread (a context manager).

    Parameters
    ----------
    ring : RingBuffer
        Samples written by the acquisition thread.
    fs_hz : float
        Sample rate, Hz.
    config : WorkerConfig
        Window, hop, budget, staleness.
    options : EstimatorOptions
        Identification settings.
    publish : callable
        Called with each message (dict following ``rtsid.io.schemas.ESTIMATE_SCHEMA``) on the
        worker thread; it must not block (the MCAP logger and zenoh publisher do not).
    robot, joint : str
        Names written into every message.
    torque_offset : callable, optional
        ``torque_offset(position_rad) -> torque_nm`` subtracted from the measured torque
        before identification (the robot's own dynamics from a calibration).
    """

    def __init__(
        self,
        ring: RingBuffer,
        fs_hz: float,
        config: WorkerConfig,
        options: EstimatorOptions,
        publish: Callable[[dict[str, Any]], None],
        *,
        robot: str = "robot",
        joint: str = "ankle",
        torque_offset: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        self.ring = ring
        self.fs_hz = float(fs_hz)
        self.config = config
        self.options = options
        self.publish = publish
        self.robot = robot
        self.joint = joint
        self.torque_offset = torque_offset
        self.window_samples = round(config.window_s * fs_hz)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._seq = 0
        self._withheld: Counter[str] = Counter()
        self._estimates = 0
        self._misses = 0
        self._deadlines: Deadlines | None = None
        self._compute_ms = 0.0
        self._last_end_index = -1
        self.error: BaseException | None = None

    # ------------------------------------------------------------------ life cycle
    def start(self) -> WindowWorker:
        """Start the worker thread."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="rtsid-worker", daemon=True)
            self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Stop and join; True if the thread ended within ``timeout_s``."""
        self._stop.set()
        if self._thread is None:
            return True
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def __enter__(self) -> WindowWorker:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def counters(self) -> WorkerCounters:
        """Totals since start."""
        return WorkerCounters(
            estimates=self._estimates,
            withheld=dict(self._withheld),
            overruns=self._deadlines.skipped if self._deadlines else 0,
            deadline_misses=self._misses,
            compute_ms_last=self._compute_ms,
        )

    # ------------------------------------------------------------------ the loop
    def _run(self) -> None:
        self._deadlines = Deadlines(self.config.hop_s)
        try:
            while self._deadlines.wait(self._stop):
                self.step()
        except BaseException as exc:  # reported in status; the daemon decides what to do
            self.error = exc
            raise

    def step(self) -> dict[str, Any] | None:
        """Estimate the newest window now and publish the message (None while warming up)."""
        started = time.perf_counter()
        snap = self.ring.latest(self.window_samples)
        if snap is None:
            return None
        reason = assess_window(snap, time.monotonic(), self.config.max_sample_age_s)
        if reason is None and int(snap.sample_index[-1]) == self._last_end_index:
            reason = "stale"  # no new sample since the previous estimate
        estimate, reason = self._estimate(snap, reason)
        compute_s = time.perf_counter() - started
        self._compute_ms = compute_s * 1e3
        if compute_s > self.config.effective_budget_s:
            self._misses += 1
        message = self._message(snap, estimate, reason, compute_s)
        self.publish(message)
        return message

    def _estimate(
        self, snap: Snapshot, reason: str | None
    ) -> tuple[WindowEstimate | None, str | None]:
        if reason is not None:
            self._withheld[reason] += 1
            return None, reason
        torque = snap.torque_nm
        if self.torque_offset is not None:
            torque = torque - self.torque_offset(snap.position_rad)
        try:
            estimate = estimate_window(snap.position_rad, torque, self.fs_hz, self.options)
        except WindowError as exc:
            self._withheld[exc.reason] += 1
            return None, exc.reason
        except NumericalError:
            self._withheld["numerical"] += 1
            return None, "numerical"
        self._estimates += 1
        self._last_end_index = int(snap.sample_index[-1])
        return estimate, None

    def _message(
        self,
        snap: Snapshot,
        estimate: WindowEstimate | None,
        reason: str | None,
        compute_s: float,
    ) -> dict[str, Any]:
        first, last = int(snap.sample_index[0]), int(snap.sample_index[-1])
        values = (
            {
                k: getattr(estimate, k)
                for k in ("I", "B", "K", "I_se", "B_se", "K_se", "vaf", "vaf_irf")
            }
            if estimate is not None
            else dict.fromkeys(("I", "B", "K", "I_se", "B_se", "K_se", "vaf", "vaf_irf"))
        )
        overrun = compute_s > self.config.effective_budget_s
        flags = [*(estimate.flags if estimate else ()), *(("over_budget",) if overrun else ())]
        seq = self._seq
        self._seq += 1
        return {
            "robot": self.robot,
            "joint": self.joint,
            "seq": seq,
            "window_start_index": first,
            "window_end_index": last,
            "t_start_s": first / self.fs_hz,
            "t_end_s": last / self.fs_hz,
            **values,
            "compute_ms": compute_s * 1e3,
            "latency_ms": (time.monotonic() - float(snap.host_time_s[-1])) * 1e3,
            "ok": estimate is not None,
            "reason": reason,
            "flags": flags,
            "host_time_ns": time.time_ns(),
        }
