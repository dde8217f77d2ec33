"""Every split of one window's stiffness into a value before and a value after.

After a stiffness step the 300 ms window estimates do not jump: they ramp over a window
length, each averaging the old value over the samples before the step with the new one
after it. No function of the window estimates can read the new value sooner than the ramp
lets it (``rtsid bench tv``'s oracle step read-out). The window's own samples can: the
output-error fit with ``K`` replaced by ``K_before`` on the rows before a split and
``K_after`` on the rows from it, scanned over every split, finds the step's instant to a
sample or two and reads ``K_after`` from the samples after it — 20 ms after a step in the
simulated ankles, against a window length for the ramp.

:func:`split_scan` forms every split of one window at once. Its problem is the window's
(:class:`~rtsid.ident.second_order.OutputErrorDesign`): torque on ``(ü, u̇, u)`` with an
offset and a trend, the held inertia (and damping) moved to the left-hand side, plus one
regressor ``v_s = u·[row ≥ s]`` carrying ``Δ = K_after − K_before``. By the Frisch–Waugh
theorem, with ``X`` the free regressors (offset, trend, the fitted derivatives, ``u``),
``G = XᵀX``, ``c_s = Xᵀv_s`` and ``w_s = G⁻¹c_s``::

    Δ_s = (v_sᵀr − c_sᵀG⁻¹Xᵀr) / (v_sᵀv_s − c_sᵀw_s),   K_after = K̂ + Δ_s·(1 − w_s[K])

where ``K̂`` is the window's own (unsplit) fit. ``c_s`` and ``v_sᵀv_s``, ``v_sᵀr`` are
suffix sums over the rows, so every split costs a few vector operations.

Variances are returned relative to the unsplit ``K̂``'s for white noise, ``σ²·G⁻¹[K,K]``:
the tracker (:mod:`rtsid.ident.tracker`) scales them by the calm windows' own standard error
of ``K``, which carries the residual's colour and the learned scale. (A straddling window's
own standard error balloons with the step it does not model; the calm windows' does not.)

:class:`SplitProblem` builds a window's problem once; besides :meth:`~SplitProblem.scan`
it reads the one split at the window's newest hop (:meth:`~SplitProblem.newest`): K of the
last hop's rows alone, which consecutive windows never share — the tracker's fast filter
takes those as independent measurements.

:func:`split_scan` makes one call into the compiled kernel when it was built
(``split_scan``: the problem and every split, into a stream's :class:`ScanBuffers`);
:class:`SplitProblem` in numpy is the reference it is tested against (``RTSID_NUMPY_ONLY=1``
runs it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid.ident.analysis import AnalysisPlan
from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.second_order import OutputErrorDesign

_eureka: Any = compiled_kernel()

FloatArray = NDArray[np.float64]

#: Rows a split leaves on each side at least (analysis samples).
MIN_SIDE_ROWS = 3

__all__ = [
    "NewestPart",
    "ScanBuffers",
    "SplitProblem",
    "SplitScan",
    "row_offsets_s",
    "split_scan",
]


@dataclass(frozen=True)
class SplitScan:
    """Every split of one window's K (see the module notes), one entry per design row.

    Attributes
    ----------
    offsets_s : numpy.ndarray
        Each row's time before the window's last sample, s (decreasing).
    k_after : numpy.ndarray
        ``K`` fitted to the rows from this one on (``K_before`` free), N·m/rad.
    k_before : numpy.ndarray
        ``K`` fitted to the rows before this one (with ``K_after``), N·m/rad.
    z_ratio : numpy.ndarray
        ``Δ`` over its standard error relative to ``K̂``'s: ``Δ_s / √(var Δ_s / σ_K²)``;
        divided by the standard error of ``K̂`` it is the split's z statistic.
    after_var : numpy.ndarray
        ``var K_after / σ_K²``.
    usable : numpy.ndarray of bool
        Splits with at least :data:`MIN_SIDE_ROWS` rows on each side.
    best_row : int
        :meth:`best`'s answer when already found (the compiled scan finds it; -1: no usable
        split), -2 when not.
    """

    offsets_s: FloatArray
    k_after: FloatArray
    k_before: FloatArray
    z_ratio: FloatArray
    after_var: FloatArray
    usable: NDArray[np.bool_]
    best_row: int = -2

    def best(self) -> int | None:
        """The most significant split's row (None: no usable split)."""
        if self.best_row != -2:
            return None if self.best_row < 0 else self.best_row
        if not self.usable.any():
            return None
        return int(np.argmax(np.where(self.usable, np.abs(self.z_ratio), -1.0)))

    def row_at(self, offset_s: float) -> int | None:
        """The first row at or after the instant ``offset_s`` before the window's end
        (None: no usable split there)."""
        row = int(np.searchsorted(-self.offsets_s, -offset_s))
        return row if row < self.usable.size and self.usable[row] else None


def split_scan(
    design: OutputErrorDesign,
    inertia: float | None,
    damping: float | None,
    plan: AnalysisPlan,
    window_samples: int,
    buffers: ScanBuffers | None = None,
) -> SplitScan | None:
    """Every split of the window's ``K`` with the held ``inertia`` (and ``damping``).

    Parameters
    ----------
    design : OutputErrorDesign
        The window's output-error problem.
    inertia, damping : float or None
        Held values (None: fitted; damping is held only with inertia).
    plan : AnalysisPlan
        The window's analysis (places each row within the window).
    window_samples : int
        Samples in the window at the data rate.

    buffers : ScanBuffers, optional
        Where the compiled scan writes (a stream's, reused every window: the scan's arrays
        are then valid until its next scan); default: new arrays.

    Returns
    -------
    SplitScan or None
        None for a window with lost samples (its rows are not contiguous) or too few rows.
    """
    if _eureka is not None and design.keep is None:
        return _compiled_scan(design, inertia, damping, plan, window_samples, buffers)
    problem = SplitProblem.of(design, inertia, damping, plan, window_samples)
    return None if problem is None else problem.scan()


class ScanBuffers:
    """The compiled scan's output rows (``SS_ROWS`` × n) and held values, allocated once per
    window size (a stream's windows are all alike) instead of once per scan."""

    def __init__(self) -> None:
        self.out = np.empty((0, 0))
        self.held = np.zeros(2)

    def for_rows(self, n: int) -> ScanBuffers:
        """These buffers sized for ``n`` design rows."""
        if self.out.shape[1] != n:
            self.out = np.empty((_eureka.SS_ROWS, n))
        return self


def _compiled_scan(
    design: OutputErrorDesign,
    inertia: float | None,
    damping: float | None,
    plan: AnalysisPlan,
    window_samples: int,
    buffers: ScanBuffers | None,
) -> SplitScan | None:
    """:meth:`SplitProblem.of` and :meth:`SplitProblem.scan` in one compiled call."""
    regressors = design.regressors
    buf = (buffers or ScanBuffers()).for_rows(regressors.shape[1])
    k = 0 if inertia is None else (1 if damping is None else 2)
    held = buf.held
    held[0] = 0.0 if inertia is None else inertia
    held[1] = 0.0 if damping is None or k < 2 else damping
    best = _eureka.split_scan(
        regressors,
        np.ascontiguousarray(design.measured),
        k,
        held,
        float(plan.factor),
        (plan.taps.size - 1) / 2.0,
        float(window_samples),
        plan.fs_hz,
        buf.out,
    )
    if best == _eureka.SS_NO_PROBLEM:
        return None
    offsets, k_after, k_before, z_ratio, after_var, usable = buf.out
    return SplitScan(offsets, k_after, k_before, z_ratio, after_var, usable > 0.0, best)


@dataclass(frozen=True)
class NewestPart:
    """:meth:`SplitProblem.newest`'s answer.

    Attributes
    ----------
    k : float
        ``K`` of the newest rows, N·m/rad.
    var : float
        Its variance relative to the whole window's ``K``'s (``σ_K²``).
    centre_s : float
        The rows' centre before the window's last sample, s.
    """

    k: float
    var: float
    centre_s: float


@dataclass(frozen=True)
class SplitProblem:
    """One window's splits of ``K``: its free regressors ``X`` (offset, trend, the fitted
    derivatives, ``u``) over the torque they fit (held parameters moved to the left), with
    ``(XᵀX)⁻¹`` and the unsplit ``K̂``; built once per window (:meth:`of`)."""

    x: FloatArray
    p: int
    inverse: FloatArray
    gkk: float
    xr: FloatArray
    k_hat: float
    plan: AnalysisPlan
    window_samples: int

    @classmethod
    def of(
        cls,
        design: OutputErrorDesign,
        inertia: float | None,
        damping: float | None,
        plan: AnalysisPlan,
        window_samples: int,
    ) -> SplitProblem | None:
        """The window's problem (arguments as :func:`split_scan`'s; None as its)."""
        if design.keep is not None:
            return None
        d2, d1, u = design.regressors
        n = u.size
        if n < 2 * MIN_SIDE_ROWS + 4:
            return None
        n_held = 0 if inertia is None else (1 if damping is None else 2)
        p = 5 - n_held  # offset, trend, the fitted derivatives, u
        x = np.empty((p + 1, n))  # the free regressors, then the torque they fit
        x[0] = 1.0
        x[1] = np.arange(n, dtype=np.float64) - (n - 1) / 2.0
        x[2 : p - 1] = design.regressors[n_held:2]
        x[p - 1] = u
        x[p] = design.measured
        if n_held:
            x[p] -= inertia * d2
        if n_held == 2:
            x[p] -= damping * d1
        gram = x @ x[:p].T  # (p + 1, p): XᵀX over Xᵀr
        try:
            inverse = np.linalg.inv(gram[:p])
        except np.linalg.LinAlgError:
            return None
        gkk = float(inverse[-1, -1])
        if not gkk > 0:
            return None
        xr = gram[p]
        k_hat = float(inverse[-1] @ xr)
        return cls(x, p, inverse, gkk, xr, k_hat, plan, window_samples)

    def scan(self) -> SplitScan:
        """Every split at once (suffix sums; see the module notes)."""
        x, p = self.x, self.p
        u = x[p - 1]
        sums = np.cumsum((x * u)[:, ::-1], axis=1)[:, ::-1]  # Xᵀv_s and v_sᵀr, every split s
        c = sums[:p]
        w = self.inverse @ c
        pvv = c[-1] - np.einsum("in,in->n", c, w)  # v_sᵀv_s = Σ u² from s on is c[-1]
        pvr = sums[p] - self.xr @ w
        n = u.size
        rows = np.arange(n, dtype=np.float64)
        usable = (rows >= MIN_SIDE_ROWS) & (rows <= n - MIN_SIDE_ROWS) & (pvv > 1e-12 * c[-1, 0])
        safe = np.where(usable, pvv, 1.0)
        delta = np.where(usable, pvr / safe, 0.0)
        after_k = 1.0 - w[-1]
        k_after = self.k_hat + delta * after_k
        return SplitScan(
            self._offsets_s(rows),
            k_after,
            k_after - delta,
            delta * np.sqrt(safe * self.gkk),
            1.0 + after_k * after_k / (safe * self.gkk),
            usable,
        )

    def newest(self, span_s: float) -> NewestPart | None:
        """``K`` of the window's newest ``span_s`` (one hop), the rest of the window with
        its own ``K``: the one split of :meth:`scan` at the first of the last
        ``round(span_s·analysis rate)`` rows. Consecutive windows' newest parts share no
        samples, so their errors are nearly independent (lag-one correlation 0.03–0.17 on
        the simulated ankles), unlike the windows' own. None: fewer than
        :data:`MIN_SIDE_ROWS` rows in the span, or none of ``u``'s variation in it."""
        x, p = self.x, self.p
        u = x[p - 1]
        n = u.size
        first = max(n - round(span_s * self.plan.analysis_fs_hz), MIN_SIDE_ROWS)
        if n - first < MIN_SIDE_ROWS:
            return None
        sums = x[:, first:] @ u[first:]
        c = sums[:p]
        w = self.inverse @ c
        pvv = float(c[-1] - c @ w)
        if not pvv > 1e-12 * float(c[-1]):
            return None
        delta = float(sums[p] - self.xr @ w) / pvv
        after_k = 1.0 - float(w[-1])
        return NewestPart(
            self.k_hat + delta * after_k,
            1.0 + after_k * after_k / (pvv * self.gkk),
            float(self._offsets_s(np.array([0.5 * (first + n - 1)]))[0]),
        )

    def _offsets_s(self, rows: FloatArray) -> FloatArray:
        """Each (fractional) row's time before the window's last sample, s."""
        return row_offsets_s(rows, self.plan, self.window_samples)


def row_offsets_s(rows: Any, plan: AnalysisPlan, window_samples: int) -> Any:
    """Each (fractional) design row's time before the window's last sample, s (``rows`` a
    float or an array)."""
    delay = (plan.taps.size - 1) / 2.0
    return (window_samples - 1 - ((rows + 4.0) * plan.factor + delay)) / plan.fs_hz
