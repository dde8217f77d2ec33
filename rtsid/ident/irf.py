"""Two-sided impulse response by Wiener–Hopf deconvolution, solved with EUREKA.

For input ``u`` (joint angle) and output ``y`` (torque) sampled every ``Δt``, the IRF
``h(τ)``, ``τ = −L·Δt … L·Δt``, minimises the error of ``ŷ(t) = Σ_k h(k)·u(t−k)·Δt``;
its normal equations ``R_uu·h·Δt = φ_uy`` have a symmetric Toeplitz ``R_uu`` and are solved
by :func:`rtsid.ident.levinson.eureka`. Impedance is non-causal in sampled data (torque
depends on velocity and acceleration), so the IRF is two-sided.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike, NDArray

from rtsid.errors import InputDataError
from rtsid.ident.correlation import auto_sums, cross_sums, lagged_cross, lagged_gram
from rtsid.ident.levinson import eureka_unchecked

__all__ = ["IRF", "estimate_irf"]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


@lru_cache(maxsize=16)
def _lag_times(max_lag: int, fs_hz: float) -> FloatArray:
    lags = np.arange(-max_lag, max_lag + 1) / fs_hz
    lags.setflags(write=False)
    return lags


@dataclass(frozen=True)
class IRF:
    """An impulse response on a lag grid.

    Attributes
    ----------
    h : numpy.ndarray, shape (2L+1,)
        IRF values, output unit per input unit per second (N·m/rad/s for impedance).
    fs_hz : float
        Sampling rate of the lag grid, Hz.
    phi_uu : numpy.ndarray, shape (2L+1,)
        Input autocorrelation used (first column of ``R_uu``, ridge included).
    """

    h: FloatArray
    fs_hz: float
    phi_uu: FloatArray

    @property
    def max_lag(self) -> int:
        """``L``, samples."""
        return (self.h.size - 1) // 2

    @property
    def lags_s(self) -> FloatArray:
        """Lag of each IRF value, s (``−L·Δt … L·Δt``); read-only, shared between IRFs."""
        return _lag_times(self.max_lag, self.fs_hz)

    def dft_matrix(self, f_hz: ArrayLike) -> ComplexArray:
        """``E`` with ``E @ h`` the frequency response at ``f_hz``, shape (n_f, 2L+1)."""
        f = np.asarray(f_hz, dtype=np.float64)
        phase = -2j * np.pi * np.multiply.outer(f, self.lags_s)
        return np.asarray(np.exp(phase) / self.fs_hz, dtype=np.complex128)

    def frequency_response(self, f_hz: ArrayLike) -> ComplexArray:
        """``H(j2πf) = Σ_k h(k)·e^{−j2πf·τ_k}·Δt`` at ``f_hz``, output unit per input unit."""
        return self.dft_matrix(f_hz) @ self.h

    def predict(self, u: ArrayLike) -> FloatArray:
        """``ŷ(t) = Σ_k h(k)·u(t−k)·Δt``; only the first and last ``L`` samples lack support.

        Returns an array as long as ``u``; use ``[L:-L]`` for the fully supported part.
        """
        u_arr = np.asarray(u, dtype=np.float64)
        full = np.convolve(u_arr, self.h / self.fs_hz, mode="full")
        return full[self.max_lag : self.max_lag + u_arr.size]


def estimate_irf(
    u: ArrayLike,
    y: ArrayLike,
    fs_hz: float,
    max_lag: int,
    *,
    ridge: float = 0.0,
    refine: int = 0,
    rows: NDArray[np.bool_] | None = None,
) -> IRF:
    """Wiener–Hopf IRF from ``u`` to ``y`` over lags ``−max_lag..max_lag`` by EUREKA.

    Parameters
    ----------
    u, y : array_like, shape (N,)
        Input and output, detrended, same rate.
    fs_hz : float
        Sampling rate, Hz.
    max_lag : int
        ``L``, samples; the Toeplitz system has ``2L+1`` unknowns and needs ``N > 2L``.
    ridge : float
        Relative diagonal loading: ``λ = ridge·φ_uu(0)`` is added to the diagonal. A small
        value (1e-4…1e-2) keeps the recursion stable when the input has little power in
        part of the band, at the price of shrinking the IRF slightly there.
    refine : int
        Refinement sweeps. The Toeplitz system uses correlations of the whole window, as
        if the signals were zero outside it, which biases short windows by about ``L/N``.
        Each sweep adds ``R⁻¹·φ_ue`` — the cross-correlation of the input with the current
        prediction error over the fully supported samples, solved again by EUREKA — and
        converges to the exact (ridge-regularised) least-squares IRF on those samples.
    rows : numpy.ndarray of bool, shape (N − 2L,), optional
        The fully supported samples to fit (default all): a window with lost samples passes
        the rows whose lags hold none (:mod:`rtsid.ident.gaps`), with the lost samples' own
        values zeroed in ``u`` and ``y`` so that the correlations run over valid pairs only.

    Returns
    -------
    IRF
        The estimate with its lag grid.

    Raises
    ------
    NotPositiveDefiniteError
        The input has too little excitation for this many lags.
    InputDataError
        Bad shapes or a lag span that does not fit the window.
    """
    if ridge < 0:
        raise InputDataError(f"ridge must be >= 0, got {ridge}")
    if refine < 0:
        raise InputDataError(f"refine must be >= 0 sweeps, got {refine}")
    u_arr = np.asarray(u, dtype=np.float64)
    y_arr = np.asarray(y, dtype=np.float64)
    n_lags = 2 * max_lag + 1
    if u_arr.size <= 2 * n_lags:
        raise InputDataError(
            f"a window of {u_arr.size} samples cannot support a {n_lags}-lag IRF; "
            "lengthen the window or shorten the lag span"
        )
    if not (math.isfinite(u_arr.sum()) and math.isfinite(y_arr.sum())):
        raise InputDataError("IRF input or output contains NaN or inf; clean the window first")
    sums_uu = auto_sums(u_arr, 2 * max_lag)
    sums_uy = cross_sums(u_arr, y_arr, max_lag)
    phi_uu = sums_uu / u_arr.size
    loading = ridge * phi_uu[0]
    phi_uu[0] += loading
    h = eureka_unchecked(phi_uu, sums_uy / u_arr.size) * fs_hz
    if refine == 0:
        return IRF(h=h, fs_hz=float(fs_hz), phi_uu=phi_uu)
    gram, xy, rows_used = _normal_equations(u_arr, y_arr, max_lag, sums_uu, sums_uy, rows)
    for _ in range(refine):
        scaled = h / fs_hz
        gradient = (xy - gram @ scaled) / rows_used - loading * scaled
        h = h + eureka_unchecked(phi_uu, gradient) * fs_hz
    return IRF(h=h, fs_hz=float(fs_hz), phi_uu=phi_uu)


def _normal_equations(
    u: FloatArray,
    y: FloatArray,
    max_lag: int,
    sums_uu: FloatArray,
    sums_uy: FloatArray,
    rows: NDArray[np.bool_] | None,
) -> tuple[FloatArray, FloatArray, float]:
    """``X'X``, ``X'y`` and the row count of the refinement's least-squares problem.

    ``X``'s rows are the fully supported samples ``t = L … N−L−1`` (``rows`` of them when
    given), its columns ``u(t − k)`` for ``k = −L … L``. A refinement sweep's gradient, the
    correlation of the input with the prediction error over those rows, is
    ``X'y − X'X·h/fs``: both matrices come from the whole-window correlation sums
    (:func:`rtsid.ident.correlation.lagged_gram`, O(L²)), less the left-out rows' own products
    when ``rows`` leaves some out; a sweep then costs O(L²) instead of O(N·L).
    """
    gram = lagged_gram(u, sums_uu, max_lag)
    xy = lagged_cross(u, y, sums_uy, max_lag)
    inner = u.size - 2 * max_lag
    if rows is None or rows.all():
        return gram, xy, float(inner)
    # Rows: fully supported samples t = L … N−L−1; columns: u(t − k) for k = −L … L.
    left_out = np.flatnonzero(~rows)
    lagged = sliding_window_view(u, 2 * max_lag + 1)[left_out, ::-1]
    gram = gram - lagged.T @ lagged
    xy = xy - lagged.T @ y[max_lag + left_out]
    return gram, xy, float(inner - left_out.size)
