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
(:func:`rtsid.ident.reflex_lane.window_vaf_gain`), its Savitzky–Golay rows carried from one
fit to the next where they are the same numbers (:class:`BasisStore`).
"""

from __future__ import annotations

import threading
from functools import lru_cache

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from rtsid.ident.designs import design
from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.reflex import zero_phase_rows

__all__ = ["BasisStore", "WindowVafBasis", "least_squares_window", "savgol_derivatives"]

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
    _savgol_ends(arr, fs_hz, d1, d2)
    return d1, d2


def _savgol_ends(arr: FloatArray, fs_hz: float, d1: FloatArray, d2: FloatArray) -> None:
    """:func:`savgol_derivatives`' first and last ``SAVGOL_POINTS // 2`` samples into ``d1``
    and ``d2``: at each end one cubic fitted to the first (last) 11 samples, its derivatives
    there a fixed linear map of those samples (:func:`_savgol_end_maps`)."""
    half, n = SAVGOL_POINTS // 2, arr.size
    maps = _savgol_end_maps(float(fs_hz))
    for (start, first), (m1, m2) in zip(((0, 0), (n - SAVGOL_POINTS, n - half)), maps, strict=True):
        samples = arr[start : start + SAVGOL_POINTS]
        d1[first : first + half] = m1 @ samples
        d2[first : first + half] = m2 @ samples


@lru_cache(maxsize=8)
def _savgol_end_maps(fs_hz: float) -> tuple[tuple[FloatArray, FloatArray], ...]:
    """For the first and the last end, the maps (shape ``(SAVGOL_POINTS // 2,
    SAVGOL_POINTS)``, 1/s and 1/s²) from an end's 11 samples to the first and second
    derivatives of the cubic fitted to them (``numpy.polyfit``'s least squares on the unit
    samples; a fit is linear in its samples), at the end's own samples (read-only).

    The same values as fitting each end's cubic (``numpy.polyfit``, ``polyder``,
    ``polyval``) to rounding, not bit for bit; a matrix-vector product a row instead of two
    least-squares solves and their Python a basis (branch ``fits7``)."""
    half = SAVGOL_POINTS // 2
    at = np.arange(float(SAVGOL_POINTS))
    cubics = np.polyfit(at, np.eye(SAVGOL_POINTS), SAVGOL_ORDER)  # (order + 1, points)
    powers = np.arange(SAVGOL_ORDER, -1, -1)  # numpy.polyfit's order: highest power first
    maps = []
    for offset in (0, SAVGOL_POINTS - half):
        t = at[offset : offset + half, None]
        slope = np.where(powers >= 1, powers * t ** np.maximum(powers - 1, 0), 0.0)
        curvature = np.where(
            powers >= 2, powers * (powers - 1) * t ** np.maximum(powers - 2, 0), 0.0
        )
        pair = (slope @ cubics * fs_hz, curvature @ cubics * fs_hz**2)
        for m in pair:
            m.setflags(write=False)
        maps.append(pair)
    return tuple(maps)


def _savgol_interior(
    arr: FloatArray, fs_hz: float, lo: int, hi: int, d1: FloatArray, d2: FloatArray
) -> None:
    """:func:`savgol_derivatives`' interior samples ``lo … hi − 1`` (``SAVGOL_POINTS // 2 ≤
    lo``, ``hi ≤ n − SAVGOL_POINTS // 2``) into ``d1`` and ``d2``, nothing else written: each
    is the convolution at that sample alone, the same numbers bit for bit whatever part of a
    record it is formed in (the compiled ``savgol_range``, ndimage's on the samples it reads
    otherwise; tested)."""
    if hi <= lo:
        return
    taps = _savgol_taps(float(fs_hz))
    if _eureka is not None:
        _eureka.savgol_range(arr, taps[0], taps[1], lo, hi, d1, d2)
        return
    from scipy import ndimage

    half = SAVGOL_POINTS // 2
    part = arr[lo - half : hi + half]
    for t, out in zip(taps, (d1, d2), strict=True):
        out[lo:hi] = ndimage.convolve1d(part, t, mode="constant")[half:-half]


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
    derivatives : (numpy.ndarray, numpy.ndarray), optional
        ``savgol_derivatives(position, fs_hz)`` when already formed (:class:`BasisStore`).
    """

    def __init__(
        self,
        position: FloatArray,
        torque: FloatArray,
        fs_hz: float,
        derivatives: tuple[FloatArray, FloatArray] | None = None,
    ) -> None:
        d1, d2 = derivatives if derivatives is not None else savgol_derivatives(position, fs_hz)
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


#: A :class:`BasisStore`'s buffers hold this many records' length (a record moved to their
#: start when it would run past their end: once every few fits).
STORE_RECORDS = 3


class BasisStore:
    """Window VAF bases whose Savitzky–Golay rows carry over from one record to the next.

    The slow lane's evidence basis spans the newest 11 s of each fit's horizon, and
    consecutive fits share 9 of them. A derivative at a sample away from a record's ends is
    the convolution of the 11 position samples around it: the same numbers bit for bit in any
    record holding those samples. So the store keeps the last record's position and
    derivatives by absolute sample index and forms only what is new: the samples not in the
    last record, and each end's cubic. What it carries is checked, not assumed: the samples
    behind every carried derivative must equal the kept ones bit for bit (a record of other
    data at the same indices carries nothing). The 40 Hz low-pass after it is formed afresh:
    run forwards from a record's start and backwards from its end, it does not give the same
    bits on the shared samples of two records (measured: its states stay apart by rounding).

    Memory: ``STORE_RECORDS`` records' length of position and two derivatives (≈ 2 MB at
    2500 Hz and 11 s). Thread-safe (one basis formed at a time).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._forget()

    def clear(self) -> None:
        """Forget the kept record (e.g. when the next record's samples were bridged)."""
        with self._lock:
            self._forget()

    def _forget(self) -> None:
        self._fs_hz = 0.0
        self._origin = 0  # absolute index of the buffers' first sample
        self._x = np.empty(0)  # position, by absolute index − origin
        self._d = np.empty((2, 0))  # first and second derivative, likewise
        self._interior = (0, 0)  # absolute [a, b): kept derivatives formed as interior ones
        #: Derivatives the last :meth:`basis` carried over instead of forming them (samples).
        self.carried = 0

    def basis(
        self, position: FloatArray, torque: FloatArray, fs_hz: float, first_index: int
    ) -> WindowVafBasis:
        """``WindowVafBasis(position, torque, fs_hz)``, the same numbers bit for bit, with the
        derivatives of the samples it shares with the last record carried over.

        Parameters
        ----------
        position, torque : numpy.ndarray, shape (N,)
            The record (rad, N·m; torque sign-corrected).
        fs_hz : float
            Sampling rate, Hz.
        first_index : int
            Absolute index of the record's first sample (a sample's index says which
            sample it is from record to record).
        """
        arr = np.ascontiguousarray(position, dtype=np.float64)
        with self._lock:
            d1, d2 = self._derivatives(arr, float(fs_hz), int(first_index))
            return WindowVafBasis(arr, torque, fs_hz, derivatives=(d1, d2))

    def _derivatives(
        self, x: FloatArray, fs_hz: float, first: int
    ) -> tuple[FloatArray, FloatArray]:
        """:func:`savgol_derivatives` of ``x`` (samples ``first …``) as views of the buffers,
        valid until the next call; the buffers then hold ``x`` and them."""
        n, half = x.size, SAVGOL_POINTS // 2
        if n < 2 * SAVGOL_POINTS:
            self._forget()
            return savgol_derivatives(x, fs_hz)
        lo, hi = self._carried_span(x, fs_hz, first)
        self._make_room(first, n, lo, hi)
        at = first - self._origin
        kept_x, d1, d2 = self._x[at : at + n], self._d[0, at : at + n], self._d[1, at : at + n]
        a, b = lo - first, hi - first  # carried: x[a − half : b + half] and d[a : b]
        if b > a:
            kept_x[: a - half] = x[: a - half]
            kept_x[b + half :] = x[b + half :]
        else:
            a = b = half
            kept_x[:] = x
        _savgol_interior(x, fs_hz, half, a, d1, d2)
        _savgol_interior(x, fs_hz, b, n - half, d1, d2)
        _savgol_ends(x, fs_hz, d1, d2)
        self._fs_hz, self._interior, self.carried = fs_hz, (first + half, first + n - half), b - a
        return d1, d2

    def _carried_span(self, x: FloatArray, fs_hz: float, first: int) -> tuple[int, int]:
        """The absolute samples ``[lo, hi)`` whose kept derivatives serve ``x`` (its interior,
        the kept record's interior, and the samples behind them equal bit for bit); an empty
        span when none do."""
        half = SAVGOL_POINTS // 2
        lo = max(first + half, self._interior[0])
        hi = min(first + x.size - half, self._interior[1])
        if fs_hz != self._fs_hz or hi <= lo:
            return first, first
        new = x[lo - half - first : hi + half - first].view(np.int64)
        kept = self._x[lo - half - self._origin : hi + half - self._origin].view(np.int64)
        return (lo, hi) if np.array_equal(new, kept) else (first, first)

    def _make_room(self, first: int, n: int, lo: int, hi: int) -> None:
        """Make the buffers hold samples ``first … first + n − 1`` in place, keeping the
        position over ``[lo − half, hi + half)`` and the derivatives over ``[lo, hi)``."""
        at = first - self._origin
        if at >= 0 and at + n <= self._x.size:
            return
        size = max(self._x.size, STORE_RECORDS * n)
        x, d = np.empty(size), np.empty((2, size))
        if hi > lo:
            half = SAVGOL_POINTS // 2
            old, new = (
                slice(lo - self._origin - half, hi - self._origin + half),
                slice(lo - first - half, hi - first + half),
            )
            x[new] = self._x[old]
            d[:, new] = self._d[:, old]
        self._origin, self._x, self._d = first, x, d
