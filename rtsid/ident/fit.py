"""Step 4, fit: ``(I, B, K)`` by output error, the default criterion.

Least squares of the window's band-limited torque on the 9-point derivative stencils of its
position, an offset and a trend as nuisance terms
(:class:`rtsid.ident.second_order.OutputErrorDesign`), over the rows the lost samples left;
standard errors by the sandwich with the residual's own autocorrelation. Inertia (and
damping) may be held (:class:`Held`) at a value learned over a longer horizon
(:class:`rtsid.ident.stream.HeldParameters`) or given; K is always the window's own. The
frequency-domain criteria (``relative``, ``logmag``) are in :mod:`rtsid.ident.legacy`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rtsid.ident.analysis import AnalysisPlan
from rtsid.ident.gaps import WindowGaps, require_rows
from rtsid.ident.irf import IRF
from rtsid.ident.options import EstimatorOptions
from rtsid.ident.second_order import OutputErrorDesign, OutputErrorFit

__all__ = [
    "NOT_HELD",
    "Held",
    "held_values",
    "noise_lags",
    "output_error_design",
    "output_error_fit",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Held:
    """Values held instead of fitted in one window (None: fitted)."""

    inertia: float | None = None
    damping: float | None = None


NOT_HELD = Held()


def held_values(options: EstimatorOptions, learned: Held = NOT_HELD) -> Held:
    """What a window holds under ``options.hold``.

    With ``hold = "none"``, ``learned`` as given (a caller's explicit values). Otherwise the
    fixed ``hold_inertia`` when set, else the learned inertia; and with ``"inertia_damping"``
    the learned damping. Nothing is held before an inertia is known. ``learned`` itself when
    that is what it holds.
    """
    if options.hold == "none":
        return learned
    inertia = options.hold_inertia if options.hold_inertia is not None else learned.inertia
    if inertia is None:
        return NOT_HELD
    damping = learned.damping if options.hold == "inertia_damping" else None
    if inertia is learned.inertia and damping is learned.damping:
        return learned  # the same values: no new record (a stream reads this every window)
    return Held(inertia, damping)


def output_error_fit(
    irf: IRF,
    u: FloatArray,
    y: FloatArray,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    held: Held = NOT_HELD,
    design: OutputErrorDesign | None = None,
    gaps: WindowGaps | None = None,
) -> OutputErrorFit:
    """Step 4: ``(I, B, K)`` minimising the window's torque prediction error, ``held``
    values not fitted; ``design`` when the caller has already formed this window's
    (:class:`~rtsid.ident.stream.WindowStream` fits it twice)."""
    design = design or output_error_design(u, y, irf, gaps)
    return design.fit(
        inertia=held.inertia,
        damping=held.damping if held.inertia is not None else None,
        uncertainty=options.uncertainty,
        noise_lags=noise_lags(irf, plan),
    )


def output_error_design(
    u: FloatArray, y: FloatArray, irf: IRF, gaps: WindowGaps | None = None
) -> OutputErrorDesign:
    """The window's output-error least-squares problem, over the rows the lost samples left."""
    if gaps is None:
        return OutputErrorDesign(u, y, irf.fs_hz)
    rows = gaps.rows(4)
    require_rows(rows, max(24, rows.size // 10), "derivative rows")
    return OutputErrorDesign(u, y, irf.fs_hz, rows)


def noise_lags(irf: IRF, plan: AnalysisPlan) -> int:
    """Residual autocorrelation lags for the sandwich: the FIR's span at the analysis rate
    (filtered noise is correlated over it) plus the stencils', and at least the IRF's."""
    return max(irf.h.size, -(-plan.taps.size // plan.factor) + 8)
