"""A stream of windows: one analysis plan, and two time scales.

:class:`WindowStream` is what the daemon's worker, ``rtsid identify`` and replay share to
estimate a stream's windows in order: the analysis is planned once, from the stream's first
estimable window (:func:`rtsid.ident.window.resolve_plan`), and reused for every window, so
all are analysed alike; and the held parameters are learned as the windows go by.

Two time scales: inertia (and damping) learned over a long horizon, stiffness per window.

A joint's inertia does not change within an experiment and its damping changes slowly, but a
300 ms window determines them worst of the three (inertia shows only at the top of the
perturbation's band). Holding them at a value learned over tens of seconds leaves the window
to determine K alone, with less spread. :class:`HeldParameters` is the learning state a
stream carries from window to window: the median of the last windows' full (unheld) fits.
It is plain data updated in window order, so a replay of the same windows reproduces it —
and every estimate after it — exactly.
"""

from __future__ import annotations

import math
from bisect import bisect_left, insort
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from rtsid.errors import InputDataError, NumericalError, WindowError
from rtsid.ident.analysis import AnalysisPlan
from rtsid.ident.assess import assemble_parts, published_vafs, withhold_unidentifiable
from rtsid.ident.fit import NOT_HELD
from rtsid.ident.fused import (
    HELD_FLAGS,
    RESULT_SLOTS,
    BackEndBuffers,
    full_fit_explains,
    fusable,
    fused_back_end,
)
from rtsid.ident.grid import window_ends
from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.onecall import OUT_LEVEL, WindowCall, one_call_possible
from rtsid.ident.records import built
from rtsid.ident.second_order import OutputErrorDesign
from rtsid.ident.split import (
    NewestPart,
    ScanBuffers,
    SplitProblem,
    SplitScan,
    row_offsets_s,
    split_scan,
)
from rtsid.ident.tracker import ParameterTracker, SplitSource, TrackerOptions, TrackEstimate
from rtsid.ident.vaf import vaf
from rtsid.ident.window import (
    EstimatorOptions,
    Held,
    WindowEstimate,
    analyse_window,
    back_end,
    check_relative_excitation,
    held_values,
    output_error_back_end,
    output_error_design,
)
from rtsid.verdicts import Reason

__all__ = [
    "HeldParameters",
    "RunningMedian",
    "StreamTracker",
    "Tracked",
    "WindowResult",
    "WindowStream",
    "median",
    "running_median",
    "sliding_estimates",
]


class RunningMedian:
    """Median of the last ``horizon`` values, once at least ``min_count`` were added (plain
    data updated in window order: a replay reproduces it).

    The values are also kept sorted (insert and remove by bisection), so the median is read
    in O(1) rather than by ``np.median`` over the whole horizon each window; it is the same
    number (the middle value, or the mean of the two middle values). A NaN, which
    ``np.median`` propagates, makes the median NaN while it is in the horizon.
    """

    def __init__(self, horizon: int, min_count: int = 5) -> None:
        self._horizon = max(1, horizon)
        self._values: deque[float] = deque(maxlen=self._horizon)
        self._sorted: list[float] = []
        self._nans = 0
        self.min_count = max(1, min(min_count, horizon))

    def add(self, value: float) -> None:
        value = float(value)
        values = self._values
        if len(values) == self._horizon:  # the oldest leaves the horizon
            oldest = values[0]
            if oldest != oldest:  # NaN (math.isnan without the call)
                self._nans -= 1
            else:
                del self._sorted[bisect_left(self._sorted, oldest)]
        values.append(value)
        if value != value:
            self._nans += 1
        else:
            insort(self._sorted, value)

    def median(self) -> float | None:
        """None before ``min_count`` values."""
        values = self._sorted
        count = len(values)
        if self._nans:
            return None if count + self._nans < self.min_count else math.nan
        if count < self.min_count:
            return None
        half = count // 2
        if count % 2:
            return values[half]
        return (values[half - 1] + values[half]) / 2.0


def median(values: ArrayLike) -> float:
    """``np.median`` of ``values`` (flattened), the same number — the middle value or the
    mean of the two middle values, NaN when one is NaN (or none is given) — without
    importing ``numpy.ma``, which ``np.median`` does at its first call (9 ms, in every
    process of a replay)."""
    a = np.asarray(values, dtype=np.float64).ravel()
    if a.size == 0 or np.isnan(a).any():
        return math.nan
    half = a.size // 2
    low = half if a.size % 2 else half - 1
    middle = np.partition(a, sorted({low, half}))
    return float(np.mean(middle[low : half + 1]))  # as np.median: -0.0's mean is 0.0


_eureka: Any = compiled_kernel()


def running_median(horizon: int, min_count: int = 5) -> RunningMedian:
    """A :class:`RunningMedian`: the compiled one (``median_new``, the same rule on a sorted
    window kept in C, tested equal) when the kernel was built, else the Python reference."""
    if _eureka is not None:
        return _eureka.median_new(horizon, min_count)
    return RunningMedian(horizon, min_count)


class HeldParameters:
    """Running medians of I and B over the last ``horizon`` windows.

    Parameters
    ----------
    hold : {"none", "inertia", "inertia_damping"}
        What is held (``EstimatorOptions.hold``).
    horizon_windows : int
        Windows in the horizon (``hold_horizon_s / hop_s``).
    min_windows : int
        Windows needed before anything is held (until then every parameter is fitted).
    """

    def __init__(self, hold: str, horizon_windows: int, min_windows: int = 5) -> None:
        self.hold = hold
        self._inertia = running_median(horizon_windows, min_windows)
        self._damping = running_median(horizon_windows, min_windows)
        self._current: Held | None = NOT_HELD if hold == "none" else None  # None: to read

    def current(self) -> Held:
        """What the next window holds: the same object until :meth:`learn` changes a median
        (a caller may key what it derives from it on its identity)."""
        current = self._current
        if current is not None:
            return current
        inertia = self._inertia.median()
        if inertia is None:
            self._current = NOT_HELD
            return NOT_HELD
        damping = self._damping.median() if self.hold == "inertia_damping" else None
        previous = self._previous
        if previous.inertia != inertia or previous.damping != damping:  # NaN: a new one too
            previous = self._previous = built(Held, inertia=inertia, damping=damping)
        self._current = previous
        return previous

    #: The latest learned values read (NOT_HELD: none yet).
    _previous: Held = NOT_HELD

    def learn(self, inertia: float, damping: float, explained: bool) -> None:
        """Add one window's full fit (I, B and K all fitted) to the horizon.

        A fit with a non-positive inertia, or that explains too little of the torque
        (``explained`` false: below ``low_vaf_percent``), is not learned from: the window
        could not determine the parameters. A non-positive damping is not learned either.
        """
        if self.hold == "none" or not explained or not inertia > 0:
            return
        self._current = None  # read again
        self._inertia.add(inertia)
        if damping > 0:
            self._damping.add(damping)

    @property
    def medians(self) -> tuple[RunningMedian, RunningMedian]:
        """The running medians of I and B (what the compiled ``stream_window`` learns into,
        as :meth:`learn`; the caller then calls :meth:`learned`)."""
        return self._inertia, self._damping

    def learned(self) -> None:
        """The medians were added to outside :meth:`learn` (``stream_window``)."""
        self._current = None


@dataclass(frozen=True)
class Tracked:
    """The tracked stiffness and damping at one window's end (NaN: not tracked yet / not
    tracked, e.g. B while it is held)."""

    K: float
    K_se: float
    B: float
    B_se: float


_UNTRACKED = TrackEstimate(float("nan"), float("nan"), float("nan"), False, False)
_NOT_TRACKED = Tracked(*(float("nan"),) * 4)
#: An estimate carrying one of these flags is not a measurement for the tracker.
_NOT_MEASURED = frozenset({"low_vaf", "model_mismatch"})
#: ... nor, of K (of B), one that reads K <= 0 (B <= 0): not a joint held by a robot (on the
#: human recording such windows read K ≈ −1600 N·m/rad during a torque burst).
_NOT_STIFFNESS, _NOT_DAMPING = "negative_stiffness", "negative_damping"


class StreamTracker:
    """K(t) and B(t) of a stream: one :class:`~rtsid.ident.tracker.ParameterTracker` each.

    Every window of the stream, estimated or withheld, steps it once (at the window's last
    sample time): an estimate is taken as a measurement unless flagged ``low_vaf`` or
    ``model_mismatch`` (and of K unless ``negative_stiffness``, of B unless
    ``negative_damping``); anything else only advances the prediction. B is tracked only
    while it is fitted per window (its standard error finite); held, it stays NaN.

    Parameters
    ----------
    window_s, hop_s : float
        The stream's window and hop, s.
    options : TrackerOptions
        The ``[tracker]`` settings.
    """

    def __init__(self, window_s: float, hop_s: float, options: TrackerOptions) -> None:
        self.options = options
        self._enabled = options.enabled  # read every window
        self.hop_s = hop_s
        self.stiffness = ParameterTracker(
            window_s,
            hop_s,
            options.stiffness_noise,
            options.stiffness_rate_noise,
            options,
            options.stiffness_acceleration_noise,
        )
        self.damping = ParameterTracker(
            window_s, hop_s, options.damping_noise, options.damping_rate_noise, options
        )
        self._latest = _NOT_TRACKED

    @property
    def latest(self) -> Tracked:
        """What the latest :meth:`step` returned (NaN before the first)."""
        return self._latest

    def step(
        self,
        t_end_s: float,
        estimate: WindowEstimate | None,
        split: SplitSource | None = None,
        newest: NewestPart | None = None,
    ) -> Tracked:
        """Advance to ``t_end_s`` (s) and take ``estimate`` if it is a measurement;
        ``split`` computes its window's splits of K, ``newest`` is K of its newest hop
        (:mod:`rtsid.ident.split`)."""
        if not self._enabled:
            return _NOT_TRACKED
        flags = () if estimate is None else estimate.flags
        if flags and not _NOT_MEASURED.isdisjoint(flags):
            estimate, flags = None, ()  # not a measurement: the prediction only advances
        if estimate is not None and _NOT_STIFFNESS not in flags:
            k = self.stiffness.step(t_end_s, estimate.K, estimate.K_se, split, newest)
        else:
            k = self.stiffness.step(t_end_s)
        b = _UNTRACKED
        b_held = estimate is not None and estimate.B_held
        if not b_held:
            b_measured = (
                estimate is not None and math.isfinite(estimate.B_se) and _NOT_DAMPING not in flags
            )
            if b_measured and estimate is not None:
                b = self.damping.step(t_end_s, estimate.B, estimate.B_se)
            elif self.damping.started:
                b = self.damping.step(t_end_s)
        self._latest = built(Tracked, K=k.value, K_se=k.se, B=b.value, B_se=b.se)
        return self._latest


class WindowStream:
    """Estimate a stream's windows in order with one plan and the held parameters.

    Parameters
    ----------
    fs_hz : float
        Sampling rate, Hz.
    options : EstimatorOptions
        Estimator settings.
    hop_s : float
        Time between windows, s (sets the hold horizon in windows).
    plan : AnalysisPlan, optional
        A plan to use from the start (default: planned from the first estimable window).
    max_lowpass_hz : float, optional
        Highest cut-off the plan may choose, Hz (e.g. the band a robot calibration models).
    window_s : float, optional
        Window length, s (the tracker's measurement model; default 0.3).
    tracker : TrackerOptions, optional
        Settings of the K(t)/B(t) tracker (:attr:`tracker`, stepped by :meth:`track`).
    """

    def __init__(
        self,
        fs_hz: float,
        options: EstimatorOptions,
        hop_s: float,
        plan: AnalysisPlan | None = None,
        max_lowpass_hz: float | None = None,
        *,
        window_s: float = 0.3,
        tracker: TrackerOptions | None = None,
    ) -> None:
        self.fs_hz = float(fs_hz)
        self.options = options
        self.plan = plan
        self.max_lowpass_hz = max_lowpass_hz
        horizon = max(1, round(options.hold_horizon_s / hop_s))
        self.held = HeldParameters(options.hold, horizon)
        # the windows' band-limited position SD: the stream's typical perturbation (every
        # analysed window counts, so a pause longer than half the horizon becomes typical)
        self.excitation = running_median(horizon)
        self.tracker = StreamTracker(window_s, hop_s, tracker or TrackerOptions())
        self._split_source: _SplitSource | None = None
        self._buffers = BackEndBuffers()
        self._scan_buffers = ScanBuffers()  # the split scan's, reused every window
        self._newest_rows: tuple[AnalysisPlan | None, int] = (None, 0)  # (plan, its hop's rows)
        self._one_call = one_call_possible(options)  # windows in one compiled call once planned
        # ... with the stream's bookkeeping in the same call (its medians are compiled)
        self._bookkept = _eureka is not None and not isinstance(self.excitation, RunningMedian)
        self._call: WindowCall | None = None  # its buffers for the plan and window length
        self._design: OutputErrorDesign | None = None  # the design over the call's buffers
        # the learned values last read and what the window holds with them (held_values)
        self._learned: Held | None = None
        self._held_now = NOT_HELD
        #: Called with a stage's name as it ends on the one-call path ("held parameters",
        #: "compiled call"): the daemon's per-window stage log (None: not logged).
        self.stage_mark: Callable[[str], None] | None = None

    def track(self, t_end_s: float, estimate: WindowEstimate | None) -> Tracked:
        """Step the tracker with this window (its end time, s; None: withheld), and with the
        splits of its K when ``estimate`` is the stream's latest."""
        source, self._split_source = self._split_source, None
        if source is None or estimate is not source.estimate or not self.tracker.options.enabled:
            return self.tracker.step(t_end_s, estimate)
        newest = source.newest(self.tracker.hop_s)
        return self.tracker.step(t_end_s, estimate, source.scan, newest)

    def estimate(
        self,
        position: ArrayLike,
        torque: ArrayLike,
        valid: ArrayLike | None = None,
        explained: ArrayLike | None = None,
    ) -> WindowEstimate:
        """The next window's estimate (same errors and ``valid`` as :func:`estimate_window`).

        ``explained``: torque another pathway explained and the caller already subtracted
        from ``torque`` (the slow lane's reflex prediction); the published ``vaf`` counts it
        as part of the model. With a learned hold, the window is fitted twice from one IRF
        and one least-squares design: in full (learned from) and with the held values
        (returned).
        """
        self._split_source = None
        if self._one_call and valid is None and self.plan is not None:
            estimate = self._fit_in_one_call(position, torque, explained)
            if estimate is not None:
                return estimate
        try:
            return withhold_unidentifiable(self._fit(position, torque, valid, explained))
        except WindowError:
            self._split_source = None
            raise

    def _fit_in_one_call(
        self, position: ArrayLike, torque: ArrayLike, explained: ArrayLike | None
    ) -> WindowEstimate | None:
        """:meth:`_fit` of a planned window without lost samples in one compiled call
        (:mod:`rtsid.ident.onecall`), the same numbers and the same state afterwards; None:
        declined, the stream's state untouched (the caller runs :meth:`_fit`)."""
        plan = self.plan
        assert plan is not None
        window_samples = len(position)  # type: ignore[arg-type]
        call = self._call
        if call is None or call.plan is not plan or call.window_samples != window_samples:
            rows = round(self.tracker.hop_s * plan.analysis_fs_hz)
            call = self._call = WindowCall(plan, self.options, window_samples, rows)
            self._design = OutputErrorDesign.formed(
                call.regressors, call.projected, call.gram, call.y
            )
        learned = self.held.current()  # from earlier windows only
        if learned is not self._learned:  # what is held follows the learned values
            self._learned, self._held_now = learned, held_values(self.options, learned)
        held = self._held_now
        mark = self.stage_mark
        if mark is not None:
            mark("held parameters")
        if self._bookkept:
            return self._bookkept_call(call, position, torque, explained, held)
        done = call(position, torque, explained, held, self.excitation.median())
        if mark is not None:
            mark("compiled call")
        if done is None:
            return None
        out, h, k = done
        options = self.options
        self.excitation.add(out[_LEVEL])
        estimate = assemble_parts(
            h,
            call.lags_s,
            call.fs_hz,
            out[_PARAMS : _PARAMS + 3],
            (out[_SE], out[_SE + 1], out[_SE + 2]),
            published_vafs(out[_VAFS], out[_VAFS + 1], out[_VAFS + 2]),
            "output_error",
            options,
            0,
            HELD_FLAGS[k],
        )
        self.held.learn(out[_WHOLE], out[_WHOLE + 1], full_fit_explains(out[_WHOLE + 3], options))
        newest = None if out[_NEWEST] != out[_NEWEST] else out[_NEWEST : _NEWEST + 3]
        if estimate.flags:  # none: nothing to withhold
            withhold_unidentifiable(estimate)  # raises, as the step-by-step path
        design = self._design
        assert design is not None
        self._split_source = _SplitSource(
            estimate, design, held, plan, window_samples, newest, self._scan_buffers
        )
        return estimate

    def _bookkept_call(
        self,
        call: WindowCall,
        position: ArrayLike,
        torque: ArrayLike,
        explained: ArrayLike | None,
        held: Held,
    ) -> WindowEstimate | None:
        """The rest of :meth:`_fit_in_one_call` with its bookkeeping in the compiled call
        (:meth:`~rtsid.ident.onecall.WindowCall.stream_window`): the same estimate and state."""
        done = call.stream_window(
            position, torque, explained, held, self.excitation, self.held.medians
        )
        mark = self.stage_mark
        if mark is not None:
            mark("compiled call")
        if done is None:
            return None
        estimate, learned, newest = done
        if learned:
            self.held.learned()
        if estimate.flags:  # none: nothing to withhold
            withhold_unidentifiable(estimate)  # raises, as the step-by-step path
        design = self._design
        assert design is not None
        self._split_source = _SplitSource(
            estimate, design, held, call.plan, call.window_samples, newest, self._scan_buffers
        )
        return estimate

    def _fit(
        self,
        position: ArrayLike,
        torque: ArrayLike,
        valid: ArrayLike | None,
        explained: ArrayLike | None,
    ) -> WindowEstimate:
        options = self.options
        window = analyse_window(
            position,
            torque,
            self.fs_hz,
            options,
            self.plan,
            valid,
            self.max_lowpass_hz,
            explained,
        )
        self.plan = plan = window.plan  # the first window's plan serves the whole stream
        level = window.excitation_rad
        typical = self.excitation.median()
        self.excitation.add(level)
        check_relative_excitation(level, typical, options)
        irf, u, y = window.signals
        gaps, score = window.gaps, window.score
        if options.hold == "none":
            return back_end(irf, u, y, options, plan, gaps=gaps, score=score)
        held = held_values(options, self.held.current())  # from earlier windows only
        if options.fit_method != "output_error":
            full = back_end(irf, u, y, options, plan, gaps=gaps, score=score)
            self.held.learn(full.I, full.B, "low_vaf" not in full.flags)
            if held.inertia is None:
                return full
            return back_end(irf, u, y, options, plan, held, gaps, score)
        window_samples = len(position)  # type: ignore[arg-type]  # checked 1-D above
        if fusable(options, score, gaps is not None):  # the same steps in one compiled call
            known, rows = self._newest_rows  # analysis rows in one hop, once per plan
            if known is not plan:
                rows = round(self.tracker.hop_s * plan.analysis_fs_hz)
                self._newest_rows = (plan, rows)
            fused = fused_back_end(
                irf,
                u,
                y,
                options,
                plan,
                held,
                score,
                learn=True,
                newest_rows=rows,
                buffers=self._buffers,
            )
            self.held.learn(fused.whole_inertia, fused.whole_damping, fused.whole_explained)
            self._split_source = _SplitSource(
                fused.estimate,
                fused.design,
                held,
                plan,
                window_samples,
                fused.newest,
                self._scan_buffers,
            )
            return fused.estimate
        design = output_error_design(u, y, irf, gaps)
        whole = design.fit()
        explained = vaf(whole.measured, whole.model) >= options.low_vaf_percent
        self.held.learn(float(whole.params[0]), float(whole.params[1]), explained)
        result = output_error_back_end(irf, u, y, options, plan, held, design, gaps, score)
        self._split_source = _SplitSource(
            result, design, held, plan, window_samples, buffers=self._scan_buffers
        )
        return result


#: Where the kernel writes the back end's values (rtsid.ident.fused) and the call's own.
_PARAMS, _SE, _VAFS, _WHOLE, _NEWEST = RESULT_SLOTS
_LEVEL = OUT_LEVEL


class _SplitSource:
    """What :meth:`WindowStream.track` reads from an estimate's samples: the splits of its K
    and its newest hop's K, from one :class:`~rtsid.ident.split.SplitProblem` built when
    first asked for (the scan in one compiled call when the kernel was built)."""

    def __init__(
        self,
        estimate: WindowEstimate,
        design: OutputErrorDesign,
        held: Held,
        plan: AnalysisPlan,
        window_samples: int,
        newest: NewestPart | Sequence[float] | bool | None = False,
        buffers: ScanBuffers | None = None,
    ) -> None:
        self.estimate = estimate
        self._args = (design, held.inertia, held.damping, plan, window_samples)
        self._problem: SplitProblem | bool | None = False  # False: not built yet
        # the compiled back end's (K, variance, centre row) of the newest hop, or its record
        # (stream_window's) (False: not read)
        self._newest = newest
        self._buffers = buffers

    def problem(self) -> SplitProblem | None:
        if self._problem is False:
            self._problem = SplitProblem.of(*self._args)
        return self._problem  # type: ignore[return-value]

    def scan(self) -> SplitScan | None:
        return split_scan(*self._args, self._buffers)

    def newest(self, span_s: float) -> NewestPart | None:
        """The newest hop's K (the compiled back end read it for the stream's hop)."""
        newest = self._newest
        if newest is None or type(newest) is NewestPart:  # the compiled call's record
            return newest
        if newest is not False:
            k, var, row = self._newest  # type: ignore[misc]
            _, _, _, plan, window_samples = self._args
            return built(
                NewestPart, k=k, var=var, centre_s=row_offsets_s(row, plan, window_samples)
            )
        problem = self.problem()
        return None if problem is None else problem.newest(span_s)


@dataclass(frozen=True)
class WindowResult:
    """One slide of :func:`sliding_estimates`: an estimate, or the reason it was withheld.

    Attributes
    ----------
    start : int
        Index of the window's first sample.
    stop : int
        One past the window's last sample.
    t_end_s : float
        Time of the window's last sample, s (sample time, first sample at 0).
    estimate : WindowEstimate or None
        The estimate; None when withheld.
    reason : str or None
        Why it was withheld (``"nan"``, ``"no_excitation"``, ``"numerical"``, …).
    track : Tracked or None
        The stream's tracked K and B after this window.
    """

    start: int
    stop: int
    t_end_s: float
    estimate: WindowEstimate | None
    reason: str | None
    track: Tracked | None = None


def sliding_estimates(
    position: ArrayLike,
    torque: ArrayLike,
    fs: float,
    window_s: float = 0.3,
    hop_s: float = 0.1,
    options: EstimatorOptions | None = None,
    *,
    stream: WindowStream | None = None,
    valid: ArrayLike | None = None,
) -> Iterator[WindowResult]:
    """Estimate every window of ``window_s`` seconds, ``hop_s`` apart, oldest first.

    Windows that must not be estimated (NaN, no excitation, numerically unsound) are
    yielded with their reason instead of an estimate, so the caller sees every window. The
    windows are one :class:`WindowStream`: one analysis plan, held parameters learned in
    order. The windows are the live worker's (:mod:`rtsid.ident.grid`): a recording and
    its replay give the same ones.

    Parameters
    ----------
    position, torque : array_like, shape (n,)
        Joint angle (rad) and torque (N·m).
    fs : float
        Sampling rate, Hz.
    window_s, hop_s : float
        Window length and hop, s.
    options : EstimatorOptions, optional
        Estimator settings.
    stream : WindowStream, optional
        The stream to estimate with (to read its plan afterwards); default a new one.
    valid : array_like of bool, shape (n,), optional
        False for lost samples (bridged by sums over valid samples, as live).

    Yields
    ------
    WindowResult
        One per window.
    """
    pos = np.asarray(position, dtype=np.float64)
    tor = np.asarray(torque, dtype=np.float64)
    n_win = round(window_s * fs)
    n_hop = round(hop_s * fs)
    if n_win < 2 or n_hop < 1:
        raise InputDataError(
            f"window_s={window_s} and hop_s={hop_s} at {fs:g} Hz give {n_win}-sample windows "
            f"every {n_hop} samples; both must be at least one sample"
        )
    if n_win > pos.size:
        raise InputDataError(
            f"the record has {pos.size} samples ({pos.size / fs:g} s), shorter than one "
            f"{window_s} s window; use a shorter --window"
        )
    stream = stream or WindowStream(
        fs, options or EstimatorOptions(), n_hop / fs, window_s=n_win / fs
    )
    mask = None if valid is None else np.asarray(valid, dtype=bool)
    for end in window_ends(0, pos.size - 1, n_win, n_hop):
        start, stop = end - n_win + 1, end + 1
        t_end = end / fs
        window_valid = None if mask is None else mask[start:stop]
        est: WindowEstimate | None = None
        reason: str | None = None
        try:
            est = stream.estimate(pos[start:stop], tor[start:stop], window_valid)
        except WindowError as exc:
            reason = exc.reason
        except NumericalError:
            reason = Reason.NUMERICAL
        track = stream.track(t_end, est)
        yield built(
            WindowResult,
            start=start,
            stop=stop,
            t_end_s=t_end,
            estimate=est,
            reason=reason,
            track=track,
        )
