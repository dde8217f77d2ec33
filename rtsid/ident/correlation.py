"""Auto- and cross-correlation over lags for Wiener–Hopf deconvolution, and detrending.

Biased estimates (divided by the window length ``N``), so the autocorrelation sequence is
positive semi-definite and its Toeplitz matrix can be solved by EUREKA. Direct sums are
used for short lag spans and FFTs for long ones, whichever does less work.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rtsid.errors import InputDataError
from rtsid.ident.levinson import compiled_kernel

__all__ = [
    "auto_correlation",
    "auto_sums",
    "causal_cross_correlation",
    "cross_correlation",
    "cross_sums",
    "detrend",
    "lagged_cross",
    "lagged_gram",
]

FloatArray = NDArray[np.float64]

_KERNEL = compiled_kernel()

# Above this many lags per sample an FFT beats np.correlate's direct sum (measured).
_FFT_LAG_FRACTION = 0.05


@lru_cache(maxsize=16)
def _centred_ramp(n: int) -> tuple[FloatArray, float]:
    t = np.arange(n, dtype=np.float64) - (n - 1) / 2.0
    t.setflags(write=False)
    return t, max(float(t @ t), 1e-300)


def trend_slope(x: ArrayLike) -> float:
    """Slope of the least-squares line through ``x``, per sample (what ``detrend`` removes
    beside the mean)."""
    arr = np.asarray(x, dtype=np.float64)
    t, tt = _centred_ramp(arr.size)
    return float(t @ arr) / tt


def detrend(x: ArrayLike, kind: str = "linear") -> FloatArray:
    """Remove the mean (``"mean"``), a straight line (``"linear"``) or nothing (``"none"``).

    Parameters
    ----------
    x : array_like, shape (n,)
        Signal.
    kind : {"linear", "mean", "none"}
        What to remove.

    Returns
    -------
    numpy.ndarray, shape (n,)
        The detrended copy.
    """
    # contiguous, as the copy it used to make was: BLAS's dot and numpy's sum of a strided
    # array add in another order (other bits)
    arr = np.ascontiguousarray(x, dtype=np.float64)
    if kind == "none":
        return np.array(arr)
    if kind == "mean":
        return np.subtract(arr, arr.sum() / arr.size)  # no copy of x first: the same numbers
    if kind == "linear":
        t, tt = _centred_ramp(arr.size)
        line = ((t @ arr) / tt) * t
        line += arr.sum() / arr.size  # mean + slope·t, as the expression added them
        return np.subtract(arr, line, out=line)  # x − line into the line: no copy of x
    raise InputDataError(f"detrend kind {kind!r} is not one of 'linear', 'mean', 'none'")


def _check_lags(n: int, max_lag: int) -> None:
    if max_lag < 0:
        raise InputDataError(f"max_lag must be >= 0, got {max_lag}")
    if max_lag >= n:
        raise InputDataError(
            f"max_lag={max_lag} needs more than {max_lag} samples, the window has {n}; "
            "lengthen the window or shorten the lag span"
        )


def _use_fft(n: int, max_lag: int) -> bool:
    return max_lag > _FFT_LAG_FRACTION * n and n > 256


def _fft_cross(u: FloatArray, y: FloatArray) -> FloatArray:
    """Full linear cross-correlation c[m] = sum_t u[t]·y[t+m], m = -(n-1)..n-1."""
    n = u.size
    nfft = 1 << (2 * n - 1).bit_length()
    spec = np.conj(np.fft.rfft(u, nfft)) * np.fft.rfft(y, nfft)
    full = np.fft.irfft(spec, nfft)
    return np.concatenate((full[nfft - (n - 1) :], full[:n]))


def _direct_lags(u: FloatArray, y: FloatArray, first: int, last: int) -> FloatArray:
    """``Σ_t u(t)·y(t+k)`` for ``k = first..last``, in O(N·(last − first + 1)).

    The compiled kernel's ``xcorr_lags`` when it was built (sixteen lags at a time, each summed
    over ``t`` in order: its ``xcorr`` loop bit for bit); otherwise ``y`` is zero-padded so that one
    ``valid``-mode correlation yields exactly the wanted lags (a ``full`` correlation would
    cost O(N²) on long records).
    """
    n = u.size
    if _KERNEL is not None:
        out = np.empty(last - first + 1)
        _KERNEL.xcorr_lags(np.ascontiguousarray(u), np.ascontiguousarray(y), first, last, 1.0, out)
        return out
    padded = np.zeros(n + (last - first))
    lo, hi = max(0, first), min(n, n + last)
    # padded[j] = y[j + first] where that index exists, so out[k - first] = Σ_t u(t)·y(t+k).
    padded[lo - first : hi - first] = y[lo:hi]
    return np.asarray(np.correlate(padded, u, mode="valid"), dtype=np.float64)


def auto_sums(u: ArrayLike, max_lag: int) -> FloatArray:
    """Autocorrelation sums ``Σ_t u(t)·u(t+k)`` for ``k = 0..max_lag`` (not divided by ``N``).

    Parameters
    ----------
    u : array_like, shape (N,)
        Input signal (detrend it first).
    max_lag : int
        Largest lag, samples (< N).

    Returns
    -------
    numpy.ndarray, shape (max_lag + 1,)
        The sums; :func:`auto_correlation` is they ÷ ``N``.
    """
    arr = np.asarray(u, dtype=np.float64)
    n = arr.size
    _check_lags(n, max_lag)
    if _use_fft(n, max_lag):
        return _fft_cross(arr, arr)[n - 1 : n + max_lag]
    return _direct_lags(arr, arr, 0, max_lag)


def auto_correlation(u: ArrayLike, max_lag: int) -> FloatArray:
    """Biased autocorrelation ``φ_uu(k) = (1/N)·Σ_t u(t)·u(t+k)`` for ``k = 0..max_lag``.

    Parameters
    ----------
    u : array_like, shape (N,)
        Input signal (detrend it first).
    max_lag : int
        Largest lag, samples (< N).

    Returns
    -------
    numpy.ndarray, shape (max_lag + 1,)
        ``φ_uu(0..max_lag)``, the first column of the Toeplitz matrix ``R_uu``.
    """
    sums = auto_sums(u, max_lag)
    return sums / np.asarray(u).size


def cross_sums(u: ArrayLike, y: ArrayLike, max_lag: int) -> FloatArray:
    """Cross-correlation sums ``Σ_t u(t−k)·y(t)`` for ``k = −max_lag..max_lag`` (not ÷ ``N``).

    Parameters
    ----------
    u, y : array_like, shape (N,)
        Input and output (detrended).
    max_lag : int
        Largest absolute lag, samples (< N).

    Returns
    -------
    numpy.ndarray, shape (2·max_lag + 1,)
        The sums; :func:`cross_correlation` is they ÷ ``N``.
    """
    u_arr = np.asarray(u, dtype=np.float64)
    y_arr = np.asarray(y, dtype=np.float64)
    if u_arr.shape != y_arr.shape or u_arr.ndim != 1:
        raise InputDataError(
            f"input and output must be 1-D and equally long, got {u_arr.shape} and {y_arr.shape}"
        )
    n = u_arr.size
    _check_lags(n, max_lag)
    if _use_fft(n, max_lag):
        return _fft_cross(u_arr, y_arr)[n - 1 - max_lag : n + max_lag]
    return _direct_lags(u_arr, y_arr, -max_lag, max_lag)


def cross_correlation(u: ArrayLike, y: ArrayLike, max_lag: int) -> FloatArray:
    """Biased cross-correlation ``φ_uy(k) = (1/N)·Σ_t u(t−k)·y(t)`` for ``k = −max_lag..max_lag``.

    With this convention the Wiener–Hopf equations of a two-sided IRF ``h`` read
    ``Σ_j h(j)·φ_uu(k−j) = φ_uy(k)``.

    Parameters
    ----------
    u, y : array_like, shape (N,)
        Input and output (detrended).
    max_lag : int
        Largest absolute lag, samples (< N).

    Returns
    -------
    numpy.ndarray, shape (2·max_lag + 1,)
        ``φ_uy(−max_lag..max_lag)``.
    """
    sums = cross_sums(u, y, max_lag)
    return sums / np.asarray(u).size


def causal_cross_correlation(u: FloatArray, y: FloatArray, max_lag: int) -> FloatArray:
    """``cross_correlation(u, y, max_lag)[max_lag:]`` (lags ``0 … max_lag``, a one-sided
    IRF's right-hand side): the same numbers bit for bit, without forming the negative lags.

    Parameters
    ----------
    u, y : numpy.ndarray, shape (N,)
        Input and output (detrended, equally long).
    max_lag : int
        Largest lag, samples (< N).

    Returns
    -------
    numpy.ndarray, shape (max_lag + 1,)
    """
    n = u.size
    if u.shape != y.shape or u.ndim != 1 or _use_fft(n, max_lag):
        return cross_correlation(u, y, max_lag)[max_lag:]
    _check_lags(n, max_lag)
    u_arr, y_arr = np.asarray(u, dtype=np.float64), np.asarray(y, dtype=np.float64)
    return _direct_lags(u_arr, y_arr, 0, max_lag) / n


def lagged_gram(u: FloatArray, sums: FloatArray, max_lag: int) -> FloatArray:
    """The Gram matrix ``X'X`` of the lagged rows, from the whole-window sums.

    ``X`` has a row for each fully supported sample ``t = L … N−L−1`` and a column for each
    lag ``k = −L … L`` (``X[t, k] = u(t − k)``; ``L = max_lag``). Entry ``(i, j)`` sums
    ``u(s)·u(s + |j − i|)`` over the rows' span, which is the whole window's sum
    ``sums[|j − i|]`` less the products of the first and last ``2L`` samples the rows leave
    out: O(L²), where ``X.T @ X`` is O(N·L²).

    Parameters
    ----------
    u : numpy.ndarray, shape (N,)
        Input, N > 4L.
    sums : numpy.ndarray, shape (2L + 1,)
        :func:`auto_sums` of ``u`` up to lag 2L.
    max_lag : int
        ``L``, samples.

    Returns
    -------
    numpy.ndarray, shape (2L + 1, 2L + 1)
        ``X'X``, symmetric, input unit².
    """
    span = 2 * max_lag
    n = u.size
    lags = np.arange(span + 1)[:, None]
    ends = np.arange(span)[None, :]
    padded = np.concatenate((u, np.zeros(span)))
    # head[d, c]: the products u(s)·u(s + d) of s < c; tail[d, c]: those of s ≥ N − c.
    head = np.zeros((span + 1, span + 1))
    np.cumsum(u[:span][None, :] * u[ends + lags], axis=1, out=head[:, 1:])
    last = n - 1 - ends  # s = N − 1, N − 2, …, N − 2L
    tail = np.zeros((span + 1, span + 1))
    np.cumsum(padded[last] * padded[last + lags], axis=1, out=tail[:, 1:])
    i, j = np.triu_indices(span + 1)
    d = j - i
    gram = np.empty((span + 1, span + 1))
    gram[i, j] = sums[d] - head[d, span - j] - tail[d, j]
    gram[j, i] = gram[i, j]
    return gram


def lagged_cross(u: FloatArray, y: FloatArray, sums: FloatArray, max_lag: int) -> FloatArray:
    """``X'y`` of :func:`lagged_gram`'s rows against ``y(L … N−L−1)``, from the whole-window sums.

    Parameters
    ----------
    u, y : numpy.ndarray, shape (N,)
        Input and output, N > 4L.
    sums : numpy.ndarray, shape (2L + 1,)
        :func:`cross_sums` of ``u`` and ``y`` (lags ``−L … L``).
    max_lag : int
        ``L``, samples.

    Returns
    -------
    numpy.ndarray, shape (2L + 1,)
        ``Σ_t u(t − k)·y(t)`` over the rows for ``k = −L … L``: each whole-window sum less
        the products of the first and last ``2L`` samples the rows leave out.
    """
    span = 2 * max_lag
    n = u.size
    shifts = np.arange(-max_lag, max_lag + 1)[:, None]
    ends = np.arange(span)[None, :]
    padded = np.concatenate((np.zeros(max_lag), y, np.zeros(max_lag)))
    # rows of lag k = j − L leave out s < 2L − j and s ≥ N − j (y beyond the window is 0)
    head = u[:span][None, :] * padded[ends + shifts + max_lag]
    head_sum = np.where(ends < span - np.arange(span + 1)[:, None], head, 0.0).sum(axis=1)
    last = n - span + ends
    tail = u[last] * padded[last + shifts + max_lag]
    tail_sum = np.where(last >= n - np.arange(span + 1)[:, None], tail, 0.0).sum(axis=1)
    return np.asarray(sums - head_sum - tail_sum, dtype=np.float64)
