"""One window in, one impedance estimate out: ``estimate_window``, a short pipeline.

Each step is a function of the previous step's result, in a module of its own:

1. **check** (:mod:`rtsid.ident.check`): finite, long enough, excited, lost samples within
   the limits — or :class:`~rtsid.errors.WindowError` with a reason, so a bad window is
   withheld, never estimated;
2. **plan** (:mod:`rtsid.ident.analysis`): band-limiting filter, analysis rate and lag span
   from the perturbation's spectrum, unless the caller passes a stream's plan or explicit
   options;
3. **IRF** (:mod:`rtsid.ident.front`): torque sign, trend removed, both signals band-limited
   with the same zero-phase FIR and decimated; the two-sided IRF by Wiener–Hopf
   deconvolution solved with EUREKA (:mod:`rtsid.ident.irf`);
4. **fit** (:mod:`rtsid.ident.fit`): ``(I, B, K)`` by output error, inertia (and damping)
   optionally held at a value learned over a longer horizon (:class:`Held`);
5. **assess** (:mod:`rtsid.ident.assess`): VAFs of the model's and the IRF's torque
   predictions, flags, the :class:`WindowEstimate`.

The legacy criteria (``fit_method = "relative"`` or ``"logmag"``: ``(I, B, K)`` fitted to
the IRF's frequency response) replace steps 4–5 with :mod:`rtsid.ident.legacy`.

:func:`analyse_window` (steps 1–3) and :func:`back_end` (steps 4–5) are the two halves that
:class:`rtsid.ident.stream.WindowStream` also composes. The steps' public names stay
importable from here.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rtsid.ident.analysis import AnalysisPlan, plan_source, resolve_plan
from rtsid.ident.assess import (
    ScoredBand,
    TorquePredictions,
    WindowEstimate,
    assess,
    predict_torque,
    published_vaf,
    supported_edge,
    window_flags,
    withhold_unidentifiable,
)
from rtsid.ident.check import check_relative_excitation, check_window, without_lost
from rtsid.ident.fit import NOT_HELD, Held, held_values, output_error_design, output_error_fit
from rtsid.ident.front import analyse_checked, front_end, prepare_window, scored_band
from rtsid.ident.fused import fusable, fused_back_end
from rtsid.ident.gaps import WindowGaps
from rtsid.ident.irf import IRF
from rtsid.ident.legacy import fit_parameters, legacy_back_end, numpy_back_end, standard_errors
from rtsid.ident.options import FIT_METHODS, HOLD_CHOICES, EstimatorOptions
from rtsid.ident.records import built
from rtsid.ident.second_order import OutputErrorDesign

__all__ = [
    "FIT_METHODS",
    "HOLD_CHOICES",
    "NOT_HELD",
    "AnalysedWindow",
    "EstimatorOptions",
    "Held",
    "TorquePredictions",
    "WindowEstimate",
    "WindowGaps",
    "analyse_window",
    "back_end",
    "check_relative_excitation",
    "check_window",
    "estimate_window",
    "fit_parameters",
    "front_end",
    "held_values",
    "numpy_back_end",
    "output_error_back_end",
    "output_error_design",
    "predict_torque",
    "prepare_window",
    "resolve_plan",
    "standard_errors",
]

FloatArray = NDArray[np.float64]


def estimate_window(
    position: ArrayLike,
    torque: ArrayLike,
    fs: float,
    options: EstimatorOptions | None = None,
    *,
    plan: AnalysisPlan | None = None,
    held: Held = NOT_HELD,
    valid: ArrayLike | None = None,
    typical_excitation_rad: float | None = None,
    **overrides: Any,
) -> WindowEstimate:
    """Identify joint impedance ``(I, B, K)`` from one window of position and torque.

    One window alone. For the numbers ``rtsid identify``, replay and the daemon give, use
    :class:`rtsid.Identifier` (or :func:`rtsid.identify`): a stream plans its analysis once,
    from its first estimable window, holds I and B at the median of its own full fits,
    tracks K and subtracts the slow lane's reflex torque — none of which one window can do.
    A lone call plans from its own window (a weakly perturbed window then gets a narrow,
    poor plan: pass the stream's ``plan``), holds only what ``held`` (or
    ``options.hold_inertia``) gives it (``hold`` alone holds nothing: holding needs values
    learned over ``hold_horizon_s`` of earlier windows), and withholds every window a stream
    withholds: the checks of one window, the ``unidentifiable`` fits
    (:func:`rtsid.ident.assess.withhold_unidentifiable`), and with
    ``typical_excitation_rad`` the paused-perturbation check a stream makes against its own
    recent windows.

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
    typical_excitation_rad : float, optional
        The stream's typical band-limited position SD, rad: a window below
        ``min_relative_excitation`` of it is withheld (``"no_excitation"``), as a stream does.

    Returns
    -------
    WindowEstimate
        Parameters, standard errors, VAFs, the IRF and flags.

    Raises
    ------
    WindowError
        The window must not be estimated: ``reason`` is ``"nan"``, ``"too_short"``,
        ``"no_excitation"``, ``"gap"`` or ``"unidentifiable"``.
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
    window = analyse_window(position, torque, fs, options, plan, valid)  # steps 1–3
    if typical_excitation_rad is not None:
        check_relative_excitation(window.excitation_rad, typical_excitation_rad, options)
    held = held_values(options, held)
    estimate = back_end(*window.signals, options, window.plan, held, window.gaps, window.score)
    return withhold_unidentifiable(estimate)


@dataclass(frozen=True)
class AnalysedWindow:
    """Steps 1–3 of one window: its plan, analysis-rate signals, IRF and lost samples."""

    plan: AnalysisPlan
    u: FloatArray
    y: FloatArray
    irf: IRF
    gaps: WindowGaps | None
    score: ScoredBand
    #: The band-limited position's standard deviation, rad.
    excitation_rad: float

    @property
    def signals(self) -> tuple[IRF, FloatArray, FloatArray]:
        """``(irf, u, y)``, the back ends' first arguments."""
        return self.irf, self.u, self.y


def analyse_window(
    position: ArrayLike,
    torque: ArrayLike,
    fs: float,
    options: EstimatorOptions,
    plan: AnalysisPlan | None = None,
    valid: ArrayLike | None = None,
    max_lowpass_hz: float | None = None,
    explained: ArrayLike | None = None,
) -> AnalysedWindow:
    """Check a window (step 1), plan it unless ``plan`` is given (step 2), band-limit it
    and identify its IRF (step 3) — what :func:`estimate_window` and
    :class:`rtsid.ident.stream.WindowStream` share before their fits. ``explained``: torque
    already subtracted from ``torque`` (the slow lane's reflex), counted in the VAF.

    Raises
    ------
    WindowError, NumericalError
        As :func:`estimate_window`.
    """
    pos = np.ascontiguousarray(position, dtype=np.float64)
    tor = np.ascontiguousarray(torque, dtype=np.float64)
    mask = None if valid is None else np.asarray(valid, dtype=bool)
    lost = check_window(pos, tor, options, mask, fs)  # 1. check
    pos, tor = without_lost(pos, tor, lost)
    plan = plan or resolve_plan(plan_source(pos, lost), fs, options, max_lowpass_hz)  # 2. plan
    u, y, irf, gaps, level, slopes = analyse_checked(pos, tor, fs, options, plan, lost)  # 3.
    score = scored_band(pos, tor, options, plan, explained, slopes)
    return built(
        AnalysedWindow,
        plan=plan,
        u=u,
        y=y,
        irf=irf,
        gaps=gaps,
        score=score,
        excitation_rad=level,
    )


def back_end(
    irf: IRF,
    u: FloatArray,
    y: FloatArray,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    held: Held = NOT_HELD,
    gaps: WindowGaps | None = None,
    score: ScoredBand | None = None,
) -> WindowEstimate:
    """Steps 4–5 of an analysed window: fit and assess it with ``options.fit_method``.

    Output error (the default): :func:`output_error_back_end`. The legacy criteria
    (``relative``, ``logmag``): :func:`rtsid.ident.legacy.legacy_back_end`, which fits all
    three parameters (``held`` is not used), its ``vaf`` then scored like the default's.
    """
    if options.fit_method == "output_error":
        return output_error_back_end(irf, u, y, options, plan, held, gaps=gaps, score=score)
    estimate = legacy_back_end(irf, u, y, options, plan, gaps)
    if score is None:
        return estimate
    params = np.array([estimate.I, estimate.B, estimate.K])
    p = predict_torque(irf, u, y, params, gaps)
    index = np.arange(supported_edge(irf), supported_edge(irf) + p.measured.size)
    # a gap window is scored on its clean rows (all of them, whether or not enough remain to
    # check the IRF: the model's torque needs only the stencils' support)
    keep = slice(None) if gaps is None else gaps.rows(supported_edge(irf))
    published = published_vaf(
        p.measured[keep],
        p.model[keep],
        estimate.K,
        score,
        irf.fs_hz,
        index[keep],
        in_band=gaps is None,
    )
    vafs = (published, estimate.vaf_irf, estimate.vaf_fit)
    se = (estimate.I_se, estimate.B_se, estimate.K_se)
    flags = window_flags((estimate.I, estimate.B, estimate.K), se, vafs, options)
    return replace(estimate, vaf=vafs[0], flags=flags)


def output_error_back_end(
    irf: IRF,
    u: FloatArray,
    y: FloatArray,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    held: Held = NOT_HELD,
    design: OutputErrorDesign | None = None,
    gaps: WindowGaps | None = None,
    score: ScoredBand | None = None,
) -> WindowEstimate:
    """Steps 4–5 with the output-error fit (the default criterion); ``design`` when the
    caller has already formed this window's (:class:`WindowStream` fits it twice)."""
    if design is None and score is not None and fusable(options, score, gaps is not None):
        return fused_back_end(irf, u, y, options, plan, held, score).estimate  # 4–5 compiled
    fit = output_error_fit(irf, u, y, options, plan, held, design, gaps)  # 4. fit
    return assess(irf, u, y, fit, options, held, gaps, score)  # 5. assess
