"""The slow lane's numerics: which reflex model a window uses, and how one is fitted.

The fast lane estimates I, B, K from 300 ms; a stretch reflex needs a reflex-IRF length
(≈ 1 s) of history and tens of seconds of data to be identified. The slow lane fits the
parallel cascade (:mod:`rtsid.ident.cascade`) over the last ``horizon_s`` every ``update_s``,
and the fast lane subtracts that model's reflex torque before its intrinsic estimate.

Deterministic by construction, so a replay reproduces a live run bit for bit:

* fit ``k`` ends at sample index ``E_k = k·U`` (``U`` = ``update_s`` in samples) and uses the
  samples ``[max(E_k − H, first), E_k)``;
* it applies to every window whose last sample ``e`` has ``e + 1 ≥ E_k + A`` (``A`` =
  ``apply_after_s``: time the live slow lane is given to finish), until the next one does.

Which model a window uses therefore depends on sample indices only. Live, a fit that has not
finished when it is due leaves the window on the previous model, flagged ``reflex_stale``
(and that window alone can differ from a replay); a window with no model yet is flagged
``reflex_absent``. A model whose reflex pathway adds less than ``min_vaf_gain_percent`` to the
intrinsic IRF's VAF is judged absent from the data: it is published, but nothing is
subtracted.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import ConfigError, InputDataError, invalid, require_choice, require_range
from rtsid.ident.cascade import CascadeFit, CascadeSettings, cascade_minimum_s, fit_parallel_cascade
from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.reflex import (
    REFLEX_VARIANTS,
    ReflexPathway,
    ReflexStream,
    prediction_history_s,
)
from rtsid.ident.stream import median
from rtsid.ident.yardstick import BasisStore, WindowVafBasis

__all__ = [
    "ReflexModels",
    "ReflexUpdate",
    "SlowLaneSettings",
    "fit_reflex_update",
    "predict_reflex_torque",
    "warm_up",
    "window_vaf_gain",
    "window_vaf_gains",
]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

LANE_MODES = ("process", "thread")

_eureka = compiled_kernel()


@dataclass(frozen=True)
class SlowLaneSettings:
    """The ``[slow_lane]`` config section.

    Attributes
    ----------
    enabled : bool
        Run the slow lane: fit the reflex pathway, decide from the data whether it is present,
        and subtract it in the fast lane while it is.
    mode : str
        ``"process"`` (a spawned worker process: never competes for the GIL) or ``"thread"``
        (a low-priority thread in the daemon).
    horizon_s : float
        Data each fit uses, s (the last ``horizon_s`` before the fit's end).
    update_s : float
        Time between fits, s.
    apply_after_s : float
        A fit applies to windows ending this long after its data end, s (its time to run).
    stale_after_s : float
        A model older than this (its data end to the window's end) flags ``reflex_stale``.
    variant : str
        Reflex pathway: ``"rect"`` or ``"hammerstein"``.
    min_vaf_gain_percent : float
        A reflex pathway that adds less VAF than this over the intrinsic IRF alone (over the
        whole horizon) is judged absent: not subtracted.
    min_window_vaf_gain_percent : float
        ... nor one whose subtraction raises the median VAF of the newest short windows
        (per-window least squares, :func:`window_vaf_gain`) by less than this many points: a
        reflex the windows' own I, B, K already explain is judged absent too (3 points: the
        shared human recording's fits reach at most 1.9, simulated reflexes of gain 10–25
        N·m·s/rad 12–46).
    max_lost_percent : float
        Lost samples a fit (or a prediction's history) bridges by linear interpolation; more,
        or a gap longer than the model's sample period, and it is skipped.
    """

    enabled: bool = True
    mode: str = "process"
    horizon_s: float = 20.0
    update_s: float = 2.0
    apply_after_s: float = 1.0
    stale_after_s: float = 10.0
    variant: str = "rect"
    min_vaf_gain_percent: float = 1.0
    min_window_vaf_gain_percent: float = 3.0
    max_lost_percent: float = 2.0

    def __post_init__(self) -> None:
        require_choice("mode", self.mode, LANE_MODES)
        require_choice("variant", self.variant, REFLEX_VARIANTS)
        minimum = cascade_minimum_s(CascadeSettings())
        require_range("horizon_s", self.horizon_s, minimum, 600.0)
        require_range("update_s", self.update_s, 0.1, 600.0)
        require_range("apply_after_s", self.apply_after_s, 0.0, 60.0)
        require_range("min_vaf_gain_percent", self.min_vaf_gain_percent, 0.0, 100.0)
        require_range(
            "min_window_vaf_gain_percent", self.min_window_vaf_gain_percent, -100.0, 100.0
        )
        require_range("max_lost_percent", self.max_lost_percent, 0.0, 50.0)
        if self.stale_after_s < self.update_s + self.apply_after_s:
            raise invalid(
                "stale_after_s",
                self.stale_after_s,
                f">= update_s + apply_after_s = {self.update_s + self.apply_after_s:g} s (every "
                "model would be stale before the next one is due)",
            )

    def cascade(self) -> CascadeSettings:
        """The cascade each fit runs."""
        return CascadeSettings(variant=self.variant)


@dataclass(frozen=True)
class ReflexUpdate:
    """One slow-lane fit.

    Attributes
    ----------
    seq : int
        Fit counter: ``E / U`` (the fit's place on the schedule).
    start_index, end_index : int
        The samples used, ``[start_index, end_index)``.
    pathway : ReflexPathway or None
        The fitted pathway (None: the fit failed or was skipped, see ``error``).
    applied : bool
        The fast lane subtracts it (the pathway adds at least ``min_vaf_gain_percent``).
    vaf_total, vaf_intrinsic_only, vaf_intrinsic_path, vaf_reflex_path : float
        The cascade's VAFs, % (NaN without a fit).
    iterations : int
        Alternations run.
    error : str or None
        Why there is no pathway.
    window_vaf_gain : float
        Median over the horizon's short windows of the VAF the reflex model adds to each
        window's own I, B, K, percentage points (NaN without a fit): the evidence for
        ``applied``.
    windows_improved : float
        Share of those windows whose VAF it raises, 0…1 (NaN without a fit).
    """

    seq: int
    start_index: int
    end_index: int
    pathway: ReflexPathway | None
    applied: bool
    vaf_total: float
    vaf_intrinsic_only: float
    vaf_intrinsic_path: float
    vaf_reflex_path: float
    iterations: int
    error: str | None = None
    window_vaf_gain: float = float("nan")
    windows_improved: float = float("nan")

    @classmethod
    def failed(cls, seq: int, start: int, end: int, error: str) -> ReflexUpdate:
        """A fit that gave no model."""
        nan = float("nan")
        return cls(seq, start, end, None, False, nan, nan, nan, nan, 0, error)


def bridged(
    x: FloatArray, valid: BoolArray | None, fs_hz: float, settings: SlowLaneSettings
) -> FloatArray:
    """``x`` with its lost samples linearly interpolated, if few and short enough.

    Raises
    ------
    InputDataError
        More than ``max_lost_percent`` lost, or a gap longer than the model's sample period.
    """
    if valid is None or bool(valid.all()):
        return x
    lost = ~valid
    percent = 100.0 * float(lost.mean())
    if percent > settings.max_lost_percent:
        raise InputDataError(
            f"{percent:.2g} % of the samples are lost (the slow lane bridges up to "
            f"{settings.max_lost_percent:g} %)"
        )
    edges = np.diff(np.concatenate([[0], lost.view(np.int8), [0]]))
    longest = int(np.max(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)))
    limit = fs_hz / settings.cascade().fs_out_hz
    if longest > limit:
        raise InputDataError(
            f"a gap of {longest} samples is longer than the reflex model's sample period "
            f"({limit:g} samples)"
        )
    keep = np.flatnonzero(valid)
    if keep.size < 2:
        raise InputDataError("fewer than two valid samples")
    return np.interp(np.arange(x.size), keep, x[keep])


def fit_reflex_update(
    seq: int,
    start_index: int,
    position: FloatArray,
    torque: FloatArray,
    valid: BoolArray | None,
    fs_hz: float,
    settings: SlowLaneSettings,
) -> ReflexUpdate:
    """Fit the parallel cascade to one horizon of samples (torque sign-corrected and with the
    robot's own dynamics removed). Never raises for bad data: the update carries the error.

    The evidence basis' derivative rows of the samples this horizon shares with the previous
    one this process fitted are carried over (:data:`EVIDENCE_BASES`, keyed by absolute
    sample index from ``start_index`` and checked sample by sample): the same numbers bit for
    bit as forming them afresh, so a fit does not depend on which fits ran before it (a replay
    equals live). A horizon with bridged samples neither uses nor leaves anything there.
    """
    end_index = start_index + position.size
    bridging = valid is not None and not bool(valid.all())
    if bridging:
        EVIDENCE_BASES.clear()
    try:
        pos = bridged(np.asarray(position, dtype=np.float64), valid, fs_hz, settings)
        tor = bridged(np.asarray(torque, dtype=np.float64), valid, fs_hz, settings)
        if not _all_finite(pos, tor):
            raise InputDataError("a valid sample is NaN or infinite")
        cascade = fit_parallel_cascade(pos, tor, fs_hz, settings.cascade())
        first = round(cascade.reflex.history_s * fs_hz)
        # the prediction only where the evidence reads it
        lead = evidence_lead(pos.size, fs_hz, first)
        reflex_torque = cascade.record_reflex_torque(pos, fs_hz, lead)
        gains = _evidence_gains(
            pos, tor, reflex_torque, lead, fs_hz, first, None if bridging else start_index
        )
        evidence = _median_gain(gains)
    except (InputDataError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return ReflexUpdate.failed(seq, start_index, end_index, str(exc))
    return _update_from(seq, start_index, end_index, cascade, evidence, settings)


def _all_finite(position: FloatArray, torque: FloatArray) -> bool:
    """No NaN nor infinity in either (the compiled ``all_finite`` when built: one pass, no
    temporaries)."""
    if _eureka is not None:
        return bool(
            _eureka.all_finite(np.ascontiguousarray(position), np.ascontiguousarray(torque))
        )
    return bool(np.isfinite(position).all() and np.isfinite(torque).all())


#: The short windows :func:`window_vaf_gain` scores: the fast lane's length, every
#: ``EVIDENCE_STEP_S`` over the last ``EVIDENCE_SPAN_S`` of the horizon (the decision is for
#: the windows to come, so the newest data judge it: a reflex that switched on or off part-way
#: through the horizon is judged by what it does now).
EVIDENCE_WINDOW_S, EVIDENCE_STEP_S, EVIDENCE_SPAN_S = 0.3, 0.25, 10.0
#: Data before the first evidence window that the window VAF basis is formed over, s: its
#: 40 Hz low-pass (forwards and backwards) forgets where it started within this (its slowest
#: pole decays ≈ 96 /s: e^-96 after 1 s), so forming it over the scored span and this much
#: before gives the numbers of the whole horizon's basis (to rounding) at half the cost.
EVIDENCE_SETTLING_S = 1.0


def window_vaf_gain(
    position: FloatArray,
    torque: FloatArray,
    reflex_torque: FloatArray,
    fs_hz: float,
    first: int = 0,
) -> tuple[float, float]:
    """Does subtracting ``reflex_torque`` help short windows explain the torque?

    Over windows of ``EVIDENCE_WINDOW_S`` every ``EVIDENCE_STEP_S`` in the last
    ``EVIDENCE_SPAN_S`` of the data, each window's own
    least-squares I, B, K is scored on the benchmarks' window VAF basis
    (:class:`rtsid.ident.yardstick.WindowVafBasis`: torque low-passed at 40 Hz), once fitted
    to the torque and once to the torque minus the reflex prediction (counted as part of the
    model). On a reflex-rich ankle the reflex torque is what a window's I, B, K cannot
    follow; on a reflex-poor one the windows' own stiffness already absorbs it, and a model
    fitted over tens of seconds only adds its own error.

    Parameters
    ----------
    position, torque, reflex_torque : numpy.ndarray, shape (n,)
        The horizon (rad, N·m sign-corrected, N·m).
    fs_hz : float
        Sampling rate, Hz.
    first : int
        First sample a window may start at (before it the prediction lacks its history).

    Returns
    -------
    (float, float)
        The median VAF gain, percentage points, and the share of windows it raises.
    """
    return _median_gain(window_vaf_gains(position, torque, reflex_torque, fs_hz, first))


def _median_gain(gains: FloatArray) -> tuple[float, float]:
    """:func:`window_vaf_gain`'s median gain and share of windows improved."""
    if gains.size == 0:
        raise InputDataError("the horizon is shorter than one evidence window")
    return median(gains), float(np.mean(gains > 0))


def window_vaf_gains(
    position: FloatArray,
    torque: FloatArray,
    reflex_torque: FloatArray,
    fs_hz: float,
    first: int = 0,
) -> FloatArray:
    """The VAF gain of each evidence window (:func:`window_vaf_gain`), percentage points, in
    time order (empty when the horizon holds none).

    The basis is formed over the scored span and the ``EVIDENCE_SETTLING_S`` before it, not
    over the whole horizon: the same numbers to rounding, at the cost of what is scored.
    """
    lead = evidence_lead(position.size, fs_hz, first)
    return _evidence_gains(position, torque, reflex_torque[lead:], lead, fs_hz, first, None)


#: The evidence bases' Savitzky–Golay rows kept from one fit to the next in this process (the
#: slow lane's worker process or thread, a replay's fits in line): bounded (one basis), keyed
#: by absolute sample index and checked sample by sample, so the numbers are those of a basis
#: formed afresh (:class:`rtsid.ident.yardstick.BasisStore`).
EVIDENCE_BASES = BasisStore()


def _evidence_gains(
    position: FloatArray,
    torque: FloatArray,
    reflex_tail: FloatArray,
    lead: int,
    fs_hz: float,
    first: int,
    start_index: int | None,
) -> FloatArray:
    """:func:`window_vaf_gains` with the reflex torque from sample ``lead`` on only
    (``reflex_tail``, ``n − lead`` samples); with ``start_index`` (the absolute index of
    ``position[0]``) the basis from :data:`EVIDENCE_BASES`."""
    n = round(EVIDENCE_WINDOW_S * fs_hz)
    first = max(first, position.size - round(EVIDENCE_SPAN_S * fs_hz))
    if start_index is None:
        basis = WindowVafBasis(position[lead:], torque[lead:], fs_hz)
    else:
        basis = EVIDENCE_BASES.basis(position[lead:], torque[lead:], fs_hz, start_index + lead)
    step = max(1, round(EVIDENCE_STEP_S * fs_hz))
    starts = np.arange(first - lead, position.size - lead - n + 1, step)
    return basis.least_squares_vaf_gains(starts, n, reflex_tail)


def evidence_lead(n: int, fs_hz: float, first: int = 0) -> int:
    """The first of ``n`` samples :func:`window_vaf_gains` reads (``first`` as there): its
    basis starts ``EVIDENCE_SETTLING_S`` before the first evidence window."""
    first = max(first, n - round(EVIDENCE_SPAN_S * fs_hz))
    return max(0, first - round(EVIDENCE_SETTLING_S * fs_hz))


def warm_up(fs_hz: float, settings: SlowLaneSettings) -> bool:
    """Run one fit on a synthetic record, so that a fresh slow-lane process has imported and
    cached everything (e.g. the dynamics grid) before its first scheduled fit is due."""
    rng = np.random.default_rng(0)
    n = round(1.05 * cascade_minimum_s(settings.cascade()) * fs_hz)
    position = np.cumsum(rng.standard_normal(n)) * 1e-3
    update = fit_reflex_update(
        0, 0, position, position + rng.standard_normal(n), None, fs_hz, settings
    )
    return update.error is None


def _update_from(
    seq: int,
    start: int,
    end: int,
    cascade: CascadeFit,
    evidence: tuple[float, float],
    settings: SlowLaneSettings,
) -> ReflexUpdate:
    gain = cascade.vaf_total - cascade.vaf_intrinsic_only
    window_gain, improved = evidence
    present = (
        gain >= settings.min_vaf_gain_percent
        and window_gain >= settings.min_window_vaf_gain_percent
    )
    return ReflexUpdate(
        seq,
        start,
        end,
        cascade.reflex,
        present,
        cascade.vaf_total,
        cascade.vaf_intrinsic_only,
        cascade.vaf_intrinsic_path,
        cascade.vaf_reflex_path,
        cascade.iterations,
        window_vaf_gain=window_gain,
        windows_improved=improved,
    )


# ----------------------------------------------------------------------------- the schedule
class ReflexModels:
    """The slow lane's fits, and which one each window uses (thread-safe).

    Parameters
    ----------
    fs_hz : float
        Sample rate, Hz.
    settings : SlowLaneSettings
    """

    def __init__(self, fs_hz: float, settings: SlowLaneSettings) -> None:
        if not settings.enabled:
            raise ConfigError("ReflexModels needs [slow_lane] enabled = true")
        self.fs_hz = float(fs_hz)
        self.settings = settings
        self.horizon = round(settings.horizon_s * fs_hz)
        self.update = max(1, round(settings.update_s * fs_hz))
        self.apply_after = round(settings.apply_after_s * fs_hz)
        self.stale_after = round(settings.stale_after_s * fs_hz)
        self.minimum = round(cascade_minimum_s(settings.cascade()) * fs_hz)
        self._updates: dict[int, ReflexUpdate] = {}
        self._lock = threading.Lock()
        # (due fit, the newest usable fit at or before it) of the latest window asked about:
        # the windows of one due fit (every update_s) share it until a fit is added
        self._newest_usable: tuple[int, ReflexUpdate | None] | None = None

    # -------------------------------------------------------------- schedule
    def fit_span(self, seq: int, first_index: int) -> tuple[int, int] | None:
        """Samples ``[start, end)`` of fit ``seq`` when data begin at ``first_index``; None
        when fewer than the cascade's minimum are there."""
        end = seq * self.update
        start = max(end - self.horizon, first_index)
        return (start, end) if end - start >= self.minimum else None

    def first_seq(self, first_index: int) -> int:
        """The first fit whose span holds enough data."""
        return -(-(first_index + self.minimum) // self.update)

    def due_seq(self, window_end: int) -> int:
        """The fit that applies to the window whose last sample is ``window_end``."""
        return (window_end + 1 - self.apply_after) // self.update

    # -------------------------------------------------------------- store
    def add(self, update: ReflexUpdate, keep_from: int | None = None) -> None:
        """Keep a finished fit; older ones beyond the stale horizon are dropped, except those
        from fit ``keep_from`` on (a replay keeps every fit its live run still used: a late
        live slow lane leaves windows on a model this far behind)."""
        with self._lock:
            self._updates[update.seq] = update
            self._newest_usable = None
            oldest = update.seq - (self.stale_after // self.update + 2)
            if keep_from is not None:
                oldest = min(oldest, keep_from)
            for seq in [s for s in self._updates if s < oldest]:
                del self._updates[seq]

    def model_for(self, window_end: int) -> tuple[ReflexUpdate | None, bool]:
        """The newest usable fit at or before the one due for ``window_end``, and whether it
        is stale (not the due one, or older than ``stale_after_s``). ``(None, False)``:
        none yet."""
        due = self.due_seq(window_end)
        newest = self._newest_usable
        if newest is None or newest[0] != due:
            newest = self._newest_usable_at(due)
        update = newest[1]
        if update is None:
            return None, False
        failed_since = update.seq != due
        too_old = window_end + 1 - update.end_index > self.stale_after
        return update, failed_since or too_old

    def _newest_usable_at(self, due: int) -> tuple[int, ReflexUpdate | None]:
        """``(due, the newest kept fit at or before fit due with a pathway)``, kept for the
        next windows of the same due fit (until :meth:`add` forgets it, under the same lock)."""
        with self._lock:
            usable = [s for s, u in self._updates.items() if s <= due and u.pathway is not None]
            newest = (due, self._updates[max(usable)] if usable else None)
            self._newest_usable = newest
        return newest

    def update_of(self, seq: int) -> ReflexUpdate | None:
        """Fit ``seq``, if kept."""
        with self._lock:
            return self._updates.get(seq)

    @property
    def history_samples(self) -> int:
        """Samples before a window its reflex prediction needs."""
        cascade = self.settings.cascade()
        lags = round(cascade.reflex_lag_s * cascade.fs_out_hz)
        return round(prediction_history_s(lags + 1, cascade.fs_out_hz) * self.fs_hz)


def predict_reflex_torque(
    pathway: ReflexPathway,
    position: FloatArray,
    valid: BoolArray | None,
    fs_hz: float,
    n_last: int,
    settings: SlowLaneSettings,
    *,
    first_index: int = 0,
    stream: ReflexStream | None = None,
) -> FloatArray:
    """The reflex torque over the last ``n_last`` samples of ``position`` (the window), from
    the window and the history before it.

    Parameters
    ----------
    pathway : ReflexPathway
        The due model.
    position : numpy.ndarray, shape (n,)
        Joint angle (rad): the window and up to :attr:`ReflexModels.history_samples` before.
    valid : numpy.ndarray of bool, shape (n,), or None
        Samples received (None: all); lost ones are bridged (:func:`bridged`).
    fs_hz : float
        Sampling rate, Hz.
    n_last : int
        Samples of the window.
    settings : SlowLaneSettings
    first_index : int
        Absolute index of ``position[0]`` (the stream's model samples sit on the absolute
        grid, so that every hop, live or replayed, forms the same numbers).
    stream : ReflexStream, optional
        The stream that carries the pathway's inputs and outputs from hop to hop (the fast
        lane's); without it, the window is formed afresh (the same numbers).

    Raises
    ------
    InputDataError
        The history has more lost samples than the slow lane bridges.
    """
    pos = bridged(np.asarray(position, dtype=np.float64), valid, fs_hz, settings)
    reuse = stream is not None and (valid is None or bool(np.all(valid)))
    return (stream or ReflexStream()).torque_tail(
        pathway, pos, first_index, fs_hz, n_last, reuse=reuse
    )
