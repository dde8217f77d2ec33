"""Step 3, IRF: band-limit a checked window and identify its two-sided IRF.

Torque sign, trend removed from both signals, the plan's zero-phase FIR on both and
decimation to the analysis rate (``u``, ``y``); then Wiener–Hopf deconvolution solved with
EUREKA and refined (:func:`rtsid.ident.irf.estimate_irf`). :func:`front_end` makes one call
into the compiled kernel when it was built (``window_irf``), :func:`prepare_window` and
``estimate_irf`` in numpy otherwise — the reference it is tested against. A window with lost
samples always takes the numpy path, with the lost samples' reach zeroed
(:class:`~rtsid.ident.gaps.WindowGaps`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rtsid.errors import WindowError
from rtsid.ident.analysis import AnalysisPlan
from rtsid.ident.check import (
    check_analysis_length,
    check_band_limited_excitation,
    check_band_limited_level,
)
from rtsid.ident.correlation import detrend, trend_slope
from rtsid.ident.gaps import LostSamples, WindowGaps, contaminated
from rtsid.ident.irf import IRF, estimate_irf
from rtsid.ident.levinson import compiled_kernel, not_positive_definite
from rtsid.ident.options import EstimatorOptions
from rtsid.ident.records import built
from rtsid.verdicts import Reason

_eureka = compiled_kernel()


@dataclass(frozen=True)
class ScoredBand:
    """What :func:`published_vaf` scores besides the analysis-rate signals ``(u, y)``.

    Attributes
    ----------
    band_hz : float
        Upper edge of the scored band, Hz: the plan's perturbation band edge (the low-pass
        cut-off ÷ 1.5 when the cut-off was set explicitly).
    position_slope, torque_slope : float
        The linear trends the window's detrending removed, rad and N·m per analysis sample.
    explained : numpy.ndarray, shape (m,), or None
        Torque explained by another pathway and subtracted before the fit (the slow lane's
        reflex prediction), band-limited like ``y``, N·m.
    """

    band_hz: float
    position_slope: float = 0.0
    torque_slope: float = 0.0
    explained: FloatArray | None = None


__all__ = ["analyse_checked", "analyse_irf", "front_end", "prepare_window"]

FloatArray = NDArray[np.float64]


def analyse_irf(
    position: FloatArray,
    torque: FloatArray,
    fs: float,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    lost: LostSamples | None,
) -> tuple[FloatArray, FloatArray, IRF, WindowGaps | None]:
    """Step 3 of a checked window: :func:`front_end`, or for a window with lost samples
    the numpy path with the lost samples' reach zeroed and the IRF fitted on clean rows."""
    u, y, irf, gaps, _, _ = analyse_checked(position, torque, fs, options, plan, lost)
    return u, y, irf, gaps


#: The position's and the signed torque's trend slopes, per sample (None: not computed).
Slopes = tuple[float, float] | None


def analyse_checked(
    position: FloatArray,
    torque: FloatArray,
    fs: float,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    lost: LostSamples | None,
) -> tuple[FloatArray, FloatArray, IRF, WindowGaps | None, float, Slopes]:
    """:func:`analyse_irf`'s ``(u, y, irf, gaps)``, the band-limited position's standard
    deviation (rad; the stream's excitation level), computed once, and the trend slopes
    the compiled front end found (:func:`scored_band` reads them)."""
    if lost is None:
        u, y, irf, level, slopes = _front_end(position, torque, fs, options, plan)
        return u, y, irf, None, level, slopes
    u, y, _ = _prepared(position, torque, options, plan)
    gaps = _gaps(lost, plan)
    u[gaps.bad], y[gaps.bad] = 0.0, 0.0
    rows = gaps.rows(plan.lag)
    # Refinement needs rows whose whole lag span is clean; without enough of them the IRF is
    # the plain Wiener–Hopf solution from correlations over valid pairs, and the checks that
    # compare against it (vaf_irf, vaf_fit) are left out (null).
    refine = options.refine if gaps.irf_checkable(plan.lag) else 0
    irf = estimate_irf(
        u, y, plan.analysis_fs_hz, plan.lag, ridge=options.ridge, refine=refine, rows=rows
    )
    return u, y, irf, gaps, float(np.std(u)), None  # the zeroed samples included


def _gaps(lost: LostSamples, plan: AnalysisPlan) -> WindowGaps:
    """The analysis samples the lost ones reach (through the FIR), and their count."""
    bad = contaminated(lost.valid, plan.taps.size, plan.factor)
    return WindowGaps(bad=bad, lost=lost.count)


_DETREND_CODES = {"none": 0, "mean": 1, "linear": 2}


def front_end(
    position: ArrayLike,
    torque: ArrayLike,
    fs: float,
    options: EstimatorOptions,
    plan: AnalysisPlan,
) -> tuple[FloatArray, FloatArray, IRF]:
    """Step 3: the analysis-rate signals ``(u, y)`` and the refined IRF.

    One call into the compiled kernel when it was built (detrend, FIR decimation,
    correlations, EUREKA and refinement in C); otherwise :func:`prepare_window` and
    :func:`rtsid.ident.irf.estimate_irf` in numpy, the reference it is tested against.
    """
    u, y, irf, _, _ = _front_end(position, torque, fs, options, plan)
    return u, y, irf


def _front_end(
    position: ArrayLike,
    torque: ArrayLike,
    fs: float,
    options: EstimatorOptions,
    plan: AnalysisPlan,
) -> tuple[FloatArray, FloatArray, IRF, float, Slopes]:
    """:func:`front_end`, the band-limited position's standard deviation (rad) and, compiled,
    the trend slopes of the position and the signed torque (per sample)."""
    if _eureka is None:
        u, y, level = _prepared(position, torque, options, plan)
        irf = estimate_irf(
            u, y, plan.analysis_fs_hz, plan.lag, ridge=options.ridge, refine=options.refine
        )
        return u, y, irf, level, None
    pos = np.ascontiguousarray(position, dtype=np.float64)
    tor = np.ascontiguousarray(torque, dtype=np.float64)
    taps, factor, lag, fs_a = plan.taps, plan.factor, plan.lag, plan.analysis_fs_hz
    m = (pos.size - taps.size) // factor + 1 if pos.size >= taps.size else 0
    check_analysis_length(m, fs_a, lag)
    u, y = np.empty(m), np.empty(m)
    h, phi = np.empty(2 * lag + 1), np.empty(2 * lag + 1)
    status, alpha, level, position_slope, torque_slope = _eureka.window_irf(
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
    check_band_limited_level(level, options)
    irf = built(IRF, h=h, fs_hz=fs_a, phi_uu=phi)
    return u, y, irf, level, (position_slope, torque_slope)


def prepare_window(
    position: ArrayLike, torque: ArrayLike, options: EstimatorOptions, plan: AnalysisPlan
) -> tuple[FloatArray, FloatArray]:
    """Step 3, first half: sign, detrend, band-limit and decimate a checked window; ``(u, y)``."""
    u, y, _ = _prepared(position, torque, options, plan)
    return u, y


def _prepared(
    position: ArrayLike, torque: ArrayLike, options: EstimatorOptions, plan: AnalysisPlan
) -> tuple[FloatArray, FloatArray, float]:
    """:func:`prepare_window` and the band-limited position's standard deviation, rad."""
    pos = np.asarray(position, dtype=np.float64)
    tor = np.asarray(torque, dtype=np.float64)
    u, y = _preprocess(pos, tor, plan, options)
    check_analysis_length(u.size, plan.analysis_fs_hz, plan.lag)
    return u, y, check_band_limited_excitation(u, options)


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


def scored_band(
    position: FloatArray,
    torque: FloatArray,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    explained: ArrayLike | None = None,
    slopes: Slopes = None,
) -> ScoredBand:
    """What the published VAF scores besides ``(u, y)`` (:func:`rtsid.ident.assess.
    published_vaf`): the trends the detrending removed, at the analysis rate, and the torque
    ``explained`` elsewhere (same samples and sign as ``torque``) band-limited like it;
    ``slopes``: the trend slopes of the position and the signed torque when the front end
    computed them (per sample)."""
    band = plan.edge_hz if plan.edge_hz is not None else plan.lowpass_hz / 1.5
    trends = (0.0, 0.0)
    if options.detrend == "linear":
        if slopes is None:
            slopes = (trend_slope(position), options.torque_sign * trend_slope(torque))
        trends = (slopes[0] * plan.factor, slopes[1] * plan.factor)
    extra = None
    if explained is not None and _eureka is not None and position.size >= plan.taps.size:
        extra = np.empty((position.size - plan.taps.size) // plan.factor + 1)
        source = np.ascontiguousarray(explained, dtype=np.float64)
        _eureka.band_limit(
            source, np.ascontiguousarray(plan.taps), plan.factor, float(options.torque_sign), extra
        )
    elif explained is not None:  # the numpy reference
        signed = options.torque_sign * np.asarray(explained, dtype=np.float64)
        extra = _band_limit(signed - signed.mean(), plan)
    return built(
        ScoredBand,
        band_hz=band,
        position_slope=trends[0],
        torque_slope=trends[1],
        explained=extra,
    )
