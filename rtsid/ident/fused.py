"""Steps 4–5 of a window without lost samples in one compiled call (``oe_window``).

What :func:`rtsid.ident.window.output_error_back_end` and
:class:`rtsid.ident.stream.WindowStream` do in several calls — the output-error design, the
full fit the held parameters learn from and its VAF, the published fit with its standard
errors, its three VAFs, and the K of the window's newest hop
(:meth:`rtsid.ident.split.SplitProblem.newest`) — the compiled kernel does in one, into
buffers a stream allocates once (:class:`BackEndBuffers`). The same C functions run in the
same order as the separate calls (``oe_design``, ``oe_fit``, ``oe_vafs``), so the numbers
are theirs; the numpy code stays the reference (``RTSID_NUMPY_ONLY=1`` runs it) and the
tests hold the two equal to 1e-9.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid.ident.analysis import AnalysisPlan
from rtsid.ident.assess import WindowEstimate, assemble, band_bins, published_vafs, twiddles
from rtsid.ident.fit import Held, noise_lags
from rtsid.ident.front import ScoredBand
from rtsid.ident.irf import IRF
from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.options import EstimatorOptions
from rtsid.ident.records import built
from rtsid.ident.second_order import OutputErrorDesign, inseparable_fit, zero_response

__all__ = [
    "HELD_FLAGS",
    "RESULT_SLOTS",
    "BackEndBuffers",
    "FusedWindow",
    "full_fit_explains",
    "fusable",
    "fused_back_end",
]

FloatArray = NDArray[np.float64]

_eureka: Any = compiled_kernel()


def fusable(options: EstimatorOptions, score: ScoredBand | None, lost: bool) -> bool:
    """Whether :func:`fused_back_end` can fit this window: the kernel was built, the
    criterion is output error, the window has no lost samples and is scored."""
    return (
        _eureka is not None
        and options.fit_method == "output_error"
        and score is not None
        and not lost
    )


class BackEndBuffers:
    """The kernel's output arrays, allocated once per window size (a stream's windows are
    all alike) instead of once per window, and what every window of one plan shares: the
    DFT's twiddles (and their table for the published VAF's DFT, ``oe_window_tabled``), the
    scored band's last bin and the sandwich's noise lags."""

    def __init__(self) -> None:
        self._m = -1
        self.regressors = self.projected = self.gram = self.model = self.out = np.empty(0)
        self.held = np.zeros(2)
        self._shared: tuple[Any, ...] = (None,)  # (plan, fs_hz, band_hz, m), then its values
        self.cos = self.sin = self.lags_s = self.table = np.empty(0)
        self.kmax = self.lags = 0

    def for_samples(self, m: int) -> BackEndBuffers:
        """These buffers sized for ``m`` analysis samples."""
        if m != self._m:
            n = m - 8
            self.regressors, self.projected = np.empty((3, n)), np.empty((4, n))
            self.gram, self.model, self.out = np.empty((4, 4)), np.empty(n), np.empty(16)
            self._m = m
        return self

    def for_window(self, m: int, irf: IRF, plan: AnalysisPlan, band_hz: float) -> BackEndBuffers:
        """:meth:`for_samples`, with the twiddles, band and lags of ``plan``'s windows."""
        self.for_samples(m)
        shared = self._shared
        if shared[0] is not plan or shared[1:] != (irf.fs_hz, band_hz, m, irf.h.size):
            n = m - 8
            self.cos, self.sin = twiddles(n)
            self.kmax = band_bins(n, irf.fs_hz, band_hz)
            self.table = kept_band_table(self.cos, self.sin, self.kmax)
            self.lags = noise_lags(irf, plan)
            self.lags_s = irf.lags_s  # read-only, shared by the IRFs of this lag grid
            self._shared = (plan, irf.fs_hz, band_hz, m, irf.h.size)
        return self


@dataclass(frozen=True)
class FusedWindow:
    """:func:`fused_back_end`'s answer.

    Attributes
    ----------
    estimate : WindowEstimate
        The published estimate (held values marked as held).
    whole_inertia, whole_damping : float
        I and B of the full fit (nothing held), for the held parameters to learn from.
    whole_explained : bool
        The full fit's VAF reaches ``low_vaf_percent``.
    newest : tuple of float or None
        ``(K, relative variance, centre row)`` of the window's newest rows
        (:meth:`rtsid.ident.split.SplitProblem.newest`); None when not asked or none.
    design : OutputErrorDesign
        The window's design (its split scan reads it), over the buffers' arrays.
    """

    estimate: WindowEstimate
    whole_inertia: float
    whole_damping: float
    whole_explained: bool
    newest: tuple[float, float, float] | None
    design: OutputErrorDesign


def fused_back_end(
    irf: IRF,
    u: FloatArray,
    y: FloatArray,
    options: EstimatorOptions,
    plan: AnalysisPlan,
    held: Held,
    score: ScoredBand,
    *,
    learn: bool = False,
    newest_rows: int = 0,
    buffers: BackEndBuffers | None = None,
) -> FusedWindow:
    """Steps 4–5 of a window (:func:`fusable`) in one call into the compiled kernel.

    Parameters
    ----------
    irf, u, y
        The analysed window (IRF, band-limited position rad and torque N·m).
    options : EstimatorOptions
    plan : AnalysisPlan
        The window's analysis (the sandwich's noise lags).
    held : Held
        Values held in the published fit.
    score : ScoredBand
        What the published VAF scores.
    learn : bool
        Also fit the full model (nothing held) for the held parameters to learn from (with
        nothing held the published fit is that fit).
    newest_rows : int
        Rows of the window's newest hop whose K to read (0: none).
    buffers : BackEndBuffers, optional
        A stream's buffers (default: allocated for this call).

    Raises
    ------
    NumericalError
        Zero torque, or free regressors that cannot be separated (as the numpy fit).
    """
    m = u.shape[0]
    buf = (buffers or BackEndBuffers()).for_window(m, irf, plan, score.band_hz)
    inertia, damping = held.inertia, held.damping
    k = 0 if inertia is None else (1 if damping is None else 2)
    if k:
        buf.held[0] = inertia
        buf.held[1] = 0.0 if damping is None else damping
    y_c = np.ascontiguousarray(y)
    explained = score.explained
    status = (_eureka.oe_window_tabled if buf.table.size else _tableless)(
        np.ascontiguousarray(u),
        y_c,
        np.ascontiguousarray(irf.h),
        irf.fs_hz,
        k,
        buf.held,
        learn,
        options.uncertainty,
        buf.lags,
        None if explained is None else np.ascontiguousarray(explained),
        score.torque_slope,
        score.position_slope,
        buf.kmax,
        buf.cos,
        buf.sin,
        newest_rows,
        buf.regressors,
        buf.projected,
        buf.gram,
        buf.model,
        buf.out,
        buf.table,
    )
    if status != _OK:
        raise zero_response() if status == _eureka.OE_ZERO_TORQUE else inseparable_fit()
    out = buf.out.tolist()
    p, s, v, w, z = RESULT_SLOTS
    vafs = published_vafs(out[v], out[v + 1], out[v + 2])
    estimate = assemble(
        irf,
        out[p : p + 3],
        (out[s], out[s + 1], out[s + 2]),
        vafs,
        "output_error",
        options,
        0,
        HELD_FLAGS[k],
        buf.lags_s,
    )
    newest = None if out[z] != out[z] else (out[z], out[z + 1], out[z + 2])
    design = OutputErrorDesign.formed(buf.regressors, buf.projected, buf.gram, y_c)
    whole_explained = full_fit_explains(out[w + 3], options) if learn else False
    return built(
        FusedWindow,
        estimate=estimate,
        whole_inertia=out[w],
        whole_damping=out[w + 1],
        whole_explained=whole_explained,
        newest=newest,
        design=design,
    )


#: The kernel's status for a fitted window, and where ``oe_window`` writes each result.
_OK = None if _eureka is None else _eureka.OE_OK
RESULT_SLOTS: tuple[int, int, int, int, int] = (
    (0, 0, 0, 0, 0)
    if _eureka is None
    else (_eureka.OW_PARAMS, _eureka.OW_SE, _eureka.OW_VAFS, _eureka.OW_WHOLE, _eureka.OW_NEWEST)
)
#: The largest band table kept (float64 values: 128 KiB).
_TABLE_LIMIT = 1 << 14


def kept_band_table(cos: FloatArray, sin: FloatArray, kmax: int) -> FloatArray:
    """The published VAF's twiddles laid out for its DFT (``band_table``), once per plan, when
    they fit in a core's cache; empty otherwise (``oe_window_tabled`` then looks them up).

    The 625 Hz plan's table is 4 k values; a 2500 Hz plan's, 60 k, would be streamed from
    memory every window, so that plan keeps the twiddle lookups.
    """
    size = (kmax + 3) // 4 * cos.size * 8
    table = np.empty(size if size <= _TABLE_LIMIT else 0)
    if table.size:
        _eureka.band_table(cos, sin, kmax, table)
    return table


def _tableless(*args: Any) -> int:
    """``oe_window`` for a plan whose band table is not kept (its last argument, empty)."""
    return int(_eureka.oe_window(*args[:-1]))


def full_fit_explains(vaf_percent: float, options: EstimatorOptions) -> bool:
    """Whether the full fit explains enough of the window to learn held values from:
    ``round(vaf_percent, 12) >= options.low_vaf_percent``, rounding only near the threshold
    (rounding to 12 decimals moves a VAF, ≤ 100 %, by less than 1e-9, so farther away the
    unrounded value compares the same; the round costs a decimal conversion each window)."""
    low = options.low_vaf_percent
    if abs(vaf_percent - low) > 1e-9:
        return vaf_percent >= low
    return round(vaf_percent, 12) >= low  # NaN too: False


#: Whether I and B were held, by the number of held parameters.
HELD_FLAGS = ((False, False), (True, False), (True, True))
