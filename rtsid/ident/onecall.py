"""A stream's window in one compiled call (``onecall_window``), from its checks to its fit.

Once a stream's plan is known, every window without lost samples goes through the same steps:
the checks (:func:`rtsid.ident.check.check_window`), the front end
(:func:`rtsid.ident.front.analyse_checked`), the band-limited level and the stream's relative
excitation check, the scored band (:func:`rtsid.ident.front.scored_band`) and the fused back end
(:func:`rtsid.ident.fused.fused_back_end`: the full fit the held parameters learn from, the
published fit with its standard errors, the VAFs and the newest hop's K). Called one by one they
cost some 60 Python-level calls a window; :class:`WindowCall` makes one, into buffers allocated
once per plan and window length, with the plan's constants packed once.

The call runs the same C functions in the same order as the separate calls, so the numbers are
theirs bit for bit. It declines (returns None) every window the step-by-step path would withhold
or fail — a check, a singular system, a zero torque — and the caller then runs that path, which
says why with its own error: the reference stays the one place each error is raised.
``RTSID_NUMPY_ONLY=1`` (no compiled kernel) leaves every window to the step-by-step path.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid.ident.analysis import AnalysisPlan
from rtsid.ident.assess import ESTIMATE_FIELDS, FLAG_ORDER, WindowEstimate, band_bins, twiddles
from rtsid.ident.fit import Held, noise_lags
from rtsid.ident.fused import HELD_FLAGS, kept_band_table
from rtsid.ident.irf import IRF
from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.options import EstimatorOptions
from rtsid.ident.split import NewestPart

__all__ = ["OUT_LEVEL", "WindowCall", "one_call_possible"]

FloatArray = NDArray[np.float64]

_eureka: Any = compiled_kernel()
_onecall_window: Any = None if _eureka is None else _eureka.onecall_window
_stream_window: Any = None if _eureka is None else _eureka.stream_window

_DETREND_CODES = {"none": 0, "mean": 1, "linear": 2}

#: Where ``onecall_window`` writes (``out``): the fused back end's values (``OW_*``), then the
#: band-limited level (rad). The estimate's flags are :func:`rtsid.ident.assess.window_flags`'s,
#: formed by the caller as for every other estimate.
OUT_LEVEL = 16 if _eureka is None else _eureka.OW_SIZE
#: ``consts`` of one plan, in the kernel's ``OC_*`` order.
_CONSTS = 13


def one_call_possible(options: EstimatorOptions) -> bool:
    """Whether a stream with ``options`` may fit its windows with :class:`WindowCall`: the
    kernel was built, the criterion is output error and parameters are held (the stream's
    fused path; with nothing held a stream fits by :func:`rtsid.ident.window.back_end`)."""
    return _eureka is not None and options.fit_method == "output_error" and options.hold != "none"


class WindowCall:
    """The buffers and constants of ``onecall_window`` for one plan and window length.

    Parameters
    ----------
    plan : AnalysisPlan
        The stream's plan.
    options : EstimatorOptions
        The stream's settings.
    window_samples : int
        Samples in each window at the data rate.
    newest_rows : int
        Analysis rows of the stream's hop (the newest hop's K), 0: none.

    Attributes
    ----------
    lags_s : numpy.ndarray
        The IRF's lags, s (read-only, every estimate of the plan shares it).
    fs_hz : float
        The analysis rate, Hz.
    regressors, projected, gram, y : numpy.ndarray
        The latest window's output-error design and analysed torque (valid until the next
        call), what its split scan reads.
    out : numpy.ndarray
        The latest window's results (``OW_*`` of the kernel, then :data:`OUT_LEVEL`).
    """

    def __init__(
        self, plan: AnalysisPlan, options: EstimatorOptions, window_samples: int, newest_rows: int
    ) -> None:
        self.plan = plan
        self.window_samples = window_samples
        taps = np.ascontiguousarray(plan.taps, dtype=np.float64)
        factor, lag, fs_a = plan.factor, plan.lag, plan.analysis_fs_hz
        self.fs_hz = fs_a
        self.nh = 2 * lag + 1
        m = (window_samples - taps.size) // factor + 1 if window_samples >= taps.size else 0
        n = max(m - 8, 0)
        cos, sin = twiddles(n) if n else (np.empty(0), np.empty(0))
        band_hz = plan.edge_hz if plan.edge_hz is not None else plan.lowpass_hz / 1.5
        model_irf = IRF(h=np.zeros(self.nh), fs_hz=fs_a, phi_uu=np.zeros(self.nh))
        self.lags_s = model_irf.lags_s
        kmax = band_bins(n, fs_a, band_hz) if n else 0
        self.held = np.zeros(4)  # k, held inertia, held damping, typical level (NaN: none)
        self._held: Held | None = None  # what self.held holds (None: nothing written yet)
        self._k = 0  # parameters held
        table = kept_band_table(cos, sin, kmax) if n else np.empty(0)
        # the kernel's thirteen arrays as views of one buffer, in its order: one buffer to
        # acquire a window (about 1 k instructions each) instead of thirteen
        sizes = (taps.size, n, n, m, m, self.nh, m, 3 * n, 4 * n, 16, n, OUT_LEVEL + 1, table.size)
        offsets = np.cumsum((0, *sizes[:-1]))
        self.work = np.empty(sum(sizes))
        arrays = [self.work[at : at + size] for at, size in zip(offsets, sizes, strict=True)]
        for view, values in ((0, taps), (1, cos), (2, sin), (12, table)):
            arrays[view][:] = values
        self.u, self.y, self.extra = arrays[3], arrays[4], arrays[6]
        self.regressors, self.projected = arrays[7].reshape(3, n), arrays[8].reshape(4, n)
        self.gram, self.model, self.out = arrays[9].reshape(4, 4), arrays[10], arrays[11]
        layout = [float(v) for pair in zip(offsets, sizes, strict=True) for v in pair]
        consts = [0.0] * _CONSTS
        consts[0], consts[1], consts[2] = (
            factor,
            options.torque_sign,
            _DETREND_CODES[options.detrend],
        )
        consts[3], consts[4], consts[5], consts[6] = lag, options.refine, options.ridge, fs_a
        consts[7], consts[8] = options.min_excitation_rad, options.min_relative_excitation
        consts[9], consts[10] = float(options.uncertainty), noise_lags(model_irf, plan)
        consts[11] = kmax
        consts[12] = newest_rows
        self.consts = np.array(consts + layout, dtype=np.float64)
        # stream_window's context for each count of held parameters (its "k")
        low = float(options.low_vaf_percent)
        fixed = (WindowEstimate, ESTIMATE_FIELDS, self.lags_s, fs_a, "output_error", 0)
        # the newest hop's record: its centre row placed as split.row_offsets_s places it
        delay = (plan.taps.size - 1) / 2.0
        newest = (NewestPart, float(window_samples - 1), float(factor), delay, plan.fs_hz)
        self._contexts = tuple((*fixed, HELD_FLAGS, FLAG_ORDER, low, k, newest) for k in range(3))

    def __call__(
        self,
        position: Any,
        torque: Any,
        explained: Any,
        held: Held,
        typical_rad: float | None,
    ) -> tuple[list[float], FloatArray, int] | None:
        """One window: ``(out as a list, the IRF (a new array, N·m/rad/s), held count)``;
        None when declined (the caller runs the step-by-step path).

        Parameters
        ----------
        position, torque : numpy.ndarray, shape (window_samples,)
            The window (rad; N·m, another pathway's torque already subtracted).
        explained : numpy.ndarray or None
            That torque (same samples and sign as ``torque``).
        held : Held
            What the published fit holds.
        typical_rad : float or None
            The stream's typical band-limited level before this window (None: not known).
        """
        state = self.held
        self._write_held(held)
        state[3] = np.nan if typical_rad is None else typical_rad
        h = np.empty(self.nh)
        status = _onecall_window(
            np.ascontiguousarray(position, dtype=np.float64),
            np.ascontiguousarray(torque, dtype=np.float64),
            None if explained is None else np.ascontiguousarray(explained, dtype=np.float64),
            h,
            self.work,
            self.consts,
            state,
        )
        if status:
            return None
        return self.out.tolist(), h, self._k

    def stream_window(
        self,
        position: Any,
        torque: Any,
        explained: Any,
        held: Held,
        excitation: Any,
        learned: tuple[Any, Any],
    ) -> tuple[WindowEstimate, bool, NewestPart | None] | None:
        """One window and the stream's bookkeeping in one compiled call (``stream_window``):
        what :meth:`__call__` and :meth:`rtsid.ident.stream.WindowStream._fit_in_one_call`
        do with its results (the typical level read from and this window's added to
        ``excitation``, the estimate assembled with its flags, the full fit learned by the
        ``learned`` running medians of I and B), the same numbers. Returns ``(estimate,
        whether the full fit was learned, the newest hop's (K, variance, centre row) or
        None)``; None when declined (nothing changed).

        ``excitation`` and ``learned`` are compiled running medians
        (:func:`rtsid.ident.stream.running_median`).
        """
        self._write_held(held)
        return _stream_window(
            np.ascontiguousarray(position, dtype=np.float64),
            np.ascontiguousarray(torque, dtype=np.float64),
            None if explained is None else np.ascontiguousarray(explained, dtype=np.float64),
            np.empty(self.nh),
            self.work,
            self.consts,
            self.held,
            self.out,
            excitation,
            learned[0],
            learned[1],
            self._contexts[self._k],
        )

    def _write_held(self, held: Held) -> None:
        """``state``'s held values (written once for each held value: a stream keeps it)."""
        if held is self._held:
            return
        self._held = held
        state = self.held
        inertia, damping = held.inertia, held.damping
        self._k = k = 0 if inertia is None else (1 if damping is None else 2)
        state[0] = k
        if k:
            state[1] = inertia
            state[2] = 0.0 if damping is None else damping
