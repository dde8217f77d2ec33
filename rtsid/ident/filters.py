"""Zero-phase FIR low-pass with decimation, and derivative stencils.

The same filter is applied to input and output, so the input→output relation inside the
pass band is unchanged (the source filtered only the output, which adds the filter's
dynamics to the identified system). Only output samples whose filter support lies fully
inside the window are produced: nothing is invented at the edges.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rtsid.errors import InputDataError
from rtsid.ident.designs import firwin_lowpass
from rtsid.ident.levinson import compiled_kernel

__all__ = [
    "band_limit_taps",
    "decimation_factor",
    "derivatives",
    "lowpass_taps",
    "stencil_derivatives",
]

FloatArray = NDArray[np.float64]

_KERNEL = compiled_kernel()

# Central-difference stencils of order 8 (accurate for signals well below Nyquist).
_D1 = np.array([1 / 280, -4 / 105, 1 / 5, -4 / 5, 0.0, 4 / 5, -1 / 5, 4 / 105, -1 / 280])
_D2 = np.array([-1 / 560, 8 / 315, -1 / 5, 8 / 5, -205 / 72, 8 / 5, -1 / 5, 8 / 315, -1 / 560])


def decimation_factor(fs_hz: float, analysis_fs_hz: float | None) -> int:
    """Integer factor bringing ``fs_hz`` down to at least ``analysis_fs_hz`` (1: none)."""
    if analysis_fs_hz is None or analysis_fs_hz >= fs_hz:
        return 1
    return max(1, int(np.floor(fs_hz / analysis_fs_hz + 1e-9)))


@lru_cache(maxsize=64)
def lowpass_taps(fs_hz: float, cutoff_hz: float, factor: int) -> FloatArray:
    """Linear-phase FIR (odd length, Hamming window) for ``cutoff_hz`` at ``fs_hz``.

    The transition band reaches from ``cutoff_hz`` to the decimated Nyquist rate
    ``fs_hz / (2·factor)``, so nothing aliases into the pass band. scipy's ``firwin``
    bit for bit, without importing scipy (:func:`rtsid.ident.designs.firwin_lowpass`).
    """
    nyq_after = fs_hz / (2 * factor)
    if not 0 < cutoff_hz < nyq_after:
        raise InputDataError(
            f"low-pass cut-off {cutoff_hz} Hz must be between 0 and the analysis Nyquist rate "
            f"{nyq_after:g} Hz; lower the cut-off or the decimation"
        )
    transition_hz = nyq_after - cutoff_hz
    numtaps = int(np.ceil(3.3 * fs_hz / transition_hz)) | 1
    taps = firwin_lowpass(numtaps, (cutoff_hz + nyq_after) / 2, fs_hz)
    taps.setflags(write=False)
    return taps


@lru_cache(maxsize=64)
def band_limit_taps(fs_hz: float, cutoff_hz: float, factor: int) -> FloatArray:
    """Short linear-phase FIR (Hamming) with its −6 dB point at ``cutoff_hz``.

    The estimator's band-limiting filter, applied to position and torque alike: a gentle
    roll-off (transition about ``4·cutoff_hz`` wide, narrowed so that the stop band starts
    below the decimated Nyquist rate ``fs_hz / (2·factor)``) keeps the filter short, so
    that it costs few samples of a short window, while it removes the band where the
    position's derivatives are mostly noise and the joint is no longer second-order.

    Parameters
    ----------
    fs_hz : float
        Sampling rate, Hz.
    cutoff_hz : float
        −6 dB frequency, Hz.
    factor : int
        Decimation that follows (>= 1).

    Returns
    -------
    numpy.ndarray, shape (numtaps,)
        Odd-length, unit-DC-gain taps (read-only): scipy's ``firwin`` bit for bit, without
        importing scipy (:func:`rtsid.ident.designs.firwin_lowpass`).

    Raises
    ------
    InputDataError
        ``cutoff_hz`` is not below the decimated Nyquist rate.
    """
    nyq_after = fs_hz / (2 * factor)
    if not 0 < cutoff_hz < nyq_after:
        raise InputDataError(
            f"low-pass cut-off {cutoff_hz:g} Hz must be between 0 and the analysis Nyquist "
            f"rate {nyq_after:g} Hz; lower lowpass_hz or raise analysis_fs_hz"
        )
    transition_hz = min(4.0 * cutoff_hz, 2.0 * (nyq_after - cutoff_hz))
    numtaps = int(np.ceil(3.3 * fs_hz / transition_hz)) | 1
    taps = firwin_lowpass(numtaps, cutoff_hz, fs_hz)
    taps.setflags(write=False)
    return taps


def derivatives(x: ArrayLike, fs_hz: float) -> tuple[FloatArray, FloatArray]:
    """First and second time derivatives by 8th-order central differences.

    Accurate for signals band-limited well below the Nyquist rate; the four samples at
    each end use lower-order one-sided estimates from ``numpy.gradient``.

    Parameters
    ----------
    x : array_like, shape (n,)
        Signal sampled at ``fs_hz``; n >= 9.
    fs_hz : float
        Sampling rate, Hz.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        ``ẋ`` and ``ẍ``, each shape (n,).
    """
    arr = np.asarray(x, dtype=float)
    if arr.size < 9:
        raise InputDataError(f"derivatives need at least 9 samples, got {arr.size}")
    dt = 1.0 / fs_hz
    d1 = np.gradient(arr, dt, edge_order=2)
    d2 = np.gradient(d1, dt, edge_order=2)
    d1[4:-4], d2[4:-4] = stencil_derivatives(arr, fs_hz)
    return d1, d2


def stencil_derivatives(x: FloatArray, fs_hz: float) -> tuple[FloatArray, FloatArray]:
    """First and second derivatives at samples ``4 … n−5`` only (shape (n−8,) each)."""
    return stencil_velocity(x, fs_hz), np.correlate(x, _D2, mode="valid") * fs_hz**2


def stencil_velocity(x: FloatArray, fs_hz: float, out: FloatArray | None = None) -> FloatArray:
    """The first derivative of :func:`stencil_derivatives` alone (samples ``4 … n−5``).

    Parameters
    ----------
    x : numpy.ndarray, shape (n,)
        Signal at ``fs_hz`` (n >= 9).
    fs_hz : float
        Sampling rate, Hz.
    out : numpy.ndarray, shape (n − 8,), optional
        Where to write it (a contiguous float64 array, e.g. a view of a larger one).

    Returns
    -------
    numpy.ndarray, shape (n − 8,)
        ``ẋ`` (``out`` when given): ``numpy.correlate(x, stencil, "valid")·fs_hz``, by the
        compiled ``stencil_correlate`` when built (the same numbers bit for bit, tested).
    """
    if _KERNEL is None or not _contiguous_doubles(x) or x.size < _D1.size:
        velocity = np.correlate(x, _D1, mode="valid") * fs_hz
        if out is None:
            return velocity
        out[...] = velocity
        return out
    if out is None:
        out = np.empty(x.size - _D1.size + 1)
    _KERNEL.stencil_correlate(x, _D1, float(fs_hz), out)
    return out


def _contiguous_doubles(x: FloatArray) -> bool:
    return bool(x.dtype == np.float64 and x.flags.c_contiguous)
