"""Intrinsic and reflex torque: the parallel-cascade model (Kearney, Stein & Parameswaran 1997).

Torque is the sum of two pathways, estimated alternately until the VAF stops improving:

* intrinsic — a two-sided IRF of position (lags ``±intrinsic_lag_s``, ≈ ±40 ms), by
  :func:`rtsid.ident.irf.estimate_irf`;
* reflex — velocity through a static nonlinearity (half-wave rectifier, or a polynomial for
  the Hammerstein variant) into a one-sided IRF (lags ``0 … reflex_lag_s``, ≈ 1 s) at its
  MDL rank, with gain and delay from a delayed low-pass fitted to that IRF
  (:mod:`rtsid.ident.reflex`).

Each pathway is fitted to the torque minus the other's current prediction, every Toeplitz
system solved by EUREKA. Both signals are first decimated to ``fs_out_hz`` (100 Hz, as the
field's toolbox does) with MATLAB's and scipy's default decimator (8th-order Chebyshev I,
0.8 × the new Nyquist rate, run forwards and backwards), so a 1 s reflex IRF has 101 lags. (A
FIR decimator keeping the band up to the new Nyquist rate left more torque noise in: 82.3 /
87.6 % instead of 85.4 / 93.9 % on the shared record.) The VAF skips the first reflex-IRF
length, where the reflex pathway has no full support.

The intrinsic I/B/K of a cascade come from the window estimator's output-error fit to the
torque with the reflex pathway's prediction removed, at the record's own rate
(:func:`intrinsic_parameters`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rtsid.errors import InputDataError
from rtsid.ident.correlation import detrend
from rtsid.ident.irf import IRF, estimate_irf
from rtsid.ident.reflex import (
    REFLEX_VARIANTS,
    ReflexInputs,
    ReflexPathway,
    fit_reflex_dynamics,
    fit_reflex_pathway,
    to_data_rate,
)
from rtsid.ident.vaf import vaf
from rtsid.ident.window import EstimatorOptions, WindowEstimate, estimate_window

__all__ = [
    "CascadeFit",
    "CascadeSettings",
    "CascadeWindow",
    "cascade_minimum_s",
    "fit_parallel_cascade",
    "intrinsic_parameters",
    "sliding_cascades",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class CascadeSettings:
    """How a parallel cascade is fitted.

    Attributes
    ----------
    variant : str
        Reflex pathway: ``"rect"`` or ``"hammerstein"``.
    fs_out_hz : float
        Rate of the model (decimation by ``round(fs / fs_out_hz)``), Hz.
    intrinsic_lag_s, reflex_lag_s : float
        Lag spans of the two pathways, s.
    ridge : float
        Relative diagonal loading of the intrinsic Toeplitz system.
    tolerance_percent : float
        Stop when an alternation gains less VAF than this (percentage points).
    max_iterations : int
        Upper bound on alternations.
    """

    variant: str = "rect"
    fs_out_hz: float = 100.0
    intrinsic_lag_s: float = 0.04
    reflex_lag_s: float = 1.0
    ridge: float = 1e-3
    tolerance_percent: float = 0.05
    max_iterations: int = 20

    def __post_init__(self) -> None:
        if self.variant not in REFLEX_VARIANTS:
            raise InputDataError(f"reflex variant {self.variant!r} is not one of {REFLEX_VARIANTS}")
        if not (self.fs_out_hz > 0 and self.intrinsic_lag_s > 0 and self.reflex_lag_s > 0):
            raise InputDataError("fs_out_hz, intrinsic_lag_s and reflex_lag_s must be > 0")
        if self.max_iterations < 1:
            raise InputDataError(f"max_iterations must be >= 1, got {self.max_iterations}")


def cascade_minimum_s(settings: CascadeSettings) -> float:
    """The shortest record a cascade is fitted on, s (three reflex-IRF lengths)."""
    return 3 * settings.reflex_lag_s


@dataclass(frozen=True)
class CascadeFit:
    """A parallel-cascade model of one record.

    Attributes
    ----------
    fs_hz : float
        Rate of the model and of the predictions, Hz.
    intrinsic : IRF
        Two-sided position → torque IRF.
    reflex : ReflexPathway
        Velocity → nonlinearity → IRF, with gain and delay.
    measured, intrinsic_torque, reflex_torque : numpy.ndarray, shape (m,)
        Torque (N·m) on the scored samples (after the first reflex-IRF length).
    vaf_total : float
        VAF (%) of the cascade.
    vaf_intrinsic_path, vaf_reflex_path : float
        VAF (%) of the measured torque by each pathway's prediction alone (in the cascade).
    vaf_intrinsic_only : float
        VAF (%) of an intrinsic IRF fitted alone (no reflex pathway).
    iterations : int
        Alternations run.
    factor : int
        Decimation factor from the input rate.
    first_scored : int
        Index (at ``fs_hz``) of the first scored sample.
    reflex_torque_all : numpy.ndarray, shape (n_model,)
        The kept pathway's torque (N·m) on every model sample of the record, scored or not.
    """

    fs_hz: float
    intrinsic: IRF
    reflex: ReflexPathway
    measured: FloatArray
    intrinsic_torque: FloatArray
    reflex_torque: FloatArray
    vaf_total: float
    vaf_intrinsic_path: float
    vaf_reflex_path: float
    vaf_intrinsic_only: float
    iterations: int
    factor: int
    first_scored: int
    reflex_torque_all: FloatArray

    def record_reflex_torque(
        self, position: FloatArray, fs_hz: float, first: int = 0
    ) -> FloatArray:
        """``self.reflex.torque(position, fs_hz)[first:]`` for the ``position`` this cascade
        was fitted to (rad, at its rate ``fs_hz``): the same numbers.

        For ``"rect"`` the cascade already convolved the same pathway input (the rectified
        velocity of this record, decimated) with the kept IRF, so only the interpolation back to
        the record's rate is left to do, and only from sample ``first`` on; the Hammerstein
        pathway's prediction is formed anew (its polynomial acts before the decimation there,
        after it inside the cascade).
        """
        if self.reflex.variant != "rect":
            return self.reflex.torque(position, fs_hz)[first:]
        return to_data_rate(self.reflex_torque_all, self.factor, np.size(position), first)


def _check_length(n: int, fs_hz: float, settings: CascadeSettings) -> None:
    minimum_s = cascade_minimum_s(settings)
    if n / fs_hz < minimum_s:
        raise InputDataError(
            f"the record lasts {n / fs_hz:.3g} s; the parallel cascade needs at least "
            f"{minimum_s:g} s (three reflex-IRF lengths of {settings.reflex_lag_s:g} s)"
        )


def fit_parallel_cascade(
    position: ArrayLike,
    torque: ArrayLike,
    fs_hz: float,
    settings: CascadeSettings | None = None,
) -> CascadeFit:
    """Fit the parallel-cascade model to a whole record.

    Parameters
    ----------
    position, torque : array_like, shape (n,)
        Joint angle (rad) and torque (N·m, sign-corrected), without gaps.
    fs_hz : float
        Sampling rate, Hz.
    settings : CascadeSettings, optional

    Returns
    -------
    CascadeFit

    Raises
    ------
    InputDataError
        The record is shorter than three reflex-IRF lengths (the minimum is named).
    """
    s = settings or CascadeSettings()
    pos = np.asarray(position, dtype=np.float64)
    tor = np.asarray(torque, dtype=np.float64)
    _check_length(pos.size, fs_hz, s)
    factor = max(1, round(fs_hz / s.fs_out_hz))
    fs = fs_hz / factor
    reflex_lags = round(s.reflex_lag_s * fs)
    # the position, the torque and the reflex pathway's input decimated in one pass
    inputs, (u, y) = ReflexInputs.decimating(pos, (pos, tor), fs_hz, factor, s.variant)
    u, y = detrend(u, "linear"), detrend(y, "linear")
    scored = slice(reflex_lags, u.size)
    lag = max(1, round(s.intrinsic_lag_s * fs))
    alone = estimate_irf(u, y, fs, lag, ridge=s.ridge)
    intrinsic_torque = alone.predict(u)
    vaf_alone = vaf(y[scored], intrinsic_torque[scored])
    best: tuple[float, IRF, ReflexPathway | None, FloatArray, FloatArray] = (
        vaf_alone,
        alone,
        None,
        intrinsic_torque,
        np.zeros_like(y),
    )
    iterations = 0
    for iterations in range(1, s.max_iterations + 1):  # noqa: B007 - reported below
        reflex, reflex_torque = fit_reflex_pathway(
            inputs, y - intrinsic_torque, fs, reflex_lags, dynamics=False
        )
        intrinsic = estimate_irf(u, y - reflex_torque, fs, lag, ridge=s.ridge)
        intrinsic_torque = intrinsic.predict(u)
        total = vaf(y[scored], (intrinsic_torque + reflex_torque)[scored])
        gained = total - best[0]
        if gained > 0 or best[2] is None:
            best = (total, intrinsic, reflex, intrinsic_torque, reflex_torque)
        if gained < s.tolerance_percent:
            break
    vaf_total, intrinsic, kept, intrinsic_torque, reflex_torque = best
    assert kept is not None
    kept = replace(kept, dynamics=fit_reflex_dynamics(kept.irf, fs))
    return CascadeFit(
        fs_hz=fs,
        intrinsic=intrinsic,
        reflex=kept,
        measured=y[scored],
        intrinsic_torque=intrinsic_torque[scored],
        reflex_torque=reflex_torque[scored],
        vaf_total=vaf_total,
        vaf_intrinsic_path=vaf(y[scored], intrinsic_torque[scored]),
        vaf_reflex_path=vaf(y[scored], reflex_torque[scored]),
        vaf_intrinsic_only=vaf_alone,
        iterations=iterations,
        factor=factor,
        first_scored=reflex_lags,
        reflex_torque_all=reflex_torque,
    )


def intrinsic_parameters(
    position: ArrayLike,
    torque: ArrayLike,
    fs_hz: float,
    reflex: ReflexPathway,
    options: EstimatorOptions | None = None,
) -> WindowEstimate:
    """I, B, K of the intrinsic pathway: the window estimator's output-error fit to the
    torque with the reflex pathway's prediction removed, over the whole record given.

    The standard errors are the fit's own (HAC); they do not include the uncertainty of the
    reflex prediction that was subtracted.
    """
    pos = np.asarray(position, dtype=np.float64)
    tor = np.asarray(torque, dtype=np.float64)
    whole = replace(options or EstimatorOptions(), torque_sign=1.0, hold="none")
    return estimate_window(pos, tor - reflex.torque(pos, fs_hz), fs_hz, whole)


@dataclass(frozen=True)
class CascadeWindow:
    """One sliding window's cascade and its intrinsic I/B/K."""

    start_index: int
    end_index: int
    cascade: CascadeFit
    intrinsic: WindowEstimate


def sliding_cascades(
    position: ArrayLike,
    torque: ArrayLike,
    fs_hz: float,
    window_s: float,
    hop_s: float,
    settings: CascadeSettings | None = None,
    options: EstimatorOptions | None = None,
) -> Iterator[CascadeWindow]:
    """A cascade (and its intrinsic I/B/K) on each window of ``window_s`` every ``hop_s``."""
    s = settings or CascadeSettings()
    pos = np.asarray(position, dtype=np.float64)
    tor = np.asarray(torque, dtype=np.float64)
    n = round(window_s * fs_hz)
    hop = max(1, round(hop_s * fs_hz))
    _check_length(n, fs_hz, s)
    if n > pos.size:
        raise InputDataError(
            f"a cascade window of {window_s:g} s is longer than the record "
            f"({pos.size / fs_hz:.3g} s); shorten --window"
        )
    for end in range(n, pos.size + 1, hop):
        p, t = pos[end - n : end], tor[end - n : end]
        cascade = fit_parallel_cascade(p, t, fs_hz, s)
        intrinsic = intrinsic_parameters(p, t, fs_hz, cascade.reflex, options)
        yield CascadeWindow(end - n, end - 1, cascade, intrinsic)
