"""Step 2, plan: choose a window's analysis from the data — band-limiting filter, analysis
rate, lag span (:func:`resolve_plan` from the estimator's options, :func:`plan_analysis`).

What a window can tell about ``(I, B, K)`` lies in the band the perturbation excites. Above
it the position's derivatives are mostly sensor noise and actuator dynamics, and a human
joint's torque is no longer second-order (the reference recording's IRF falls off above
≈ 45 Hz); below the sampling rate's reach nothing is lost by decimating. So the analysis is
planned from the perturbation's measured spectrum:

* ``edge_hz`` — the frequency below which 99.9 % of the (detrended, Hann-tapered) position's
  power lies;
* the low-pass cut-off (−6 dB) at ``1.5 · edge_hz``, a short FIR
  (:func:`rtsid.ident.filters.band_limit_taps`) applied to position and torque alike;
* the analysis rate at least ``10 ×`` the cut-off (the derivative stencils then stay exact to
  well within 0.1 % in the band), by integer decimation;
* the IRF lag span ``lag_s`` (±20 ms by default) at the analysis rate;
* the frequency grid of the relative and log-magnitude fits, 1 Hz up to the cut-off.

Explicit options (``lowpass_hz``, ``analysis_fs_hz``, ``fit_band_hz``) override each choice.
A stream (the daemon's worker, ``rtsid identify``, replay) plans once and reuses the plan, so
every window of a stream is analysed alike; :func:`estimate_window` alone plans from its
own window.

Measured on the shared real recording (1 kHz PRBS, 300 ms windows) and on simulated ankles
(2500 Hz, 20 and 40 Hz perturbation bands): see ``docs/identification.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rtsid.errors import InputDataError, WindowError
from rtsid.ident.correlation import detrend
from rtsid.ident.filters import band_limit_taps, decimation_factor
from rtsid.ident.gaps import LostSamples
from rtsid.ident.options import EstimatorOptions
from rtsid.verdicts import Reason

__all__ = [
    "AnalysisPlan",
    "hann_periodogram",
    "hann_taper",
    "perturbation_edge_hz",
    "plan_analysis",
    "plan_source",
    "resolve_plan",
]

FloatArray = NDArray[np.float64]

POWER_QUANTILE = 0.999
CUTOFF_PER_EDGE = 1.5
RATE_PER_CUTOFF = 10.0


@dataclass(frozen=True)
class AnalysisPlan:
    """How a window is analysed.

    Attributes
    ----------
    fs_hz : float
        Input sampling rate, Hz.
    edge_hz : float or None
        Measured perturbation band edge (None when every choice was explicit).
    lowpass_hz : float
        −6 dB cut-off of the band-limiting FIR, Hz.
    factor : int
        Decimation factor.
    lag : int
        IRF lag span ``L`` in analysis samples (lags ``−L … L``).
    fit_band_hz : (float, float)
        Band of the relative and log-magnitude fits, Hz.
    taps : numpy.ndarray
        The FIR, read-only.
    """

    fs_hz: float
    edge_hz: float | None
    lowpass_hz: float
    factor: int
    lag: int
    fit_band_hz: tuple[float, float]
    taps: FloatArray

    @property
    def analysis_fs_hz(self) -> float:
        """Analysis rate, Hz."""
        return self.fs_hz / self.factor

    def describe(self) -> str:
        """One line for logs and command output."""
        edge = "set" if self.edge_hz is None else f"{self.edge_hz:.3g} Hz"
        lo, hi = self.fit_band_hz
        return (
            f"analysis: perturbation edge {edge}, low-pass {self.lowpass_hz:.3g} Hz "
            f"({self.taps.size} taps), {self.analysis_fs_hz:g} Hz analysis rate, "
            f"IRF ±{self.lag} lags ({self.lag / self.analysis_fs_hz * 1e3:.3g} ms), "
            f"fit band {lo:g}–{hi:.3g} Hz"
        )

    def as_dict(self) -> dict[str, Any]:
        """The chosen values, JSON-friendly."""
        return {
            "edge_hz": self.edge_hz,
            "lowpass_hz": self.lowpass_hz,
            "analysis_fs_hz": self.analysis_fs_hz,
            "taps": int(self.taps.size),
            "lag_s": self.lag / self.analysis_fs_hz,
            "fit_band_hz": list(self.fit_band_hz),
        }


def perturbation_edge_hz(position: FloatArray, fs_hz: float) -> float:
    """Frequency below which 99.9 % of the position's power lies, Hz.

    Parameters
    ----------
    position : numpy.ndarray, shape (n,)
        Joint angle, rad (any offset or trend is removed first).
    fs_hz : float
        Sampling rate, Hz.

    Returns
    -------
    float
        The band edge, Hz, from the Hann-tapered periodogram of the whole input.

    Raises
    ------
    WindowError
        ``reason = "no_excitation"``: the position carries no power beyond its trend, or
        all of it lies in the two lowest frequency bins (a drift, not a perturbation).
    """
    n = position.size
    spectrum = hann_periodogram(detrend(position, "linear"))
    total = float(spectrum.sum())
    if not total > 0:
        raise _no_usable_power(n, fs_hz)
    cumulative = np.cumsum(spectrum) / total
    bin_index = int(np.searchsorted(cumulative, POWER_QUANTILE))
    if bin_index <= 2:
        raise _no_usable_power(n, fs_hz)
    return bin_index * fs_hz / n


@lru_cache(maxsize=32)
def hann_taper(n: int) -> FloatArray:
    """The Hann window of ``n`` samples (read-only, cached)."""
    window = np.hanning(n)
    window.setflags(write=False)
    return window


def hann_periodogram(x: FloatArray) -> FloatArray:
    """``|FFT(x · Hann)|²`` on the bins ``0 … n/2`` (unscaled)."""
    return np.asarray(np.abs(np.fft.rfft(x * hann_taper(x.size))) ** 2, dtype=np.float64)


def _no_usable_power(n: int, fs_hz: float) -> WindowError:
    return WindowError(
        f"the position has no usable power above {2 * fs_hz / n:.3g} Hz in these {n} samples "
        "(a drift or a constant, not a perturbation); nothing to identify — is the "
        "perturbation enabled?",
        Reason.NO_EXCITATION,
    )


def plan_analysis(
    position: FloatArray,
    fs_hz: float,
    *,
    lowpass_hz: float | None,
    analysis_fs_hz: float | None,
    lag_s: float,
    fit_band_hz: tuple[float, float] | None,
    max_lowpass_hz: float | None = None,
) -> AnalysisPlan:
    """Plan the analysis of ``position``'s stream (explicit values override choices).

    Parameters
    ----------
    position : numpy.ndarray, shape (n,)
        Joint angle, rad: one window, or a longer stretch of the stream.
    fs_hz : float
        Sampling rate, Hz.
    lowpass_hz, analysis_fs_hz : float or None
        −6 dB cut-off and analysis rate, Hz; None: chosen from the data.
    lag_s : float
        IRF lag span, s.
    fit_band_hz : (float, float) or None
        Band of the frequency-domain fits; None: 1 Hz to the cut-off.
    max_lowpass_hz : float, optional
        Highest cut-off to choose, Hz (a robot calibration models its torque only below its
        own band; above it the residual robot torque would bias inertia).

    Returns
    -------
    AnalysisPlan

    Raises
    ------
    WindowError
        ``"no_excitation"`` (see :func:`perturbation_edge_hz`) or ``"too_short"`` (the
        cut-off does not fit the analysis rate).
    """
    fs = float(fs_hz)
    edge = None
    if lowpass_hz is None:
        edge = perturbation_edge_hz(position, fs)
        lowpass_hz = min(CUTOFF_PER_EDGE * edge, 0.4 * fs, max_lowpass_hz or math.inf)
    if analysis_fs_hz is None:
        factor = max(1, math.floor(fs / (RATE_PER_CUTOFF * lowpass_hz)))
    else:
        factor = decimation_factor(fs, analysis_fs_hz)
    try:
        taps = band_limit_taps(fs, float(lowpass_hz), factor)
    except InputDataError as exc:
        raise WindowError(str(exc), Reason.TOO_SHORT) from None
    fs_a = fs / factor
    lag = max(1, round(lag_s * fs_a))
    band = fit_band_hz if fit_band_hz is not None else (1.0, min(lowpass_hz, 0.45 * fs_a))
    lo, hi = band
    return AnalysisPlan(fs, edge, float(lowpass_hz), factor, lag, (float(lo), float(hi)), taps)


def plan_source(position: FloatArray, lost: LostSamples | None) -> FloatArray:
    """What to plan an analysis from: the window, or its longest stretch of valid samples."""
    return position if lost is None else position[lost.longest_valid_stretch()]


def resolve_plan(
    position: ArrayLike,
    fs: float,
    options: EstimatorOptions,
    max_lowpass_hz: float | None = None,
) -> AnalysisPlan:
    """The analysis plan for ``position`` (a window or a longer stretch of a stream), its
    chosen cut-off no higher than ``max_lowpass_hz`` (e.g. a robot calibration's band).

    Raises
    ------
    WindowError
        ``"no_excitation"``: nothing in the position to plan from.
    """
    return plan_analysis(
        np.asarray(position, dtype=np.float64),
        float(fs),
        lowpass_hz=options.lowpass_hz,
        analysis_fs_hz=options.analysis_fs_hz,
        lag_s=options.lag_s,
        fit_band_hz=options.fit_band_hz,
        max_lowpass_hz=max_lowpass_hz,
    )
