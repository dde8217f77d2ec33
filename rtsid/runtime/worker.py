"""The window worker: every hop, one window from the ring → one estimate message.

Windows end on a fixed grid of sample indices — every ``hop`` samples (``end + 1`` a multiple
of the hop) — so the windows do not depend on thread timing and a replay of the recording
reproduces them exactly (same windows, same numbers). The worker thread sleeps until the
acquisition thread publishes the window's last sample (the ring wakes it), so the time from
that sample to the estimate is the wake-up plus the compute time.

A window is estimated only from valid, unsaturated, fresh samples without a discontinuity —
a few lost samples are bridged by sums over the valid ones (never interpolated) and counted in
``lost_samples``; otherwise the message says why (``ok: false`` and a ``reason``) — never a
silent number. When the worker
falls behind by a hop or more it skips to the newest window (stale work is dropped and
counted as overruns); compute beyond the budget counts a deadline miss.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rtsid.config import from_config_folder, require_range, section_from_mapping
from rtsid.errors import (
    ConfigError,
    InputDataError,
    NumericalError,
    TorqueSignError,
    WindowError,
)
from rtsid.ident.check import window_scan
from rtsid.ident.grid import first_window_end
from rtsid.ident.records import built
from rtsid.ident.reflex import ReflexStream
from rtsid.ident.reflex_lane import ReflexModels, ReflexUpdate, predict_reflex_torque
from rtsid.ident.sign import SignCount, inverted_torque_message
from rtsid.ident.stream import Tracked, WindowStream
from rtsid.ident.tracker import TrackerOptions
from rtsid.ident.window import EstimatorOptions, WindowEstimate
from rtsid.io.calibration import Calibration, load_calibration
from rtsid.io.messages import EstimateMessage, ReflexMessage
from rtsid.io.recording import GridColumns
from rtsid.lifecycle import ThreadOwner
from rtsid.link.protocol import (
    STATUS_DISCONTINUITY,
    STATUS_POSITION_SATURATED,
    STATUS_TORQUE_SATURATED,
)
from rtsid.runtime.gate import WindowGate
from rtsid.verdicts import Flag, Reason

if TYPE_CHECKING:  # the live worker's own: a replay's evaluator does not import them
    from rtsid.link.ring import RingBuffer, Snapshot
    from rtsid.runtime.stages import StageLog
    from rtsid.runtime.stalls import StallJournal

__all__ = ["OVERRUN_CAUSES", "WindowWorker", "WorkerConfig", "WorkerCounters", "assess_window"]

#: Why windows were skipped (``overrun_causes`` in the worker's counters): the link delivered
#: more than a hop of samples in one block; the worker was still computing the window
#: before; it was waiting and woke late; the rows were no longer (or not yet) in the ring.
OVERRUN_CAUSES = (
    "samples came in one burst",
    "previous window still computing",
    "worker woke late",
    "rows not in the ring",
)

_SATURATED = STATUS_POSITION_SATURATED | STATUS_TORQUE_SATURATED
log = logging.getLogger(__name__)


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
    calibration_file : str
        Robot-dynamics calibration (``rtsid calibrate``) whose predicted robot torque is
        subtracted from every window before identification ("": none). In a config file, a
        relative path is taken from the file's folder (as ``protocol.dbc`` and
        ``plant.player_file``); elsewhere from the working directory. It is kept absolute (so a
        recording's stored config still finds it when replayed from elsewhere).
    """

    window_s: float = 0.3
    hop_s: float = 0.02
    budget_s: float = 0.0
    max_sample_age_s: float = 0.1
    calibration_file: str = ""

    def __post_init__(self) -> None:
        require_range("window_s", self.window_s, 0.01, 60.0)
        require_range("hop_s", self.hop_s, 0.001, 60.0)
        require_range("budget_s", self.budget_s, 0.0, 60.0)
        require_range("max_sample_age_s", self.max_sample_age_s, 0.0, 60.0, low_inclusive=False)
        if self.calibration_file:
            path = os.path.abspath(os.path.expanduser(self.calibration_file))
            object.__setattr__(self, "calibration_file", path)
            try:
                load_calibration(path)
            except InputDataError as exc:
                raise ConfigError(f"config key 'worker.calibration_file': {exc}") from None

    @classmethod
    def from_mapping(cls, mapping: Any, base_dir: str | Path | None = None) -> WorkerConfig:
        """Build from the ``[worker]`` TOML table; a relative ``calibration_file`` is taken
        from ``base_dir`` (the config file's folder) when given."""
        if isinstance(mapping, Mapping) and "calibration_file" in mapping:
            path = from_config_folder(mapping["calibration_file"], base_dir)
            mapping = {**mapping, "calibration_file": path}
        return section_from_mapping(cls, mapping, "worker")

    @property
    def effective_budget_s(self) -> float:
        """The compute budget actually applied, s."""
        return self.budget_s or self.hop_s


@dataclass(frozen=True)
class WorkerCounters:
    """Totals since start (the ``worker`` object of the status message).

    ``compute_ms_last`` and ``compute_s`` are wall time (``perf_counter``: what the deadline
    is about); ``compute_cpu_ms_last`` and ``compute_cpu_s`` the worker thread's CPU time over
    the same spans (``thread_time``). Wall minus CPU is time the worker was ready but did not
    run: waiting for the GIL, or for a CPU the kernel or the hypervisor gave to others.
    """

    estimates: int
    withheld: dict[str, int]
    overruns: int
    deadline_misses: int
    compute_ms_last: float
    reflex_flagged: dict[str, int] = field(default_factory=dict)
    compute_cpu_ms_last: float = 0.0
    compute_s: float = 0.0
    compute_cpu_s: float = 0.0
    miss_causes: dict[str, int] = field(default_factory=dict)
    miss_waits: dict[str, int] = field(default_factory=dict)
    overrun_causes: dict[str, int] = field(default_factory=dict)
    gc_collections: list[int] = field(default_factory=list)
    gc_ms: list[float] = field(default_factory=list)
    miss_stages: dict[str, int] = field(default_factory=dict)
    costly_stages: dict[str, int] = field(default_factory=dict)
    #: missed windows, and costly ones missed or not, by why their CPU ran long
    #: (:data:`rtsid.runtime.stages.CPU_CAUSES`)
    miss_cpu_causes: dict[str, int] = field(default_factory=dict)
    costly_causes: dict[str, int] = field(default_factory=dict)
    #: windows whose worker thread took page faults, and those faults (getrusage); of them,
    #: in the compiled call
    faulted_windows: int = 0
    window_faults: int = 0
    faulted_calls: int = 0
    call_faults: int = 0
    #: the longest collection while running windows, and at start-up:
    #: ``[generation, wall ms, CPU ms]`` (None: none)
    gc_longest: list[float] | None = None
    gc_longest_startup: list[float] | None = None
    gc_frozen: int = 0  # objects moved out of the collector's view (gc.freeze)


def assess_window(
    snap: Snapshot, now_s: float, max_age_s: float, all_valid: bool | None = None
) -> Reason | None:
    """Why this window must not be estimated, or None when it may be.

    Parameters
    ----------
    snap : Snapshot
        The window's rows from the ring.
    now_s : float
        ``time.monotonic()`` now.
    max_age_s : float
        Largest acceptable age of the newest sample, s.
    all_valid : bool, optional
        Ignored (the one pass over the rows reads it anyway); kept for callers that pass it.

    Returns
    -------
    str or None
        ``"stale"``, ``"gap"`` (a discontinuity in the signal), ``"saturated"`` or
        ``"nan"``; None when the window may be estimated. Lost samples are not judged here:
        the estimator bridges a few (sums over valid samples only) and withholds the window
        with ``"gap"`` past its limits (``max_lost_percent``, ``max_gap_s``).
    """
    if now_s - float(snap.host_time_s[-1]) > max_age_s:
        return Reason.STALE
    rows = len(snap)
    raised, _, finite = window_scan(
        snap.position_rad, snap.torque_nm, snap.valid, snap.status, 0, rows
    )
    return scanned_reason(raised, finite)


def scanned_reason(raised: int, finite: bool) -> Reason | None:
    """What a window's rows say against estimating it (:func:`~rtsid.ident.check.window_scan`
    read them): its rows' status bits ``raised`` and whether its valid rows are ``finite``;
    None when nothing does."""
    if raised & STATUS_DISCONTINUITY:
        return Reason.GAP  # the signal itself jumps: no sum over valid samples bridges that
    if raised & _SATURATED:
        return Reason.SATURATED
    if not finite:  # lost rows hold no value (a recording stores NaN there): not counted
        return Reason.NAN
    return None


@dataclass(frozen=True)
class _ReflexUse:
    """The slow lane's part in one window: the fit used, its torque over the window (None:
    nothing subtracted) and its flags."""

    seq: int | None
    torque: Any
    flags: tuple[Flag, ...]


_NO_REFLEX = _ReflexUse(None, None, ())
_ABSENT_REFLEX = _ReflexUse(None, None, (Flag.REFLEX_ABSENT,))


class WindowEvaluator:
    """Windows in, estimate messages out: the one message builder of live runs and replay.

    It owns what a stream carries from window to window (the analysis plan, the held
    parameters, the message counter) and the window counters; the :class:`WindowWorker`
    thread feeds it from the ring, :func:`rtsid.replay.replay_file` from a recording.

    Parameters
    ----------
    fs_hz : float
        Sample rate, Hz.
    config : WorkerConfig
        Window, hop, budget, staleness.
    options : EstimatorOptions
        Identification settings.
    publish : callable
        Called with each message (dict following ``rtsid.io.messages.ESTIMATE_SCHEMA``); it
        must not block (the MCAP logger and zenoh publisher do not).
    robot, joint : str
        Names written into every message.
    calibration : Calibration, optional
        The robot's own dynamics (``rtsid calibrate``): its predicted torque is subtracted
        from the measured torque before identification, and the analysis stays within the
        band the calibration models (``robot.analysis_cutoff_hz``).
    live : bool
        Samples arriving now (staleness judged, latency measured), or from a recording (never
        stale, ``latency_ms`` null).
    reflex : ReflexModels, optional
        The slow lane's reflex models: the due model's reflex torque is subtracted before
        the intrinsic estimate; snapshots then carry :attr:`history_samples` rows before
        the window (the reflex pathway's memory).
    tracker : TrackerOptions, optional
        The K(t)/B(t) tracker's settings (every message carries ``K_track`` …).
    """

    def __init__(
        self,
        fs_hz: float,
        config: WorkerConfig,
        options: EstimatorOptions,
        publish: Callable[[dict[str, Any]], None],
        *,
        robot: str = "robot",
        joint: str = "ankle",
        calibration: Calibration | None = None,
        live: bool = True,
        reflex: ReflexModels | None = None,
        tracker: TrackerOptions | None = None,
    ) -> None:
        self.fs_hz = float(fs_hz)
        self.config = config
        self.options = options
        self.publish = publish
        self.robot = robot
        self.joint = joint
        self.calibration = calibration
        self.live = live
        # The analysis plan and the held parameters: deterministic state carried from window
        # to window, so a replay of the same windows reproduces every number.
        band = calibration.robot.analysis_cutoff_hz if calibration is not None else None
        self.stream = WindowStream(
            fs_hz,
            options,
            config.hop_s,
            max_lowpass_hz=band,
            window_s=config.window_s,
            tracker=tracker,
        )
        self.window_samples = round(config.window_s * fs_hz)
        self.hop_samples = max(1, round(config.hop_s * fs_hz))
        self.reflex = reflex
        self.history_samples = reflex.history_samples if reflex is not None else 0
        self.reflex_stream = ReflexStream()  # the reflex prediction carried from hop to hop
        if reflex is not None:  # not inside the first window that takes up a model
            ReflexStream.prepare(fs_hz, reflex.settings.cascade().fs_out_hz)
        self.reflex_flagged: Counter[str] = Counter()
        self.last_reflex = _NO_REFLEX  # the slow lane's part in the latest window
        self._unapplied = _NO_REFLEX  # the latest model judged absent from the data, as used
        # a replay following a live run: window end -> (reflex_seq, absent, stale) as live had
        self.recorded_reflex: dict[int, tuple[int | None, bool, bool]] | None = None
        # ... and the windows it withheld as stale (its samples' age is not in a recording)
        self.recorded_stale: frozenset[int] = frozenset()
        self._seq = 0
        self.withheld: Counter[str] = Counter()
        self.estimates = 0
        self.misses = 0
        self.compute_ms = 0.0  # the latest window's, wall time
        self.compute_cpu_ms = 0.0  # the latest window's, this thread's CPU time
        self.compute_s = 0.0  # every window's wall time, summed
        self.compute_cpu_s = 0.0  # every window's CPU time, summed
        self.sign = SignCount()  # windows reading K, B, I < 0 (rtsid.ident.sign)
        self.stages: StageLog | None = None  # the per-window stage log (live: the worker's)
        # read every window: the staleness limit (live) and the compute budget, s
        self._max_age_s = config.max_sample_age_s
        self._budget_s = config.effective_budget_s

    def log_stages(self, stages: StageLog | None) -> None:
        """Mark each stage of every window in ``stages`` (None: stop; replay logs none)."""
        self.stages = stages
        self.stream.stage_mark = None if stages is None else stages.mark

    def first_window_end(self, first_index: int) -> int:
        """The first grid window end whose window starts at or after ``first_index``."""
        return first_window_end(first_index, self.window_samples, self.hop_samples)

    def model_torque(self, position: Any, torque: Any) -> Any:
        """The torque the models explain: sign-corrected, the robot's own dynamics removed
        (what the slow lane fits)."""
        if self.calibration is not None:
            torque = torque - self.calibration.torque_offset(position)
        return self.options.torque_sign * torque

    def reflex_message(self, update: ReflexUpdate, fit_ms: float | None) -> dict[str, Any]:
        """The ``/reflex`` message of one slow-lane fit."""
        assert self.reflex is not None
        applies_from = update.seq * self.reflex.update + self.reflex.apply_after - 1
        return ReflexMessage.of(
            update,
            robot=self.robot,
            joint=self.joint,
            variant=self.reflex.settings.variant,
            applies_from_index=applies_from,
            fit_ms=fit_ms,
        ).as_dict()

    def evaluate(
        self,
        snap: Snapshot,
        *,
        started_s: float | None = None,
        started_cpu_s: float | None = None,
    ) -> dict[str, Any]:
        """Estimate one window of samples and publish its message.

        Parameters
        ----------
        snap : Snapshot
            The window's rows, oldest first, after up to :attr:`history_samples` rows of
            history (with a slow lane).
        started_s : float, optional
            ``perf_counter()`` when work on the window began (default: now).
        started_cpu_s : float, optional
            ``thread_time()`` then, on this thread (default: now).
        """
        first = int(snap.sample_index[0])
        columns = (snap.position_rad, snap.torque_nm, snap.valid, snap.status, first)
        arrival = float(snap.host_time_s[-1]) if self.live else None
        return self.evaluate_rows(
            columns,
            first,
            first + len(snap),
            arrival_s=arrival,
            started_s=started_s,
            started_cpu_s=started_cpu_s,
        )

    def evaluate_rows(
        self,
        columns: GridColumns,
        start: int,
        stop: int,
        *,
        arrival_s: float | None = None,
        started_s: float | None = None,
        started_cpu_s: float | None = None,
    ) -> dict[str, Any]:
        """:meth:`evaluate` of samples ``start .. stop − 1`` held in ``columns`` (replay: the
        recording's grid, whose windows are rows of the same columns; no snapshot cut).

        Parameters
        ----------
        columns : tuple
            Position (rad), torque (N·m), valid and status columns, and the sample index of
            their row 0 (:meth:`rtsid.io.recording.SampleGrid.buffers`).
        start, stop : int
            The window's samples, after up to :attr:`history_samples` of history.
        arrival_s : float, optional
            ``time.monotonic()`` when the newest sample arrived (live; None: recorded
            samples, never stale).
        started_s, started_cpu_s : float, optional
            As :meth:`evaluate`.
        """
        started = time.perf_counter() if started_s is None else started_s
        started_cpu = time.thread_time() if started_cpu_s is None else started_cpu_s
        position, torque, valid, status, base = columns
        last = stop - 1
        first = max(start, stop - self.window_samples)
        lo, hi = first - base, stop - base  # the window's rows
        all_valid = True
        if arrival_s is not None and self._stale(arrival_s, last):
            reason: Reason | None = Reason.STALE
        else:
            raised, all_valid, finite = window_scan(position, torque, valid, status, lo, hi)
            reason = scanned_reason(raised, finite) if raised or not finite else None
            if reason is None and last in self.recorded_stale:
                reason = Reason.STALE  # live withheld it so; the tracker steps alike
        stages = self.stages
        if stages is not None:
            stages.mark("window check")
        reflex = _NO_REFLEX
        if reason is None and self.reflex is not None:
            reflex = self._reflex_torque(position, valid, start - base, hi, start)
        self.last_reflex = reflex
        estimate = None
        if reason is None:
            window_valid = None if all_valid else valid[lo:hi]
            estimate, reason = self._estimate(
                position[lo:hi], torque[lo:hi], window_valid, reflex.torque
            )
        else:
            self.withheld[reason] += 1
        if stages is not None:
            stages.mark("assembly")  # the estimate's rest (all of it, step by step)
        track = self.stream.track(last / self.fs_hz, estimate)  # every evaluated window steps it
        # the window's compute time: wall (the deadline's) and this thread's CPU
        compute_s = time.perf_counter() - started
        cpu_s = time.thread_time() - started_cpu
        self.compute_ms, self.compute_cpu_ms = compute_s * 1e3, cpu_s * 1e3
        self.compute_s += compute_s
        self.compute_cpu_s += cpu_s
        if stages is not None:
            stages.mark("tracker")
            stages.reflex_used(reflex.seq)
        overrun = self._over_budget(compute_s)
        if overrun:
            self.misses += 1
        message = self._message(
            first, last, estimate, reason, compute_s, arrival_s, reflex, track, overrun
        )
        if stages is not None:
            stages.mark("message")
        self.publish(message)
        if stages is not None:
            stages.mark("publish")
        return message

    def _stale(self, arrival_s: float, window_end: int) -> bool:
        """A live window (ending at sample ``window_end``) whose newest sample arrived (at
        ``arrival_s``, ``time.monotonic()``) longer than ``max_sample_age_s`` ago."""
        return time.monotonic() - arrival_s > self._max_age_s

    def _over_budget(self, compute_s: float) -> bool:
        """A live window whose compute overran the budget (recorded samples have no deadline:
        a replay's numbers and flags never depend on how busy the computer was)."""
        return self.live and compute_s > self._budget_s

    def publish_stale(self, end_index: int) -> None:
        """No samples are arriving: say so once per hop for the window that is due.

        The window may still be evaluated when its samples come (or skipped as late), so the
        message carries the latest track without stepping it: a replay, which has the
        samples, steps the tracker once per evaluated window exactly as live did."""
        self.withheld[Reason.STALE] += 1
        start = end_index - self.window_samples + 1
        track = self.stream.tracker.latest
        self.publish(
            self._message(start, end_index, None, Reason.STALE, 0.0, None, _NO_REFLEX, track)
        )

    def _reflex_torque(
        self, position: Any, valid: Any, lo: int, hi: int, first_index: int
    ) -> _ReflexUse:
        """The due reflex model's torque over the window, in the recorded torque's sign, from
        rows ``lo .. hi − 1`` of the ``position`` and ``valid`` columns (the window and its
        history; sample ``first_index`` first)."""
        assert self.reflex is not None
        update, stale = self._due_reflex(first_index + hi - lo - 1)
        stages = self.stages
        if stages is not None:
            stages.mark("reflex model")
        if update is None or update.pathway is None:
            self.reflex_flagged[Flag.REFLEX_ABSENT] += 1
            return _ABSENT_REFLEX
        flags: tuple[Flag, ...] = ()
        if stale:
            flags = (Flag.REFLEX_STALE,)
            self.reflex_flagged[Flag.REFLEX_STALE] += 1
        if not update.applied:  # the reflex pathway is not in the data: nothing to subtract
            unapplied = self._unapplied  # the same for every window of the model
            if unapplied.seq != update.seq or unapplied.flags != flags:
                unapplied = self._unapplied = _ReflexUse(update.seq, None, flags)
            return unapplied
        rows_valid = valid[lo:hi]
        try:
            predicted = predict_reflex_torque(
                update.pathway,
                position[lo:hi],
                None if rows_valid.all() else rows_valid,
                self.fs_hz,
                self.window_samples,
                self.reflex.settings,
                first_index=first_index,
                stream=self.reflex_stream,
            )
        except InputDataError:  # the history has too many lost samples to predict from
            self.reflex_flagged[Flag.REFLEX_ABSENT] += 1
            return _ABSENT_REFLEX
        torque = self.options.torque_sign * predicted
        if stages is not None:
            stages.mark("reflex prediction")
        return built(_ReflexUse, seq=update.seq, torque=torque, flags=flags)

    def _due_reflex(self, end: int) -> tuple[ReflexUpdate | None, bool]:
        """The model the window uses: the schedule's, or (replaying a live run) the one live
        used, which differs when the live slow lane was late."""
        assert self.reflex is not None
        recorded = self.recorded_reflex.get(end) if self.recorded_reflex else None
        if recorded is None:
            return self.reflex.model_for(end)
        seq, absent, stale = recorded
        if absent:
            return None, False
        if seq is None:
            return self.reflex.model_for(end)  # judged absent from the data: the same again
        return self.reflex.update_of(seq), stale

    def _estimate(
        self, position: Any, torque: Any, valid: Any, reflex_torque: Any = None
    ) -> tuple[WindowEstimate | None, Reason | None]:
        """The window's estimate, or why it is withheld (counted): ``valid`` None when every
        row is."""
        if self.calibration is not None:
            torque = torque - self.calibration.torque_offset(position)
        if reflex_torque is not None:
            torque = torque - reflex_torque
        stream = self.stream
        planned = stream.plan is not None
        try:
            estimate = stream.estimate(position, torque, valid, reflex_torque)
        except WindowError as exc:
            self.withheld[exc.reason] += 1
            return None, exc.reason
        except NumericalError:
            self.withheld[Reason.NUMERICAL] += 1
            return None, Reason.NUMERICAL
        self.estimates += 1
        self._refuse_inverted_sign(estimate)
        if not planned and stream.plan is not None:
            log.info("%s/%s %s", self.robot, self.joint, stream.plan.describe())
        return estimate, None

    def _refuse_inverted_sign(self, e: WindowEstimate) -> None:
        """Stop the stream (live: the worker thread fails, the daemon exits 1; replay: the
        command refuses) once most windows read K, B, I < 0."""
        if self.sign.add(e.K, e.B, e.I, e.I_held):
            other = f"{-self.options.torque_sign:g}"
            fix = f"set [estimator] torque_sign = {other} in the config (--config TOML)"
            inverted, estimable = self.sign.inverted, self.sign.estimable
            message = inverted_torque_message(inverted, estimable, fix)
            raise TorqueSignError(message, inverted, estimable, self.options.torque_sign)

    def _message(
        self,
        first: int,
        last: int,
        estimate: WindowEstimate | None,
        reason: Reason | None,
        compute_s: float,
        last_arrival_s: float | None,
        reflex: _ReflexUse,
        track: Tracked,
        overrun: bool | None = None,
    ) -> dict[str, Any]:
        if overrun is None:
            overrun = self._over_budget(compute_s)
        flags = (Flag.OVER_BUDGET, *reflex.flags) if overrun else reflex.flags
        latency = None if last_arrival_s is None else (time.monotonic() - last_arrival_s) * 1e3
        seq = self._seq
        self._seq += 1
        return EstimateMessage.window_dict(
            estimate,
            reason,
            track,
            seq=seq,
            first=first,
            last=last,
            fs_hz=self.fs_hz,
            robot=self.robot,
            joint=self.joint,
            flags=flags,
            compute_ms=compute_s * 1e3,
            latency_ms=latency,
            reflex_seq=reflex.seq,
        )


class WindowWorker(ThreadOwner):
    """Estimate the latest window every hop on a named thread (a context manager).

    A :class:`~rtsid.lifecycle.ThreadOwner`: ``start()``, ``stop(timeout_s)``, ``failure``.
    It cuts the ring's newest grid window every hop and hands it to its
    :class:`WindowEvaluator` (``evaluator``), which builds and publishes the message.

    Parameters
    ----------
    ring : RingBuffer
        Samples written by the acquisition thread.
    evaluator : WindowEvaluator
        The stream's message builder (live: ``live=True``).
    """

    def __init__(self, ring: RingBuffer, evaluator: WindowEvaluator) -> None:
        from rtsid.runtime.stages import StageLog
        from rtsid.runtime.stalls import RunQueueClock

        super().__init__("rtsid-worker")
        self.ring = ring
        self.config = evaluator.config
        self.evaluator = evaluator
        self.window_samples = self.evaluator.window_samples
        self.hop_samples = self.evaluator.hop_samples
        self._wake = threading.Event()  # set by the ring's writer, or by stop()
        self._overruns = 0
        #: overruns by why the windows were skipped (:data:`OVERRUN_CAUSES`)
        self.overrun_causes: Counter[str] = Counter()
        self._first_index = 0  # the stream's first sample (history is never read before it)
        #: Set by the daemon: each window over budget is set against what ran meanwhile.
        self.stalls: StallJournal | None = None
        self._run_queue = RunQueueClock()  # this thread's waits for a CPU (with stalls only)
        #: Says when a window is computing and when the worker has gone to wait for the next
        #: one: the daemon's housekeeping runs its tick then, not across a window.
        self.gate = WindowGate()
        #: The worker's CPU by stage of its recent windows (a missed window's goes into its
        #: miss line): on in every live run.
        self.stages = StageLog()
        evaluator.log_stages(self.stages)

    @property
    def stream(self) -> WindowStream:
        """The evaluator's stream (plan and held parameters)."""
        return self.evaluator.stream

    # ------------------------------------------------------------------ life cycle
    def _interrupt(self) -> None:
        self._wake.set()

    def counters(self) -> WorkerCounters:
        """Totals since start."""
        e = self.evaluator
        return WorkerCounters(
            estimates=e.estimates,
            withheld=dict(e.withheld),
            overruns=self._overruns,
            deadline_misses=e.misses,
            overrun_causes=dict(self.overrun_causes),
            compute_ms_last=e.compute_ms,
            reflex_flagged=dict(e.reflex_flagged),
            compute_cpu_ms_last=e.compute_cpu_ms,
            compute_s=e.compute_s,
            compute_cpu_s=e.compute_cpu_s,
            miss_stages=dict(self.stages.miss_stages),
            costly_stages=dict(self.stages.costly_stages),
            miss_cpu_causes=dict(self.stages.miss_cpu_causes),
            costly_causes=dict(self.stages.costly_causes),
            faulted_windows=self.stages.faulted_windows,
            window_faults=self.stages.window_faults,
            faulted_calls=self.stages.faulted_calls,
            call_faults=self.stages.call_faults,
            **self._stall_counters(),
        )

    def _stall_counters(self) -> dict[str, Any]:
        """Misses by what overlapped them, and the collections seen (empty without a
        journal)."""
        stalls = self.stalls
        if stalls is None:
            return {}
        return {
            "miss_causes": stalls.causes(),
            "miss_waits": dict(stalls.miss_waits),
            **stalls.gc_counters(),
        }

    # ------------------------------------------------------------------ the grid
    def first_window_end(self, first_index: int) -> int:
        """The first grid window end whose window starts at or after ``first_index``."""
        return self.evaluator.first_window_end(first_index)

    def _starting_window_end(self, newest: int) -> int:
        """At start, the newest complete grid window (earlier ones are history, not overruns)."""
        first = self.first_window_end(self.ring.oldest_index)
        hop = self.hop_samples
        newest_end = (newest + 1) // hop * hop - 1
        return max(first, newest_end)

    # ------------------------------------------------------------------ the loop
    def _run(self) -> None:  # errors are kept by ThreadOwner; the daemon decides what to do
        try:
            self._loop()
        finally:
            self._run_queue.close()

    def _loop(self) -> None:
        hop_s = self.config.hop_s
        next_end: int | None = None
        next_stale_s = 0.0
        after_window = False  # the last pass evaluated a window (rather than waited)
        while not self._stop.is_set():
            newest = self.ring.newest_index
            if newest < 0:
                self._stop.wait(hop_s)
                continue
            if next_end is None:
                self._first_index = self.ring.oldest_index
                next_end = self._starting_window_end(newest)
            if newest >= next_end:
                behind = (newest - next_end) // self.hop_samples
                if behind:
                    self._count_overruns(
                        behind, self._overrun_cause(next_end, newest, after_window)
                    )
                    next_end += behind * self.hop_samples
                self.process_window(next_end)
                next_end += self.hop_samples
                after_window = True
                continue
            after_window = False
            last = self.ring.latest(1)
            now = time.monotonic()
            arrived_s = float(last.host_time_s[-1]) if last is not None else now
            if now - arrived_s > self.config.max_sample_age_s and now >= next_stale_s:
                self.evaluator.publish_stale(next_end)
                next_stale_s = now + hop_s
            self._wait_for_sample(next_end, hop_s)

    def _count_overruns(self, windows: int, cause: str) -> None:
        self._overruns += windows
        self.overrun_causes[cause] += windows

    def _overrun_cause(self, skipped_end: int, newest: int, after_window: bool) -> str:
        """Why the worker found the ring a hop or more past the window it was due to evaluate.

        The link wrote the skipped window's last row and the newest row in one block
        (``"samples came in one burst"``: late data, not a slow worker); else the worker was
        still on the previous window (``"previous window still computing"``) or had been
        waiting and woke late (``"worker woke late"``: the GIL or a CPU given to others).
        """
        rows = self.ring.read_since(skipped_end, 1)
        if len(rows) and int(rows.sample_index[0]) == skipped_end:
            newest_rows = self.ring.latest(1)
            if newest_rows is not None and int(newest_rows.sample_index[-1]) == newest:
                if float(rows.host_time_s[0]) == float(newest_rows.host_time_s[-1]):
                    return OVERRUN_CAUSES[0]
        return OVERRUN_CAUSES[1] if after_window else OVERRUN_CAUSES[2]

    def _wait_for_sample(self, index: int, timeout_s: float) -> None:
        """Sleep until the ring publishes row ``index`` (or ``timeout_s``, or stop())."""
        self._wake.clear()
        if self._stop.is_set():
            return
        self.ring.wake_at(index, self._wake)
        if not self._wake.is_set():  # truly going to sleep: the housekeeping tick may run
            self.gate.worker_waiting()
        self._wake.wait(timeout_s)

    def process_window(self, end_index: int) -> dict[str, Any] | None:
        """Estimate the window ending at ``end_index`` from the ring and publish its message.

        Returns
        -------
        dict or None
            The message, or None when those samples are no longer (or not yet) in the ring.
        """
        self.gate.window_started()
        self.stages.begin(end_index)
        try:
            return self._process_window(end_index)
        finally:
            self.stages.end()
            self.gate.window_finished()

    def _process_window(self, end_index: int) -> dict[str, Any] | None:
        journal = self.stalls is not None
        queued_ns = self._run_queue.read_ns() if journal else None
        started, started_cpu = time.perf_counter(), time.thread_time()
        start = end_index - self.window_samples + 1
        # history before the window, but never before the stream's first sample
        first = max(start - self.evaluator.history_samples, min(self._first_index, start))
        count = end_index - first + 1
        snap = self.ring.read_since(first, count)
        self.stages.mark("ring read")
        if len(snap) != count or int(snap.sample_index[0]) != first:
            self._count_overruns(1, OVERRUN_CAUSES[3])  # overwritten before we got to it
            return None
        message = self.evaluator.evaluate(snap, started_s=started, started_cpu_s=started_cpu)
        if self.stalls is not None and Flag.OVER_BUDGET in message.get("flags", ()):
            ended = time.perf_counter()
            now_ns = self._run_queue.read_ns() if queued_ns is not None else None
            waited_ms = None if now_ns is None or queued_ns is None else 1e-6 * (now_ns - queued_ns)
            cpu_ms = self.evaluator.compute_cpu_ms
            stages = self.stages.missed()  # with the thread's counters over the window
            host = self.stalls.host_since_tick()
            self.stalls.miss(end_index, started, ended, cpu_ms, waited_ms, stages, host)
        return message
