"""Step 1, check: withhold a window that must not be estimated.

Each check raises :class:`~rtsid.errors.WindowError` with its ``reason`` — the window is
withheld, never estimated:

* :func:`check_window` — shapes, length, lost samples within the limits (``"gap"``,
  :mod:`rtsid.ident.gaps`), finite values (``"nan"``), a perturbation at all
  (``"no_excitation"``); before anything is computed;
* :func:`check_analysis_length` and :func:`check_band_limited_excitation` — after
  band-limiting (:mod:`rtsid.ident.front`): enough analysis samples for the IRF
  (``"too_short"``), and perturbation power left in the analysed band;
* :func:`check_relative_excitation` — in a stream, a window whose perturbation paused
  against the last windows' (``"no_excitation"``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import InputDataError, WindowError
from rtsid.ident.gaps import LostSamples, count_lost
from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.options import EstimatorOptions
from rtsid.verdicts import Reason

__all__ = [
    "check_analysis_length",
    "check_band_limited_excitation",
    "check_band_limited_level",
    "check_relative_excitation",
    "check_window",
    "window_scan",
    "window_sums",
    "without_lost",
]

FloatArray = NDArray[np.float64]

_eureka: Any = compiled_kernel()


def check_window(
    position: FloatArray,
    torque: FloatArray,
    options: EstimatorOptions,
    valid: NDArray[np.bool_] | None = None,
    fs: float = 0.0,
) -> LostSamples | None:
    """Step 1: withhold (raise :class:`WindowError`) a window that must not be estimated.

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
    # A sum is finite only if every term is (rad and N·m never overflow).
    total, torque_total, squares = window_sums(position, torque)
    if not (math.isfinite(total) and math.isfinite(torque_total)):
        raise WindowError("window contains NaN or inf samples; it is withheld", Reason.NAN)
    mean = total / position.size
    variance = max(0.0, squares / position.size - mean * mean)
    if math.sqrt(variance) < options.min_excitation_rad:
        raise WindowError(
            f"position varies by less than {options.min_excitation_rad} rad in this window: "
            "no perturbation, nothing to identify (is the perturbation enabled?)",
            Reason.NO_EXCITATION,
        )
    return lost


def window_sums(position: FloatArray, torque: FloatArray) -> tuple[float, float, float]:
    """``(Σ position, Σ torque, Σ position²)`` of a window, plain floats: one pass in the
    compiled kernel when it was built (``window_sums``), numpy's reductions otherwise (the
    reference, equal to 1e-9 of the sums' scale)."""
    if _eureka is not None and position.dtype == np.float64 and torque.dtype == np.float64:
        return _eureka.window_sums(np.ascontiguousarray(position), np.ascontiguousarray(torque))
    return float(np.add.reduce(position)), float(np.add.reduce(torque)), float(position @ position)


def window_scan(
    position: FloatArray,
    torque: FloatArray,
    valid: NDArray[np.bool_],
    status: NDArray[np.integer[Any]],
    start: int,
    stop: int,
) -> tuple[int, bool, bool]:
    """The checks' reading of rows ``start .. stop − 1`` of a window's columns, in one pass.

    Parameters
    ----------
    position, torque : numpy.ndarray of float64, shape (n,)
        Joint angle (rad) and torque (N·m); lost rows hold no value (NaN in a recording).
    valid : numpy.ndarray of bool, shape (n,)
        False for lost rows.
    status : numpy.ndarray of unsigned int, shape (n,)
        Each row's status bits (``rtsid.link.protocol.STATUS_*``).
    start, stop : int
        The rows to read (the window's, within columns that may hold more).

    Returns
    -------
    raised : int
        The status bits any row raises (their OR).
    all_valid : bool
        Every row is valid.
    finite : bool
        The valid rows' position and torque are finite: their sums are (a sum is finite only
        if every term is; rad and N·m never overflow).

    Notes
    -----
    One compiled pass (``window_scan``) when the kernel was built and the columns are the data
    path's types; numpy's reductions otherwise, the reference it is tested equal to.
    """
    if _eureka is not None:
        scanned = _eureka.window_scan(position, torque, valid, status, start, stop)
        if scanned is not None:
            return scanned
    return window_scan_reference(position, torque, valid, status, start, stop)


def window_scan_reference(
    position: FloatArray,
    torque: FloatArray,
    valid: NDArray[np.bool_],
    status: NDArray[np.integer[Any]],
    start: int,
    stop: int,
) -> tuple[int, bool, bool]:
    """:func:`window_scan` by numpy's reductions (the reference)."""
    rows = slice(start, stop)
    raised = int(np.bitwise_or.reduce(status[rows]))
    valid = valid[rows]
    all_valid = bool(np.logical_and.reduce(valid))
    position, torque = position[rows], torque[rows]
    if not all_valid:
        position, torque = position[valid], torque[valid]
    finite = math.isfinite(float(np.add.reduce(position))) and math.isfinite(
        float(np.add.reduce(torque))
    )
    return raised, all_valid, finite


def without_lost(
    position: FloatArray, torque: FloatArray, lost: LostSamples | None
) -> tuple[FloatArray, FloatArray]:
    """Copies with the lost samples' (unknown) values set to zero — they enter no sum."""
    if lost is None:
        return position, torque
    return np.where(lost.valid, position, 0.0), np.where(lost.valid, torque, 0.0)


def check_analysis_length(m: int, fs_a: float, max_lag: int) -> None:
    if m <= max(4 * max_lag + 1, 16):
        raise WindowError(
            f"window gives {m} samples at {fs_a:g} Hz after the low-pass, too few for a "
            f"±{max_lag}-lag IRF and the derivative stencils; lengthen the window, shorten "
            "lag_s or raise lowpass_hz",
            Reason.TOO_SHORT,
        )


def check_band_limited_excitation(u: FloatArray, options: EstimatorOptions) -> float:
    """Withhold a window whose perturbation has no power left in the analysed band; else
    its band-limited standard deviation, rad."""
    return check_band_limited_level(float(np.std(u)), options)


def check_band_limited_level(level: float, options: EstimatorOptions) -> float:
    """:func:`check_band_limited_excitation` of the band-limited position's standard
    deviation ``level`` (rad), already computed; returns it."""
    if level < options.min_excitation_rad:
        raise WindowError(
            f"the position varies by less than {options.min_excitation_rad} rad in the "
            "analysed band: no usable perturbation, nothing to identify",
            Reason.NO_EXCITATION,
        )
    return level


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
