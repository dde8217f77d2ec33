"""The reflex pathway of the parallel-cascade model: velocity → static nonlinearity → dynamics.

Two variants (Kearney, Stein & Parameswaran, IEEE TBME 44(6), 1997; Westwick & Kearney,
*Identification of Nonlinear Physiological Systems*, 2003):

* ``rect`` — half-wave-rectified velocity ``max(θ̇, 0)`` into a one-sided IRF;
* ``hammerstein`` — a polynomial ``p(θ̇)`` (degree 3, powers of the velocity over its RMS)
  into a one-sided IRF, ``p`` and the IRF found alternately (Hunter–Korenberg).

Both work on signals decimated to the model's rate (100 Hz by default). The IRF covers lags
``0 … L`` (≈ 1 s); its Toeplitz normal equations are solved by EUREKA, and its *effective
rank* is then chosen by the minimum description length (:func:`mdl_projection`): the
solution is written in the eigenvectors of the Toeplitz matrix, ordered by the output variance
each explains, and the first ``M`` are kept where ``V(M)·(1 + M·ln N / N)`` is smallest
(``V(M)`` the residual variance with ``M`` components, ``N`` the samples) — the
pseudo-inverse IRF of Westwick & Kearney, ch. 5.

The delay is estimated from the IRF: a delayed second-order low-pass ``G·h(t − δ)`` (unit
static gain, corner ``f_c``, damping ratio ``ζ``) is fitted to the IRF lags by nonlinear
least squares (:func:`fit_reflex_dynamics`), which places the onset between lags. ``G`` is the
reflex gain reported (N·m·s/rad: torque per rad/s of stretch velocity).

The delay is searched from one model sample (10 ms at 100 Hz) to :data:`DELAY_MAX_S`
(:func:`delay_search_s`): the IRF's lag 0 holds the rectifier's instantaneous share
(``max(θ̇, 0) = θ̇/2 + |θ̇|/2``, and the intrinsic pathway's damping explains ``θ̇/2`` as well),
so an onset before the first lag is not resolved. A delay that ends at a bound of that search
is not a measured delay: :attr:`ReflexDynamics.delay_at_bound` says which bound. On the shared
real record the fit ends at the lower bound at every model rate tried (10.0 ms at 100 Hz,
5.0 at 200 Hz, 4.0 at 250 Hz) and in every 20 s window; on simulated reflexes of 20, 30 and
50 ms it finds 21.3, 30.0 and 51.1 ms.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rtsid.errors import InputDataError
from rtsid.ident.correlation import auto_correlation, causal_cross_correlation, detrend
from rtsid.ident.designs import design
from rtsid.ident.filters import stencil_derivatives, stencil_velocity
from rtsid.ident.levinson import compiled_kernel, eureka

__all__ = [
    "REFLEX_VARIANTS",
    "ReflexDynamics",
    "ReflexInputs",
    "ReflexPathway",
    "ReflexStream",
    "ToeplitzSystem",
    "bounded_least_squares",
    "convolve_causal",
    "convolve_causal_reference",
    "decimated",
    "decimated_rows",
    "delay_search_s",
    "fit_reflex_dynamics",
    "fit_reflex_pathway",
    "mdl_on_eigenpairs",
    "mdl_projection",
    "prediction_history_s",
    "stream_taps",
    "stretch_velocity",
    "to_data_rate",
    "zero_phase",
    "zero_phase_rows",
]

FloatArray = NDArray[np.float64]

_eureka = compiled_kernel()

REFLEX_VARIANTS = ("rect", "hammerstein")
POLYNOMIAL_DEGREE = 3
HAMMERSTEIN_SWEEPS = 4
#: The grid searched before the delayed low-pass is refined (δ is then continuous), from
#: the search's lower bound (:func:`delay_search_s`).
DELAY_GRID_S = np.arange(0.0, 0.1501, 0.002)
#: The longest reflex delay searched, s.
DELAY_MAX_S = 0.2


def delay_search_s(fs_hz: float) -> tuple[float, float]:
    """The reflex delay's search range at the model's rate ``fs_hz``, s: one model sample
    (an earlier onset is not resolved, see the module notes) to :data:`DELAY_MAX_S`."""
    return 1.0 / fs_hz, DELAY_MAX_S


CORNER_GRID_HZ = np.geomspace(0.3, 20.0, 24)
DAMPING_GRID = np.geomspace(0.3, 2.5, 10)


@dataclass(frozen=True)
class _Decimator:
    """A filter and what its zero-phase run (scipy's ``sosfiltfilt``) needs, computed once per
    filter (the decimator's once per factor)."""

    sos: FloatArray  # second-order sections (n, 6)
    zi: FloatArray  # sosfilt_zi(sos): steady-state initial conditions per unit step (n, 2)
    edge: int  # samples of odd extension at each end (scipy's default padlen)


def _zero_phase_of(sos: FloatArray) -> _Decimator:
    """What scipy's ``sosfiltfilt(sos, x)`` (default padding) needs, for the filter ``sos``
    (its ``sosfilt_zi`` from the design cache: :func:`rtsid.ident.designs.design`)."""
    zeros = min(int((sos[:, 2] == 0).sum()), int((sos[:, 5] == 0).sum()))
    edge = 3 * (2 * len(sos) + 1 - zeros)
    return _Decimator(sos, design("sosfilt_zi", sos), edge)


@lru_cache(maxsize=8)
def _decimator(factor: int) -> _Decimator:
    """The decimator's filter (scipy's ``cheby1``, from the design cache)."""
    return _zero_phase_of(design("cheby1", 8, 0.05, 0.8 / factor, output="sos"))


@lru_cache(maxsize=8)
def _zero_phase_setup(sos_bytes: bytes, sections: int) -> _Decimator:
    sos = np.frombuffer(sos_bytes, dtype=np.float64).reshape(sections, 6).copy()
    return _zero_phase_of(sos)


def zero_phase(sos: FloatArray, x: FloatArray) -> FloatArray:
    """``scipy.signal.sosfiltfilt(sos, x)`` of a 1-D ``x`` with scipy's default padding: the
    same numbers bit for bit, by the compiled kernel's ``sos_filtfilt`` when built (the
    filter's initial conditions prepared once per filter)."""
    sos = np.ascontiguousarray(sos, dtype=np.float64)
    return _filtfilt(_zero_phase_setup(sos.tobytes(), len(sos)), np.asarray(x, dtype=np.float64))


def zero_phase_rows(sos: FloatArray, rows: Sequence[ArrayLike]) -> FloatArray:
    """:func:`zero_phase` of each of ``rows`` (``k`` of ``n`` samples; shape (k, n)): the
    same numbers bit for bit, by the compiled kernel's ``zero_phase_rows`` (four rows at
    once) when built."""
    sos = np.ascontiguousarray(sos, dtype=np.float64)
    return _zero_phase_rows(_zero_phase_setup(sos.tobytes(), len(sos)), rows, 1)


def _zero_phase_rows(d: _Decimator, rows: Sequence[ArrayLike], factor: int) -> FloatArray:
    """``_filtfilt(d, row)[::factor]`` of each row (``k`` rows of ``n`` samples → shape
    (k, ⌈n/factor⌉)), in one call of the compiled ``zero_phase_rows`` when built and the rows
    are longer than the padding (the rows read where they are, their odd extension built
    there: no copy here); each row alone through :func:`_filtfilt` otherwise (the reference:
    the same numbers bit for bit)."""
    x = tuple(np.ascontiguousarray(row, dtype=np.float64) for row in rows)
    n = x[0].size
    if _eureka is None or n <= d.edge:
        return np.vstack([_filtfilt(d, row)[::factor] for row in x])
    out = np.empty((len(x), -(-n // factor)))
    _eureka.zero_phase_rows(d.sos, d.zi, x, n, d.edge, factor, out)
    return out


def _filtfilt(d: _Decimator, x: FloatArray) -> FloatArray:
    """scipy's ``sosfiltfilt`` step by step with ``d``'s filter (its checks and messages for
    a record no longer than the padding)."""
    from scipy import signal

    if x.size <= d.edge:
        return np.asarray(signal.sosfiltfilt(d.sos.copy(), x), dtype=np.float64)
    ext = np.concatenate(
        (2 * x[0] - x[d.edge : 0 : -1], x, 2 * x[-1] - x[-2 : -d.edge - 2 : -1])
    )  # scipy's odd extension
    if _eureka is not None:  # the same two passes compiled, bit for bit (tested)
        _eureka.sos_filtfilt(d.sos, d.zi, ext)
        return ext[d.edge : -d.edge]
    y, _ = signal.sosfilt(d.sos, ext, zi=d.zi * ext[0])
    y, _ = signal.sosfilt(d.sos, y[::-1], zi=d.zi * y[-1])
    return np.asarray(y[::-1][d.edge : -d.edge], dtype=np.float64)


def decimated(x: FloatArray, factor: int) -> FloatArray:
    """``x`` at ``1/factor`` of its rate: MATLAB's and scipy's default decimator (8th-order
    Chebyshev I at 0.8 × the new Nyquist rate, run forwards and backwards; the same numbers as
    ``scipy.signal.decimate(x, factor)``: scipy's ``sosfiltfilt`` step by step, its filter
    and initial conditions computed once per factor instead of on every call; the two passes
    by the compiled kernel's ``sos_filtfilt`` when built, scipy's ``sosfilt`` loop bit for
    bit)."""
    if factor == 1:
        return np.array(x, dtype=np.float64)
    return np.asarray(
        _filtfilt(_decimator(factor), np.asarray(x, dtype=np.float64))[::factor],
        dtype=np.float64,
    )


def decimated_rows(rows: Sequence[FloatArray], factor: int) -> FloatArray:
    """:func:`decimated` of each of ``rows`` (equal lengths ``n``), shape
    (k, ⌈n/factor⌉): the same numbers bit for bit, all rows in one call of the compiled
    kernel when built (a cascade decimates its position, torque and rectified velocity
    together)."""
    if factor == 1:
        return np.vstack(rows).astype(np.float64, copy=False)
    return _zero_phase_rows(_decimator(factor), rows, factor)


def stretch_velocity(position: FloatArray, fs_hz: float) -> FloatArray:
    """Joint velocity at the data's own rate (rad/s), the input of the reflex nonlinearity:
    the muscle spindle sees the velocity before any decimation, so the rectifier (or
    polynomial) acts at the full rate and its output is decimated afterwards."""
    x = detrend(position, "linear")
    if x.size < 9:
        raise InputDataError(f"derivatives need at least 9 samples, got {x.size}")
    # filters.derivatives' first derivative (its second is not needed): the 9-point stencil,
    # and numpy.gradient's estimates at the four samples of each end (from those samples
    # alone: the same numbers as over the whole record)
    velocity = np.empty(x.size)
    stencil_velocity(x, fs_hz, out=velocity[4:-4])
    velocity[:4], velocity[-4:] = _gradient_ends(x[:5].tolist(), x[-5:].tolist(), 1.0 / fs_hz)
    return velocity


def _gradient_ends(
    head: list[float], tail: list[float], dt: float
) -> tuple[list[float], list[float]]:
    """``numpy.gradient(head, dt, edge_order=2)[:4]`` and ``numpy.gradient(tail, dt,
    edge_order=2)[-4:]`` of five samples each, by its very expressions (its one-sided
    second-order ends and central interior) in Python floats: the same numbers bit for bit
    (tested) without two numpy calls per fit."""
    a0, b0, c0 = -1.5 / dt, 2.0 / dt, -0.5 / dt
    a1, b1, c1 = 0.5 / dt, -2.0 / dt, 1.5 / dt
    two_dt = 2.0 * dt
    first = [a0 * head[0] + b0 * head[1] + c0 * head[2]]
    first += [(head[i + 1] - head[i - 1]) / two_dt for i in (1, 2, 3)]
    last = [(tail[i + 1] - tail[i - 1]) / two_dt for i in (1, 2, 3)]
    last.append(a1 * tail[2] + b1 * tail[3] + c1 * tail[4])
    return first, last


@dataclass(frozen=True)
class ToeplitzSystem:
    """An IRF input's symmetric Toeplitz matrix, formed once per input and lag span (a
    cascade's ``rect`` alternations all fit the same input), and its eigendecomposition when
    asked for (the numpy path's MDL rank; the compiled one needs none, :func:`mdl_projection`).

    Attributes
    ----------
    phi_rr : numpy.ndarray, shape (L+1,)
        First column: the input's autocorrelation at lags ``0 … L``.
    """

    phi_rr: FloatArray

    @property
    def eigenvalues(self) -> FloatArray:
        """Of the matrix, ascending (``numpy.linalg.eigh``'s order), shape (L+1,)."""
        return self._eigenpairs[0]

    @property
    def vectors(self) -> FloatArray:
        """The eigenvectors, by column, shape (L+1, L+1)."""
        return self._eigenpairs[1]

    @cached_property
    def decomposition(self) -> bytes | None:
        """The compiled ``mdl_decompose``'s tridiagonal halves, eigenvalues and rotations (what
        :func:`mdl_projection` needs of the matrix, formed on first use); None on the numpy
        path or below 4 lags."""
        if _eureka is None or self.phi_rr.size < 4:
            return None
        return bytes(_eureka.mdl_decompose(np.ascontiguousarray(self.phi_rr, dtype=np.float64)))

    @cached_property
    def _eigenpairs(self) -> tuple[FloatArray, FloatArray]:
        """The eigenvalues and vectors.

        A symmetric Toeplitz matrix is centrosymmetric, so each eigenvector is symmetric or
        skew-symmetric about its middle: the matrix splits into two of half the size (the
        symmetric and the skew-symmetric halves, :func:`_centrosymmetric_halves`), and two
        half-size ``eigh`` cost a quarter of the whole one (the same eigenpairs to rounding,
        tested against ``numpy.linalg.eigh`` of the whole matrix).
        """
        phi_rr = self.phi_rr
        lags = phi_rr.size
        if lags < 4:
            index = np.abs(np.arange(lags)[:, None] - np.arange(lags)[None, :])
            eigenvalues, vectors = np.linalg.eigh(phi_rr[index])
            return eigenvalues, vectors
        symmetric, skew = _centrosymmetric_halves(phi_rr)
        values_s, vectors_s = np.linalg.eigh(symmetric)
        values_k, vectors_k = np.linalg.eigh(skew)
        half = lags // 2
        vectors = np.empty((lags, lags))
        a, b = vectors[:, : values_s.size], vectors[:, values_s.size :]
        a[:half] = vectors_s[:half] * np.sqrt(0.5)
        a[lags - half :] = a[half - 1 :: -1] if half else a[:0]
        if lags % 2:
            a[half] = vectors_s[half]
            b[half] = 0.0
        b[:half] = vectors_k * np.sqrt(0.5)
        b[lags - half :] = -b[half - 1 :: -1]
        eigenvalues = np.concatenate((values_s, values_k))
        order = np.argsort(eigenvalues, kind="stable")
        return eigenvalues[order], np.ascontiguousarray(vectors[:, order])

    @classmethod
    def of(cls, phi_rr: FloatArray) -> ToeplitzSystem:
        """The system whose first column is ``phi_rr``."""
        return cls(phi_rr)

    @classmethod
    def of_input(cls, r: FloatArray, lags: int) -> ToeplitzSystem:
        """The system of a one-sided IRF ``g(0 … lags)`` with input ``r``."""
        return cls.of(auto_correlation(r, lags))


@lru_cache(maxsize=8)
def _half_lags(n: int) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """The lags ``|i − j|`` and ``n − 1 − i − j`` of :func:`_centrosymmetric_halves` for
    ``i, j < n // 2``, and ``i`` (formed once per size; read-only)."""
    i = np.arange(n // 2)
    lags = (np.abs(i[:, None] - i[None, :]), n - 1 - i[:, None] - i[None, :], i)
    for a in lags:
        a.setflags(write=False)
    return lags


def _centrosymmetric_halves(phi_rr: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The symmetric Toeplitz matrix ``T`` (first column ``phi_rr``, size ``n``) in the
    orthonormal bases of the symmetric vectors (``(e_i + e_{n−1−i})/√2``, and the middle
    ``e_m`` when ``n = 2m + 1``) and of the skew-symmetric ones (``(e_i − e_{n−1−i})/√2``):
    ``T_ij ± T_i,n−1−j = φ(|i − j|) ± φ(n − 1 − i − j)`` for ``i, j < n // 2``, and
    ``√2·φ(m − i)`` against the middle.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Shapes (⌈n/2⌉, ⌈n/2⌉) and (n//2, n//2).
    """
    n = phi_rr.size
    half = n // 2
    near_lags, far_lags, i = _half_lags(n)
    near = phi_rr[near_lags]
    far = phi_rr[far_lags]
    symmetric = np.empty((n - half, n - half))
    symmetric[:half, :half] = near + far
    if n % 2:
        edge = np.sqrt(2.0) * phi_rr[half - i]
        symmetric[:half, half] = symmetric[half, :half] = edge
        symmetric[half, half] = phi_rr[0]
    return symmetric, near - far


def mdl_projection(
    phi_rr: FloatArray,
    phi_re: FloatArray,
    power_e: float,
    n: int,
    system: ToeplitzSystem | None = None,
) -> tuple[FloatArray, int]:
    """The minimum-description-length rank of a Toeplitz system and its projected solution.

    Parameters
    ----------
    phi_rr : numpy.ndarray, shape (L+1,)
        First column of the (symmetric Toeplitz) input autocorrelation matrix.
    phi_re : numpy.ndarray, shape (L+1,)
        Input–output cross-correlation.
    power_e : float
        Mean square of the output (``φ_ee(0)``).
    n : int
        Samples behind the correlations.
    system : ToeplitzSystem, optional
        ``ToeplitzSystem.of(phi_rr)``, when already formed (the same numbers either way): the
        compiled path uses its ``decomposition``, the numpy path its eigenpairs.

    Returns
    -------
    (numpy.ndarray, int)
        The solution (in correlation units) projected on the ``M`` leading components, and
        ``M``.

    Raises
    ------
    ArithmeticError
        The compiled eigenvalue iteration did not converge (60 sweeps for one eigenvalue; not
        seen).

    Notes
    -----
    The compiled ``mdl_decompose`` (section ``fits7`` of ``_eureka.c``, once per system:
    :attr:`ToeplitzSystem.decomposition`) reduces each centrosymmetric half to tridiagonal
    form and records implicit QL's rotations instead of accumulating eigenvectors; ``mdl_rank``
    applies them to the solution's coefficients and forms only the kept components' sum:
    the eigenpairs of :func:`mdl_on_eigenpairs` (``numpy.linalg.eigh``, the
    ``RTSID_NUMPY_ONLY=1`` path) to rounding, not bit for bit (tested: the same ranks, the
    projection within 1e-11 of its largest value).
    """
    full = eureka(phi_rr, phi_re)
    system = system or ToeplitzSystem.of(phi_rr)
    decomposition = system.decomposition
    if decomposition is not None:
        projected = np.empty(phi_rr.size)
        rank = _eureka.mdl_rank(decomposition, full, power_e, float(n), projected)
        return projected, int(rank)
    return mdl_on_eigenpairs(system.eigenvalues, system.vectors, full, power_e, n)


def mdl_on_eigenpairs(
    eigenvalues: FloatArray, vectors: FloatArray, full: FloatArray, power_e: float, n: int
) -> tuple[FloatArray, int]:
    """:func:`mdl_projection` from the matrix's eigenpairs (ascending, vectors by column) and
    the full solution ``full``: the numpy reference (``RTSID_NUMPY_ONLY=1``)."""
    coefficients = vectors.T @ full
    explained = np.maximum(eigenvalues, 0.0) * coefficients**2
    order = np.argsort(explained)[::-1]
    residual = power_e - np.cumsum(explained[order])
    ranks = np.arange(1, full.size + 1)
    mdl = np.maximum(residual, 1e-300) * (1.0 + ranks * np.log(n) / n)
    rank = int(ranks[np.argmin(mdl)])
    kept = order[:rank]
    return np.asarray(vectors[:, kept] @ coefficients[kept], dtype=np.float64), rank


def _causal_irf(
    r: FloatArray, e: FloatArray, lags: int, fs_hz: float, system: ToeplitzSystem | None = None
) -> tuple[FloatArray, int]:
    """One-sided IRF ``g(0 … lags)`` from ``r`` to ``e`` at its MDL rank, and the rank
    (``system``: ``r``'s, when already formed)."""
    system = system or ToeplitzSystem.of_input(r, lags)
    phi_re = causal_cross_correlation(r, e, lags)
    projected, rank = mdl_projection(system.phi_rr, phi_re, float(e @ e) / e.size, e.size, system)
    return projected * fs_hz, rank


def convolve_causal(r: FloatArray, g: FloatArray, fs_hz: float) -> FloatArray:
    """``Σ_k g(k)·r(t−k)·Δt`` on the samples of ``r`` (``g`` per second, ``fs_hz`` in Hz).

    The compiled ``causal_convolve`` when built: each output summed over ``k`` in order and
    only the samples of ``r`` formed; equal to the numpy reference
    (:func:`convolve_causal_reference`, ``RTSID_NUMPY_ONLY=1``) to rounding (tested).
    """
    if _eureka is None or g.size == 0:
        return convolve_causal_reference(r, g, fs_hz)
    signal = np.ascontiguousarray(r, dtype=np.float64)
    out = np.empty(signal.size)
    _eureka.causal_convolve(signal, np.ascontiguousarray(g, dtype=np.float64), fs_hz, out)
    return out


def convolve_causal_reference(r: FloatArray, g: FloatArray, fs_hz: float) -> FloatArray:
    """:func:`convolve_causal` in numpy: the first ``r.size`` samples of the full convolution."""
    return np.asarray(np.convolve(r, g / fs_hz)[: r.size], dtype=np.float64)


# ----------------------------------------------------------------------------- dynamics
@dataclass(frozen=True)
class ReflexDynamics:
    """A delayed second-order low-pass fitted to the reflex IRF.

    Attributes
    ----------
    gain : float
        Static gain ``G``, N·m·s/rad (torque per rad/s of the pathway's input).
    delay_s : float
        Onset ``δ``, s.
    corner_hz, damping_ratio : float
        ``f_c`` and ``ζ`` of the low-pass.
    vaf : float
        Of the IRF by the fitted response, % (a low value: the IRF is not of this shape, and
        gain and delay say little).
    delay_search_s : tuple of float
        The ``(lowest, longest)`` delay searched, s (:func:`delay_search_s`).
    """

    gain: float
    delay_s: float
    corner_hz: float
    damping_ratio: float
    vaf: float
    delay_search_s: tuple[float, float] = (float("nan"), float("nan"))

    @property
    def delay_at_bound(self) -> str | None:
        """``"lower"`` or ``"upper"`` when the fitted delay ended at that bound of its search
        (within 1 % of the lower bound; the delay then is not a measurement), else None."""
        low, high = self.delay_search_s
        tolerance = 0.01 * low
        if self.delay_s <= low + tolerance:
            return "lower"
        if self.delay_s >= high - tolerance:
            return "upper"
        return None

    def describe_delay(self) -> str:
        """``"delay 40.2 ms"``, and at a bound of the search what that means."""
        said = f"delay {self.delay_s * 1e3:.1f} ms"
        low, high = (v * 1e3 for v in self.delay_search_s)
        span = f"{low:g}–{high:g} ms search"
        if self.delay_at_bound == "lower":
            return (
                f"{said} (at the lower bound of the {span}: the delay is not resolved and the "
                "true one may be shorter; the reflex IRF's first lags may hold intrinsic torque)"
            )
        if self.delay_at_bound == "upper":
            return (
                f"{said} (at the upper bound of the {span}: the true delay may be longer, or "
                "the reflex IRF holds no clear onset)"
            )
        return said

    def response(self, lags_s: FloatArray) -> FloatArray:
        """``G·h(t − δ)`` at ``lags_s``."""
        return self.gain * _low_pass_response(
            lags_s - self.delay_s, 2 * np.pi * self.corner_hz, self.damping_ratio
        )


#: Placeholder dynamics of a pathway fitted without them (inside the cascade's alternations).
UNFITTED = ReflexDynamics(float("nan"), float("nan"), float("nan"), float("nan"), 0.0)


#: Model-rate samples the decimator needs to settle at the start of a prediction's history.
DECIMATOR_SETTLING = 30


def prediction_history_s(irf_size: int, fs_model_hz: float) -> float:
    """Position history a reflex prediction needs before its first sample, s: the IRF's span
    and the decimator's settling."""
    return (irf_size + DECIMATOR_SETTLING) / fs_model_hz


def _low_pass_response(t: FloatArray, wn: ArrayLike, zeta: ArrayLike) -> FloatArray:
    """Impulse response of ``ωn²/(s² + 2ζωn·s + ωn²)`` at times ``t`` (0 before 0);
    ``wn`` and ``zeta`` broadcast against ``t``."""
    z = np.asarray(zeta, dtype=np.float64)
    z = np.where(np.abs(z - 1.0) < 1e-6, 1.0 + 1e-6, z)
    w = np.asarray(wn, dtype=np.float64)
    root = np.sqrt((z * z - 1.0).astype(np.complex128))
    p1, p2 = w * (-z + root), w * (-z - root)
    tt = np.maximum(t, 0.0)
    h = (w * w / (p1 - p2) * (np.exp(p1 * tt) - np.exp(p2 * tt))).real
    return np.asarray(np.where(t > 0, h, 0.0), dtype=np.float64)


def _low_pass_and_slopes(t: FloatArray, wn: float, zeta: float) -> tuple[FloatArray, FloatArray]:
    """:func:`_low_pass_response` at times ``t`` (s) and its derivatives, shape (3, n), by
    ``t``, ``ωn`` (rad/s) and ``ζ`` (0 where ``t ≤ 0``).

    With ``p₁,₂ = ωn·c₁,₂``, ``c₁,₂ = −ζ ± r``, ``r = √(ζ² − 1)`` and ``A = ωn/(2r)``,
    ``h = Re A·(e^{p₁t} − e^{p₂t})``; ``∂h/∂t = Re A·(p₁e^{p₁t} − p₂e^{p₂t})``;
    ``h(t; ωn) = ωn·f(ωn·t)`` gives ``∂h/∂ωn = (h + t·∂h/∂t)/ωn``; and
    ``∂h/∂ζ = Re[−A·ζ/r²·(e^{p₁t} − e^{p₂t}) + A·ωn·t·(ċ₁e^{p₁t} − ċ₂e^{p₂t})]`` with
    ``ċ₁,₂ = −1 ± ζ/r``. ``h`` is the very numbers of :func:`_low_pass_response`; the
    compiled kernel's ``low_pass_slopes``, when built, gives these to rounding (tested).
    """
    if _eureka is not None:
        t = np.ascontiguousarray(t, dtype=np.float64)
        h_out, slopes_out = np.empty(t.size), np.empty((3, t.size))
        _eureka.low_pass_slopes(t, float(wn), float(zeta), h_out, slopes_out)
        return h_out, slopes_out
    z = 1.0 + 1e-6 if abs(zeta - 1.0) < 1e-6 else float(zeta)
    w = float(wn)
    root = np.sqrt(complex(z * z - 1.0))
    p1, p2 = w * (-z + root), w * (-z - root)
    positive = t > 0
    tt = np.maximum(t, 0.0)
    e1, e2 = np.exp(p1 * tt), np.exp(p2 * tt)
    scale = w * w / (p1 - p2)
    h = np.where(positive, (scale * (e1 - e2)).real, 0.0)
    slopes = np.empty((3, t.size))
    slopes[0] = np.where(positive, (scale * (p1 * e1 - p2 * e2)).real, 0.0)
    slopes[1] = (h + tt * slopes[0]) / w
    by_zeta = -scale * z / (root * root) * (e1 - e2) + scale * w * tt * (
        (-1.0 + z / root) * e1 - (-1.0 - z / root) * e2
    )
    slopes[2] = np.where(positive, by_zeta.real, 0.0)
    return h, slopes


@dataclass(frozen=True)
class _Residue:
    """The grid's delays whose responses start at one residue of the lag step in the time
    table: their scores are one matrix product (see :class:`_Grid`)."""

    table: FloatArray  # (pairs, times): the table's times at this residue, every `step`-th
    delays: NDArray[np.intp]  # the delays' indices in the grid
    rows: NDArray[np.intp]  # (n_lags, delays): where lag k of each delay falls in `table`

    @cached_property
    def _strides(self) -> tuple[int, int, int, slice] | None:
        """``(first, by_lag, by_delay, delays)`` when the placed matrix's entries
        ``(rows[k, j], j)`` are ``first + k·by_lag + j·by_delay`` of its flat buffer and the
        delays are a slice of the grid's (the product form's grids: each delay's rows one
        after the other, the delays every ``step``-th): the placement is then one strided
        assignment, the same matrix; None otherwise."""
        n_lags, count = self.rows.shape
        d = self.delays
        if count < 2 or n_lags < 2:
            return None
        lag_step, delay_step = int(self.rows[1, 0] - self.rows[0, 0]), int(d[1] - d[0])
        row_step = int(self.rows[0, 1] - self.rows[0, 0])
        k, j = np.arange(n_lags)[:, None], np.arange(count)[None, :]
        regular = lag_step == 1 and delay_step > 0
        regular = regular and np.array_equal(self.rows, self.rows[0, 0] + k + j * row_step)
        regular = regular and np.array_equal(d, d[0] + delay_step * np.arange(count))
        if not regular:
            return None
        first = int(self.rows[0, 0]) * count
        by_delay = row_step * count + 1
        corners = [
            first + a + b for a in (0, (n_lags - 1) * count) for b in (0, (count - 1) * by_delay)
        ]
        if min(corners) < 0 or max(corners) >= self.table.shape[1] * count:
            return None
        return first, count, by_delay, slice(int(d[0]), int(d[-1]) + 1, delay_step)

    def place(self, g: FloatArray) -> FloatArray:
        """The matrix (times, delays) holding ``g`` at each delay's rows, zero elsewhere:
        ``table @ place(g)`` are the delays' dot products with ``g``."""
        placed = np.zeros((self.table.shape[1], self.delays.size))
        strides = self._strides
        if strides is None:
            placed[self.rows, np.arange(self.delays.size)] = g[:, None]
            return placed
        first, by_lag, by_delay, _ = strides
        step = placed.itemsize  # a view of the lags' entries (numpy checks it lies within)
        shape, steps = (g.size, self.delays.size), (by_lag * step, by_delay * step)
        np.ndarray(shape, np.float64, placed, first * step, steps)[...] = g[:, None]
        return placed


@dataclass(frozen=True)
class _Grid:
    """The (δ, f_c, ζ) grid on ``n`` lags and its unit-energy responses, formed once per lag
    grid.

    The responses are evaluated on the times ``t = m·Δ`` (``Δ`` = :data:`DELAY_STEP_S`, ``m``
    whole) that ``lag − δ`` takes when the lag step is a whole number ``s`` of ``Δ`` (the
    model's 100 Hz: ``s = 5``), each (f_c, ζ) pair once per time. The response of delay
    ``δ = d·Δ`` at lag ``k`` is then the pair's value at ``m = s·k − d``: for the delays
    with the same ``−d mod s`` these are consecutive columns of every ``s``-th time, and
    their scores against an IRF ``g`` are one matrix product of that table with ``g``
    placed at each delay's offset — a few small products instead of a pass over the
    ``m × n`` response matrix (13 MB at 101 lags). Other lag steps score with that matrix
    (:attr:`shapes`).

    Attributes
    ----------
    params : numpy.ndarray, shape (m, 3)
        The grid points, δ outermost (``m = delays × pairs``; ``pairs`` the (f_c, ζ) pairs).
    norms : numpy.ndarray, shape (delays, pairs)
        The responses' norms before the scaling (at least 1e-300).
    residues : tuple of _Residue
        The product form's tables (empty when the lag step is not a whole number of ``Δ``).
    table : numpy.ndarray, shape (pairs, times)
        Each (f_c, ζ) pair's response at each time the grid takes.
    time_of : numpy.ndarray of int, shape (delays, n)
        The column of ``table`` holding each delay's response at each lag.
    """

    params: FloatArray
    norms: FloatArray
    residues: tuple[_Residue, ...]
    table: FloatArray
    time_of: NDArray[np.intp]

    @cached_property
    def shapes(self) -> FloatArray:
        """Unit-energy responses at the grid points, shape (m, n): formed when first asked
        for (the product form scores without them; at 101 lags they are 13 MB, and forming
        them was most of a process's first reflex fit)."""
        n_lags = self.time_of.shape[1]
        gathered = self.table[:, self.time_of].transpose(1, 0, 2).reshape(-1, n_lags)
        shapes = np.ascontiguousarray(gathered)
        shapes /= self.norms.reshape(-1, 1)
        shapes.setflags(write=False)
        return shapes

    def scores(self, g: FloatArray) -> FloatArray:
        """``|shapes @ g|``, shape (m,): each grid point's best-scaled fit to ``g`` (to
        rounding, by the residues' products when there are some)."""
        if not self.residues:
            return np.asarray(np.abs(self.shapes @ g), dtype=np.float64)
        dots = np.empty(self.norms.shape)
        for r in self.residues:  # the delays' rows a slice where they are (the same numbers)
            strides = r._strides
            dots[r.delays if strides is None else strides[3]] = (r.table @ r.place(g)).T
        return np.asarray(np.abs(dots / self.norms).ravel(), dtype=np.float64)


#: The delay grid's step, s.
DELAY_STEP_S = 0.002


@lru_cache(maxsize=4)
def _grid(n_lags: int, fs_hz: float) -> _Grid:
    """The (δ, f_c, ζ) grid and its responses on ``n_lags`` lags (:class:`_Grid`)."""
    delays = DELAY_GRID_S[DELAY_GRID_S >= delay_search_s(fs_hz)[0]]
    params = np.stack(
        [v.ravel() for v in np.meshgrid(delays, CORNER_GRID_HZ, DAMPING_GRID, indexing="ij")],
        axis=1,
    )
    pairs = params[: CORNER_GRID_HZ.size * DAMPING_GRID.size, 1:]  # δ = delays[0]: all pairs
    step = 1.0 / (fs_hz * DELAY_STEP_S)  # lag step in delay steps
    d = np.rint(delays / DELAY_STEP_S).astype(np.intp)
    whole = abs(step - round(step)) < 1e-9 and np.allclose(d * DELAY_STEP_S, delays, 1e-12, 0)
    if whole:  # t = m·Δ, m = s·k − d
        s = round(step)
        first = -int(d.max())
        m = np.arange(first, s * (n_lags - 1) - int(d.min()) + 1)
        times = m * DELAY_STEP_S
        time_of = s * np.arange(n_lags)[None, :] - d[:, None] - first  # (delays, lags)
    else:  # every distinct t = lag − δ
        lags_s = np.arange(n_lags) / fs_hz
        times, time_of = np.unique(lags_s[None, :] - delays[:, None], return_inverse=True)
        time_of = time_of.reshape(delays.size, n_lags)
    # each (f_c, ζ) evaluated once per time and gathered: every element depends on its own t,
    # f_c and ζ only, so these are the numbers of evaluating every grid point (tested)
    at = np.asarray(times, dtype=np.float64)[None, :]
    table = _low_pass_response(at, 2 * np.pi * pairs[:, :1], pairs[:, 1:])
    norms = np.maximum(_response_norms(table, time_of), 1e-300)
    residues: list[_Residue] = []
    if whole:
        start = time_of[:, 0]
        # the residues as Python ints: np.unique imported numpy.ma (9 ms) in every process
        for rho in sorted(set((start % s).tolist())):
            chosen = np.flatnonzero(start % s == rho)
            rows = (start[chosen][None, :] - rho) // s + np.arange(n_lags)[:, None]
            residues.append(
                _Residue(np.ascontiguousarray(table[:, rho::s]), chosen, np.asarray(rows))
            )
    for a in (params, norms, table, time_of, *(x for r in residues for x in (r.table, r.rows))):
        a.setflags(write=False)
    return _Grid(params, norms, tuple(residues), table, time_of)


def _response_norms(table: FloatArray, time_of: NDArray[np.intp]) -> FloatArray:
    """The norm of each grid point's response, shape (delays, pairs): a delay's responses
    at a time, each in a contiguous row (summed as the whole response matrix's rows were:
    the same numbers; ``table[:, columns]``'s rows are strided, and numpy sums those in
    another order)."""
    norms = np.empty((time_of.shape[0], table.shape[0]))
    for j, columns in enumerate(time_of):
        norms[j] = np.linalg.norm(np.take(table, columns, axis=1), axis=1)
    return norms


def _best_on_grid(g: FloatArray, fs_hz: float) -> tuple[float, float, float]:
    """The grid point (δ, f_c, ζ) whose best-scaled response explains most of the IRF."""
    grid = _grid(g.size, fs_hz)
    i = int(np.argmax(grid.scores(np.asarray(g, dtype=np.float64))))
    return float(grid.params[i, 0]), float(grid.params[i, 1]), float(grid.params[i, 2])


def fit_reflex_dynamics(irf: FloatArray, fs_hz: float) -> ReflexDynamics:
    """Fit ``G·h(t − δ)`` (:class:`ReflexDynamics`) to a one-sided IRF at ``fs_hz``.

    ``G`` is solved linearly for each ``(δ, f_c, ζ)``; these three are first searched on a
    grid (δ every 2 ms from one model sample up to 150 ms, f_c 0.3–20 Hz, ζ 0.3–2.5), then
    refined by bounded nonlinear least squares (δ within :func:`delay_search_s`) from the best
    grid point (:func:`bounded_least_squares`).
    """
    g = np.asarray(irf, dtype=np.float64)
    lags = np.arange(g.size) / fs_hz
    start = np.array(_best_on_grid(g, fs_hz))
    low, high = delay_search_s(fs_hz)
    box = (np.array([low, 0.3, 0.2]), np.array([high, 20.0, 3.0]))
    x, cost = _dynamics_solution(g, lags, start, box)
    delay, corner, zeta = (float(v) for v in x)
    h = _low_pass_response(lags - delay, 2 * np.pi * corner, zeta)
    gain = float(h @ g) / max(float(h @ h), 1e-300)
    power = float(g @ g)
    explained = 100.0 * (1.0 - 2.0 * cost / power) if power > 0 else 0.0
    return ReflexDynamics(gain, delay, corner, zeta, max(0.0, explained), (low, high))


def _dynamics_solution(
    g: FloatArray, lags_s: FloatArray, start: FloatArray, box: tuple[FloatArray, FloatArray]
) -> tuple[FloatArray, float]:
    """:func:`bounded_least_squares` of :class:`_DelayedLowPass` from ``start`` within ``box``
    (``(low, high)``): by the compiled kernel's ``reflex_dynamics_fit`` when built (the same
    steps in one call, no Python per iteration: equal to the numpy reference to the solver's
    tolerance, tested), else the numpy reference.

    Raises
    ------
    numpy.linalg.LinAlgError
        A damped system is singular (as ``numpy.linalg.solve`` raises there).
    """
    low, high = box
    if _eureka is None:
        model = _DelayedLowPass(g, lags_s)
        return bounded_least_squares(
            model.residual, model.jacobian, start, low, high, DYNAMICS_SCALE
        )
    x = np.empty(3)
    limit = 100 * x.size  # bounded_least_squares' default
    cost = _eureka.reflex_dynamics_fit(
        np.ascontiguousarray(g), lags_s, start, low, high, DYNAMICS_SCALE, FIT_TOLERANCE, limit, x
    )
    if cost < 0:
        raise np.linalg.LinAlgError("Singular matrix")
    return x, float(cost)


#: The typical size of δ (s), f_c (Hz) and ζ: the dynamics fit's damping is in these units.
DYNAMICS_SCALE = np.array([0.01, 1.0, 0.3])
#: The dynamics fit's tolerance on the cost, the step and the gradient. scipy
#: ``least_squares``' default (1e-8), which the fit used with scipy's TRF before it had a
#: solver of its own, stopped it early in the flat valleys of IRFs with no low-pass shape (no
#: reflex): 1e-10 costs a few more steps of this solver and ends at a cost no higher than
#: TRF's on every record compared (the sims', the bench's noise, the real ankle's).
FIT_TOLERANCE = 1e-10


def bounded_least_squares(
    residual: Callable[[FloatArray], FloatArray],
    jacobian: Callable[[FloatArray], FloatArray],
    start: FloatArray,
    low: FloatArray,
    high: FloatArray,
    scale: FloatArray,
    *,
    tolerance: float = FIT_TOLERANCE,
    max_evaluations: int | None = None,
) -> tuple[FloatArray, float]:
    """Minimise ``½‖r(x)‖²`` within the box ``low ≤ x ≤ high``: projected Levenberg–Marquardt
    with the exact Jacobian, for a few parameters.

    Each step solves the damped normal equations ``(JᵀJ + λ·D)p = −Jᵀr`` (``D = 1/scale²``)
    in the parameters not held at a bound (a parameter is held where it sits on a bound and
    the gradient pushes it outwards) and projects ``x + p`` on the box; a step that lowers the
    cost is taken and ``λ`` shrinks by the gain ratio (Nielsen's rule), one that does not is
    tried again with ``λ`` doubled (then quadrupled, …). It stops by scipy's
    ``least_squares``' three tests, with ``tolerance`` for each: the cost falls by less than
    ``tolerance·cost`` on a step that does as predicted (gain ratio > 0.25), or the step is
    shorter than ``tolerance·(tolerance + ‖x‖)``, or the gradient scaled by each free
    parameter's distance to the bound it points to is below ``tolerance`` (or after
    ``max_evaluations`` residuals, default ``100·len(x)``).

    Parameters
    ----------
    residual, jacobian : callable
        ``r(x)``, shape (m,), and ``∂r/∂x``, shape (m, k).
    start, low, high, scale : numpy.ndarray, shape (k,)
        The first point (clipped to the box), the bounds, and each parameter's typical size.

    Returns
    -------
    (numpy.ndarray, float)
        The solution, shape (k,), and its cost ``½‖r‖²``.
    """
    x = np.clip(start, low, high)
    r = residual(x)
    cost = 0.5 * float(r @ r)
    limit = max_evaluations or 100 * x.size
    evaluations, damping, growth = 1, -1.0, 2.0
    weight = 1.0 / scale**2
    while evaluations < limit:
        j = jacobian(x)
        gradient = j.T @ r
        if _scaled_gradient_norm(x, gradient, low, high) < tolerance:
            break
        free = ~(((x <= low) & (gradient > 0)) | ((x >= high) & (gradient < 0)))
        normal = j.T @ j
        if damping < 0:  # the first: 1e-3 of the largest scaled curvature
            damping = 1e-3 * float(np.max(np.diag(normal) / weight))
        stop = False
        while evaluations < limit:
            step = np.zeros_like(x)
            system = normal[np.ix_(free, free)] + np.diag(damping * weight[free])
            step[free] = np.linalg.solve(system, -gradient[free])
            trial = np.clip(x + step, low, high)
            moved = trial - x
            r_trial = residual(trial)
            evaluations += 1
            cost_trial = 0.5 * float(r_trial @ r_trial) if np.all(np.isfinite(r_trial)) else np.inf
            reduction = cost - cost_trial
            predicted = -float(gradient @ moved) - 0.5 * float(moved @ normal @ moved)
            ratio = reduction / predicted if predicted > 0 else 0.0
            step_norm = float(np.sqrt(moved @ moved))
            stop = bool(
                (reduction < tolerance * cost and ratio > 0.25)
                or step_norm < tolerance * (tolerance + float(np.sqrt(x @ x)))
            )
            if reduction > 0:
                x, r, cost = trial, r_trial, cost_trial
                damping *= max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3)
                growth = 2.0
                break
            if stop:
                break
            damping *= growth
            growth *= 2.0
        if stop:
            break
    return x, cost


def _scaled_gradient_norm(
    x: FloatArray, gradient: FloatArray, low: FloatArray, high: FloatArray
) -> float:
    """``‖g·v‖∞``, ``v`` each parameter's distance to the bound its descent direction heads
    for (scipy's Coleman–Li scaling: a parameter on that bound counts 0)."""
    v = np.where(gradient < 0, high - x, np.where(gradient > 0, x - low, 1.0))
    return float(np.max(np.abs(gradient * v)))


class _DelayedLowPass:
    """The residual ``G·h(t − δ) − g`` of :func:`fit_reflex_dynamics` in ``x = (δ, f_c, ζ)``
    (``G`` solved linearly at every ``x``: a variable projection) and its exact Jacobian, so
    that the solver needs no finite differences; the last point's work is kept for the
    Jacobian the solver asks for at the same point."""

    def __init__(self, g: FloatArray, lags_s: FloatArray) -> None:
        self.g = g
        self.lags_s = lags_s
        self._at: bytes = b""
        self._h = np.zeros(0)
        self._slopes = np.zeros((3, 0))

    def _evaluate(self, x: FloatArray) -> None:
        key = np.asarray(x, dtype=np.float64).tobytes()
        if key != self._at:
            self._h, self._slopes = _low_pass_and_slopes(self.lags_s - x[0], 2 * np.pi * x[1], x[2])
            self._at = key

    def residual(self, x: FloatArray) -> FloatArray:
        """``G·h − g``, shape (n,)."""
        self._evaluate(x)
        h = self._h
        energy = float(h @ h)
        gain = float(h @ self.g) / energy if energy > 0 else 0.0
        return np.asarray(gain * h - self.g, dtype=np.float64)

    def jacobian(self, x: FloatArray) -> FloatArray:
        """``∂(G·h − g)/∂x``, shape (n, 3): ``G·∂h + h·∂G`` with
        ``∂G = (∂h·g − 2G·h·∂h)/(h·h)``."""
        self._evaluate(x)
        h = self._h
        energy = float(h @ h)
        if energy <= 0:
            return np.zeros((h.size, 3))
        gain = float(h @ self.g) / energy
        by_x = self._slopes * np.array([[-1.0], [2 * np.pi], [1.0]])  # δ, f_c, ζ
        gain_by_x = (by_x @ self.g - 2.0 * gain * (by_x @ h)) / energy
        return np.asarray((gain * by_x + gain_by_x[:, None] * h).T, dtype=np.float64)


# ----------------------------------------------------------------------------- the pathway
def _powers(velocity: FloatArray, scale: float, degree: int) -> list[FloatArray]:
    """``s·(θ̇/s)^j`` for ``j = 1 … degree``, at the data's rate."""
    x = velocity / scale
    return [scale * x ** (j + 1) for j in range(degree)]


def _at_model_rate(x: FloatArray, factor: int) -> FloatArray:
    return detrend(decimated(x, factor), "mean")


@dataclass(frozen=True)
class ReflexPathway:
    """A fitted reflex pathway: what turns joint position into reflex torque.

    Attributes
    ----------
    variant : str
        ``"rect"`` or ``"hammerstein"``.
    fs_hz : float
        The model's rate, Hz.
    factor : int
        Decimation from the rate of the data it was fitted on.
    irf : numpy.ndarray, shape (L+1,)
        Lags ``0 … L`` of the IRF from the pathway's input (rectified velocity or ``p(θ̇)``,
        rad/s, at the model's rate) to torque, N·m per rad/s per s.
    rank : int
        Components kept by the MDL criterion (of ``L+1``).
    polynomial : numpy.ndarray, shape (degree,)
        ``hammerstein``: ``p(v) = Σ_j c_j·s·(v/s)^j``, ``j = 1 … degree``; empty for ``rect``.
    velocity_scale : float
        ``s``, rad/s (the velocity's RMS in the fitted record).
    dynamics : ReflexDynamics
        Gain, delay and low-pass fitted to the IRF.
    """

    variant: str
    fs_hz: float
    factor: int
    irf: FloatArray
    rank: int
    polynomial: FloatArray
    velocity_scale: float
    dynamics: ReflexDynamics

    @property
    def gain(self) -> float:
        """Reflex gain, N·m·s/rad (of the fitted delayed low-pass)."""
        return self.dynamics.gain

    @property
    def delay_s(self) -> float:
        """Reflex delay, s."""
        return self.dynamics.delay_s

    @property
    def irf_gain(self) -> float:
        """Static gain of the IRF itself (its area), N·m·s/rad."""
        return float(np.sum(self.irf) / self.fs_hz)

    @property
    def history_s(self) -> float:
        """Position history a prediction needs before its first sample, s."""
        return prediction_history_s(self.irf.size, self.fs_hz)

    def nonlinearity(self, velocity: FloatArray) -> FloatArray:
        """The static nonlinearity at the data's rate: ``max(θ̇, 0)`` or ``p(θ̇)``."""
        if self.variant == "rect":
            return np.maximum(velocity, 0.0)
        powers = _powers(velocity, self.velocity_scale, self.polynomial.size)
        return np.asarray(self.polynomial @ np.stack(powers), dtype=np.float64)

    def torque(self, position: ArrayLike, fs_hz: float) -> FloatArray:
        """Reflex torque (N·m) for ``position`` sampled at ``fs_hz``, at that rate.

        The first :attr:`history_s` of the result lack the pathway's full support; a live
        prediction passes that much history before the samples it needs.
        """
        pos = np.asarray(position, dtype=np.float64)
        factor = self._factor(fs_hz)
        pathway_input = _at_model_rate(self.nonlinearity(stretch_velocity(pos, fs_hz)), factor)
        low = convolve_causal(pathway_input, self.irf, self.fs_hz)
        return to_data_rate(low, factor, pos.size)

    @cached_property
    def _per_sample_irf(self) -> FloatArray:
        """The IRF per model sample (``irf / fs_hz``), formed once per pathway."""
        return np.ascontiguousarray(self.irf / self.fs_hz)

    def _factor(self, fs_hz: float) -> int:
        factor = max(1, round(fs_hz / self.fs_hz))
        if abs(fs_hz / factor - self.fs_hz) > 1e-6 * self.fs_hz:
            raise InputDataError(
                f"a reflex model at {self.fs_hz:g} Hz cannot predict data at {fs_hz:g} Hz "
                "(not a whole multiple)"
            )
        return factor


def to_data_rate(low: FloatArray, factor: int, n: int, first: int = 0) -> FloatArray:
    """A prediction on the model's samples (every ``factor``-th data sample) on the samples
    ``first … n − 1`` of the data: linear interpolation between the model's samples (the
    reflex torque is smooth at 100 Hz), held after the last one; ``low[first:]`` when
    ``factor`` is 1. Each sample's value does not depend on ``first``."""
    if factor == 1:
        return low[first:]
    if low.size < 2 or not np.all(np.isfinite(low)):
        return np.interp(np.arange(first, n), np.arange(low.size) * factor, low)
    # numpy.interp's own arithmetic, slope·(x − x_j) + y_j with the slope (y_j+1 − y_j)/factor,
    # on whole intervals at once (no search for each sample's interval): the same numbers
    # from the interval of sample `first` on
    j = min(first // factor, low.size - 1)
    part, first, n = low[j:], first - j * factor, n - j * factor
    slopes = np.diff(part) / float(factor)
    grid = np.empty(part.size * factor)
    intervals = grid[: slopes.size * factor].reshape(slopes.size, factor)  # a view: no copy
    np.add(slopes[:, None] * np.arange(float(factor)), part[:-1, None], out=intervals)
    grid[slopes.size * factor :] = part[-1]  # held after the last model sample
    if n <= grid.size:
        return grid[first:n]
    return np.concatenate((grid[first:], np.full(n - max(first, grid.size), part[-1])))


# ----------------------------------------------------------------------------- the stream
#: Model samples of position a streamed pathway input reaches either side of its own time:
#: the decimator's zero-phase response is kept over ±this many model samples (±0.1 s at
#: 100 Hz), so a model sample's input is final once this much newer data has arrived.
STREAM_REACH_MODEL_SAMPLES = 10
#: Data samples the velocity stencil reaches either side (9-point central differences).
_STENCIL_HALF = 4


@lru_cache(maxsize=8)
def stream_taps(factor: int) -> FloatArray:
    """The streamed decimator: the zero-phase response of :func:`decimated`'s filter (its
    impulse response correlated with itself: what a forward-and-backward run applies far from
    a record's ends), kept over ``±STREAM_REACH_MODEL_SAMPLES·factor`` samples with a
    cos² taper, scaled to the same static gain; ``[1.0]`` when ``factor`` is 1.

    Returns
    -------
    numpy.ndarray, shape (2N+1,)
        Symmetric taps at the data's rate, lag ``−N … N``.
    """
    if factor == 1:
        return np.ones(1)
    d = _decimator(factor)
    reach = STREAM_REACH_MODEL_SAMPLES * factor
    impulse = np.zeros(400 * factor)  # the slowest pole (|p| ≈ 0.993 at 25) decays to 1e-12
    impulse[0] = 1.0
    h = design("sosfilt", d.sos, impulse)  # scipy's, from the design cache
    half = np.array([h[: h.size - j] @ h[j:] for j in range(reach + 1)])
    half *= np.cos(0.5 * np.pi * np.arange(reach + 1) / (reach + 1)) ** 2
    taps = np.concatenate((half[:0:-1], half))
    static = np.prod(d.sos[:, :3].sum(axis=1) / d.sos[:, 3:].sum(axis=1)) ** 2
    taps *= static / taps.sum()
    taps.setflags(write=False)
    return taps


def _extended(position: FloatArray, first_index: int, low: int, high: int) -> FloatArray:
    """Position at the absolute sample indices ``low … high``, the segment point-reflected
    about its first and last samples beyond its ends (``θ(e + j) = 2θ(e) − θ(e − j)``: the
    velocity continues mirrored, so a rectifier sees no jump)."""
    n = position.size
    at = np.arange(low - first_index, high - first_index + 1)
    before, after = at < 0, at > n - 1
    inside = np.clip(at, 0, n - 1)
    out = position[inside]
    out[before] = 2 * position[0] - position[-at[before]]
    out[after] = 2 * position[n - 1] - position[2 * (n - 1) - at[after]]
    return out


def _pathway_rates(
    position: FloatArray,
    first_index: int,
    fs_hz: float,
    taps: FloatArray,
    factor: int,
    m_from: int,
    m_to: int,
    nonlinearity: Callable[[FloatArray], FloatArray],
) -> FloatArray:
    """The streamed pathway input at model samples ``m_from … m_to`` (at absolute data
    samples ``m·factor``): the velocity by the 9-point stencil of the (point-reflected)
    position, the static nonlinearity, and the decimator's taps centred on each model
    sample. Each value is its own dot product, the same whichever run it is computed in."""
    reach = (taps.size - 1) // 2
    low, high = m_from * factor - reach, m_to * factor + reach
    x = _extended(position, first_index, low - _STENCIL_HALF, high + _STENCIL_HALF)
    velocity, _ = stencil_derivatives(x, fs_hz)
    u = nonlinearity(velocity)
    return np.array(
        [taps @ u[k * factor : k * factor + taps.size] for k in range(m_to - m_from + 1)],
        dtype=np.float64,
    )


@dataclass
class _Kept:
    """Final values from earlier hops at model samples ``first … first + count − 1`` (in
    ``values[:count]``; ``values`` has room for a segment's model samples)."""

    first: int = 0
    count: int = 0
    values: FloatArray = field(default_factory=lambda: np.empty(0))

    def with_room(self, capacity: int) -> _Kept:
        """Itself, its buffer grown to ``capacity`` values when smaller."""
        if self.values.size < capacity:
            grown = np.empty(capacity)
            grown[: self.count] = self.values[: self.count]
            self.values = grown
        return self

    def gather(
        self, low: int, high: int, usable: int, form: Callable[[int, int], FloatArray]
    ) -> FloatArray:
        """Values at ``low … high``: the kept ones from ``usable`` on (where this segment
        would form them final too), the others by ``form(a, b)`` (``a … b``)."""
        out = np.empty(high - low + 1)
        kept_low, kept_high = max(self.first, usable), self.first + self.count - 1
        if self.count == 0 or kept_low > kept_high or kept_high < low or kept_low > high:
            out[:] = form(low, high)
            return out
        a, b = max(low, kept_low), min(high, kept_high)
        out[a - low : b - low + 1] = self.values[a - self.first : b - self.first + 1]
        if low < a:
            out[: a - low] = form(low, a - 1)
        if b < high:
            out[b - low + 1 :] = form(b + 1, high)
        return out

    def keep(self, values: FloatArray, low: int, a: int, b: int) -> None:
        """Keep ``values`` (at ``low …``) from ``a`` to ``b`` (nothing when ``b < a``)."""
        self.first, self.count = a, max(0, b - a + 1)
        self.values = values[a - low : a - low + self.count].copy()


@dataclass(frozen=True)
class _HopGrid:
    """Where one hop's model samples lie (absolute model-sample indices; see ReflexStream)."""

    last: int  # the model sample at or before the segment's last data sample
    window_first: int  # the model sample at or before the first sample wanted
    inputs_low: int  # the first pathway input the window's outputs convolve
    final_low: int  # pathway inputs final from here …
    final_high: int  # … to here (their taps and stencils within the segment)

    @classmethod
    def of(
        cls, first_index: int, n: int, n_last: int, factor: int, reach: int, lags: int
    ) -> _HopGrid:
        end = first_index + n - 1
        window_first = (end - n_last + 1) // factor
        inputs_low = max(window_first - lags, -(-first_index // factor))
        return cls(
            end // factor,
            window_first,
            inputs_low,
            -(-(first_index + reach) // factor),
            (end - reach) // factor,
        )


def _hop(
    pathway: ReflexPathway,
    position: FloatArray,
    first_index: int,
    fs_hz: float,
    n_last: int,
    taps: FloatArray,
    factor: int,
    inputs: _Kept,
    outputs: _Kept,
    reuse: bool,
) -> FloatArray:
    """One hop of :class:`ReflexStream` (the numpy reference of ``reflex_rect_hop``)."""
    g = pathway._per_sample_irf
    lags = g.size - 1
    grid = _HopGrid.of(
        first_index, position.size, n_last, factor, taps.size // 2 + _STENCIL_HALF, lags
    )
    low = grid.inputs_low

    def rates(a: int, b: int) -> FloatArray:
        return _pathway_rates(
            position, first_index, fs_hz, taps, factor, a, b, pathway.nonlinearity
        )

    r = (inputs if reuse else _Kept()).gather(low, grid.last, grid.final_low, rates)

    def convolved(a: int, b: int) -> FloatArray:  # y(m) = Σ_k g_k·r(m − k), r = 0 before low
        start = max(0, a - low - lags)
        full = np.convolve(r[start : b - low + 1], g)
        return full[a - low - start : b - low - start + 1]

    first_output = max(grid.final_low + lags, grid.window_first)  # all inputs final
    y = (outputs if reuse else _Kept()).gather(
        grid.window_first, grid.last, first_output, convolved
    )
    offset = math.fsum(r) / r.size * math.fsum(g)  # exact sums: alike whatever r's memory
    z = y - offset
    out = _interpolated(z, grid.window_first, factor, first_index + position.size - n_last, n_last)
    if reuse:
        inputs.keep(r, low, max(grid.final_low, low), min(grid.final_high, grid.last))
        outputs.keep(y, grid.window_first, first_output, min(grid.final_high, grid.last))
    return out


def _interpolated(z: FloatArray, z_first: int, factor: int, first: int, n: int) -> FloatArray:
    """``z`` (at model samples ``z_first …``) at data samples ``first … first + n − 1``:
    linear between model samples, the last one held after it."""
    at = np.arange(first, first + n)
    model = at // factor
    j = model - z_first
    last = z.size - 1
    if last == 0:
        return np.full(n, z[0])
    below = np.minimum(j, last - 1)
    z0, z1 = z[below], z[below + 1]
    out = z0 + (z1 - z0) * ((at - model * factor) / factor)
    out[j >= last] = z[last]
    return out


class ReflexStream:
    """The fast lane's reflex prediction, hop by hop: each model sample's pathway input and
    IRF output are computed once and carried to the next hop.

    The prediction is defined on the absolute sample grid (model sample ``m`` at data sample
    ``m·factor``) as a function of the position samples alone, so carrying values from hop
    to hop gives the very numbers of computing them afresh (tested): a replay that evaluates
    the same windows, or skips some, reproduces a live run bit for bit.

    * Pathway input ``r(m)``: the velocity by the 9-point stencil (no detrending: the fit's
      line over 20 s is a velocity offset of ≈ 0), the static nonlinearity, and the fit's
      zero-phase decimator as taps over ``±STREAM_REACH_MODEL_SAMPLES`` model samples
      (:func:`stream_taps`). Final once that much newer data has arrived; the newest are
      formed again each hop, from the position point-reflected about its last sample.
    * IRF output ``y(m) = Σ_k g_k·r(m − k)``: final once all its inputs are.
    * Torque: ``y − c·Σ g``, ``c`` the mean of the inputs the window's outputs convolve (the
      fit's input is mean-free; a window's offset, as before), linear between model samples
      and held after the last one.

    Per hop the cost is the new model samples and the ``≈ STREAM_REACH_MODEL_SAMPLES`` newest
    formed again: it grows with the hop, not with the window and history (plus copying the
    window's torque out). Compiled for ``"rect"`` (``reflex_rect_hop``); the numpy code is
    the reference.
    """

    def __init__(self) -> None:
        self._rates: tuple[int, float] = (0, 0.0)  # (factor, fs_hz) of the kept inputs
        self._inputs_of: ReflexPathway | None = None  # their polynomial's pathway (rect: None)
        self._outputs_of: ReflexPathway | None = None  # the pathway of the kept outputs
        self._inputs = _Kept()
        self._outputs = _Kept()

    @staticmethod
    def prepare(fs_hz: float, model_fs_hz: float) -> None:
        """Form, before the first hop, what a model's first hop at these rates would form.

        The streamed decimator's taps (:func:`stream_taps`: a filter design and its impulse
        response, ≈ 3 ms of CPU, once per process and rate) were otherwise formed by the first
        window to use a model: in a daemon whose slow lane fits in its own process, the worker
        paid them inside that window's deadline. The numbers are the same either way.

        Parameters
        ----------
        fs_hz : float
            The data's sampling rate, Hz.
        model_fs_hz : float
            The reflex models' rate, Hz (``CascadeSettings.fs_out_hz``).
        """
        stream_taps(max(1, round(fs_hz / model_fs_hz)))

    def torque_tail(
        self,
        pathway: ReflexPathway,
        position: ArrayLike,
        first_index: int,
        fs_hz: float,
        n_last: int,
        *,
        reuse: bool = True,
    ) -> FloatArray:
        """The reflex torque (N·m) at the last ``n_last`` samples of ``position``.

        Parameters
        ----------
        pathway : ReflexPathway
            The model the window uses.
        position : array_like, shape (n,)
            Joint angle (rad) at samples ``first_index … first_index + n − 1``: the window
            and the pathway's history before it (:attr:`ReflexPathway.history_s`).
        first_index : int
            Absolute index of the first sample.
        fs_hz : float
            Sampling rate, Hz (a whole multiple of the model's).
        n_last : int
            Samples wanted.
        reuse : bool
            The samples are the recorded ones (none bridged): values from earlier hops may be
            used, and this hop's final ones are kept. Otherwise all are formed from
            ``position`` and nothing is kept.

        Raises
        ------
        InputDataError
            The rates do not match, or ``position`` is shorter than the decimator's reach.
        """
        pos = np.ascontiguousarray(position, dtype=np.float64)
        factor = pathway._factor(fs_hz)
        taps = stream_taps(factor)
        shortest = taps.size // 2 + _STENCIL_HALF + 1
        n_last = min(n_last, pos.size)
        if n_last <= 0:
            return np.empty(0)
        if pos.size < shortest:
            raise InputDataError(
                f"a reflex prediction needs at least {shortest} samples of position, got {pos.size}"
            )
        # the rectifier's inputs serve every rect pathway of a rate; a polynomial's are its own
        owner = None if pathway.variant == "rect" else pathway
        if (factor, fs_hz) != self._rates or owner is not self._inputs_of:
            self._rates, self._inputs_of, self._inputs = (factor, fs_hz), owner, _Kept()
            self._outputs_of = None
        if pathway is not self._outputs_of:
            self._outputs_of, self._outputs = pathway, _Kept()
        inputs, outputs = (self._inputs, self._outputs) if reuse else (_Kept(), _Kept())
        if _eureka is None or pathway.variant != "rect":
            return _hop(
                pathway, pos, first_index, fs_hz, n_last, taps, factor, inputs, outputs, reuse
            )
        capacity = pos.size // factor + 2
        inputs.with_room(capacity)
        outputs.with_room(capacity)
        out = np.empty(n_last)
        inputs.first, inputs.count, outputs.first, outputs.count = _eureka.reflex_rect_hop(
            pos,
            first_index,
            fs_hz,
            taps,
            factor,
            pathway._per_sample_irf,
            int(reuse),
            inputs.values,
            inputs.first,
            inputs.count,
            outputs.values,
            outputs.first,
            outputs.count,
            out,
        )
        return out


class ReflexInputs:
    """The candidate pathway inputs of one record at the model's rate (computed once per
    record, reused by every alternation of the cascade)."""

    def __init__(self, position: FloatArray, fs_hz: float, factor: int, variant: str) -> None:
        self._of_velocity(stretch_velocity(position, fs_hz), factor, variant, ())

    @classmethod
    def decimating(
        cls,
        position: FloatArray,
        others: Sequence[FloatArray],
        fs_hz: float,
        factor: int,
        variant: str,
    ) -> tuple[ReflexInputs, FloatArray]:
        """The inputs of ``position``'s record, and ``others`` (records of the same length,
        e.g. its position and torque) by :func:`decimated`, all rows in one
        :func:`decimated_rows`: the same numbers as decimating each alone.

        Returns
        -------
        (ReflexInputs, numpy.ndarray)
            The inputs, and ``others`` decimated, shape (len(others), m).
        """
        inputs = cls.__new__(cls)
        decimated_others = inputs._of_velocity(
            stretch_velocity(position, fs_hz), factor, variant, others
        )
        return inputs, decimated_others

    def _of_velocity(
        self, velocity: FloatArray, factor: int, variant: str, others: Sequence[FloatArray]
    ) -> FloatArray:
        """Set the inputs from the stretch velocity; ``others`` decimated with the rectified
        velocity (returned)."""
        self.factor = factor
        self.variant = variant
        self.scale = float(np.sqrt(np.mean(velocity**2))) or 1.0
        rows = decimated_rows([*others, np.maximum(velocity, 0.0)], factor)
        self.rectified = detrend(rows[-1], "mean")
        self.powers = (
            [_at_model_rate(p, factor) for p in _powers(velocity, self.scale, POLYNOMIAL_DEGREE)]
            if variant == "hammerstein"
            else []
        )
        self._systems: dict[int, ToeplitzSystem] = {}
        return rows[:-1]

    def rectified_system(self, lags: int) -> ToeplitzSystem:
        """The rectified input's Toeplitz system for ``lags`` (formed on first use, then
        reused by every alternation)."""
        if lags not in self._systems:
            self._systems[lags] = ToeplitzSystem.of_input(self.rectified, lags)
        return self._systems[lags]


def fit_reflex_pathway(
    inputs: ReflexInputs, residual: FloatArray, fs_hz: float, lags: int, *, dynamics: bool = True
) -> tuple[ReflexPathway, FloatArray]:
    """Fit the reflex pathway to the torque the intrinsic pathway leaves.

    Parameters
    ----------
    inputs : ReflexInputs
        The record's pathway inputs at the model's rate ``fs_hz``.
    residual : numpy.ndarray, shape (m,)
        Torque minus the intrinsic prediction, N·m, at the model's rate.
    lags : int
        IRF lags ``0 … lags``.
    dynamics : bool
        Fit gain and delay (:func:`fit_reflex_dynamics`); the cascade's alternations skip it
        and fit them once on the pathway kept.

    Returns
    -------
    (ReflexPathway, numpy.ndarray)
        The pathway, and its torque on the record (N·m, model's rate).
    """
    irf, rank = _causal_irf(inputs.rectified, residual, lags, fs_hz, inputs.rectified_system(lags))
    coefficients = np.zeros(0)
    pathway_input = inputs.rectified
    if inputs.variant == "hammerstein":
        irf, rank, coefficients, pathway_input = _hammerstein(inputs, residual, fs_hz, lags, irf)
    pathway = ReflexPathway(
        inputs.variant,
        fs_hz,
        inputs.factor,
        irf,
        rank,
        coefficients,
        inputs.scale,
        fit_reflex_dynamics(irf, fs_hz) if dynamics else UNFITTED,
    )
    return pathway, convolve_causal(pathway_input, irf, fs_hz)


def _hammerstein(
    inputs: ReflexInputs, residual: FloatArray, fs_hz: float, lags: int, irf: FloatArray
) -> tuple[FloatArray, int, FloatArray, FloatArray]:
    """Alternate the polynomial (least squares on the IRF-filtered powers) and the IRF
    (EUREKA, MDL rank), starting from the rectifier's IRF. The polynomial is normalised to
    the rectifier's scale (least-squares slope 1 against ``max(θ̇, 0)``), so the IRF's gain
    compares with the ``rect`` variant's."""
    rectified = inputs.rectified
    powers = np.stack(inputs.powers, axis=1)
    coefficients: NDArray[np.floating] = np.zeros(POLYNOMIAL_DEGREE)
    shaped = rectified
    rank = 0
    for _ in range(HAMMERSTEIN_SWEEPS):
        filtered = np.stack([convolve_causal(p, irf, fs_hz) for p in inputs.powers], axis=1)
        coefficients, *_ = np.linalg.lstsq(filtered, residual, rcond=None)
        candidate = powers @ coefficients
        slope = float(candidate @ rectified) / float(rectified @ rectified)
        if slope == 0 or not np.isfinite(slope):
            break
        coefficients = coefficients / slope
        shaped = candidate / slope
        irf, rank = _causal_irf(shaped, residual, lags, fs_hz)
    return irf, rank, np.asarray(coefficients, dtype=np.float64), shaped
