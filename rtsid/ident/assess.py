"""Step 5, assess: VAFs and flags of a fitted window, and its :class:`WindowEstimate`.

* ``vaf`` (:func:`published_vaf`), the one VAF rtsid publishes: the share of the measured
  torque's variance in the perturbation's band (above DC up to the plan's band edge) that the
  published model explains — ``I·θ̈ + B·θ̇ + K·θ`` plus any torque another pathway explained
  first (the slow lane's reflex prediction) — over the window, its mean removed but not its
  trend;
* the model checks ``vaf_irf`` (the IRF's prediction against the band-limited torque) and
  ``vaf_fit`` (the model against the IRF), over the samples with full support
  (:func:`predict_torque`) and, when samples were lost, the clean rows only;
* flags that do not withhold the estimate (:func:`window_flags`);
* the estimate itself (:func:`assemble`), held values marked as held.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import WindowError
from rtsid.ident.filters import stencil_derivatives
from rtsid.ident.fit import NOT_HELD, Held
from rtsid.ident.front import ScoredBand
from rtsid.ident.gaps import WindowGaps
from rtsid.ident.irf import IRF
from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.options import EstimatorOptions
from rtsid.ident.records import built
from rtsid.ident.second_order import OutputErrorFit
from rtsid.ident.vaf import vaf
from rtsid.verdicts import Flag, Reason

__all__ = [
    "ESTIMATE_FIELDS",
    "FLAG_ORDER",
    "TorquePredictions",
    "WindowEstimate",
    "assemble",
    "assemble_parts",
    "assess",
    "band_bins",
    "predict_torque",
    "published_vaf",
    "published_vafs",
    "three_vafs",
    "twiddles",
    "window_flags",
    "withhold_unidentifiable",
]

FloatArray = NDArray[np.float64]

_eureka = compiled_kernel()
#: round(x, 12) of each argument, as Python's round gives it (glue7): the compiled kernel's when
#: it has it (a decimal conversion costs ≈ 8 k instructions, a window publishes three)
_round12: Any = getattr(_eureka, "round12", None)


def published_vafs(model: float, irf: float, fit: float) -> tuple[float, float, float]:
    """The three VAFs (%) as an estimate publishes them: each rounded to 12 decimals
    (``round(x, 12)``; the compiled ``round12`` gives the same floats, tested)."""
    if _round12 is not None:
        return _round12(model, irf, fit)
    return round(model, 12), round(irf, 12), round(fit, 12)


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
        Percent of the measured torque's variance in the perturbation's band accounted for
        by the published model (:func:`published_vaf`).
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


def published_vaf(
    measured: FloatArray,
    model: FloatArray,
    stiffness: float,
    score: ScoredBand,
    fs_hz: float,
    index: NDArray[np.intp],
    *,
    in_band: bool = True,
) -> float:
    """The published VAF, %: the measured torque in ``score``'s band against the model.

    ``measured = y + trend + explained`` and ``model = I·θ̈ + B·θ̇ + K·(u + trend) +
    explained`` at the analysis rate, each window's mean removed; the VAF is taken over the
    DFT bins above DC up to ``score.band_hz`` (the torque beyond the perturbation's band is
    noise no model of the position explains). A window with lost samples is scored on its
    clean rows in time (``in_band`` False: its DFT would mix the zeroed rows in).

    Parameters
    ----------
    measured, model : numpy.ndarray, shape (k,)
        Band-limited torque ``y`` and the model's ``I·θ̈ + B·θ̇ + K·u``, N·m.
    stiffness : float
        K, N·m/rad (the position trend's torque).
    score : ScoredBand
    fs_hz : float
        Analysis rate, Hz.
    index : numpy.ndarray of int, shape (k,)
        The analysis samples ``measured`` and ``model`` hold.
    """
    measured = measured + score.torque_slope * index
    model = model + stiffness * score.position_slope * index
    if score.explained is not None:
        measured = measured + score.explained[index]
        model = model + score.explained[index]
    if not in_band:
        return vaf(measured, model)
    return _band_vaf(measured - measured.mean(), measured - model, fs_hz, score.band_hz)


def _band_vaf(measured: FloatArray, error: FloatArray, fs_hz: float, band_hz: float) -> float:
    error = error - error.mean()
    bins = np.fft.rfftfreq(measured.size, 1.0 / fs_hz)
    scored = (bins > 0) & (bins <= band_hz)
    total = float(np.sum(np.abs(np.fft.rfft(measured)[scored]) ** 2))
    if total <= 0:
        return 0.0
    left = float(np.sum(np.abs(np.fft.rfft(error)[scored]) ** 2))
    return round(max(0.0, 1.0 - left / total) * 100.0, 12)


def assess(
    irf: IRF,
    u: FloatArray,
    y: FloatArray,
    fit: OutputErrorFit,
    options: EstimatorOptions,
    held: Held = NOT_HELD,
    gaps: WindowGaps | None = None,
    score: ScoredBand | None = None,
) -> WindowEstimate:
    """Step 5 of an output-error fit: its VAFs, flags and estimate.

    ``vaf`` is :func:`published_vaf` (``score`` None: the fit's own model torque against the
    torque it was fitted to); ``vaf_irf`` and ``vaf_fit`` compare with the IRF's prediction.
    The standard errors are the fit's (NaN for held values, which are marked as held).
    """
    if _eureka is not None and gaps is None and score is not None:
        vafs = _compiled_vafs(irf, u, y, fit, score)
    else:
        vafs = _numpy_vafs(irf, u, y, fit, gaps, score)
    se_i, se_b, se_k = fit.se.tolist()
    lost = 0 if gaps is None else gaps.lost
    held_flags = (held.inertia is not None, held.inertia is not None and held.damping is not None)
    se = (se_i, se_b, se_k)
    return assemble(irf, fit.params, se, vafs, "output_error", options, lost, held_flags)


def _numpy_vafs(
    irf: IRF,
    u: FloatArray,
    y: FloatArray,
    fit: OutputErrorFit,
    gaps: WindowGaps | None,
    score: ScoredBand | None,
) -> tuple[float, float, float]:
    """``(vaf, vaf_irf, vaf_fit)`` of an output-error fit: the reference of
    :func:`_compiled_vafs`, and the path of windows with lost samples."""
    _, vaf_irf, vaf_fit = three_vafs(predict_torque(irf, u, y, fit.params, gaps))
    if score is None:
        published = vaf(fit.measured, fit.model)
    else:
        rows = fit_rows(gaps)
        index = np.arange(4, 4 + fit.measured.size) if rows is None else rows
        stiffness = float(fit.params[2])
        published = published_vaf(
            fit.measured, fit.model, stiffness, score, irf.fs_hz, index, in_band=rows is None
        )
    return published, vaf_irf, vaf_fit


def _compiled_vafs(
    irf: IRF, u: FloatArray, y: FloatArray, fit: OutputErrorFit, score: ScoredBand
) -> tuple[float, float, float]:
    """:func:`_numpy_vafs` of a window without lost samples in one call into the compiled
    kernel (``oe_vafs``): the same predictions, VAFs and in-band DFT sums."""
    n = fit.model.size
    cos, sin = twiddles(n)
    published, vaf_irf, vaf_fit = _eureka.oe_vafs(
        np.ascontiguousarray(u),
        np.ascontiguousarray(y),
        np.ascontiguousarray(irf.h),
        np.ascontiguousarray(fit.params),
        fit.model,
        irf.fs_hz,
        None if score.explained is None else np.ascontiguousarray(score.explained),
        score.torque_slope,
        float(fit.params[2]) * score.position_slope,
        band_bins(n, irf.fs_hz, score.band_hz),
        cos,
        sin,
    )
    return published_vafs(published, vaf_irf, vaf_fit)


@lru_cache(maxsize=16)
def band_bins(n: int, fs_hz: float, band_hz: float) -> int:
    """DFT bins 1 … k of ``n`` samples at ``fs_hz`` in ``(0, band_hz]``: k (as _band_vaf)."""
    bins = np.fft.rfftfreq(n, 1.0 / fs_hz)
    return int(np.count_nonzero((bins > 0) & (bins <= band_hz)))


@lru_cache(maxsize=16)
def twiddles(n: int) -> tuple[FloatArray, FloatArray]:
    """``cos`` and ``sin`` of ``2πj/n``, ``j = 0 … n−1`` (the compiled DFT's table)."""
    angle = 2.0 * np.pi * np.arange(n) / n
    cos, sin = np.cos(angle), np.sin(angle)
    cos.setflags(write=False)
    sin.setflags(write=False)
    return cos, sin


def fit_rows(gaps: WindowGaps | None) -> NDArray[np.intp] | None:
    """Analysis-sample indices of a gap window's fitted rows (None without lost samples)."""
    if gaps is None:
        return None
    return np.flatnonzero(gaps.rows(4)) + 4  # the stencils' rows 4 … m − 5 that were kept


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
    """Torque predicted by the IRF and by the parametric model ``(I, B, K)``."""
    edge = supported_edge(irf)
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


def supported_edge(irf: IRF) -> int:
    """Samples at each end without full support for the IRF (``L``) or the 9-point
    derivative stencils (4): predictions and residuals skip them."""
    return max(irf.max_lag, 4)


def three_vafs(p: TorquePredictions) -> tuple[float, float, float]:
    """VAF of the model and of the IRF against the measurement, and of the model against
    the IRF (over the clean rows when samples were lost)."""
    rows = slice(None) if p.rows is None else p.rows
    measured, irf, model = p.measured[rows], p.irf[rows], p.model[rows]
    if measured.size < 2:  # lost samples left no row over the IRF's whole lag span
        return vaf(p.measured, p.model), math.nan, math.nan
    return vaf(measured, model), vaf(measured, irf), vaf(irf, model)


def assemble(
    irf: IRF,
    params: FloatArray | Sequence[float],
    se: tuple[float, float, float],
    vafs: tuple[float, float, float],
    method: str,
    options: EstimatorOptions,
    lost: int = 0,
    held: tuple[bool, bool] = (False, False),
    lags_s: FloatArray | None = None,
) -> WindowEstimate:
    """The :class:`WindowEstimate` of fitted ``params`` (a sequence of three, I, B, K);
    ``held``: whether I and B were held; ``lags_s``: ``irf.lags_s`` when the caller has it."""
    lags = irf.lags_s if lags_s is None else lags_s
    return assemble_parts(irf.h, lags, irf.fs_hz, params, se, vafs, method, options, lost, held)


def assemble_parts(
    h: FloatArray,
    lags_s: FloatArray,
    fs_hz: float,
    params: FloatArray | Sequence[float],
    se: tuple[float, float, float],
    vafs: tuple[float, float, float],
    method: str,
    options: EstimatorOptions,
    lost: int = 0,
    held: tuple[bool, bool] = (False, False),
) -> WindowEstimate:
    """:func:`assemble` from the IRF's parts (its taps ``h``, N·m/rad/s; lags, s; rate, Hz),
    for a caller that has them without an :class:`~rtsid.ident.irf.IRF` (the one compiled
    window call)."""
    inertia, damping, stiffness = float(params[0]), float(params[1]), float(params[2])
    return built(
        WindowEstimate,
        I=inertia,
        B=damping,
        K=stiffness,
        I_se=se[0],
        B_se=se[1],
        K_se=se[2],
        vaf=vafs[0],
        vaf_irf=vafs[1],
        vaf_fit=vafs[2],
        irf=h,
        lags_s=lags_s,
        fs_hz=fs_hz,
        flags=window_flags((inertia, damping, stiffness), se, vafs, options),
        method=method,
        lost_samples=lost,
        I_held=held[0],
        B_held=held[1],
    )


_LOW_VAF, _MISMATCH = Flag.LOW_VAF, Flag.MODEL_MISMATCH
_NEGATIVE = (Flag.NEGATIVE_STIFFNESS, Flag.NEGATIVE_DAMPING, Flag.NEGATIVE_INERTIA)
_UNCERTAIN = (Flag.INERTIA_UNCERTAIN, Flag.STIFFNESS_UNCERTAIN)


def window_flags(
    params: tuple[float, float, float],
    se: tuple[float, float, float],
    vafs: tuple[float, float, float],
    options: EstimatorOptions,
) -> tuple[Flag, ...]:
    """The flags that do not withhold an estimate, in a fixed order: ``low_vaf``,
    ``model_mismatch``, ``negative_stiffness``, ``negative_damping``, ``negative_inertia``,
    ``inertia_uncertain``, ``stiffness_uncertain`` (see :class:`WindowEstimate`)."""
    inertia, damping, stiffness = params
    se_i, se_k = se[0], se[2]
    flags: list[Flag] = []
    if vafs[0] < options.low_vaf_percent:
        flags.append(_LOW_VAF)
    if vafs[2] < 50.0:  # NaN (not checkable): no flag
        flags.append(_MISMATCH)
    if stiffness <= 0:
        flags.append(_NEGATIVE[0])
    if damping <= 0:
        flags.append(_NEGATIVE[1])
    if inertia <= 0:
        flags.append(_NEGATIVE[2])
    if math.isfinite(se_i) and se_i > 0.25 * abs(inertia):
        flags.append(_UNCERTAIN[0])
    if math.isfinite(se_k) and se_k > 0.1 * abs(stiffness):
        flags.append(_UNCERTAIN[1])
    return tuple(flags) if flags else ()


#: window_flags' flags in its order (the compiled stream_window raises them from this table).
FLAG_ORDER = (_LOW_VAF, _MISMATCH, *_NEGATIVE, *_UNCERTAIN)
#: WindowEstimate's fields in order (the compiled stream_window fills an estimate's __dict__).
ESTIMATE_FIELDS = tuple(f.name for f in fields(WindowEstimate))

#: An estimate carrying all of these is no joint's impedance: withheld, not published.
UNIDENTIFIABLE = frozenset({Flag.NEGATIVE_STIFFNESS, Flag.MODEL_MISMATCH})


def withhold_unidentifiable(estimate: WindowEstimate) -> WindowEstimate:
    """``estimate``, unless it reads K <= 0 while its model does not even match the window's
    own IRF: then :class:`~rtsid.errors.WindowError` (``"unidentifiable"``). On the shared
    human recording such windows read K = −1316 N·m/rad (a torque burst) or, planned from a
    window alone, −5580; a stream and a lone call withhold them alike."""
    if estimate.flags and UNIDENTIFIABLE.issubset(estimate.flags):
        raise WindowError(
            f"the window's fit reads K = {estimate.K:.4g} N·m/rad and the second-order model "
            f"explains {estimate.vaf_fit:.0f} % of its own IRF: not a joint's impedance, "
            "withheld",
            Reason.UNIDENTIFIABLE,
        )
    return estimate
