"""The honest references every accuracy figure is set against, measured in the same run.

* :func:`least_squares_window` — per-window least squares of the same three parameters on
  the same window: torque on ``(θ̈, θ̇, θ)`` with an offset and a trend, the derivatives by
  Savitzky–Golay (11 samples, cubic) inside the window (no sample outside it), or exact
  derivatives where a simulation has them.
* :class:`WindowVafBasis` — how well a window's ``(I, B, K)`` explain the torque a user
  sees: the prediction ``I·θ̈ + B·θ̇ + K·θ`` (Savitzky–Golay derivatives of the whole
  record) and the measured torque, both low-passed at 40 Hz (4th-order Butterworth, zero
  phase, over the whole record), each window's mean removed.

The benchmarks score every estimator against these; the slow lane uses the same basis to
judge, from its own data, whether subtracting a reflex model helps the windows
(:func:`rtsid.ident.reflex_lane.window_vaf_gain`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from rtsid.ident.designs import design
from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.reflex import zero_phase_rows

__all__ = ["WindowVafBasis", "least_squares_window", "savgol_derivatives"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
SAVGOL_POINTS, SAVGOL_ORDER = 11, 3
BASIS_LOWPASS_HZ = 40.0

_eureka = compiled_kernel()


def savgol_derivatives(x: FloatArray, fs_hz: float) -> tuple[FloatArray, FloatArray]:
    """First and second derivative by Savitzky–Golay (11 points, cubic).

    ``scipy.signal.savgol_filter(x, 11, 3, deriv=1 and 2, delta=1/fs_hz)`` (mode
    ``"interp"``) to rounding (tested to 1e-12): its filters designed once per rate, and at
    each end one cubic fitted to the first (last) 11 samples serving both derivatives.
    """
    arr = np.asarray(x, dtype=np.float64)
    if arr.size < SAVGOL_POINTS:  # scipy's own checks and messages
        from scipy import signal

        d1 = signal.savgol_filter(arr, SAVGOL_POINTS, SAVGOL_ORDER, deriv=1, delta=1 / fs_hz)
        d2 = signal.savgol_filter(arr, SAVGOL_POINTS, SAVGOL_ORDER, deriv=2, delta=1 / fs_hz)
        return np.asarray(d1), np.asarray(d2)
    taps = _savgol_taps(float(fs_hz))
    if _eureka is not None:  # ndimage's convolution of both filters, bit for bit (tested)
        d1, d2 = np.empty(arr.size), np.empty(arr.size)
        _eureka.savgol_pair(np.ascontiguousarray(arr), taps[0], taps[1], d1, d2)
    else:
        from scipy import ndimage

        d1, d2 = (np.asarray(ndimage.convolve1d(arr, t, mode="constant")) for t in taps)
    half, n, dt = SAVGOL_POINTS // 2, arr.size, 1.0 / fs_hz
    at = np.arange(float(SAVGOL_POINTS))
    for start, first in ((0, 0), (n - SAVGOL_POINTS, n - half)):
        cubic = np.polyfit(at, arr[start : start + SAVGOL_POINTS], SAVGOL_ORDER)
        points = at[first - start : first - start + half]
        d1[first : first + half] = np.polyval(np.polyder(cubic, 1), points) / dt
        d2[first : first + half] = np.polyval(np.polyder(cubic, 2), points) / dt**2
    return d1, d2


@lru_cache(maxsize=8)
def _savgol_taps(fs_hz: float) -> tuple[FloatArray, FloatArray]:
    """The first- and second-derivative Savitzky–Golay filters at ``fs_hz`` (read-only;
    scipy's ``savgol_coeffs``, from the design cache: :func:`rtsid.ident.designs.design`)."""
    taps = tuple(
        design("savgol_coeffs", SAVGOL_POINTS, SAVGOL_ORDER, deriv=d, delta=1 / fs_hz)
        for d in (1, 2)
    )
    for t in taps:
        t.setflags(write=False)
    return taps[0], taps[1]


def least_squares_window(
    position: FloatArray,
    torque: FloatArray,
    fs_hz: float,
    derivatives: tuple[FloatArray, FloatArray] | None = None,
) -> FloatArray:
    """``(I, B, K)`` by least squares on one window (offset and trend as nuisance terms).

    Parameters
    ----------
    position, torque : numpy.ndarray, shape (n,)
        The window (rad, N·m; torque already sign-corrected).
    fs_hz : float
        Sampling rate, Hz.
    derivatives : (numpy.ndarray, numpy.ndarray), optional
        ``(θ̇, θ̈)`` to use (e.g. a simulation's exact ones); default Savitzky–Golay of the
        window.
    """
    d1, d2 = derivatives if derivatives is not None else savgol_derivatives(position, fs_hz)
    n = position.size
    x = np.column_stack((d2, d1, position, np.ones(n), np.linspace(-1.0, 1.0, n)))
    return np.asarray(np.linalg.lstsq(x, torque, rcond=None)[0][:3], dtype=np.float64)


@lru_cache(maxsize=8)
def _basis_lowpass(fs_hz: float) -> FloatArray:
    """The basis's low-pass (second-order sections) at ``fs_hz``, designed once per rate (the
    design costs about a millisecond, as much as filtering a second of data); read-only:
    scipy's filters take a writable copy. scipy's ``butter``, from the design cache
    (:func:`rtsid.ident.designs.design`)."""
    sos = design("butter", 4, BASIS_LOWPASS_HZ, fs=fs_hz, output="sos")
    sos.setflags(write=False)
    return sos


class WindowVafBasis:
    """The window VAF basis over one whole record (see the module notes).

    Parameters
    ----------
    position, torque : numpy.ndarray, shape (N,)
        The record (rad, N·m; torque sign-corrected).
    fs_hz : float
        Sampling rate, Hz.
    """

    def __init__(self, position: FloatArray, torque: FloatArray, fs_hz: float) -> None:
        d1, d2 = savgol_derivatives(position, fs_hz)
        # scipy's sosfiltfilt of each row, compiled when built (the same numbers bit for bit)
        low = zero_phase_rows(_basis_lowpass(float(fs_hz)), (torque, d2, d1, position))
        self.torque = low[0]
        self.regressors = low[1:]

    def vaf(
        self, params: FloatArray, start: int, stop: int, extra: FloatArray | None = None
    ) -> float:
        """VAF (%) of ``(I, B, K)`` on samples ``start … stop − 1`` (NaN params: NaN), with
        ``extra`` torque (e.g. the slow lane's reflex prediction) added to the model's."""
        measured = self.torque[start:stop] - self.torque[start:stop].mean()
        return self._vaf_of(params, measured, start, stop, extra)

    def _vaf_of(
        self,
        params: FloatArray,
        measured: FloatArray,
        start: int,
        stop: int,
        extra: FloatArray | None = None,
    ) -> float:
        """:meth:`vaf` with the window's mean-free measured torque given."""
        if not np.all(np.isfinite(params)):
            return float("nan")
        predicted = np.asarray(params) @ self.regressors[:, start:stop]
        if extra is not None:
            predicted = predicted + extra
        predicted = predicted - predicted.mean()
        error = measured - predicted
        return float(100.0 * (1.0 - (error @ error) / (measured @ measured)))

    def least_squares_vaf(self, start: int, stop: int, extra: FloatArray | None = None) -> float:
        """VAF (%) on samples ``start … stop − 1`` of the window's own least-squares
        ``(I, B, K)`` (offset and trend as nuisance terms) fitted to the torque minus
        ``extra``, with ``extra`` (the same length; a smooth torque such as a reflex
        prediction) counted as part of the model."""
        target = self.torque[start:stop] if extra is None else self.torque[start:stop] - extra
        params = np.linalg.lstsq(self._design(start, stop), target, rcond=None)[0][:3]
        return self.vaf(np.asarray(params, dtype=np.float64), start, stop, extra)

    def least_squares_vaf_gains(self, starts: IntArray, n: int, extra: FloatArray) -> FloatArray:
        """``least_squares_vaf(a, a + n, e) − least_squares_vaf(a, a + n)`` with
        ``e = extra[a : a + n]``, for every window start ``a`` in ``starts``, percentage
        points: the VAF that counting the extra torque (N·m) as part of the model adds to each
        window's own least-squares fit.

        All windows in one pass: each window's regressors are centred (the offset term
        removed exactly), scaled to unit norm, and the small normal equations (``θ̈, θ̇, θ``
        and the trend, both right-hand sides) of every window formed and solved at once; by
        the compiled kernel's ``evidence_gains_lanes`` when built (four windows at a time,
        ``evidence_gains``' operations lane by lane: its numbers bit for bit; the numpy code
        below is the reference). The same numbers as the per-window ``numpy.linalg.lstsq`` of
        :meth:`least_squares_vaf` to rounding (tested to 1e-9).

        Parameters
        ----------
        starts : numpy.ndarray of int, shape (w,)
            First sample of each window.
        n : int
            Samples per window.
        extra : numpy.ndarray, shape (N,)
            The extra torque on the basis's samples, N·m.

        Returns
        -------
        numpy.ndarray, shape (w,)
        """
        starts = np.asarray(starts, dtype=np.int64)
        extra = np.ascontiguousarray(extra, dtype=np.float64)
        if _eureka is not None:
            gains = np.empty(starts.size)
            torque, regressors = self.torque, self.regressors
            _eureka.evidence_gains_lanes(torque, regressors, extra, starts, n, gains)
            return gains
        x = np.empty((starts.size, 4, n))  # per window: centred θ̈, θ̇, θ, and the trend
        x[:, :3] = sliding_window_view(self.regressors, n, axis=1)[:, starts].transpose(1, 0, 2)
        x[:, :3] -= x[:, :3].mean(axis=2, keepdims=True)
        x[:, 3] = np.linspace(-1.0, 1.0, n)
        x /= np.sqrt(np.einsum("wkn,wkn->wk", x, x))[:, :, None]
        torque = sliding_window_view(self.torque, n)[starts]
        measured = torque - torque.mean(axis=1, keepdims=True)
        added = sliding_window_view(extra, n)[starts]
        added = added - added.mean(axis=1, keepdims=True)
        targets = np.stack((measured - added, measured), axis=2)  # (w, n, 2)
        params = np.linalg.solve(x @ x.transpose(0, 2, 1), x @ targets)  # (w, 4, 2)
        error = measured[:, :, None] - x[:, :3].transpose(0, 2, 1) @ params[:, :3]
        error[:, :, 0] -= added
        vafs = 100.0 * (1.0 - np.einsum("wnj,wnj->wj", error, error) / _power(measured)[:, None])
        return np.asarray(vafs[:, 0] - vafs[:, 1], dtype=np.float64)

    def _design(self, start: int, stop: int) -> FloatArray:
        """Least-squares design on samples ``start … stop − 1``: the regressors, an offset and
        a trend."""
        n = stop - start
        return np.column_stack(
            (self.regressors[:, start:stop].T, np.ones(n), np.linspace(-1.0, 1.0, n))
        )


def _power(rows: FloatArray) -> FloatArray:
    """Each row's sum of squares."""
    return np.asarray(np.einsum("wn,wn->w", rows, rows), dtype=np.float64)
