"""The legacy criteria, ``relative`` and ``logmag``: ``(I, B, K)`` fitted to the IRF.

Selected by ``EstimatorOptions.fit_method``; the default criterion is output error
(:mod:`rtsid.ident.fit`). Both fit the IRF's frequency response on a grid over the fit band
(:func:`fit_parameters`): ``relative`` in closed form, weighted by ``1/|Z|`` and by the
window's own excitation spectrum; ``logmag`` refines it on log magnitude (the source's
Nelder–Mead). Their standard errors are the IRF's sandwich covariance mapped through the
fit's sensitivity (:func:`standard_errors`). Nothing is held: all three are fitted.

The relative fit makes one call into the compiled kernel when it was built (``window_fit``)
and no sample was lost; :func:`numpy_back_end` otherwise, the reference it is tested against.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import InputDataError, NotPositiveDefiniteError, NumericalError
from rtsid.ident.analysis import AnalysisPlan, hann_periodogram, hann_taper
from rtsid.ident.assess import (
    TorquePredictions,
    WindowEstimate,
    assemble,
    predict_torque,
    published_vafs,
    supported_edge,
    three_vafs,
)
from rtsid.ident.correlation import auto_correlation
from rtsid.ident.gaps import WindowGaps
from rtsid.ident.irf import IRF
from rtsid.ident.levinson import compiled_kernel, eureka_unchecked
from rtsid.ident.options import EstimatorOptions
from rtsid.ident.second_order import (
    ParameterFit,
    fit_linear,
    fit_logmag,
    inseparable_fit,
    zero_response,
)

_eureka = compiled_kernel()

__all__ = ["fit_parameters", "legacy_back_end", "numpy_back_end", "standard_errors"]

FloatArray = NDArray[np.float64]


def legacy_back_end(
    irf: IRF,
    u: FloatArray,
    y: FloatArray,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    gaps: WindowGaps | None = None,
) -> WindowEstimate:
    """Steps 4–5 with the ``relative`` or ``logmag`` criterion: fit, VAFs, standard errors
    and flags of one window (all three parameters fitted).

    The relative fit makes one call into the compiled kernel when it was built and no
    sample was lost; :func:`numpy_back_end` otherwise (and for the log-magnitude fit), the
    reference it is tested against.
    """
    if _eureka is None or options.fit_method != "relative" or gaps is not None:
        return numpy_back_end(irf, u, y, options, plan, gaps)
    fs_a = irf.fs_hz
    band = plan.fit_band_hz
    grid_key = (*band, options.fit_points, fs_a / 2)
    u = np.ascontiguousarray(u, dtype=np.float64)
    params, sensitivity, out = np.empty(3), np.empty((3, irf.h.size)), np.empty(6)
    status = _eureka.window_fit(
        u,
        np.ascontiguousarray(y, dtype=np.float64),
        irf.h,
        irf.phi_uu,
        _stacked_dft(irf.max_lag, fs_a, grid_key),
        _fit_grid(band, options.fit_points, fs_a / 2),
        hann_taper(u.size),
        fs_a,
        options.weight_power,
        options.uncertainty,
        params,
        sensitivity,
        out,
    )
    _raise_for_fit_status(status)
    se_i, se_b, se_k, vaf_model, vaf_irf, vaf_fit = out.tolist()
    vafs = published_vafs(vaf_model, vaf_irf, vaf_fit)
    return assemble(irf, params, (se_i, se_b, se_k), vafs, "relative", options)


def numpy_back_end(
    irf: IRF,
    u: FloatArray,
    y: FloatArray,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    gaps: WindowGaps | None = None,
) -> WindowEstimate:
    """Steps 4–5 of the frequency-domain fits in numpy: :func:`fit_parameters`,
    :func:`~rtsid.ident.assess.predict_torque`, the VAFs and :func:`standard_errors`."""
    fit = fit_parameters(irf, u, options, plan)
    predictions = predict_torque(irf, u, y, fit.params, gaps)
    se = standard_errors(irf, u, predictions, fit) if options.uncertainty else np.full(3, np.nan)
    se_i, se_b, se_k = se.tolist()
    lost = 0 if gaps is None else gaps.lost
    return assemble(
        irf, fit.params, (se_i, se_b, se_k), three_vafs(predictions), fit.method, options, lost
    )


def fit_parameters(
    irf: IRF, u: FloatArray, options: EstimatorOptions, plan: AnalysisPlan
) -> ParameterFit:
    """Step 4 (frequency domain): ``(I, B, K)`` fitted to the IRF's response, weighted by
    the excitation (``relative``), then refined on log magnitude (``logmag``)."""
    fs_a = irf.fs_hz
    band = plan.fit_band_hz
    grid_key = (*band, options.fit_points, fs_a / 2)
    f = _fit_grid(band, options.fit_points, fs_a / 2)
    e = _dft(irf.max_lag, fs_a, grid_key)
    weights = _excitation_weights(u, fs_a, f, options.weight_power)
    fit = fit_linear(
        f, e, irf.h, weights=weights, stacked=_stacked_dft(irf.max_lag, fs_a, grid_key)
    )
    if options.fit_method == "logmag":
        fit = fit_logmag(f, e, irf.h, start=fit.params, weights=weights)
    return fit


def standard_errors(
    irf: IRF, u: FloatArray, predictions: TorquePredictions, fit: ParameterFit
) -> FloatArray:
    """Standard errors of ``(I, B, K)`` from the IRF's sandwich covariance."""
    edge = supported_edge(irf)
    inner_u = u[edge : u.size - edge]
    residual = predictions.measured - predictions.irf
    if predictions.rows is not None:
        residual = residual * predictions.rows
    cov = _parameter_covariance(irf, inner_u, residual, fit.sensitivity)
    return np.asarray(np.sqrt(np.clip(np.diag(cov), 0.0, None)), dtype=np.float64)


def _raise_for_fit_status(status: int) -> None:
    """The error for a ``window_fit`` status (the codes are the kernel's own constants)."""
    if status == _eureka.FIT_OK:
        return
    if status in (_eureka.FIT_FIRST_SINGULAR, _eureka.FIT_FINAL_SINGULAR):
        raise inseparable_fit()
    if status == _eureka.FIT_ZERO_RESPONSE:
        raise zero_response()
    if status == _eureka.FIT_NOT_PD:
        raise NotPositiveDefiniteError(
            "the input autocorrelation is not positive definite in the standard errors' "
            "Toeplitz solves: the perturbation has too little bandwidth for the lag span; "
            "shorten lag_s or widen the perturbation",
            step=-1,
        )
    raise NumericalError(f"window_fit returned the unknown status {status}")


@lru_cache(maxsize=32)
def _fit_grid(band: tuple[float, float], points: int, nyquist_hz: float) -> FloatArray:
    lo, hi = band
    if hi >= nyquist_hz:
        raise InputDataError(
            f"fit band up to {hi} Hz reaches the analysis Nyquist rate {nyquist_hz} Hz; "
            "lower fit_band_hz or raise analysis_fs_hz"
        )
    grid = np.linspace(max(lo, 1e-3), hi, points)
    grid.setflags(write=False)
    return grid


@lru_cache(maxsize=32)
def _stacked_dft(
    max_lag: int, fs_hz: float, grid_key: tuple[float, float, int, float]
) -> FloatArray:
    e = _dft(max_lag, fs_hz, grid_key)
    stacked = np.vstack((e.real, e.imag))
    stacked.setflags(write=False)
    return stacked


@lru_cache(maxsize=32)
def _dft(max_lag: int, fs_hz: float, grid_key: tuple[float, float, int, float]) -> NDArray[Any]:
    f = _fit_grid(grid_key[:2], grid_key[2], grid_key[3])
    lags = np.arange(-max_lag, max_lag + 1) / fs_hz
    e = np.exp(-2j * np.pi * np.multiply.outer(f, lags)) / fs_hz
    e.setflags(write=False)
    return e


_THIRDS = np.full(3, 1.0 / 3.0)


@lru_cache(maxsize=32)
def _bin_frequencies(n: int, fs_hz: float) -> FloatArray:
    bins = np.arange(n // 2 + 1, dtype=np.float64) * (fs_hz / n)
    bins.setflags(write=False)
    return bins


def _excitation_weights(u: FloatArray, fs_hz: float, f_hz: FloatArray, power: float) -> FloatArray:
    """``(S_uu(f) / max S_uu)^power`` on the fit grid, from the window's own periodogram.

    Frequencies the perturbation did not excite get (almost) no weight in the fit. The
    periodogram (Hann taper, FFT) is averaged over three neighbouring bins and interpolated
    onto the grid — no dense matrix products, so no BLAS threads on the hot path.
    """
    spectrum = hann_periodogram(u)
    smoothed = np.convolve(spectrum, _THIRDS, mode="same")
    on_grid = np.interp(f_hz, _bin_frequencies(u.size, fs_hz), smoothed)
    top = float(on_grid.max())
    return np.asarray((on_grid / top) ** power) if top > 0 else np.ones(f_hz.size)


@lru_cache(maxsize=8)
def _bartlett(lags: int) -> FloatArray:
    taper = 1.0 - np.arange(lags + 1) / (lags + 1)
    taper.setflags(write=False)
    return taper


@lru_cache(maxsize=8)
def _toeplitz_index(n: int) -> NDArray[np.intp]:
    """``|i − j|`` for an n × n symmetric Toeplitz matrix built by indexing."""
    index = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    index.setflags(write=False)
    return index


def _parameter_covariance(
    irf: IRF, u: FloatArray, residual: FloatArray, sensitivity: FloatArray
) -> FloatArray:
    """Sandwich covariance of ``(I, B, K)``: ``M·R⁻¹·C_φ·R⁻¹·Mᵀ / Δt²``.

    ``C_φ`` is the covariance of the cross-correlation estimate for noise with the
    residual's own autocorrelation: ``C_φ(j, k) = (1/N)·Σ_m φ_uu(m + j − k)·φ_ee(m)``.
    """
    n_h = irf.h.size
    noise_lags = min(n_h, residual.size - 1)
    # Bartlett taper: the truncated residual autocorrelation then has a non-negative
    # spectrum (Fejér-smoothed), so C_φ is positive semi-definite and no variance is < 0.
    phi_ee = auto_correlation(residual, noise_lags) * _bartlett(noise_lags)
    phi_uu = auto_correlation(u, n_h - 1 + noise_lags)
    ee = np.concatenate((phi_ee[:0:-1], phi_ee))
    uu = np.concatenate((phi_uu[noise_lags:0:-1], phi_uu))
    c = np.correlate(uu, ee, mode="valid")[:n_h] / u.size
    z = np.column_stack(
        [eureka_unchecked(irf.phi_uu, np.ascontiguousarray(row)) for row in sensitivity]
    )
    cov = (z.T @ c[_toeplitz_index(n_h)] @ z) * irf.fs_hz**2
    return np.asarray((cov + cov.T) / 2, dtype=np.float64)
