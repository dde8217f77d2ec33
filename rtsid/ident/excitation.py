"""Perturbation signals: PRBS, low-pass filtered Gaussian noise and random-phase multisines.

Pure functions: arrays and numbers in, arrays out. Every generator takes a
``numpy.random.Generator`` (or a seed) so that signals are reproducible.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import InputDataError

__all__ = ["Multisine", "filtered_noise", "multisine", "prbs"]

FloatArray = NDArray[np.float64]


def _rng(seed: int | np.random.Generator | None) -> np.random.Generator:
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


def _check_positive(name: str, value: float) -> None:
    if not np.isfinite(value) or value <= 0:
        raise InputDataError(f"{name} must be a positive finite number, got {value!r}")


def prbs(
    n: int,
    amplitude: float = 0.03,
    *,
    min_hold: int = 1,
    switch_probability: float = 0.5,
    seed: int | np.random.Generator | None = None,
) -> FloatArray:
    """Pseudo-random binary sequence of ``±amplitude``.

    Every ``min_hold`` samples the level switches with probability ``switch_probability``
    (the source used 0.5), so the shortest pulse lasts ``min_hold`` samples and the
    spectrum is flat up to about ``fs / (2·min_hold)``.

    Parameters
    ----------
    n : int
        Number of samples.
    amplitude : float
        Level in the signal's unit (rad for a position perturbation).
    min_hold : int
        Samples between switching decisions (>= 1).
    switch_probability : float
        Probability of switching at each decision, in (0, 1].
    seed : int or numpy.random.Generator, optional
        Source of randomness.

    Returns
    -------
    numpy.ndarray, shape (n,)
        The sequence, values in ``{-amplitude, +amplitude}``.

    Examples
    --------
    >>> u = prbs(10, 0.05, min_hold=2, seed=1)
    >>> sorted(set(u.tolist()))
    [-0.05, 0.05]
    """
    if n < 1:
        raise InputDataError(f"prbs needs n >= 1 samples, got {n}")
    if min_hold < 1:
        raise InputDataError(f"min_hold must be >= 1 sample, got {min_hold}")
    if not 0 < switch_probability <= 1:
        raise InputDataError(f"switch_probability must be in (0, 1], got {switch_probability}")
    rng = _rng(seed)
    decisions = -(-n // min_hold)
    switches = rng.random(decisions) < switch_probability
    switches[0] = False
    levels = np.where(np.cumsum(switches) % 2 == 0, 1.0, -1.0)
    if rng.random() < 0.5:
        levels = -levels
    return amplitude * np.repeat(levels, min_hold)[:n]


def filtered_noise(
    n: int,
    fs_hz: float,
    cutoff_hz: float = 200.0,
    *,
    peak: float = 0.05,
    order: int = 4,
    seed: int | np.random.Generator | None = None,
) -> FloatArray:
    """Gaussian white noise, low-pass filtered (zero phase) and scaled to a peak value.

    The source used a 200 Hz cut-off and ±0.05 rad in simulation.

    Parameters
    ----------
    n : int
        Number of samples.
    fs_hz : float
        Sampling rate, Hz.
    cutoff_hz : float
        Butterworth cut-off, Hz, below the Nyquist rate.
    peak : float
        Largest absolute value of the result.
    order : int
        Butterworth order.
    seed : int or numpy.random.Generator, optional
        Source of randomness.

    Returns
    -------
    numpy.ndarray, shape (n,)
        Zero-mean noise with ``max(abs(x)) == peak``.
    """
    from scipy import signal

    _check_positive("fs_hz", fs_hz)
    _check_positive("cutoff_hz", cutoff_hz)
    if cutoff_hz >= fs_hz / 2:
        raise InputDataError(
            f"cutoff_hz={cutoff_hz} must be below the Nyquist rate {fs_hz / 2} Hz; "
            "lower the cut-off or raise the sampling rate"
        )
    if n < 1:
        raise InputDataError(f"filtered_noise needs n >= 1 samples, got {n}")
    rng = _rng(seed)
    pad = min(n, int(3 * fs_hz / cutoff_hz) + 16)
    white = rng.standard_normal(n + 2 * pad)
    sos = signal.butter(order, cutoff_hz, fs=fs_hz, output="sos")
    x = signal.sosfiltfilt(sos, white)[pad : pad + n]
    x -= x.mean()
    top = np.max(np.abs(x))
    return x * (peak / top) if top > 0 else x


@dataclass(frozen=True)
class Multisine:
    """A periodic random-phase multisine and the bins it excites.

    Attributes
    ----------
    fs_hz : float
        Sampling rate, Hz.
    period_samples : int
        Samples in one period ``N``; the frequency grid is ``fs_hz / N``.
    excited_bins : numpy.ndarray of int
        DFT bins (of one period) that carry power.
    amplitudes : numpy.ndarray
        Amplitude of each excited cosine.
    phases_rad : numpy.ndarray
        Phase of each excited cosine, rad.
    """

    fs_hz: float
    period_samples: int
    excited_bins: NDArray[np.int64]
    amplitudes: FloatArray
    phases_rad: FloatArray

    @property
    def frequencies_hz(self) -> FloatArray:
        """Excited frequencies, Hz."""
        return np.asarray(self.excited_bins * (self.fs_hz / self.period_samples), dtype=float)

    def evaluate(self, t_s: FloatArray | float) -> FloatArray:
        """Value at arbitrary times (seconds), e.g. inside an ODE solver."""
        t = np.asarray(t_s, dtype=float)
        w = 2 * np.pi * self.frequencies_hz
        return np.cos(np.multiply.outer(t, w) + self.phases_rad) @ self.amplitudes

    def samples(self, n_periods: int = 1) -> FloatArray:
        """``n_periods`` whole periods sampled at ``fs_hz`` (exact by inverse FFT)."""
        if n_periods < 1:
            raise InputDataError(f"n_periods must be >= 1, got {n_periods}")
        n = self.period_samples
        spectrum = np.zeros(n // 2 + 1, dtype=complex)
        spectrum[self.excited_bins] = (n / 2) * self.amplitudes * np.exp(1j * self.phases_rad)
        one = np.fft.irfft(spectrum, n)
        return np.tile(one, n_periods)


def multisine(
    fs_hz: float,
    period_s: float,
    f_max_hz: float,
    *,
    every: int = 1,
    f_min_hz: float | None = None,
    rms: float = 1.0,
    seed: int | np.random.Generator | None = None,
) -> Multisine:
    """Random-phase multisine exciting every ``every``-th bin up to ``f_max_hz``.

    Parameters
    ----------
    fs_hz : float
        Sampling rate, Hz.
    period_s : float
        Period, s; must hold a whole number of samples.
    f_max_hz : float
        Highest excited frequency, Hz (inclusive).
    every : int
        Excite bins ``every, 2·every, …`` (``P`` in the source; 1 excites all bins).
    f_min_hz : float, optional
        Lowest excited frequency; default the first excited bin.
    rms : float
        RMS value of the resulting signal.
    seed : int or numpy.random.Generator, optional
        Source of the random phases.

    Returns
    -------
    Multisine
        The signal's definition; call ``.samples()`` or ``.evaluate(t)``.
    """
    _check_positive("fs_hz", fs_hz)
    _check_positive("period_s", period_s)
    n = round(period_s * fs_hz)
    if abs(n - period_s * fs_hz) > 1e-6 * n:
        raise InputDataError(
            f"period_s={period_s} at fs_hz={fs_hz} is not a whole number of samples; "
            "choose a period that is a multiple of 1/fs"
        )
    if every < 1:
        raise InputDataError(f"every must be >= 1, got {every}")
    df = fs_hz / n
    k_max = min(int(np.floor(f_max_hz / df + 1e-9)), n // 2 - 1)
    bins = np.arange(every, k_max + 1, every, dtype=np.int64)
    if f_min_hz is not None:
        bins = bins[bins * df >= f_min_hz - 1e-9]
    if bins.size == 0:
        raise InputDataError(
            f"no excited bin between {f_min_hz or df} and {f_max_hz} Hz with every={every} "
            f"on a {df:g} Hz grid; lengthen the period or raise f_max_hz"
        )
    rng = _rng(seed)
    phases = rng.uniform(0, 2 * np.pi, bins.size)
    amplitudes = np.full(bins.size, rms * np.sqrt(2.0 / bins.size))
    return Multisine(float(fs_hz), int(n), bins, amplitudes, phases)
