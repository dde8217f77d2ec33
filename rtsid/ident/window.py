"""One window in, one impedance estimate out: ``estimate_window``.

Pipeline (each stage is a pure function of the previous one):

1. check the window (finite, long enough, excited) — or raise :class:`WindowError` with a
   reason, so a bad window is withheld, never estimated;
2. apply the torque sign, remove a linear trend from both signals;
3. low-pass both signals with the same zero-phase FIR and decimate to the analysis rate;
4. two-sided IRF by Wiener–Hopf deconvolution solved with EUREKA;
5. ``(I, B, K)`` fitted to the IRF's frequency response in the fit band;
6. VAF of the IRF's and of the parametric model's torque prediction, and between the two;
7. standard errors of ``(I, B, K)`` propagated from the IRF's covariance (sandwich
   estimate with the residual's own autocorrelation).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rtsid.config import invalid, require_choice, require_range
from rtsid.errors import InputDataError, NumericalError, WindowError
from rtsid.ident.correlation import auto_correlation, detrend
from rtsid.ident.filters import (
    decimation_factor,
    lowpass_decimate,
    lowpass_taps,
    stencil_derivatives,
)
from rtsid.ident.irf import IRF, estimate_irf
from rtsid.ident.levinson import compiled_kernel, eureka_unchecked, not_positive_definite
from rtsid.ident.second_order import (
    ParameterFit,
    fit_linear,
    fit_logmag,
    inseparable_fit,
    zero_response,
)

_eureka = compiled_kernel()

__all__ = [
    "EstimatorOptions",
    "WindowEstimate",
    "WindowResult",
    "estimate_window",
    "sliding_estimates",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class EstimatorOptions:
    """Options of :func:`estimate_window` (the ``[estimator]`` config section).

    The defaults suit a 300 ms window at 2500 Hz on a human ankle
    (I ≈ 0.01–0.03 kg·m², B ≈ 0.3–2 N·m·s/rad, K ≈ 30–400 N·m/rad) perturbed with
    ≥ 40 Hz of bandwidth.

    Attributes
    ----------
    lag_s : float
        IRF lag span: lags ``−lag_s … +lag_s``.
    lowpass_hz : float or None
        Zero-phase low-pass applied to both signals (the source used 100 Hz on the output).
    analysis_fs_hz : float or None
        Decimate to about this rate before correlating (None: keep the input rate).
    ridge : float
        Relative diagonal loading of ``R_uu`` (stabilises the recursion where the
        perturbation has little power).
    refine : int
        Refinement sweeps removing the Toeplitz approximation's edge bias
        (see :func:`rtsid.ident.irf.estimate_irf`).
    fit_method : {"linear", "logmag"}
        Closed-form weighted linear fit, or the source's log-magnitude Nelder–Mead.
    fit_band_hz : (float, float)
        Frequencies used by the fit; keep them inside the perturbation's band.
    fit_points : int
        Frequencies in the fit grid.
    torque_sign : float
        +1, or −1 for rigs that report torque inverted.
    detrend : {"linear", "mean", "none"}
        Trend removed from both signals.
    uncertainty : bool
        Compute standard errors (adds a few Toeplitz solves).
    min_excitation_rad : float
        Windows whose position standard deviation is below this are withheld
        (``reason="no_excitation"``).
    """

    lag_s: float = 0.02
    lowpass_hz: float | None = 100.0
    analysis_fs_hz: float | None = 500.0
    ridge: float = 1e-3
    refine: int = 3
    fit_method: str = "linear"
    fit_band_hz: tuple[float, float] = (1.0, 80.0)
    fit_points: int = 30
    weight_power: float = 0.5
    torque_sign: float = 1.0
    detrend: str = "linear"
    uncertainty: bool = True
    min_excitation_rad: float = 1e-5

    def __post_init__(self) -> None:
        require_range("lag_s", self.lag_s, 0.0, low_inclusive=False)
        if self.lowpass_hz is not None:
            require_range("lowpass_hz", self.lowpass_hz, 0.0, low_inclusive=False)
        if self.analysis_fs_hz is not None:
            require_range("analysis_fs_hz", self.analysis_fs_hz, 0.0, low_inclusive=False)
        require_range("ridge", self.ridge, 0.0)
        require_range("refine", self.refine, 0)
        require_choice("fit_method", self.fit_method, ("linear", "logmag"))
        require_choice("torque_sign", self.torque_sign, (1.0, -1.0))
        require_choice("detrend", self.detrend, ("linear", "mean", "none"))
        require_range("fit_points", self.fit_points, 3)
        require_range("min_excitation_rad", self.min_excitation_rad, 0.0)
        lo, hi = self.fit_band_hz
        if not 0 <= lo < hi:
            raise invalid("fit_band_hz", self.fit_band_hz, "(low, high) with 0 <= low < high")
        if self.lowpass_hz is not None and hi > self.lowpass_hz:
            raise invalid(
                "fit_band_hz", self.fit_band_hz, f"a band below lowpass_hz = {self.lowpass_hz} Hz"
            )


@dataclass(frozen=True)
class WindowEstimate:
    """Impedance of one window.

    Attributes
    ----------
    I, B, K : float
        Inertia kg·m², damping N·m·s/rad, stiffness N·m/rad.
    I_se, B_se, K_se : float
        Standard errors (NaN when not computed).
    vaf : float
        Percent of torque variance accounted for by the parametric model's prediction.
    vaf_irf : float
        Percent accounted for by the IRF's prediction.
    vaf_fit : float
        Percent of the IRF's predicted torque accounted for by the parametric model.
    irf : numpy.ndarray, shape (2L+1,)
        IRF values, N·m/rad/s.
    lags_s : numpy.ndarray, shape (2L+1,)
        IRF lags, s.
    fs_hz : float
        Analysis rate of the IRF, Hz.
    flags : tuple of str
        Warnings that do not withhold the estimate: ``"negative_stiffness"``,
        ``"negative_damping"``, ``"negative_inertia"``, ``"inertia_uncertain"`` (SE > 25 %),
        ``"stiffness_uncertain"`` (SE > 10 %), ``"model_mismatch"`` (the second-order model
        explains < 50 % of the IRF's prediction: the joint or rig is not second-order in the
        analysed band — lower ``lowpass_hz`` and ``fit_band_hz``).
    method : str
        Fit method used.
    """

    I: float  # noqa: E741 - the physical symbol
    B: float
    K: float
    I_se: float
    B_se: float
    K_se: float
    vaf: float
    vaf_irf: float
    vaf_fit: float
    irf: FloatArray = field(repr=False)
    lags_s: FloatArray = field(repr=False)
    fs_hz: float
    flags: tuple[str, ...]
    method: str

    def as_dict(self) -> dict[str, Any]:
        """The scalar fields, JSON-friendly (NaN becomes None)."""
        out: dict[str, Any] = {}
        for key in ("I", "B", "K", "I_se", "B_se", "K_se", "vaf", "vaf_irf", "vaf_fit"):
            value = float(getattr(self, key))
            out[key] = value if np.isfinite(value) else None
        out["flags"] = list(self.flags)
        out["method"] = self.method
        return out


def _check_window(position: FloatArray, torque: FloatArray, options: EstimatorOptions) -> None:
    if position.ndim != 1 or position.shape != torque.shape:
        raise InputDataError(
            f"position and torque must be 1-D and equally long, got {position.shape} and "
            f"{torque.shape}"
        )
    # One pass each: a sum is finite only if every term is (rad and N·m never overflow).
    if not (math.isfinite(position.sum()) and math.isfinite(torque.sum())):
        raise WindowError("window contains NaN or inf samples; it is withheld", "nan")
    mean = position.sum() / position.size
    variance = max(0.0, float(position @ position) / position.size - mean * mean)
    if math.sqrt(variance) < options.min_excitation_rad:
        raise WindowError(
            f"position varies by less than {options.min_excitation_rad} rad in this window: "
            "no perturbation, nothing to identify (is the perturbation enabled?)",
            "no_excitation",
        )


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


def _preprocess(
    position: FloatArray, torque: FloatArray, fs_hz: float, options: EstimatorOptions
) -> tuple[FloatArray, FloatArray, float]:
    factor = decimation_factor(fs_hz, options.analysis_fs_hz)
    u = detrend(position, options.detrend)
    y = detrend(torque * options.torque_sign, options.detrend)
    u = lowpass_decimate(u, fs_hz, options.lowpass_hz, factor)
    y = lowpass_decimate(y, fs_hz, options.lowpass_hz, factor)
    return u, y, fs_hz / factor


_THIRDS = np.full(3, 1.0 / 3.0)


@lru_cache(maxsize=32)
def _bin_frequencies(n: int, fs_hz: float) -> FloatArray:
    bins = np.arange(n // 2 + 1, dtype=np.float64) * (fs_hz / n)
    bins.setflags(write=False)
    return bins


@lru_cache(maxsize=32)
def _hann(n: int) -> FloatArray:
    window = np.hanning(n)
    window.setflags(write=False)
    return window


def _excitation_weights(u: FloatArray, fs_hz: float, f_hz: FloatArray, power: float) -> FloatArray:
    """``(S_uu(f) / max S_uu)^power`` on the fit grid, from the window's own periodogram.

    Frequencies the perturbation did not excite get (almost) no weight in the fit. The
    periodogram (Hann taper, FFT) is averaged over three neighbouring bins and interpolated
    onto the grid — no dense matrix products, so no BLAS threads on the hot path.
    """
    spectrum = np.abs(np.fft.rfft(u * _hann(u.size))) ** 2
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


def _flags(
    params: tuple[float, float, float], se: tuple[float, float, float], vaf_fit: float
) -> tuple[str, ...]:
    inertia, damping, stiffness = params
    flags = []
    if vaf_fit < 50.0:
        flags.append("model_mismatch")
    if stiffness <= 0:
        flags.append("negative_stiffness")
    if damping <= 0:
        flags.append("negative_damping")
    if inertia <= 0:
        flags.append("negative_inertia")
    if math.isfinite(se[0]) and se[0] > 0.25 * abs(inertia):
        flags.append("inertia_uncertain")
    if math.isfinite(se[2]) and se[2] > 0.1 * abs(stiffness):
        flags.append("stiffness_uncertain")
    return tuple(flags)


def estimate_window(
    position: ArrayLike,
    torque: ArrayLike,
    fs: float,
    options: EstimatorOptions | None = None,
    **overrides: Any,
) -> WindowEstimate:
    """Identify joint impedance ``(I, B, K)`` from one window of position and torque.

    Parameters
    ----------
    position : array_like, shape (n,)
        Joint angle, rad.
    torque : array_like, shape (n,)
        Joint torque, N·m.
    fs : float
        Sampling rate, Hz.
    options : EstimatorOptions, optional
        Estimator settings; keyword ``overrides`` replace single fields
        (``estimate_window(p, t, 2500, torque_sign=-1)``).

    Returns
    -------
    WindowEstimate
        Parameters, standard errors, VAFs, the IRF and flags.

    Raises
    ------
    WindowError
        The window must not be estimated: ``reason`` is ``"nan"``, ``"too_short"`` or
        ``"no_excitation"``.
    NotPositiveDefiniteError
        The perturbation does not excite enough bandwidth for the lag span.
    InputDataError
        Inconsistent shapes or options.

    Examples
    --------
    >>> import numpy as np
    >>> from rtsid.ident.excitation import filtered_noise
    >>> from rtsid.sim import JointParameters, simulate_impedance
    >>> theta = filtered_noise(750, 2500.0, 60.0, peak=0.03, seed=1)
    >>> tau = simulate_impedance(theta, 2500.0, JointParameters(0.015, 0.8, 150.0))
    >>> est = estimate_window(theta, tau, 2500.0)
    >>> round(est.K), round(est.B, 1)
    (150, 0.8)
    """
    options = options or EstimatorOptions()
    if overrides:
        options = replace(options, **overrides)
    u, y, irf = front_end(position, torque, fs, options)
    return back_end(irf, u, y, options)


def back_end(irf: IRF, u: FloatArray, y: FloatArray, options: EstimatorOptions) -> WindowEstimate:
    """Stages 5–7: fit, VAFs and standard errors of one window's IRF.

    One call into the compiled kernel for the linear fit when it was built;
    :func:`numpy_back_end` otherwise (and for the log-magnitude fit), the reference it is
    tested against.
    """
    if _eureka is None or options.fit_method != "linear":
        return numpy_back_end(irf, u, y, options)
    fs_a = irf.fs_hz
    grid_key = (*options.fit_band_hz, options.fit_points, fs_a / 2)
    u = np.ascontiguousarray(u, dtype=np.float64)
    params, sensitivity, out = np.empty(3), np.empty((3, irf.h.size)), np.empty(6)
    status = _eureka.window_fit(
        u,
        np.ascontiguousarray(y, dtype=np.float64),
        irf.h,
        irf.phi_uu,
        _stacked_dft(irf.max_lag, fs_a, grid_key),
        _fit_grid(options.fit_band_hz, options.fit_points, fs_a / 2),
        _hann(u.size),
        fs_a,
        options.weight_power,
        options.uncertainty,
        params,
        sensitivity,
        out,
    )
    if status in (_FIRST_FIT_SINGULAR, _FINAL_FIT_SINGULAR):
        raise inseparable_fit()
    if status == _ZERO_RESPONSE:
        raise zero_response()
    if status >= 0:
        raise not_positive_definite(status, float("nan"))
    se_i, se_b, se_k, vaf, vaf_irf, vaf_fit = out.tolist()
    fit = ParameterFit(params=params, sensitivity=sensitivity, method="linear")
    vafs = (round(vaf, 12), round(vaf_irf, 12), round(vaf_fit, 12))
    return _assemble(irf, fit, (se_i, se_b, se_k), vafs)


# window_fit's status codes (see _eureka.c)
_FIRST_FIT_SINGULAR, _FINAL_FIT_SINGULAR, _ZERO_RESPONSE = 1, 2, 4


def numpy_back_end(
    irf: IRF, u: FloatArray, y: FloatArray, options: EstimatorOptions
) -> WindowEstimate:
    """Stages 5–7 in numpy: :func:`fit_parameters`, :func:`predict_torque`, the VAFs and
    :func:`standard_errors`."""
    fit = fit_parameters(irf, u, options)
    predictions = predict_torque(irf, u, y, fit)
    se = standard_errors(irf, u, predictions, fit) if options.uncertainty else np.full(3, np.nan)
    se_i, se_b, se_k = se.tolist()
    return _assemble(irf, fit, (se_i, se_b, se_k), _three_vafs(predictions))


_DETREND_CODES = {"none": 0, "mean": 1, "linear": 2}
_NO_FILTER = np.ones(1)


def front_end(
    position: ArrayLike, torque: ArrayLike, fs: float, options: EstimatorOptions
) -> tuple[FloatArray, FloatArray, IRF]:
    """Stages 1–4: the analysis-rate signals ``(u, y)`` and the refined IRF.

    One call into the compiled kernel when it was built (detrend, FIR decimation,
    correlations, EUREKA and refinement in C); otherwise :func:`prepare_window` and
    :func:`rtsid.ident.irf.estimate_irf` in numpy, the reference it is tested against.
    """
    if _eureka is None:
        u, y, fs_a = prepare_window(position, torque, fs, options)
        max_lag = max(1, round(options.lag_s * fs_a))
        return u, y, estimate_irf(u, y, fs_a, max_lag, ridge=options.ridge, refine=options.refine)
    pos = np.ascontiguousarray(position, dtype=np.float64)
    tor = np.ascontiguousarray(torque, dtype=np.float64)
    _check_window(pos, tor, options)
    fs = float(fs)
    factor = decimation_factor(fs, options.analysis_fs_hz)
    if options.lowpass_hz is None and factor != 1:
        raise InputDataError("decimation needs a low-pass cut-off to avoid aliasing")
    try:
        taps = (
            _NO_FILTER
            if options.lowpass_hz is None
            else lowpass_taps(fs, float(options.lowpass_hz), factor)
        )
    except InputDataError as exc:
        raise WindowError(str(exc), "too_short") from None
    fs_a = fs / factor
    max_lag = max(1, round(options.lag_s * fs_a))
    m = (pos.size - taps.size) // factor + 1 if pos.size >= taps.size else 0
    _check_analysis_length(m, fs_a, max_lag)
    u, y = np.empty(m), np.empty(m)
    h, phi = np.empty(2 * max_lag + 1), np.empty(2 * max_lag + 1)
    status, alpha = _eureka.window_irf(
        pos,
        tor,
        taps,
        factor,
        options.torque_sign,
        _DETREND_CODES[options.detrend],
        max_lag,
        options.refine,
        options.ridge,
        fs_a,
        u,
        y,
        h,
        phi,
    )
    if status >= 0:
        raise not_positive_definite(status, alpha)
    return u, y, IRF(h=h, fs_hz=fs_a, phi_uu=phi)


def _check_analysis_length(m: int, fs_a: float, max_lag: int) -> None:
    if m <= 4 * max_lag + 1:
        raise WindowError(
            f"window gives {m} samples at {fs_a:g} Hz, too few for a ±{max_lag}-lag IRF; "
            "lengthen the window or shorten lag_s",
            "too_short",
        )


def prepare_window(
    position: ArrayLike, torque: ArrayLike, fs: float, options: EstimatorOptions
) -> tuple[FloatArray, FloatArray, float]:
    """Stage 1–3: check, sign, detrend, low-pass and decimate; ``(u, y, analysis_fs_hz)``."""
    pos = np.asarray(position, dtype=np.float64)
    tor = np.asarray(torque, dtype=np.float64)
    _check_window(pos, tor, options)
    try:
        u, y, fs_a = _preprocess(pos, tor, float(fs), options)
    except InputDataError as exc:
        raise WindowError(str(exc), "too_short") from None
    _check_analysis_length(u.size, fs_a, max(1, round(options.lag_s * fs_a)))
    return u, y, fs_a


def fit_parameters(irf: IRF, u: FloatArray, options: EstimatorOptions) -> ParameterFit:
    """Stage 5: ``(I, B, K)`` fitted to the IRF's response, weighted by the excitation."""
    fs_a = irf.fs_hz
    grid_key = (*options.fit_band_hz, options.fit_points, fs_a / 2)
    f = _fit_grid(options.fit_band_hz, options.fit_points, fs_a / 2)
    e = _dft(irf.max_lag, fs_a, grid_key)
    weights = _excitation_weights(u, fs_a, f, options.weight_power)
    fit = fit_linear(
        f, e, irf.h, weights=weights, stacked=_stacked_dft(irf.max_lag, fs_a, grid_key)
    )
    if options.fit_method == "logmag":
        fit = fit_logmag(f, e, irf.h, start=fit.params, weights=weights)
    return fit


@dataclass(frozen=True)
class TorquePredictions:
    """Measured and predicted torque over the fully supported samples (N·m)."""

    measured: FloatArray
    irf: FloatArray
    model: FloatArray


def predict_torque(irf: IRF, u: FloatArray, y: FloatArray, fit: ParameterFit) -> TorquePredictions:
    """Stage 6: torque predicted by the IRF and by the parametric model."""
    edge = _supported_edge(irf)
    inertia, damping, stiffness = fit.params
    d1, d2 = stencil_derivatives(u, irf.fs_hz)
    model_torque = inertia * d2 + damping * d1 + stiffness * u[4:-4]  # samples 4 … n−5
    inner = slice(edge, u.size - edge)
    return TorquePredictions(
        measured=y[inner],
        irf=irf.predict(u)[inner],
        model=model_torque[edge - 4 : u.size - edge - 4],
    )


def _supported_edge(irf: IRF) -> int:
    """Samples at each end without full support for the IRF (``L``) or the 9-point
    derivative stencils (4): predictions and residuals skip them."""
    return max(irf.max_lag, 4)


def standard_errors(
    irf: IRF, u: FloatArray, predictions: TorquePredictions, fit: ParameterFit
) -> FloatArray:
    """Stage 7: standard errors of ``(I, B, K)`` from the IRF's sandwich covariance."""
    edge = _supported_edge(irf)
    inner_u = u[edge : u.size - edge]
    residual = predictions.measured - predictions.irf
    cov = _parameter_covariance(irf, inner_u, residual, fit.sensitivity)
    return np.asarray(np.sqrt(np.clip(np.diag(cov), 0.0, None)), dtype=np.float64)


def _three_vafs(p: TorquePredictions) -> tuple[float, float, float]:
    """VAF of the model and of the IRF against the measurement, and of the model against
    the IRF — :func:`rtsid.ident.vaf.vaf` three times, sharing the centred signals."""
    n = p.measured.size
    measured = p.measured - p.measured.sum() / n
    irf = p.irf - p.irf.sum() / n
    model = p.model - p.model.sum() / n

    def percent(target: FloatArray, error: FloatArray) -> float:
        total = float(target @ target)
        return 0.0 if total <= 0 else round(max(0.0, 1.0 - float(error @ error) / total) * 100, 12)

    return (
        percent(measured, measured - model),
        percent(measured, measured - irf),
        percent(irf, irf - model),
    )


def _assemble(
    irf: IRF,
    fit: ParameterFit,
    se: tuple[float, float, float],
    vafs: tuple[float, float, float],
) -> WindowEstimate:
    inertia, damping, stiffness = fit.params.tolist()
    vaf_model, vaf_irf, vaf_fit = vafs
    return WindowEstimate(
        I=inertia,
        B=damping,
        K=stiffness,
        I_se=se[0],
        B_se=se[1],
        K_se=se[2],
        vaf=vaf_model,
        vaf_irf=vaf_irf,
        vaf_fit=vaf_fit,
        irf=irf.h,
        lags_s=irf.lags_s,
        fs_hz=irf.fs_hz,
        flags=_flags((inertia, damping, stiffness), se, vaf_fit),
        method=fit.method,
    )


@dataclass(frozen=True)
class WindowResult:
    """One slide of :func:`sliding_estimates`: an estimate, or the reason it was withheld.

    Attributes
    ----------
    start : int
        Index of the window's first sample.
    stop : int
        One past the window's last sample.
    t_end_s : float
        Time of the window's last sample, s (sample time, first sample at 0).
    estimate : WindowEstimate or None
        The estimate; None when withheld.
    reason : str or None
        Why it was withheld (``"nan"``, ``"no_excitation"``, ``"numerical"``, …).
    """

    start: int
    stop: int
    t_end_s: float
    estimate: WindowEstimate | None
    reason: str | None


def sliding_estimates(
    position: ArrayLike,
    torque: ArrayLike,
    fs: float,
    window_s: float = 0.3,
    hop_s: float = 0.1,
    options: EstimatorOptions | None = None,
) -> Iterator[WindowResult]:
    """Estimate every window of ``window_s`` seconds, ``hop_s`` apart, oldest first.

    Windows that must not be estimated (NaN, no excitation, numerically unsound) are
    yielded with their reason instead of an estimate, so the caller sees every window.

    Parameters
    ----------
    position, torque : array_like, shape (n,)
        Joint angle (rad) and torque (N·m).
    fs : float
        Sampling rate, Hz.
    window_s, hop_s : float
        Window length and hop, s.
    options : EstimatorOptions, optional
        Estimator settings.

    Yields
    ------
    WindowResult
        One per window.
    """
    pos = np.asarray(position, dtype=np.float64)
    tor = np.asarray(torque, dtype=np.float64)
    n_win = round(window_s * fs)
    n_hop = round(hop_s * fs)
    if n_win < 2 or n_hop < 1:
        raise InputDataError(
            f"window_s={window_s} and hop_s={hop_s} at {fs:g} Hz give {n_win}-sample windows "
            f"every {n_hop} samples; both must be at least one sample"
        )
    if n_win > pos.size:
        raise InputDataError(
            f"the record has {pos.size} samples ({pos.size / fs:g} s), shorter than one "
            f"{window_s} s window; use a shorter --window"
        )
    for start in range(0, pos.size - n_win + 1, n_hop):
        stop = start + n_win
        t_end = (stop - 1) / fs
        try:
            est = estimate_window(pos[start:stop], tor[start:stop], fs, options)
        except WindowError as exc:
            yield WindowResult(start, stop, t_end, None, exc.reason)
        except NumericalError:
            yield WindowResult(start, stop, t_end, None, "numerical")
        else:
            yield WindowResult(start, stop, t_end, est, None)
