"""One window in, one impedance estimate out: ``estimate_window``.

Pipeline (each stage is a pure function of the previous one):

1. check the window (finite, long enough, excited) — or raise :class:`WindowError` with a
   reason, so a bad window is withheld, never estimated;
2. plan the analysis from the perturbation's spectrum (:mod:`rtsid.ident.analysis`), unless
   the caller passes a stream's plan or explicit options;
3. apply the torque sign, remove a linear trend from both signals, band-limit both with the
   same zero-phase FIR and decimate to the analysis rate;
4. two-sided IRF by Wiener–Hopf deconvolution solved with EUREKA (the nonparametric core:
   ``vaf_irf`` and the model check ``vaf_fit``);
5. ``(I, B, K)`` by the output-error fit (default), or fitted to the IRF's frequency
   response (``relative``, ``logmag``); inertia (and damping) optionally held at a value
   learned over a longer horizon (:class:`rtsid.ident.timescales.HeldParameters`);
6. VAF of the model's torque prediction against the band-limited measured torque, of the
   IRF's, and between the two;
7. standard errors (sandwich estimates with the residual's own autocorrelation) and flags.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rtsid.errors import (
    InputDataError,
    NotPositiveDefiniteError,
    NumericalError,
    WindowError,
    invalid,
    require_choice,
    require_range,
)
from rtsid.ident.analysis import AnalysisPlan, hann_periodogram, hann_taper, plan_analysis
from rtsid.ident.correlation import auto_correlation, detrend
from rtsid.ident.filters import stencil_derivatives
from rtsid.ident.gaps import LostSamples, clean_rows, contaminated, count_lost, require_rows
from rtsid.ident.irf import IRF, estimate_irf
from rtsid.ident.levinson import compiled_kernel, eureka_unchecked, not_positive_definite
from rtsid.ident.second_order import (
    OutputErrorDesign,
    ParameterFit,
    fit_linear,
    fit_logmag,
    inseparable_fit,
    zero_response,
)
from rtsid.ident.vaf import vaf
from rtsid.verdicts import Flag, Reason

_eureka = compiled_kernel()

__all__ = [
    "EstimatorOptions",
    "WindowEstimate",
    "estimate_window",
]

FloatArray = NDArray[np.float64]


FIT_METHODS = ("output_error", "relative", "logmag")
HOLD_CHOICES = ("none", "inertia", "inertia_damping")


@dataclass(frozen=True)
class EstimatorOptions:
    """Options of :func:`estimate_window` (the ``[estimator]`` config section).

    The defaults need no preset: the analysis is planned from the perturbation's spectrum
    (:mod:`rtsid.ident.analysis`), so a 1 kHz PRBS recording and a 2500 Hz robot with a
    40 Hz band both work as they are. Set a value to override the choice.

    Attributes
    ----------
    lag_s : float
        IRF lag span: lags ``−lag_s … +lag_s``.
    lowpass_hz : float or None
        −6 dB cut-off of the band-limiting FIR applied to both signals, Hz
        (None: 1.5 × the perturbation's band edge).
    analysis_fs_hz : float or None
        Decimate to about this rate (None: at least 10 × the cut-off).
    ridge : float
        Relative diagonal loading of ``R_uu`` (stabilises the recursion where the
        perturbation has little power).
    refine : int
        Refinement sweeps removing the Toeplitz approximation's edge bias
        (see :func:`rtsid.ident.irf.estimate_irf`).
    fit_method : {"output_error", "relative", "logmag"}
        Output error (minimum torque prediction error; default), the closed-form fit of the
        IRF's response weighted by ``1/|Z|``, or the source's log-magnitude Nelder–Mead.
    fit_band_hz : (float, float) or None
        Frequencies of the relative and log-magnitude fits (None: 1 Hz to the cut-off).
    fit_points : int
        Frequencies in their grid.
    weight_power : float
        Their weights: the input's amplitude spectrum to this power.
    torque_sign : float
        +1, or −1 for rigs that report torque inverted.
    detrend : {"linear", "mean", "none"}
        Trend removed from both signals before filtering (the output-error fit also carries
        an offset and a trend as nuisance terms, so what is left cannot bias it).
    uncertainty : bool
        Compute standard errors.
    min_excitation_rad : float
        Windows whose position standard deviation is below this are withheld
        (``reason="no_excitation"``).
    min_relative_excitation : float
        In a stream of windows (:class:`~rtsid.ident.stream.WindowStream`), a window whose
        band-limited position varies by less than this fraction of the median of the last
        ``hold_horizon_s`` of windows is withheld too (``reason="no_excitation"``): the
        perturbation paused, and what the torque does then says nothing about stiffness
        (0: no such check).
    max_lost_percent : float
        A window may have up to this share of lost samples, bridged by sums over valid
        samples only (:mod:`rtsid.ident.gaps`); more withholds it (``reason="gap"``).
    max_gap_s : float
        Longest run of lost samples that is bridged, s.
    hold : {"none", "inertia", "inertia_damping"}
        Parameters held at a value learned over ``hold_horizon_s`` (or at ``hold_inertia``)
        instead of fitted per window; K always stays per window. Streams (the worker,
        ``rtsid identify``, replay) learn the value; a lone ``estimate_window`` call holds
        only what it is given.
    hold_horizon_s : float
        Horizon of the learned values (median of the full fits over the last this many
        seconds of windows).
    hold_inertia : float or None
        A fixed inertia to hold, kg·m² (e.g. from a calibration); None: learned.
    low_vaf_percent : float
        An estimate whose ``vaf`` is below this carries the ``low_vaf`` flag.
    """

    lag_s: float = 0.02
    lowpass_hz: float | None = None
    analysis_fs_hz: float | None = None
    ridge: float = 1e-3
    refine: int = 3
    fit_method: str = "output_error"
    fit_band_hz: tuple[float, float] | None = None
    fit_points: int = 30
    weight_power: float = 0.5
    torque_sign: float = 1.0
    detrend: str = "linear"
    uncertainty: bool = True
    min_excitation_rad: float = 1e-5
    min_relative_excitation: float = 0.1
    max_lost_percent: float = 2.0
    max_gap_s: float = 0.004
    hold: str = "inertia_damping"
    hold_horizon_s: float = 20.0
    hold_inertia: float | None = None
    low_vaf_percent: float = 50.0

    def __post_init__(self) -> None:
        if self.fit_method == "linear":  # the name before output error (recordings keep it)
            object.__setattr__(self, "fit_method", "relative")
        require_range("lag_s", self.lag_s, 0.0, low_inclusive=False)
        if self.lowpass_hz is not None:
            require_range("lowpass_hz", self.lowpass_hz, 0.0, low_inclusive=False)
        if self.analysis_fs_hz is not None:
            require_range("analysis_fs_hz", self.analysis_fs_hz, 0.0, low_inclusive=False)
        require_range("ridge", self.ridge, 0.0)
        require_range("refine", self.refine, 0)
        require_choice("fit_method", self.fit_method, FIT_METHODS)
        require_choice("torque_sign", self.torque_sign, (1.0, -1.0))
        require_choice("detrend", self.detrend, ("linear", "mean", "none"))
        require_choice("hold", self.hold, HOLD_CHOICES)
        require_range("hold_horizon_s", self.hold_horizon_s, 0.0, 3600.0, low_inclusive=False)
        if self.hold_inertia is not None:
            require_range("hold_inertia", self.hold_inertia, 0.0, low_inclusive=False)
            if self.hold == "none":
                raise invalid(
                    "hold_inertia",
                    self.hold_inertia,
                    "no value while hold = 'none' (set hold = 'inertia' to hold it)",
                )
        require_range("low_vaf_percent", self.low_vaf_percent, 0.0, 100.0)
        require_range("fit_points", self.fit_points, 3)
        require_range("min_excitation_rad", self.min_excitation_rad, 0.0)
        require_range("min_relative_excitation", self.min_relative_excitation, 0.0, 1.0)
        require_range("max_lost_percent", self.max_lost_percent, 0.0, 100.0)
        require_range("max_gap_s", self.max_gap_s, 0.0, 1.0)
        if self.fit_band_hz is not None:
            object.__setattr__(self, "fit_band_hz", tuple(self.fit_band_hz))
            self._check_fit_band(self.fit_band_hz)

    def _check_fit_band(self, band: tuple[float, float]) -> None:
        lo, hi = band
        if not 0 <= lo < hi:
            raise invalid("fit_band_hz", band, "(low, high) with 0 <= low < high")
        if self.lowpass_hz is not None and hi > self.lowpass_hz:
            raise invalid("fit_band_hz", band, f"a band below lowpass_hz = {self.lowpass_hz} Hz")


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
    lost_samples : int
        Lost samples in the window, bridged by sums over valid samples only.
    I_held, B_held : bool
        True when the value was held (learned over a longer horizon, or given), not fitted
        in this window: its standard error is then NaN, never a band.
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
    flags: tuple[Flag, ...]
    method: str
    lost_samples: int = 0
    I_held: bool = False
    B_held: bool = False

    def as_dict(self) -> dict[str, Any]:
        """The scalar fields, JSON-friendly (NaN becomes None)."""
        out: dict[str, Any] = {}
        for key in ("I", "B", "K", "I_se", "B_se", "K_se", "vaf", "vaf_irf", "vaf_fit"):
            value = float(getattr(self, key))
            out[key] = value if np.isfinite(value) else None
        out["flags"] = list(self.flags)
        out["method"] = self.method
        out["lost_samples"] = self.lost_samples
        out["I_held"] = self.I_held
        out["B_held"] = self.B_held
        return out


def check_window(
    position: FloatArray,
    torque: FloatArray,
    options: EstimatorOptions,
    valid: NDArray[np.bool_] | None = None,
    fs: float = 0.0,
) -> LostSamples | None:
    """Stage 1: withhold (raise :class:`WindowError`) a window that must not be estimated.

    Returns
    -------
    LostSamples or None
        The window's lost samples (``valid`` False) when it has any within the limits.
    """
    if position.ndim != 1 or position.shape != torque.shape:
        raise InputDataError(
            f"position and torque must be 1-D and equally long, got {position.shape} and "
            f"{torque.shape}"
        )
    if position.size < 16:
        raise WindowError(
            f"a window of {position.size} samples is too short to identify; lengthen it",
            Reason.TOO_SHORT,
        )
    lost = None
    if valid is not None and not valid.all():
        lost = count_lost(valid, fs, options.max_lost_percent, options.max_gap_s)
        position, torque = position[valid], torque[valid]
    # One pass each: a sum is finite only if every term is (rad and N·m never overflow).
    if not (math.isfinite(position.sum()) and math.isfinite(torque.sum())):
        raise WindowError("window contains NaN or inf samples; it is withheld", Reason.NAN)
    mean = position.sum() / position.size
    variance = max(0.0, float(position @ position) / position.size - mean * mean)
    if math.sqrt(variance) < options.min_excitation_rad:
        raise WindowError(
            f"position varies by less than {options.min_excitation_rad} rad in this window: "
            "no perturbation, nothing to identify (is the perturbation enabled?)",
            Reason.NO_EXCITATION,
        )
    return lost


def without_lost(
    position: FloatArray, torque: FloatArray, lost: LostSamples | None
) -> tuple[FloatArray, FloatArray]:
    """Copies with the lost samples' (unknown) values set to zero — they enter no sum."""
    if lost is None:
        return position, torque
    return np.where(lost.valid, position, 0.0), np.where(lost.valid, torque, 0.0)


def plan_source(position: FloatArray, lost: LostSamples | None) -> FloatArray:
    """What to plan an analysis from: the window, or its longest stretch of valid samples."""
    return position if lost is None else position[lost.longest_valid_stretch()]


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
    position: FloatArray, torque: FloatArray, plan: AnalysisPlan, options: EstimatorOptions
) -> tuple[FloatArray, FloatArray]:
    u = detrend(position, options.detrend)
    y = detrend(torque * options.torque_sign, options.detrend)
    return _band_limit(u, plan), _band_limit(y, plan)


def _band_limit(x: FloatArray, plan: AnalysisPlan) -> FloatArray:
    """The plan's FIR over the fully supported samples, every ``factor``-th kept."""
    if x.size < plan.taps.size:
        raise WindowError(
            f"window of {x.size} samples is shorter than the {plan.taps.size}-tap low-pass; "
            "lengthen the window or raise lowpass_hz",
            Reason.TOO_SHORT,
        )
    return np.convolve(x, plan.taps, mode="valid")[:: plan.factor]


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


def _flags(
    params: tuple[float, float, float],
    se: tuple[float, float, float],
    vafs: tuple[float, float, float],
    options: EstimatorOptions,
) -> tuple[Flag, ...]:
    inertia, damping, stiffness = params
    vaf_model, _, vaf_fit = vafs
    checks = (
        (vaf_model < options.low_vaf_percent, Flag.LOW_VAF),
        (vaf_fit < 50.0, Flag.MODEL_MISMATCH),  # NaN (not checkable): no flag
        (stiffness <= 0, Flag.NEGATIVE_STIFFNESS),
        (damping <= 0, Flag.NEGATIVE_DAMPING),
        (inertia <= 0, Flag.NEGATIVE_INERTIA),
        (math.isfinite(se[0]) and se[0] > 0.25 * abs(inertia), Flag.INERTIA_UNCERTAIN),
        (math.isfinite(se[2]) and se[2] > 0.1 * abs(stiffness), Flag.STIFFNESS_UNCERTAIN),
    )
    return tuple(flag for raised, flag in checks if raised)


@dataclass(frozen=True)
class Held:
    """Values held instead of fitted in one window (None: fitted)."""

    inertia: float | None = None
    damping: float | None = None


NOT_HELD = Held()


@dataclass(frozen=True)
class WindowGaps:
    """Where a window's lost samples reach after band-limiting (:mod:`rtsid.ident.gaps`).

    Attributes
    ----------
    bad : numpy.ndarray of bool, shape (m,)
        Analysis samples whose FIR support held a lost sample (zeroed in ``u`` and ``y``).
    lost : int
        Lost input samples.
    """

    bad: NDArray[np.bool_]
    lost: int

    def rows(self, half_width: int) -> NDArray[np.bool_]:
        """Rows ``half_width … m − half_width − 1`` whose ``±half_width`` support is clean."""
        return clean_rows(self.bad, half_width)

    def irf_checkable(self, lag: int) -> bool:
        """Enough clean rows over the IRF's lag span to fit and check it (2L + 11)."""
        return int(self.rows(lag).sum()) >= 2 * lag + 11


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


def estimate_window(
    position: ArrayLike,
    torque: ArrayLike,
    fs: float,
    options: EstimatorOptions | None = None,
    *,
    plan: AnalysisPlan | None = None,
    held: Held = NOT_HELD,
    valid: ArrayLike | None = None,
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
    plan : AnalysisPlan, optional
        The stream's analysis plan (:func:`resolve_plan`); default: planned from this window.
    held : Held, optional
        Inertia (and damping) to hold instead of fitting (``options.hold_inertia``, when set,
        is held without being passed here).
    valid : array_like of bool, shape (n,), optional
        False for lost samples (their values are ignored): bridged by sums over valid samples
        only, up to ``max_lost_percent`` and ``max_gap_s`` (:mod:`rtsid.ident.gaps`).

    Returns
    -------
    WindowEstimate
        Parameters, standard errors, VAFs, the IRF and flags.

    Raises
    ------
    WindowError
        The window must not be estimated: ``reason`` is ``"nan"``, ``"too_short"``,
        ``"no_excitation"`` or ``"gap"``.
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
    window = analyse_window(position, torque, fs, options, plan, valid)
    return back_end(*window.signals, options, window.plan, held_values(options, held), window.gaps)


@dataclass(frozen=True)
class AnalysedWindow:
    """Stages 1–4 of one window: its plan, analysis-rate signals, IRF and lost samples."""

    plan: AnalysisPlan
    u: FloatArray
    y: FloatArray
    irf: IRF
    gaps: WindowGaps | None

    @property
    def signals(self) -> tuple[IRF, FloatArray, FloatArray]:
        """``(irf, u, y)``, the back ends' first arguments."""
        return self.irf, self.u, self.y

    @property
    def excitation_rad(self) -> float:
        """The band-limited position's standard deviation, rad."""
        return float(np.std(self.u))


def analyse_window(
    position: ArrayLike,
    torque: ArrayLike,
    fs: float,
    options: EstimatorOptions,
    plan: AnalysisPlan | None = None,
    valid: ArrayLike | None = None,
    max_lowpass_hz: float | None = None,
) -> AnalysedWindow:
    """Check a window (stage 1), plan it unless ``plan`` is given (stage 2), band-limit it
    and identify its IRF (stages 3–4) — what :func:`estimate_window` and
    :class:`rtsid.ident.stream.WindowStream` share before their fits.

    Raises
    ------
    WindowError, NumericalError
        As :func:`estimate_window`.
    """
    pos = np.ascontiguousarray(position, dtype=np.float64)
    tor = np.ascontiguousarray(torque, dtype=np.float64)
    mask = None if valid is None else np.asarray(valid, dtype=bool)
    lost = check_window(pos, tor, options, mask, fs)
    pos, tor = without_lost(pos, tor, lost)
    plan = plan or resolve_plan(plan_source(pos, lost), fs, options, max_lowpass_hz)
    u, y, irf, gaps = analyse(pos, tor, fs, options, plan, lost)
    return AnalysedWindow(plan, u, y, irf, gaps)


def analyse(
    position: FloatArray,
    torque: FloatArray,
    fs: float,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    lost: LostSamples | None,
) -> tuple[FloatArray, FloatArray, IRF, WindowGaps | None]:
    """Stages 3–4 of a checked window: :func:`front_end`, or for a window with lost samples
    the numpy path with the lost samples' reach zeroed and the IRF fitted on clean rows."""
    if lost is None:
        return (*front_end(position, torque, fs, options, plan), None)
    u, y = prepare_window(position, torque, options, plan)
    bad = contaminated(lost.valid, plan.taps.size, plan.factor)
    u[bad], y[bad] = 0.0, 0.0
    gaps = WindowGaps(bad=bad, lost=lost.count)
    rows = gaps.rows(plan.lag)
    # Refinement needs rows whose whole lag span is clean; without enough of them the IRF is
    # the plain Wiener–Hopf solution from correlations over valid pairs, and the checks that
    # compare against it (vaf_irf, vaf_fit) are left out (null).
    refine = options.refine if gaps.irf_checkable(plan.lag) else 0
    irf = estimate_irf(
        u, y, plan.analysis_fs_hz, plan.lag, ridge=options.ridge, refine=refine, rows=rows
    )
    return u, y, irf, gaps


def held_values(options: EstimatorOptions, learned: Held = NOT_HELD) -> Held:
    """What a window holds under ``options.hold``.

    With ``hold = "none"``, ``learned`` as given (a caller's explicit values). Otherwise the
    fixed ``hold_inertia`` when set, else the learned inertia; and with ``"inertia_damping"``
    the learned damping. Nothing is held before an inertia is known.
    """
    if options.hold == "none":
        return learned
    inertia = options.hold_inertia if options.hold_inertia is not None else learned.inertia
    if inertia is None:
        return NOT_HELD
    damping = learned.damping if options.hold == "inertia_damping" else None
    return Held(inertia, damping)


def back_end(
    irf: IRF,
    u: FloatArray,
    y: FloatArray,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    held: Held = NOT_HELD,
    gaps: WindowGaps | None = None,
) -> WindowEstimate:
    """Stages 5–7: fit, VAFs, standard errors and flags of one window.

    The output-error fit runs in numpy (a 3 × 3 solve; see
    :func:`rtsid.ident.second_order.fit_output_error`). The relative fit makes one call into
    the compiled kernel when it was built; :func:`numpy_back_end` otherwise (and for the
    log-magnitude fit), the reference it is tested against.
    """
    if options.fit_method == "output_error":
        return output_error_back_end(irf, u, y, options, plan, held, gaps=gaps)
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
    vafs = (round(vaf_model, 12), round(vaf_irf, 12), round(vaf_fit, 12))
    return _assemble(irf, params, (se_i, se_b, se_k), vafs, "relative", options)


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


def output_error_back_end(
    irf: IRF,
    u: FloatArray,
    y: FloatArray,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    held: Held = NOT_HELD,
    design: OutputErrorDesign | None = None,
    gaps: WindowGaps | None = None,
) -> WindowEstimate:
    """Stages 5–7 with the output-error fit (the default criterion); ``design`` when the
    caller has already formed this window's (:class:`WindowStream` fits it twice)."""
    design = design or output_error_design(u, y, irf, gaps)
    fit = design.fit(
        inertia=held.inertia,
        damping=held.damping if held.inertia is not None else None,
        uncertainty=options.uncertainty,
        noise_lags=_noise_lags(irf, plan),
    )
    _, vaf_irf, vaf_fit = _three_vafs(predict_torque(irf, u, y, fit.params, gaps))
    vafs = (vaf(fit.measured, fit.model), vaf_irf, vaf_fit)
    se_i, se_b, se_k = fit.se.tolist()
    lost = 0 if gaps is None else gaps.lost
    estimate = _assemble(irf, fit.params, (se_i, se_b, se_k), vafs, "output_error", options, lost)
    if held.inertia is None:
        return estimate
    return replace(estimate, I_held=True, B_held=held.damping is not None)


def output_error_design(
    u: FloatArray, y: FloatArray, irf: IRF, gaps: WindowGaps | None = None
) -> OutputErrorDesign:
    """The window's output-error least-squares problem, over the rows the lost samples left."""
    if gaps is None:
        return OutputErrorDesign(u, y, irf.fs_hz)
    rows = gaps.rows(4)
    require_rows(rows, max(24, rows.size // 10), "derivative rows")
    return OutputErrorDesign(u, y, irf.fs_hz, rows)


def _noise_lags(irf: IRF, plan: AnalysisPlan) -> int:
    """Residual autocorrelation lags for the sandwich: the FIR's span at the analysis rate
    (filtered noise is correlated over it) plus the stencils', and at least the IRF's."""
    return max(irf.h.size, -(-plan.taps.size // plan.factor) + 8)


def numpy_back_end(
    irf: IRF,
    u: FloatArray,
    y: FloatArray,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    gaps: WindowGaps | None = None,
) -> WindowEstimate:
    """Stages 5–7 of the frequency-domain fits in numpy: :func:`fit_parameters`,
    :func:`predict_torque`, the VAFs and :func:`standard_errors`."""
    fit = fit_parameters(irf, u, options, plan)
    predictions = predict_torque(irf, u, y, fit.params, gaps)
    se = standard_errors(irf, u, predictions, fit) if options.uncertainty else np.full(3, np.nan)
    se_i, se_b, se_k = se.tolist()
    lost = 0 if gaps is None else gaps.lost
    return _assemble(
        irf, fit.params, (se_i, se_b, se_k), _three_vafs(predictions), fit.method, options, lost
    )


_DETREND_CODES = {"none": 0, "mean": 1, "linear": 2}


def front_end(
    position: ArrayLike,
    torque: ArrayLike,
    fs: float,
    options: EstimatorOptions,
    plan: AnalysisPlan,
) -> tuple[FloatArray, FloatArray, IRF]:
    """Stages 3–4: the analysis-rate signals ``(u, y)`` and the refined IRF.

    One call into the compiled kernel when it was built (detrend, FIR decimation,
    correlations, EUREKA and refinement in C); otherwise :func:`prepare_window` and
    :func:`rtsid.ident.irf.estimate_irf` in numpy, the reference it is tested against.
    """
    if _eureka is None:
        u, y = prepare_window(position, torque, options, plan)
        irf = estimate_irf(
            u, y, plan.analysis_fs_hz, plan.lag, ridge=options.ridge, refine=options.refine
        )
        return u, y, irf
    pos = np.ascontiguousarray(position, dtype=np.float64)
    tor = np.ascontiguousarray(torque, dtype=np.float64)
    taps, factor, lag, fs_a = plan.taps, plan.factor, plan.lag, plan.analysis_fs_hz
    m = (pos.size - taps.size) // factor + 1 if pos.size >= taps.size else 0
    _check_analysis_length(m, fs_a, lag)
    u, y = np.empty(m), np.empty(m)
    h, phi = np.empty(2 * lag + 1), np.empty(2 * lag + 1)
    status, alpha = _eureka.window_irf(
        pos,
        tor,
        np.ascontiguousarray(taps),
        factor,
        options.torque_sign,
        _DETREND_CODES[options.detrend],
        lag,
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
    _check_band_limited_excitation(u, options)
    return u, y, IRF(h=h, fs_hz=fs_a, phi_uu=phi)


def _check_analysis_length(m: int, fs_a: float, max_lag: int) -> None:
    if m <= max(4 * max_lag + 1, 16):
        raise WindowError(
            f"window gives {m} samples at {fs_a:g} Hz after the low-pass, too few for a "
            f"±{max_lag}-lag IRF and the derivative stencils; lengthen the window, shorten "
            "lag_s or raise lowpass_hz",
            Reason.TOO_SHORT,
        )


def _check_band_limited_excitation(u: FloatArray, options: EstimatorOptions) -> None:
    """Withhold a window whose perturbation has no power left in the analysed band."""
    if float(np.std(u)) < options.min_excitation_rad:
        raise WindowError(
            f"the position varies by less than {options.min_excitation_rad} rad in the "
            "analysed band: no usable perturbation, nothing to identify",
            Reason.NO_EXCITATION,
        )


def check_relative_excitation(
    level_rad: float, typical_rad: float | None, options: EstimatorOptions
) -> None:
    """Withhold a window of a stream whose band-limited perturbation ``level_rad`` is below
    ``min_relative_excitation`` of the stream's ``typical_rad`` (None: not known yet): the
    perturbation paused, and the torque then follows the person, not the position."""
    fraction = options.min_relative_excitation
    if typical_rad is not None and level_rad < fraction * typical_rad:
        raise WindowError(
            f"the position varies by {level_rad:.3g} rad in the analysed band, under "
            f"{fraction:g} of the last windows' median {typical_rad:.3g} rad: the "
            "perturbation paused, nothing to identify (estimator.min_relative_excitation)",
            Reason.NO_EXCITATION,
        )


def prepare_window(
    position: ArrayLike, torque: ArrayLike, options: EstimatorOptions, plan: AnalysisPlan
) -> tuple[FloatArray, FloatArray]:
    """Stage 3: sign, detrend, band-limit and decimate a checked window; ``(u, y)``."""
    pos = np.asarray(position, dtype=np.float64)
    tor = np.asarray(torque, dtype=np.float64)
    u, y = _preprocess(pos, tor, plan, options)
    _check_analysis_length(u.size, plan.analysis_fs_hz, plan.lag)
    _check_band_limited_excitation(u, options)
    return u, y


def fit_parameters(
    irf: IRF, u: FloatArray, options: EstimatorOptions, plan: AnalysisPlan
) -> ParameterFit:
    """Stage 5 (frequency domain): ``(I, B, K)`` fitted to the IRF's response, weighted by
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


@dataclass(frozen=True)
class TorquePredictions:
    """Measured and predicted torque over the fully supported samples (N·m)."""

    measured: FloatArray
    irf: FloatArray
    model: FloatArray
    rows: NDArray[np.bool_] | None = None  # the clean ones, when samples were lost


def predict_torque(
    irf: IRF, u: FloatArray, y: FloatArray, params: FloatArray, gaps: WindowGaps | None = None
) -> TorquePredictions:
    """Stage 6: torque predicted by the IRF and by the parametric model ``(I, B, K)``."""
    edge = _supported_edge(irf)
    inertia, damping, stiffness = params
    d1, d2 = stencil_derivatives(u, irf.fs_hz)
    model_torque = inertia * d2 + damping * d1 + stiffness * u[4:-4]  # samples 4 … n−5
    inner = slice(edge, u.size - edge)
    return TorquePredictions(
        measured=y[inner],
        irf=irf.predict(u)[inner],
        model=model_torque[edge - 4 : u.size - edge - 4],
        rows=None if gaps is None else _checkable_rows(gaps, irf, edge),
    )


def _checkable_rows(gaps: WindowGaps, irf: IRF, edge: int) -> NDArray[np.bool_]:
    """The clean rows the IRF's checks may use: none when too few remain to check it."""
    rows = gaps.rows(edge)
    return rows if gaps.irf_checkable(irf.max_lag) else np.zeros_like(rows)


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
    if predictions.rows is not None:
        residual = residual * predictions.rows
    cov = _parameter_covariance(irf, inner_u, residual, fit.sensitivity)
    return np.asarray(np.sqrt(np.clip(np.diag(cov), 0.0, None)), dtype=np.float64)


def _three_vafs(p: TorquePredictions) -> tuple[float, float, float]:
    """VAF of the model and of the IRF against the measurement, and of the model against
    the IRF (over the clean rows when samples were lost)."""
    rows = slice(None) if p.rows is None else p.rows
    measured, irf, model = p.measured[rows], p.irf[rows], p.model[rows]
    if measured.size < 2:  # lost samples left no row over the IRF's whole lag span
        return vaf(p.measured, p.model), math.nan, math.nan
    return vaf(measured, model), vaf(measured, irf), vaf(irf, model)


def _assemble(
    irf: IRF,
    params: FloatArray,
    se: tuple[float, float, float],
    vafs: tuple[float, float, float],
    method: str,
    options: EstimatorOptions,
    lost: int = 0,
) -> WindowEstimate:
    inertia, damping, stiffness = (float(v) for v in params)
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
        flags=_flags((inertia, damping, stiffness), se, vafs, options),
        method=method,
        lost_samples=lost,
    )
