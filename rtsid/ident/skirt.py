"""Time-varying identification by skirt decomposition of a multisine response.

Lataire, Pintelon & Louarroudi (Automatica 48(4), 2012) estimate the system function
``G(jω, t)`` of a linear time-varying (LTV) system from one record excited by a multisine:

.. math::

    G(jω, t) = \\sum_{p=0}^{N_p-1} G_p(jω)\\, b_p(t), \\qquad
    y(t) = \\sum_p b_p(t)\\,(g_p * u)(t),

with ``b_p`` a time basis over the record: the Legendre polynomials shifted and scaled to it
(the paper's choice, the default), or — the paper's "tailored basis functions" for faster
variation — Fourier terms periodic over the record (cyclic change) or cubic B-splines (local
change); see :data:`BASIS_FAMILIES` and :func:`basis_functions`. Multiplying by
``b_p(t)`` spreads each excited line of the (periodic) response over a *skirt* ``B_p`` (the DFT
of ``b_p``), so the output DFT over the whole record of ``N`` samples is

.. math::

    Y(k) = \\frac{1}{N} \\sum_{k_e} \\sum_p U(k_e)\\, G_p(k_e)\\, B_p\\big((k - k_e) \\bmod N\\big)
           + T(k) + V(k).

The ``1/N`` comes from numpy's unnormalised DFT (a cosine of amplitude ``A`` gives
``U(k_e) = N·A/2·e^{jφ}``), and skirt offsets wrap modulo ``N`` (negative offsets index the
top of the DFT). Around each excited line a window of bins holds the line's own skirts, the
skirts of its two neighbours and, optionally, a low-order polynomial ``T(k)`` in ``k`` for
transients and the leakage of lines further away. A neighbour's ``p = 0`` skirt is a single
bin (the constant ``b_0``), so it enters only when the neighbour's line lies inside the
window; otherwise that column is pure round-off and is dropped, not normalised. One linear
least-squares problem per line gives ``G_p(k_e)``; the neighbours' ``G_p`` and the
polynomial are nuisance parameters of that problem.

Two choices differ from a literal reading of the paper, both measured on its simulation
study (``rtsid bench skirt``, ``docs/skirt.md``). The window reaches a quarter of a line
spacing past each neighbour (``window_lines=1.25``) rather than half-way: the line's own
skirts are captured whole and the neighbours' skirts are seen on both sides of their lines,
so the validation VAF matches the best any ``N_p``-term Legendre expansion of the true
``G(jω, t)`` can give (half-way windows lose up to 10 % with lines 0.8 Hz apart and
collapse at 0.2 Hz; windows ending at the neighbours collapse at 0.2 Hz from ``N_p ≈ 12``).
And the transient polynomial is off by default (``n_transient=None``): in 200 s records
the start-up transient is small and the polynomial's extra unknowns cost more than they
gain (see the ablation in ``docs/skirt.md``); it does absorb the leakage of lines beyond
the modelled neighbours.

Legendre skirts widen roughly as ``p²/π`` bins, so a large ``N_p`` with closely spaced
lines makes the local problems ill-conditioned. :func:`skirt_conditioning` measures it (the
variance inflation of the line's own ``G_p`` against orthogonal skirts) from the design
alone; :func:`identify_ltv` warns (:class:`SkirtConditioningWarning`) above
:data:`WARN_VARIANCE_INFLATION` and refuses (:class:`~rtsid.errors.NumericalError`) when
the problem is under-determined or above :data:`MAX_VARIANCE_INFLATION`.

The family sets how compact the skirts are and so how many ``b_p`` fit between lines: a
Fourier term's skirt is exactly two bins (``±h``), so ``N_p = 2H + 1`` is limited only by
``2H < Δk`` (refused beyond) and the local problems are exact per bin; B-splines' main lobe is
``±(N_p − 3)`` bins. B-splines are not orthogonal, so their conditioning is measured on the
basis orthonormalised over the record (:func:`_whitener`). :func:`select_basis_size` chooses
``N_p`` per family from the record: the well-conditioned candidates, scored by
:func:`predicted_validation_vaf` (Mallows' C_p).

Beyond the paper, :meth:`LtvEstimate.fit_second_order` fits the frozen admittance
``1/(K − Iω² + jBω)`` to ``G(jω, t)`` at each time, which tracks ``K(t)`` and the natural
frequency ``f_n(t)`` with sub-line resolution (the paper's peak-picking resonance,
:meth:`LtvEstimate.resonance_from_peak`, is quantised to the line grid).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rtsid.errors import InputDataError, NumericalError

__all__ = [
    "AUTO_MAX_BASIS",
    "BASIS_FAMILIES",
    "MAX_VARIANCE_INFLATION",
    "WARN_VARIANCE_INFLATION",
    "BasisSelection",
    "LtvEstimate",
    "ModelSelection",
    "SecondOrderTrack",
    "SkirtConditioning",
    "SkirtConditioningWarning",
    "basis_functions",
    "check_basis_family",
    "fit_admittance",
    "fourier_harmonics",
    "identify_ltv",
    "legendre_basis",
    "max_stable_basis",
    "predicted_validation_vaf",
    "select_basis_size",
    "select_model",
    "skirt_conditioning",
]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

#: Variance inflation of a line's own ``G_p`` above which :func:`identify_ltv` warns.
WARN_VARIANCE_INFLATION = 4.0
#: Variance inflation above which :func:`identify_ltv` refuses to estimate.
MAX_VARIANCE_INFLATION = 1e6
#: Largest fraction of the input's power allowed outside the declared excited bins.
DEFAULT_INPUT_TOLERANCE = 1e-3


class SkirtConditioningWarning(RuntimeWarning):
    """``N_p`` is large for the line spacing: the estimate's variance is inflated."""


# --------------------------------------------------------------------------------------
# basis and skirts
# --------------------------------------------------------------------------------------


#: The time-basis families :func:`identify_ltv` accepts (the first is the default).
BASIS_FAMILIES = ("legendre", "fourier", "bspline")

_FAMILY_NAMES = {
    "legendre": "Legendre polynomials",
    "fourier": "Fourier terms",
    "bspline": "cubic B-splines",
}


def check_basis_family(family: str) -> str:
    """``family`` if it is one of :data:`BASIS_FAMILIES`, else a one-line InputDataError."""
    if family not in BASIS_FAMILIES:
        raise InputDataError(
            f"unknown basis family {family!r}; choose one of {', '.join(BASIS_FAMILIES)}"
        )
    return family


def _legendre(x: FloatArray, n_basis: int) -> FloatArray:
    out = np.empty((n_basis, x.size))
    out[0] = 1.0
    if n_basis > 1:
        out[1] = x
    for p in range(1, n_basis - 1):
        out[p + 1] = ((2 * p + 1) * x * out[p] - p * out[p - 1]) / (p + 1)
    return out


def _fourier(theta: FloatArray, n_basis: int) -> FloatArray:
    """``1, cos θ, sin θ, cos 2θ, sin 2θ, …`` (``n_basis`` rows)."""
    out = np.empty((n_basis, theta.size))
    out[0] = 1.0
    for p in range(1, n_basis):
        harmonic = (p + 1) // 2
        out[p] = np.cos(harmonic * theta) if p % 2 else np.sin(harmonic * theta)
    return out


def fourier_harmonics(n_basis: int) -> int:
    """Highest harmonic of the record reached by ``n_basis`` Fourier terms."""
    return n_basis // 2


def _bspline_knots(n_basis: int, end: float) -> tuple[int, FloatArray]:
    """Degree (3, or less for ``n_basis < 4``) and clamped uniform knots over ``[0, end]``."""
    degree = min(3, n_basis - 1)
    breaks = np.linspace(0.0, end, n_basis - degree + 1)
    return degree, np.concatenate([np.zeros(degree), breaks, np.full(degree, end)])


def _bspline(s: FloatArray, n_basis: int, end: float) -> FloatArray:
    """Clamped uniform B-splines (Cox–de Boor) at positions ``s`` clipped to ``[0, end]``."""
    degree, knots = _bspline_knots(n_basis, end)
    x = np.clip(s, 0.0, end)
    n_intervals = n_basis - degree
    span = np.clip(np.floor(x / end * n_intervals).astype(np.int64), 0, n_intervals - 1) + degree
    out = np.zeros((knots.size - 1, x.size))
    out[span, np.arange(x.size)] = 1.0
    for k in range(1, degree + 1):
        nxt = np.zeros((knots.size - 1 - k, x.size))
        for i in range(knots.size - 1 - k):
            left, right = knots[i + k] - knots[i], knots[i + k + 1] - knots[i + 1]
            if left > 0:
                nxt[i] += (x - knots[i]) / left * out[i]
            if right > 0:
                nxt[i] += (knots[i + k + 1] - x) / right * out[i + 1]
        out = nxt
    return out[:n_basis]


def _basis_at(family: str, s: FloatArray, n_samples: int, n_basis: int) -> FloatArray:
    """``b_p`` of ``family`` at (fractional) sample positions ``s`` of an N-sample record.

    Legendre: ``x = 2s/(N−1) − 1`` runs over ``[-1, 1]`` across the record. Fourier:
    ``θ = 2πs/N``, so every term is periodic over exactly ``N`` samples and its DFT lies on
    bins ``±h``. B-splines: clamped, uniform knots from sample 0 to ``N−1`` (held at the end
    values outside the record).
    """
    if family == "legendre":
        return _legendre(2.0 * s / (n_samples - 1) - 1.0, n_basis)
    if family == "fourier":
        return _fourier(2.0 * np.pi * s / n_samples, n_basis)
    return _bspline(s, n_basis, float(n_samples - 1))


def basis_functions(n_samples: int, n_basis: int, family: str = "legendre") -> FloatArray:
    """The first ``n_basis`` functions of a basis ``family`` over a record of ``n_samples``.

    Parameters
    ----------
    n_samples : int
        Samples in the record ``N``.
    n_basis : int
        ``N_p``.
    family : str
        ``"legendre"``: Legendre polynomials ``P_0 … P_{N_p−1}`` on ``[-1, 1]`` across the
        record. ``"fourier"``: ``1, cos θ, sin θ, cos 2θ, …`` with ``θ = 2πn/N`` (the
        record is one period; ``N_p = 2H + 1`` reaches harmonic ``H``). ``"bspline"``: cubic
        B-splines on uniform knots clamped at both ends (lower degree for ``N_p < 4``).

    Returns
    -------
    numpy.ndarray, shape (n_basis, n_samples)
    """
    check_basis_family(family)
    if n_samples < 2 or n_basis < 1:
        raise InputDataError(f"need n_samples >= 2 and n_basis >= 1, got {n_samples}, {n_basis}")
    return _basis_at(family, np.arange(n_samples, dtype=float), n_samples, n_basis)


def legendre_basis(n_samples: int, n_basis: int) -> FloatArray:
    """Legendre polynomials ``P_0 … P_{n_basis−1}`` over a record of ``n_samples``.

    Sample ``n`` maps to ``x = 2n/(N−1) − 1``, so ``b_p`` runs over ``[-1, 1]`` across the
    record.

    Returns
    -------
    numpy.ndarray, shape (n_basis, n_samples)
    """
    return basis_functions(n_samples, n_basis, "legendre")


def _skirts(family: str, n_samples: int, n_basis: int) -> ComplexArray:
    """DFT of each basis function over the record, shape (n_basis, n_samples).

    Transformed a few rows at a time: the FFT's complex copy of its input then stays small
    beside the result (a 500 000-sample record with 50 functions: 0.7 GB at peak, not 1 GB).
    """
    basis = basis_functions(n_samples, n_basis, family)
    out = np.empty(basis.shape, dtype=np.complex128)
    for i in range(0, n_basis, _FFT_ROWS):
        out[i : i + _FFT_ROWS] = np.fft.fft(basis[i : i + _FFT_ROWS], axis=1)
    return out


#: Basis functions transformed at once by :func:`_skirts`.
_FFT_ROWS = 8


def _nested(family: str) -> bool:
    """Whether the first ``q`` functions of ``N_p`` are the basis of ``N_p = q``."""
    return family != "bspline"


# --------------------------------------------------------------------------------------
# local design
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Layout:
    """Columns of one local problem, identical for every line with the same neighbourhood.

    ``left``/``right`` are the bins below/above the line in its window; ``neighbours`` the
    signed distances (bins) to the other lines whose skirts are modelled in it.
    """

    left: int
    right: int
    neighbours: tuple[int, ...]

    @property
    def offsets(self) -> NDArray[np.int64]:
        return np.arange(-self.left, self.right + 1)


def _design(
    layout: _Layout, skirts: ComplexArray, n_samples: int, n_transient: int | None
) -> tuple[ComplexArray, int]:
    """Columns ``B_p(k − k_e')/N`` of the line, its neighbours and the polynomial.

    A neighbour's skirt enters only where it reaches into the window: a column holding less
    than :data:`_NEGLIGIBLE_SKIRT` of the skirt's energy there is round-off and is dropped
    (Legendre ``p = 0`` is a single bin at the neighbour's line; a Fourier term's skirt is
    two bins, ``±h`` from it).
    Returns the design (rows = window bins) and the number of the line's own columns
    (the first ``n_basis``).
    """
    n_basis = skirts.shape[0]
    m = layout.offsets
    cols = [skirts[:, m % n_samples].T]
    energy = np.sum(np.abs(skirts) ** 2, axis=1)
    for d in layout.neighbours:
        block = skirts[:, (m - d) % n_samples]
        seen = np.sum(np.abs(block) ** 2, axis=1) > _NEGLIGIBLE_SKIRT * energy
        cols.append(block[seen].T)
    design = np.concatenate(cols, axis=1) / n_samples
    if n_transient is not None:
        scale = max(layout.left, layout.right, 1)
        powers = (m[:, None] / scale) ** np.arange(n_transient + 1)
        design = np.concatenate([design, powers.astype(complex)], axis=1)
    return design, n_basis


#: Fraction of a skirt's energy below which its part inside a window is round-off.
_NEGLIGIBLE_SKIRT = 1e-20


@dataclass(frozen=True)
class _Solver:
    """Solution map of one local design for the line's own columns.

    The neighbours' skirts and the transient polynomial are nuisance: only their span
    matters, and it is nearly degenerate (a neighbour's high-order skirts are all smooth
    inside the window), so it is represented by an orthonormal basis of its numerical range
    (singular values above :data:`_NUISANCE_RCOND`). The line's own columns, with the
    nuisance span projected out, are then solved by SVD; their variance inflation is the
    diagonal of ``(A_⊥^H A_⊥)^{-1}`` for unit-norm columns (1 when the own skirts are
    orthogonal to each other and to the nuisance).

    That is the variance of each ``G_p`` (``variance_inflation``, used for the standard
    errors). For a basis that is not orthogonal over the record (B-splines) it includes the
    basis's own correlation, which does not make ``G(jω, t)`` any noisier; the conditioning
    checks use ``skirt_inflation`` instead: the same measure for the own columns of the
    basis orthonormalised over the record (``whiten``, see :func:`_whitener`), i.e. only
    what the window and the neighbours cost. For orthogonal bases the two are equal.
    """

    own_pinv: ComplexArray  # (n_own, rows), maps the window spectrum to normalised unknowns
    residual_projector: ComplexArray  # (rows, rows)
    column_norms: FloatArray  # (n_own,)
    variance_inflation: FloatArray  # (n_own,)
    skirt_inflation: FloatArray  # (n_own,)
    dof: int

    @classmethod
    def build(cls, design: ComplexArray, n_own: int, whiten: FloatArray | None = None) -> _Solver:
        rows = design.shape[0]
        own, nuisance = design[:, :n_own], design[:, n_own:]
        norms = _unit_norms(own)
        q = _range_basis(nuisance)
        own_perp = (own - q @ (q.conj().T @ own)) / norms
        u, s, vh = np.linalg.svd(own_perp, full_matrices=False)
        inflation = _inflation(s, vh, n_own)
        if np.isfinite(inflation).all():
            pinv = (vh.conj().T / s) @ u.conj().T
        else:
            pinv = np.full((n_own, rows), np.nan, dtype=complex)
        skirt_inflation = inflation
        if whiten is not None:
            white = own @ whiten
            white_perp = (white - q @ (q.conj().T @ white)) / _unit_norms(white)
            _, s_w, vh_w = np.linalg.svd(white_perp, full_matrices=False)
            skirt_inflation = _inflation(s_w, vh_w, n_own)
        basis = np.concatenate([q, u], axis=1)
        projector = np.eye(rows) - basis @ basis.conj().T
        return cls(pinv, projector, norms, inflation, skirt_inflation, rows - basis.shape[1])


def _unit_norms(columns: ComplexArray) -> FloatArray:
    norms = np.linalg.norm(columns, axis=0)
    norms[norms == 0] = 1.0
    return np.asarray(norms, dtype=float)


def _inflation(s: FloatArray, vh: ComplexArray, n_own: int) -> FloatArray:
    """Diagonal of ``(A^H A)^{-1}`` from the SVD of unit-norm ``A`` (inf when singular)."""
    if s.size < n_own or s[-1] <= 1e-12 * max(s[0], 1.0):
        return np.full(n_own, np.inf)
    return np.asarray((np.abs(vh.T) ** 2) @ (1.0 / s**2), dtype=float)


def _whitener(family: str, n_samples: int, n_basis: int) -> FloatArray | None:
    """``L^{-T}`` with ``L L^T`` the Gram matrix of the basis over the record, for the
    families that are not orthogonal there (B-splines); None for Legendre and Fourier."""
    if family != "bspline" or n_basis == 1:
        return None
    basis = basis_functions(n_samples, n_basis, family)
    chol = np.linalg.cholesky(basis @ basis.T / n_samples)
    return np.asarray(np.linalg.inv(chol).T, dtype=float)


#: Relative singular value below which directions of the nuisance span are dropped.
_NUISANCE_RCOND = 1e-10


def _range_basis(columns: ComplexArray) -> ComplexArray:
    """Orthonormal basis (rows, rank) of the numerical range of ``columns``."""
    if columns.shape[1] == 0:
        return np.zeros((columns.shape[0], 0), dtype=complex)
    norms = np.linalg.norm(columns, axis=0)
    norms[norms == 0] = 1.0
    u, s, _ = np.linalg.svd(columns / norms, full_matrices=False)
    rank = int(np.sum(s > s[0] * _NUISANCE_RCOND))
    return u[:, :rank]


def _layouts(
    bins: NDArray[np.int64], n_samples: int, window_lines: float, neighbours: int
) -> list[_Layout]:
    """Window and modelled neighbours of each excited line.

    The window reaches ``window_lines`` × the distance to the next line on each side (0.5:
    half-way, so windows tile the band), inside ``1 … N/2``; the skirts of the
    ``neighbours`` nearest lines on each side, and of any line inside the window, are
    modelled.
    """
    layouts = []
    for i, k in enumerate(bins):
        gap_left = int(k - bins[i - 1]) if i > 0 else 0
        gap_right = int(bins[i + 1] - k) if i + 1 < bins.size else 0
        gap_left, gap_right = gap_left or gap_right, gap_right or gap_left
        if gap_left:
            left, right = int(window_lines * gap_left), int(window_lines * gap_right)
        else:  # a single line: use what room there is
            left = right = n_samples
        left = int(min(left, k - 1))
        right = int(min(right, n_samples // 2 - k))
        near = set(range(max(0, i - neighbours), min(bins.size, i + neighbours + 1)))
        near |= {j for j, kj in enumerate(bins) if k - left <= kj <= k + right}
        near.discard(i)
        layouts.append(_Layout(left, right, tuple(sorted(int(bins[j] - k) for j in near))))
    return layouts


# --------------------------------------------------------------------------------------
# conditioning
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SkirtConditioning:
    """How well the local problems determine ``G_p`` for a line spacing and ``N_p``.

    Attributes
    ----------
    n_basis : int
        ``N_p``.
    spacing_bins : int
        Distance between excited lines in bins of the whole record.
    rows, unknowns : int
        Bins and complex unknowns (own ``G_p``, neighbours' ``G_p``, polynomial) of an
        interior line's local problem.
    variance_inflation : numpy.ndarray, shape (n_basis,)
        Variance of each own ``G_p`` relative to what orthogonal skirts would give (1 is
        ideal; ``inf`` when the problem is singular).
    """

    n_basis: int
    spacing_bins: int
    rows: int
    unknowns: int
    variance_inflation: FloatArray = field(repr=False)

    @property
    def max_variance_inflation(self) -> float:
        """Largest inflation over ``p`` (``inf`` when singular or under-determined)."""
        return float(np.max(self.variance_inflation))


def _interior_layout(spacing_bins: int, window_lines: float, neighbours: int) -> _Layout:
    bins = spacing_bins * np.arange(1, 4 * (neighbours + int(window_lines) + 1) + 2)
    middle = bins.size // 2
    return _layouts(bins, 1 << 40, window_lines, neighbours)[middle]


def skirt_conditioning(
    n_samples: int,
    spacing_bins: int,
    n_basis: int,
    n_transient: int | None = None,
    *,
    window_lines: float = 1.25,
    neighbours: int = 1,
    basis_family: str = "legendre",
) -> SkirtConditioning:
    """Conditioning of an interior line's local problem (depends on the design only).

    Parameters
    ----------
    n_samples : int
        Samples in the record ``N``.
    spacing_bins : int
        Distance between excited lines, in DFT bins of the whole record
        (``every × n_periods`` for a multisine exciting every ``every``-th bin of a period).
    n_basis : int
        ``N_p``.
    n_transient : int or None
        Degree of the transient polynomial (None: no polynomial).
    window_lines, neighbours : float, int
        Local window and modelled neighbours, as in :func:`identify_ltv`.
    basis_family : str
        One of :data:`BASIS_FAMILIES`.

    Returns
    -------
    SkirtConditioning
    """
    family = check_basis_family(basis_family)
    skirts = _skirts(family, n_samples, n_basis)
    whiten = _whitener(family, n_samples, n_basis)
    return _conditioning(skirts, spacing_bins, n_transient, window_lines, neighbours, whiten)


def _conditioning(
    skirts: ComplexArray,
    spacing_bins: int,
    n_transient: int | None,
    window_lines: float,
    neighbours: int,
    whiten: FloatArray | None = None,
) -> SkirtConditioning:
    if spacing_bins < 2:
        raise InputDataError(
            f"excited lines {spacing_bins} bin(s) apart leave no bins for the skirts; "
            "excite every P-th bin with P >= 2 or record more periods"
        )
    n_basis, n_samples = skirts.shape
    layout = _interior_layout(spacing_bins, window_lines, neighbours)
    design, n_own = _design(layout, skirts, n_samples, n_transient)
    rows, unknowns = design.shape
    inflation = _Solver.build(design, n_own, whiten).skirt_inflation
    return SkirtConditioning(n_basis, spacing_bins, rows, unknowns, inflation)


def max_stable_basis(
    n_samples: int,
    spacing_bins: int,
    n_transient: int | None = None,
    limit: float = WARN_VARIANCE_INFLATION,
    n_max: int = 40,
    *,
    window_lines: float = 1.25,
    neighbours: int = 1,
    basis_family: str = "legendre",
) -> int:
    """Largest ``N_p`` (≤ ``n_max``) whose variance inflation stays ≤ ``limit`` (0: none).

    Found by bisection: for the nested families (Legendre, Fourier: a smaller basis is a
    prefix) adding a function never lowers the inflation of the others, so the worst
    inflation grows with ``N_p`` and the bisection is exact; B-splines change with ``N_p``
    and follow the same trend (their inflation is measured on the orthonormalised basis).
    """
    family = check_basis_family(basis_family)
    nested = _skirts(family, n_samples, n_max) if _nested(family) else None

    def inflation(n_basis: int) -> float:
        skirts = nested[:n_basis] if nested is not None else _skirts(family, n_samples, n_basis)
        whiten = _whitener(family, n_samples, n_basis)
        cond = _conditioning(skirts, spacing_bins, n_transient, window_lines, neighbours, whiten)
        return cond.max_variance_inflation

    lo, hi = 0, n_max + 1  # inflation(lo) <= limit (or lo = 0); inflation(hi) > limit
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if inflation(mid) <= limit else (lo, mid)
    return lo


# --------------------------------------------------------------------------------------
# estimate
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SecondOrderTrack:
    """Frozen second-order admittance ``1/(K − Iω² + jBω)`` fitted at each time.

    Attributes
    ----------
    t_s : numpy.ndarray, shape (n_times,)
        Times, s from the record's first sample.
    stiffness, damping, inertia : numpy.ndarray, shape (n_times,)
        ``K`` (N·m/rad), ``B`` (N·m·s/rad), ``I`` (kg·m²).
    natural_frequency_hz : numpy.ndarray, shape (n_times,)
        ``√(K/I)/2π``, Hz (NaN where ``K/I <= 0``).
    fit_error : numpy.ndarray, shape (n_times,)
        Relative misfit ``‖G − Ĝ‖/‖G‖`` over the excited lines.
    """

    t_s: FloatArray
    stiffness: FloatArray
    damping: FloatArray
    inertia: FloatArray
    natural_frequency_hz: FloatArray
    fit_error: FloatArray


@dataclass(frozen=True)
class LtvEstimate:
    """``G(jω, t) = Σ_p G_p(jω)·b_p(t)`` at the excited lines of a multisine.

    Attributes
    ----------
    G_p : numpy.ndarray of complex, shape (n_basis, n_lines)
        Coefficient of basis function ``p`` at each excited line (output unit per input
        unit, e.g. rad/(N·m)).
    G_p_se : numpy.ndarray, shape (n_basis, n_lines)
        Standard error of ``G_p`` from each local problem's residual.
    frequencies_hz : numpy.ndarray, shape (n_lines,)
        Excited frequencies, Hz.
    excited_bins : numpy.ndarray of int, shape (n_lines,)
        Excited bins of one multisine period.
    fs_hz : float
        Sampling rate, Hz.
    period_samples, n_periods : int
        Samples per period and periods in the record.
    n_transient : int or None
        Degree of the transient polynomial used.
    variance_inflation : float
        Worst variance inflation of the line's own ``G_p`` over all local problems.
    basis_family : str
        The family of ``b_p`` (one of :data:`BASIS_FAMILIES`); :meth:`basis`,
        :meth:`G`, :meth:`simulate` evaluate that family.
    output_noise_variance : float
        Expected variance per sample that the estimation noise adds to the model's output
        (:meth:`simulate`), output unit²: ``(2/N²)·Σ_e σ_e²·Σ_p ι_p`` with ``σ_e²`` the
        residual variance per bin of line ``e``'s local problem and ``ι_p`` the skirt
        inflation (``σ_t²·2·N_p·n_lines/N`` for orthogonal skirts and white noise of
        variance ``σ_t²``). NaN when unknown.
    """

    G_p: ComplexArray
    G_p_se: FloatArray
    frequencies_hz: FloatArray
    excited_bins: NDArray[np.int64]
    fs_hz: float
    period_samples: int
    n_periods: int
    n_transient: int | None
    variance_inflation: float
    basis_family: str = "legendre"
    output_noise_variance: float = float("nan")

    def __post_init__(self) -> None:
        check_basis_family(self.basis_family)

    @property
    def basis_name(self) -> str:
        """What ``b_p`` are, for reports: e.g. ``"Fourier terms"``."""
        return _FAMILY_NAMES[self.basis_family]

    @property
    def n_basis(self) -> int:
        """``N_p``."""
        return int(self.G_p.shape[0])

    @property
    def n_samples(self) -> int:
        """Samples in the estimation record."""
        return self.period_samples * self.n_periods

    @property
    def duration_s(self) -> float:
        """Length of the record, s (first to last sample)."""
        return (self.n_samples - 1) / self.fs_hz

    def default_times(self, n_times: int = 500) -> FloatArray:
        """``n_times`` evenly spaced times over the record, s."""
        return np.linspace(0.0, self.duration_s, n_times)

    def basis(self, t_s: ArrayLike) -> FloatArray:
        """``b_p(t)`` at times ``t_s`` (s), shape (n_basis, n_times)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        return _basis_at(self.basis_family, t * self.fs_hz, self.n_samples, self.n_basis)

    def G(self, t_s: ArrayLike | None = None) -> ComplexArray:
        """``G(jω_e, t)`` at the excited lines, shape (n_times, n_lines).

        Parameters
        ----------
        t_s : array_like, optional
            Times in s from the first sample (default :meth:`default_times`).
        """
        t = self.default_times() if t_s is None else t_s
        return self.basis(t).T @ self.G_p

    def simulate(self, u: ArrayLike) -> FloatArray:
        """Output of the estimated LTV model for another realisation of the multisine.

        Parameters
        ----------
        u : array_like, shape (n_samples,)
            Input with the same excited bins, period and length as the estimation record.

        Returns
        -------
        numpy.ndarray, shape (n_samples,)
            ``ŷ(t) = Σ_p b_p(t)·(g_p * u)(t)`` (steady state; transients are not modelled).
        """
        u = _as_signal("u", u)
        if u.size != self.n_samples:
            raise InputDataError(
                f"the validation input has {u.size} samples but the model spans {self.n_samples}; "
                "pass a record of the same length (the basis b_p(t) is tied to the record)"
            )
        record_bins = self.excited_bins * self.n_periods
        spectrum = _check_multisine(u, record_bins, DEFAULT_INPUT_TOLERANCE, self.fs_hz)
        n = self.n_samples
        x = np.zeros((self.n_basis, n // 2 + 1), dtype=complex)
        x[:, record_bins] = spectrum[record_bins] * self.G_p
        responses = np.fft.irfft(x, n, axis=1)
        basis = basis_functions(n, self.n_basis, self.basis_family)
        return np.asarray(np.sum(basis * responses, axis=0))

    def resonance_from_peak(self, t_s: ArrayLike | None = None) -> FloatArray:
        """Excited frequency of largest ``|G(jω, t)|`` at each time, Hz (the paper's metric).

        Quantised to the line grid: against a continuously moving resonance its RMSE cannot
        go below about ``Δf_exc/√12``.
        """
        return self.frequencies_hz[np.argmax(np.abs(self.G(t_s)), axis=1)]

    def G_se(self, t_s: ArrayLike | None = None) -> FloatArray:
        """Standard error of :meth:`G` (``G_p`` errors taken as independent), (n_times, n_lines)."""
        t = self.default_times() if t_s is None else t_s
        return np.sqrt(self.basis(t).T ** 2 @ self.G_p_se**2)

    def fit_second_order(
        self,
        t_s: ArrayLike | None = None,
        *,
        iterations: int = 8,
        weighted: bool = True,
        common: tuple[str, ...] = (),
    ) -> SecondOrderTrack:
        """Fit ``1/(K − Iω² + jBω)`` to ``G(jω_e, t)`` at each time.

        Linear least squares on ``G·Z − 1`` (Levy), then Sanathanan–Koerner iterations that
        reweight by ``1/|Ẑ|²`` so the fit converges to the output-error criterion
        ``Σ_e |G − 1/Z|²/σ_e²`` (``σ_e`` from :meth:`G_se` when ``weighted``, else 1).
        Vectorised over times.

        Parameters
        ----------
        t_s : array_like, optional
            Times in s (default :meth:`default_times`).
        iterations : int
            Reweighting iterations after the first linear fit.
        weighted : bool
            Weight each line by its inverse variance (lines far above the resonance carry
            little output and are noisy).
        common : tuple of str
            Parameters held constant over the times, fitted jointly: ``("inertia",)`` when
            the inertia is known not to change (it does not for a joint, and the high lines
            that determine it are the noisiest), ``("inertia", "damping")`` for a plant
            whose damping is constant too. ``K`` is always free per time.

        Returns
        -------
        SecondOrderTrack
        """
        t = self.default_times() if t_s is None else np.atleast_1d(np.asarray(t_s, float))
        g = self.G(t)
        if self.frequencies_hz.size < 2:
            raise InputDataError(
                "a second-order fit needs at least 2 excited lines (3 real parameters from "
                f"{self.frequencies_hz.size} complex value(s)); excite more lines"
            )
        line_weights = None
        if weighted:
            se = self.G_se(t)
            if np.all(np.isfinite(se)) and np.all(se > 0):
                line_weights = 1.0 / se**2
        theta, fit_error = fit_admittance(
            g,
            2 * np.pi * self.frequencies_hz,
            iterations,
            line_weights=line_weights,
            common=common,
        )
        k, inertia, damping = theta[:, 0], theta[:, 1], theta[:, 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.where((inertia != 0), k / inertia, np.nan)
            fn = np.where(ratio > 0, np.sqrt(np.abs(ratio)) / (2 * np.pi), np.nan)
        return SecondOrderTrack(t, k, damping, inertia, fn, fit_error)


#: Times per block in the (independent-row) second-order fit.
_FIT_CHUNK = 4096


def fit_admittance(
    g: ComplexArray,
    w_rad_s: FloatArray,
    iterations: int = 8,
    *,
    line_weights: FloatArray | None = None,
    common: tuple[str, ...] = (),
) -> tuple[FloatArray, FloatArray]:
    """Fit ``1/(K − Iω² + jBω)`` to rows of ``g`` (shape (n_times, n_lines)).

    ``line_weights`` (same shape as ``g``, default 1) weight the output error of each line.
    ``common`` names parameters (``"inertia"``, ``"damping"``) held equal at all times: they
    are fitted jointly over every row while ``K`` (and the others) stay free per row.
    Returns ``theta`` of shape (n_times, 3) with columns ``K, I, B`` and the relative misfit
    ``‖G − Ĝ‖/‖G‖`` per row.
    """
    names = ("stiffness", "inertia", "damping")
    unknown = set(common) - set(names[1:])
    if unknown:
        raise InputDataError(
            f"common parameters must be among 'inertia', 'damping', got {sorted(unknown)}"
        )
    shared = [names.index(c) for c in names if c in common]
    free = [i for i in range(3) if i not in shared]
    if not shared and g.shape[0] > _FIT_CHUNK:  # rows are independent: bound the memory
        parts = [
            fit_admittance(
                g[i : i + _FIT_CHUNK],
                w_rad_s,
                iterations,
                line_weights=None if line_weights is None else line_weights[i : i + _FIT_CHUNK],
            )
            for i in range(0, g.shape[0], _FIT_CHUNK)
        ]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    # Columns a_tei = g_te·c_ei with c_e = (1, −ω_e², jω_e): the normal equations are
    # matrix products over lines instead of a (T, E, 3) temporary.
    c = np.stack([np.ones_like(w_rad_s), -(w_rad_s**2), 1j * w_rad_s], axis=-1)  # (E, 3)
    cc = (c.conj()[:, :, None] * c[:, None, :]).real.reshape(-1, 9)  # (E, 9)
    g_abs2 = np.abs(g) ** 2
    base = np.ones(g.shape) if line_weights is None else np.asarray(line_weights, float)
    weights = base / np.maximum(g_abs2, 1e-300)  # first pass ≈ output error
    theta = np.zeros((g.shape[0], 3))
    for _ in range(iterations + 1):
        normal = ((weights * g_abs2) @ cc).reshape(-1, 3, 3)
        rhs = ((weights * g.conj()) @ c.conj()).real
        theta = _solve_shared(normal, rhs, free, shared) if shared else _solve_batched(normal, rhs)
        z = theta[:, :1] - theta[:, 1:2] * w_rad_s**2 + 1j * theta[:, 2:3] * w_rad_s
        weights = base / np.maximum(np.abs(z) ** 2, 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        model = 1.0 / z
        err = np.linalg.norm(g - model, axis=1) / np.linalg.norm(g, axis=1)
    return theta, err


def _solve_shared(
    normal: FloatArray, rhs: FloatArray, free: list[int], shared: list[int]
) -> FloatArray:
    """Per-row normal equations with the ``shared`` unknowns common to all rows.

    Eliminates each row's ``free`` unknowns (Schur complement), solves the small common
    system summed over rows, then back-substitutes.
    """
    m_ff = normal[:, free][:, :, free]
    m_fc = normal[:, free][:, :, shared]
    m_cc = normal[:, shared][:, :, shared]
    r_f, r_c = rhs[:, free], rhs[:, shared]
    scale = np.sqrt(np.abs(np.einsum("tii->ti", m_ff)))
    scale[scale == 0] = 1.0
    m_ff_s = m_ff / (scale[:, :, None] * scale[:, None, :])
    stacked = np.concatenate([m_fc, r_f[..., None]], axis=2) / scale[..., None]
    try:
        x = np.linalg.solve(m_ff_s, stacked)
    except np.linalg.LinAlgError:
        x = np.linalg.pinv(m_ff_s) @ stacked
    x /= scale[..., None]  # M_ff^{-1} [M_fc | r_f]
    x_c, x_r = x[..., :-1], x[..., -1]
    schur = np.sum(m_cc - np.transpose(m_fc, (0, 2, 1)) @ x_c, axis=0)
    target = np.sum(r_c - np.einsum("tfc,tf->tc", m_fc, x_r), axis=0)
    d = np.sqrt(np.abs(np.diag(schur)))
    d[d == 0] = 1.0
    common_values = np.linalg.lstsq(schur / np.outer(d, d), target / d, rcond=None)[0] / d
    theta = np.empty_like(rhs)
    theta[:, shared] = common_values
    theta[:, free] = x_r - x_c @ common_values
    return theta


def _solve_batched(normal: FloatArray, rhs: FloatArray) -> FloatArray:
    """Solve each 3×3 system after scaling columns (K, I, B differ by orders of magnitude)."""
    d = np.sqrt(np.abs(np.einsum("tii->ti", normal)))
    d[d == 0] = 1.0
    scaled = normal / (d[:, :, None] * d[:, None, :])
    try:
        x = np.linalg.solve(scaled, (rhs / d)[..., None])[..., 0]
    except np.linalg.LinAlgError:
        x = np.stack(
            [np.linalg.lstsq(s, r, rcond=None)[0] for s, r in zip(scaled, rhs / d, strict=True)]
        )
    return x / d


# --------------------------------------------------------------------------------------
# input checks
# --------------------------------------------------------------------------------------


def _as_signal(name: str, x: ArrayLike) -> FloatArray:
    arr = np.asarray(x, dtype=float)
    if arr.ndim != 1:
        raise InputDataError(f"{name} must be one-dimensional, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise InputDataError(f"{name} has a non-finite value at sample {bad}; remove or repair it")
    return arr


def _check_multisine(
    u: FloatArray, record_bins: NDArray[np.int64], tolerance: float, fs_hz: float
) -> ComplexArray:
    """DFT of ``u`` after checking it is a multisine on ``record_bins``; shape (N//2+1,)."""
    spectrum = np.fft.rfft(u)
    power = np.abs(spectrum) ** 2
    power[1:] *= 2.0
    total = float(np.sum(power))
    if total == 0.0:
        raise InputDataError("the input is identically zero; it must be the multisine excitation")
    outside = power.copy()
    outside[record_bins] = 0.0
    fraction = float(np.sum(outside)) / total
    if fraction > tolerance:
        worst = int(np.argmax(outside))
        if worst == 0 and outside[0] > 0.5 * float(np.sum(outside)):
            raise InputDataError(
                f"the input has a DC offset of {u.mean():.4g} ({100 * outside[0] / total:.3g} % "
                "of its power), which a multisine has not; subtract its mean if the joint is "
                "linear about that operating point"
            )
        raise InputDataError(
            f"the input is not a periodic multisine on the declared excited bins: "
            f"{100 * fraction:.3g} % of its power lies outside them (largest at "
            f"{worst * fs_hz / u.size:.4g} Hz, record bin {worst}); pass the excited_bins and "
            "period_samples the excitation was generated with, and a whole number of periods"
        )
    line_power = power[record_bins]
    silent = line_power < 1e-12 * float(np.max(line_power))
    if np.any(silent):
        f = record_bins[silent][0] * fs_hz / u.size
        raise InputDataError(
            f"declared excited line at {f:.4g} Hz carries no power; "
            "remove it from excited_bins or check the excitation"
        )
    return spectrum


def _check_bins(excited_bins: ArrayLike, period_samples: int) -> NDArray[np.int64]:
    bins = np.asarray(excited_bins)
    if bins.ndim != 1 or bins.size == 0:
        raise InputDataError("excited_bins must be a non-empty 1-D array of DFT bins of one period")
    if not np.all(bins == np.round(bins)):
        raise InputDataError(f"excited_bins must be whole DFT bins, got {bins[:5]}…")
    bins = bins.astype(np.int64)
    if np.any(np.diff(bins) <= 0):
        raise InputDataError("excited_bins must be strictly increasing (sort them, drop repeats)")
    if bins[0] < 1 or 2 * bins[-1] >= period_samples:
        raise InputDataError(
            f"excited_bins must lie in 1 … {(period_samples - 1) // 2} (between DC and Nyquist "
            f"of a {period_samples}-sample period), got {bins[0]} … {bins[-1]}"
        )
    return bins


def _record_periods(n: int, period_samples: int, n_periods: int | None) -> int:
    if period_samples < 2:
        raise InputDataError(f"period_samples must be >= 2, got {period_samples}")
    if n_periods is None:
        if n % period_samples:
            whole = n // period_samples
            raise InputDataError(
                f"the record of {n} samples is not a whole number of {period_samples}-sample "
                f"periods ({n / period_samples:.3f}); trim it to the first "
                f"{whole * period_samples} samples ({whole} periods)"
            )
        n_periods = n // period_samples
    if n_periods < 1 or n != n_periods * period_samples:
        raise InputDataError(
            f"the record has {n} samples but {n_periods} periods of {period_samples} samples "
            f"make {n_periods * period_samples}; pass the record's whole periods only"
        )
    return n_periods


# --------------------------------------------------------------------------------------
# identification
# --------------------------------------------------------------------------------------


def _worst_inflation(
    family: str, skirts: ComplexArray, layouts: set[_Layout], n_transient: int | None
) -> float:
    n_basis, n_samples = skirts.shape
    whiten = _whitener(family, n_samples, n_basis)
    return max(
        float(
            np.max(
                _Solver.build(*_design(lay, skirts, n_samples, n_transient), whiten).skirt_inflation
            )
        )
        for lay in layouts
    )


def _largest_stable(
    family: str, skirts: ComplexArray, layouts: set[_Layout], n_transient: int | None
) -> int:
    """Largest ``q < N_p`` whose skirt inflation is ≤ the warning level (0: none).

    Nested families take prefixes of ``skirts``, counting down; B-splines change with
    ``N_p``, so their ``q`` is found by bisection (inflation grows with ``N_p``).
    """
    n_basis, n_samples = skirts.shape

    def stable(q: int) -> bool:
        smaller = skirts[:q] if _nested(family) else _skirts(family, n_samples, q)
        return _worst_inflation(family, smaller, layouts, n_transient) <= WARN_VARIANCE_INFLATION

    if _nested(family):
        return next((q for q in range(n_basis - 1, 0, -1) if stable(q)), 0)
    lo, hi = 0, n_basis  # stable(lo) (or lo = 0), not stable(hi)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return lo


def _check_conditioning(
    solvers: dict[_Layout, _Solver],
    family: str,
    skirts: ComplexArray,
    n_transient: int | None,
    spacing: int,
    fs_hz: float,
) -> float:
    """Worst skirt inflation; warn above the warning level, refuse above the maximum."""
    worst = max(float(np.max(s.skirt_inflation)) for s in solvers.values())
    if worst <= WARN_VARIANCE_INFLATION:
        return worst
    n_basis, n_samples = skirts.shape
    stable = _largest_stable(family, skirts, set(solvers), n_transient)
    df = spacing * fs_hz / n_samples
    advice = (
        f"use N_p <= {stable} for lines {df:g} Hz apart, or excite lines further apart"
        if stable
        else f"excite lines further apart than {df:g} Hz"
    )
    what = (
        f"N_p = {n_basis} is too large for Δf_exc = {df:g} Hz: the "
        f"{_skirt_width(family, n_basis, n_samples, fs_hz)} spill past the {spacing} bins "
        f"between excited lines"
    )
    if not np.isfinite(worst) or worst > MAX_VARIANCE_INFLATION:
        raise NumericalError(
            f"{what}, so G_p is not determined (variance inflation {worst:.3g}); {advice}"
        )
    warnings.warn(
        f"{what}; the estimate's variance is inflated ×{worst:.3g} and time variation beyond "
        f"N_p leaks in more; {advice}",
        SkirtConditioningWarning,
        stacklevel=3,
    )
    return worst


def _skirt_width(family: str, n_basis: int, n_samples: int, fs_hz: float) -> str:
    """How wide the skirts of ``N_p`` functions of ``family`` are, for messages."""
    if family == "legendre":
        return f"Legendre skirts (width ≈ p²/π ≈ {(n_basis - 1) ** 2 / np.pi:.0f} bins)"
    if family == "fourier":
        return f"Fourier skirts (bins ±{fourier_harmonics(n_basis)} around each line)"
    knots_s = (n_samples - 1) / fs_hz / max(n_basis - 3, 1)
    return (
        f"cubic B-spline skirts (knots {knots_s:.3g} s apart: main lobe ≈ ±{max(n_basis - 3, 1)} "
        "bins)"
    )


def _check_fourier_room(n_basis: int, record_bins: NDArray[np.int64], fs_hz: float, n: int) -> None:
    """Refuse Fourier harmonics that reach the bins of another line (or DC) in one line.

    A :class:`~rtsid.errors.NumericalError`, like any ``N_p`` too large for the line
    spacing, only known here before building the local problems.

    Harmonic ``h`` of the record puts line ``k_e``'s skirt on bins ``k_e ± h``; with lines
    ``D`` bins apart two lines share a bin once ``2h >= D``, and the lowest line's skirt
    reaches DC once ``h >= k_1``: ``G_p`` is then not determined.
    """
    harmonic = fourier_harmonics(n_basis)
    spacing = int(np.min(np.diff(record_bins))) if record_bins.size > 1 else 2 * n
    room = min((spacing - 1) // 2, int(record_bins[0]) - 1)
    if harmonic <= room:
        return
    why = (
        f"excited lines are only {spacing} record bins apart, so neighbouring lines' skirts "
        "share bins"
        if (spacing - 1) // 2 <= int(record_bins[0]) - 1
        else f"the lowest line is only {int(record_bins[0])} record bins above DC"
    )
    fix = f"use N_p <= {2 * room + 1}" if room > 0 else "use another basis family"
    raise NumericalError(
        f"N_p = {n_basis} Fourier terms reach harmonic {harmonic} of the record "
        f"({harmonic * fs_hz / n:.3g} Hz) but {why}; {fix}, or record more periods"
    )


def identify_ltv(
    u: ArrayLike,
    y: ArrayLike,
    fs_hz: float,
    excited_bins: ArrayLike,
    period_samples: int,
    n_periods: int | None = None,
    n_basis: int = 8,
    *,
    n_transient: int | None = None,
    window_lines: float = 1.25,
    neighbours: int = 1,
    input_tolerance: float = DEFAULT_INPUT_TOLERANCE,
    basis_family: str = "legendre",
) -> LtvEstimate:
    """Estimate ``G(jω, t) = Σ_p G_p(jω)·b_p(t)`` from one multisine-excited record.

    Parameters
    ----------
    u : array_like, shape (n,)
        Input: the periodic multisine (e.g. torque, N·m); ``n = n_periods·period_samples``.
    y : array_like, shape (n,)
        Output (e.g. angle, rad).
    fs_hz : float
        Sampling rate, Hz.
    excited_bins : array_like of int
        Excited DFT bins of one period (as :attr:`Multisine.excited_bins`).
    period_samples : int
        Samples per multisine period.
    n_periods : int, optional
        Periods in the record (default: inferred; the record must hold whole periods).
    n_basis : int
        ``N_p``, the number of basis functions ``b_p``.
    n_transient : int or None
        Degree of the polynomial in ``k`` that absorbs transients and far leakage in each
        window (None, the default: no polynomial; see the module notes).
    window_lines : float
        How far each local window reaches, in units of the distance to the next line on
        each side (1.25, the default: a quarter spacing past each neighbour; 1.0: from
        neighbour to neighbour; 0.5: half-way, windows tile the band).
    neighbours : int
        Lines on each side whose skirts are modelled as nuisance (plus any inside the
        window).
    input_tolerance : float
        Largest fraction of the input's power allowed outside the excited bins.
    basis_family : str
        The time basis, one of :data:`BASIS_FAMILIES` (see :func:`basis_functions`):
        ``"legendre"`` (default; smooth, slow variation), ``"fourier"`` (variation periodic
        with a period that divides the record: each term's skirt is two bins, so ``N_p``
        is limited by the line spacing only, ``2H < Δk``), ``"bspline"`` (local changes;
        skirts ≈ ``±(N_p − 3)`` bins, much narrower than Legendre's ``p²/π`` at large
        ``N_p``).

    Returns
    -------
    LtvEstimate

    Raises
    ------
    InputDataError
        Inputs of different lengths, a record that is not a whole number of periods, an
        input that is not a multisine on ``excited_bins``, non-finite samples, an unknown
        basis family.
    NumericalError
        ``N_p`` far too large for the line spacing (the local problems are singular; for
        Fourier terms: harmonics that reach another line's bins).

    Warns
    -----
    SkirtConditioningWarning
        ``N_p`` large for the line spacing: variance inflated above
        :data:`WARN_VARIANCE_INFLATION`.
    """
    u_arr, y_arr = _as_signal("u", u), _as_signal("y", y)
    if u_arr.size != y_arr.size:
        raise InputDataError(
            f"input and output differ in length ({u_arr.size} vs {y_arr.size} samples); "
            "pass simultaneous samples of both"
        )
    if not np.isfinite(fs_hz) or fs_hz <= 0:
        raise InputDataError(f"fs_hz must be a positive number, got {fs_hz!r}")
    family = check_basis_family(basis_family)
    if int(n_basis) != n_basis or n_basis < 1:
        raise InputDataError(f"n_basis must be a positive integer, got {n_basis!r}")
    n_basis = int(n_basis)
    if not window_lines > 0 or neighbours < 0:
        raise InputDataError(
            f"window_lines must be > 0 and neighbours >= 0, got {window_lines}, {neighbours}"
        )
    if n_transient is not None and n_transient < 0:
        raise InputDataError(f"n_transient must be >= 0 or None, got {n_transient}")
    n = u_arr.size
    n_periods = _record_periods(n, int(period_samples), n_periods)
    bins = _check_bins(excited_bins, int(period_samples))
    record_bins = bins * n_periods
    if family == "fourier":
        _check_fourier_room(n_basis, record_bins, fs_hz, n)
    if family == "bspline" and n_basis > n // 2:
        raise InputDataError(
            f"N_p = {n_basis} B-splines over {n} samples leave under 2 samples per knot "
            f"interval; use N_p <= {n // 2}"
        )
    spectrum_u = _check_multisine(u_arr, record_bins, input_tolerance, fs_hz)
    spectrum_y = np.fft.fft(y_arr)

    whiten = _whitener(family, n, n_basis)  # before the skirts: one basis in memory at a time
    skirts = _skirts(family, n, n_basis)
    layouts = _layouts(record_bins, n, window_lines, neighbours)
    solvers = {
        layout: _Solver.build(*_design(layout, skirts, n, n_transient), whiten)
        for layout in set(layouts)
    }
    spacing = int(np.min(np.diff(record_bins))) if bins.size > 1 else 2 * layouts[0].left
    worst = _check_conditioning(solvers, family, skirts, n_transient, spacing, fs_hz)

    g_p = np.empty((n_basis, bins.size), dtype=complex)
    se = np.empty((n_basis, bins.size))
    u_lines = spectrum_u[record_bins]
    absorbed = 0.0  # Σ_e σ_e²·Σ_p (skirt inflation): the noise the own G_p take up
    for layout, solver in solvers.items():
        idx = np.array([i for i, lay in enumerate(layouts) if lay == layout])
        windows = record_bins[idx][None, :] + layout.offsets[:, None]  # (rows, lines)
        rhs = spectrum_y[windows]
        theta = solver.own_pinv @ rhs  # unit-norm-column unknowns U·G_p·‖col‖, (n_basis, lines)
        resid = solver.residual_projector @ rhs
        if solver.dof > 0:
            sigma = np.sqrt(np.sum(np.abs(resid) ** 2, axis=0) / solver.dof)
        else:
            sigma = np.full(idx.size, np.nan)
        scale = solver.column_norms[:, None] * u_lines[None, idx]
        g_p[:, idx] = theta / scale
        se[:, idx] = sigma[None, :] * np.sqrt(solver.variance_inflation[:, None]) / np.abs(scale)
        absorbed += float(np.sum(sigma**2) * np.sum(solver.skirt_inflation))
    return LtvEstimate(
        G_p=g_p,
        G_p_se=se,
        frequencies_hz=bins * fs_hz / period_samples,
        excited_bins=bins,
        fs_hz=float(fs_hz),
        period_samples=int(period_samples),
        n_periods=int(n_periods),
        n_transient=n_transient,
        variance_inflation=worst,
        basis_family=family,
        output_noise_variance=2.0 * absorbed / n**2,
    )


# --------------------------------------------------------------------------------------
# choosing N_p from the data
# --------------------------------------------------------------------------------------

#: Largest ``N_p`` :func:`select_basis_size` tries per family (Legendre: as ``--basis auto``
#: always has; Fourier 101 = harmonics up to 50 of the record; B-splines 80).
AUTO_MAX_BASIS = {"legendre": 20, "fourier": 101, "bspline": 80}


@dataclass(frozen=True)
class BasisSelection:
    """``N_p`` chosen by :func:`select_basis_size`, with what it was chosen from.

    Attributes
    ----------
    basis_family : str
        The family.
    n_basis : int
        The chosen ``N_p``.
    n_stable : int
        Largest ``N_p`` (≤ ``n_cap``) whose skirt inflation stays ≤
        :data:`WARN_VARIANCE_INFLATION`: the candidates end there.
    candidates : tuple of int
        The ``N_p`` tried.
    predicted_vaf : tuple of float
        Predicted validation VAF (%, of a noisy validation output) per candidate.
    estimate : LtvEstimate
        The estimate at the chosen ``N_p``.
    n_cap : int
        The largest ``N_p`` the search would try for this family (:data:`AUTO_MAX_BASIS`, or
        ``n_max``).
    cap_reason : str
        Why the search stopped below ``n_cap`` (one line with the numbers), or ``""`` when
        it covered the whole range.
    """

    basis_family: str
    n_basis: int
    n_stable: int
    candidates: tuple[int, ...]
    predicted_vaf: tuple[float, ...]
    estimate: LtvEstimate = field(repr=False)
    n_cap: int = 0
    cap_reason: str = ""

    @property
    def chosen_vaf(self) -> float:
        """Predicted validation VAF at the chosen ``N_p``, %."""
        return self.predicted_vaf[self.candidates.index(self.n_basis)]


@dataclass(frozen=True)
class ModelSelection:
    """Basis family and ``N_p`` chosen by :func:`select_model`.

    Attributes
    ----------
    families : tuple of BasisSelection
        Each family's own choice, best predicted validation VAF first: ``families[0]`` is
        the model chosen. Their scores and estimates are of the record the search ran on.
    estimate : LtvEstimate
        The chosen model estimated on the whole record.
    refused : tuple of (str, str)
        Families with no usable ``N_p`` for this record, with the reason.
    decimation : int
        The search ran on the record band-limited and resampled to ``1/decimation`` of its
        samples (1: on the record itself); see :func:`select_model`.
    band_hz : float
        The band the search's scores cover, Hz (the Nyquist frequency of the record it ran
        on).
    """

    families: tuple[BasisSelection, ...]
    estimate: LtvEstimate
    refused: tuple[tuple[str, str], ...] = ()
    decimation: int = 1
    band_hz: float = float("nan")

    @property
    def chosen(self) -> BasisSelection:
        """The selection of the winning family."""
        return self.families[0]

    @property
    def runners_up(self) -> tuple[BasisSelection, ...]:
        """The other families' choices, best first."""
        return self.families[1:]


def predicted_validation_vaf(estimate: LtvEstimate, u: ArrayLike, y: ArrayLike) -> float:
    """Validation VAF (%) the estimate should reach on another realisation, from its own record.

    Mallows' ``C_p`` in the time domain: on another realisation with the same noise the
    model's error is its error on the estimation record plus twice the noise the estimate
    took up (``estimate.output_noise_variance``: once it is missing from the estimation
    residual, once it is added to the prediction). So
    ``100·(1 − (mean(e²) + 2·v_noise)/var(y))`` with ``e = y − estimate.simulate(u)``
    predicts the VAF of the *noisy* validation output; the model with the highest value is
    expected to predict best.
    """
    u_arr, y_arr = _as_signal("u", u), _as_signal("y", y)
    residual = y_arr - estimate.simulate(u_arr)
    error = float(np.mean(residual**2)) + 2.0 * estimate.output_noise_variance
    return float(100.0 * (1.0 - error / np.var(y_arr)))


def _candidates(family: str, n_stable: int) -> tuple[int, ...]:
    """``N_p`` to try up to ``n_stable``: every value to 12, then steps of ≈ 20 %.

    Fourier takes whole harmonics only (odd ``N_p = 2H + 1``); Legendre every value (its
    cap is 20).
    """
    if family == "legendre":
        values = set(range(1, n_stable + 1))
    else:
        values = set(range(1, min(12, n_stable) + 1))
        n = 12
        while n < n_stable:
            n = max(n + 1, round(n * 1.2))
            values.add(min(n, n_stable))
        values.add(n_stable)
    if family == "fourier":
        values = {v - (1 - v % 2) for v in values}
    return tuple(sorted(v for v in values if v >= 1))


def select_basis_size(
    u: ArrayLike,
    y: ArrayLike,
    fs_hz: float,
    excited_bins: ArrayLike,
    period_samples: int,
    n_periods: int | None = None,
    *,
    basis_family: str = "legendre",
    n_max: int | None = None,
    n_transient: int | None = None,
    window_lines: float = 1.25,
    neighbours: int = 1,
    input_tolerance: float = DEFAULT_INPUT_TOLERANCE,
) -> BasisSelection:
    """Choose ``N_p`` for a basis family from the record: conditioning, then predicted VAF.

    The candidates run up to the largest ``N_p`` whose local problems stay well conditioned
    (:func:`max_stable_basis`, skirt inflation ≤ :data:`WARN_VARIANCE_INFLATION`, at most
    ``n_max``: :data:`AUTO_MAX_BASIS` by default); each is estimated and scored by
    :func:`predicted_validation_vaf`; the best score wins. Arguments as in
    :func:`identify_ltv`.

    Returns
    -------
    BasisSelection

    Raises
    ------
    InputDataError
        As :func:`identify_ltv`; or lines so close that not even ``N_p = 1`` is well
        conditioned.
    """
    family = check_basis_family(basis_family)
    record = _SearchRecord.build(u, y, fs_hz, excited_bins, period_samples, n_periods)
    search = _search_range(family, n_max, record, n_transient, window_lines, neighbours)
    if search.n_stable < 1:
        raise InputDataError(search.reason)
    return _score_candidates(
        family,
        search,
        record,
        n_transient=n_transient,
        window_lines=window_lines,
        neighbours=neighbours,
        input_tolerance=input_tolerance,
    )


@dataclass(frozen=True)
class _SearchRecord:
    """A record checked once for every family's search."""

    u: FloatArray
    y: FloatArray
    fs_hz: float
    excited_bins: NDArray[np.int64]
    period_samples: int
    n_periods: int
    record_bins: NDArray[np.int64]
    spacing: int

    @classmethod
    def build(
        cls,
        u: ArrayLike,
        y: ArrayLike,
        fs_hz: float,
        excited_bins: ArrayLike,
        period_samples: int,
        n_periods: int | None,
    ) -> _SearchRecord:
        u_arr, y_arr = _as_signal("u", u), _as_signal("y", y)
        periods = _record_periods(u_arr.size, int(period_samples), n_periods)
        bins = _check_bins(excited_bins, int(period_samples))
        record_bins = bins * periods
        if record_bins.size < 2:
            raise InputDataError("choosing N_p needs at least two excited lines; excite more lines")
        spacing = int(np.min(np.diff(record_bins)))
        return cls(
            u_arr, y_arr, float(fs_hz), bins, int(period_samples), periods, record_bins, spacing
        )

    @property
    def n_samples(self) -> int:
        return self.u.size

    def estimate(self, n_basis: int, family: str, **options: Any) -> LtvEstimate:
        """:func:`identify_ltv` of this record on ``n_basis`` functions of ``family`` (its
        conditioning warnings, about edge lines only, silenced: the search scores them)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SkirtConditioningWarning)
            return identify_ltv(
                self.u,
                self.y,
                self.fs_hz,
                self.excited_bins,
                self.period_samples,
                self.n_periods,
                n_basis,
                basis_family=family,
                **options,
            )


@dataclass(frozen=True)
class _SearchRange:
    """``N_p`` a family's search covers: up to ``n_stable`` of ``n_cap``, and why not more."""

    n_cap: int
    n_stable: int
    reason: str


def _search_range(
    family: str,
    n_max: int | None,
    record: _SearchRecord,
    n_transient: int | None,
    window_lines: float,
    neighbours: int,
) -> _SearchRange:
    """The family's documented cap (:data:`AUTO_MAX_BASIS` or ``n_max``), lowered by what
    the record's bins allow at all and by the conditioning of the local problems."""
    n_cap = AUTO_MAX_BASIS[family] if n_max is None else int(n_max)
    if n_cap < 1:
        raise InputDataError(f"n_max must be >= 1, got {n_max!r}")
    n, spacing = record.n_samples, record.spacing
    cap, reason = _room_cap(family, n_cap, spacing, record.record_bins, n, record.fs_hz)
    stable = max_stable_basis(
        n,
        spacing,
        n_transient,
        n_max=cap,
        window_lines=window_lines,
        neighbours=neighbours,
        basis_family=family,
    )
    if stable < 1:
        return _SearchRange(
            n_cap,
            0,
            f"excited lines {spacing} record bins apart leave no room for time variation "
            f"with {_FAMILY_NAMES[family]}; excite lines further apart or record more periods",
        )
    if stable < cap:
        cond = skirt_conditioning(
            n,
            spacing,
            stable + 1,
            n_transient,
            window_lines=window_lines,
            neighbours=neighbours,
            basis_family=family,
        )
        reason = _conditioning_reason(cond, stable, n_cap, n, record.fs_hz)
    return _SearchRange(n_cap, stable, reason)


def _score_candidates(
    family: str,
    search: _SearchRange,
    record: _SearchRecord,
    **options: Any,
) -> BasisSelection:
    """Estimate every candidate ``N_p`` of ``search`` and keep the best predicted VAF."""
    candidates = _candidates(family, search.n_stable)
    scores: list[float] = []
    best: LtvEstimate | None = None
    for n_basis in candidates:
        est = record.estimate(n_basis, family, **options)
        scores.append(predicted_validation_vaf(est, record.u, record.y))
        if best is None or scores[-1] > max(scores[:-1]):
            best = est
    assert best is not None
    return BasisSelection(
        family,
        best.n_basis,
        search.n_stable,
        candidates,
        tuple(scores),
        best,
        search.n_cap,
        search.reason,
    )


def _room_cap(
    family: str, cap: int, spacing: int, record_bins: NDArray[np.int64], n: int, fs_hz: float
) -> tuple[int, str]:
    """The family's cap after what the record's bins allow at all, and why it is lower.

    Fourier harmonics beyond those a line owns alone are refused by :func:`identify_ltv`
    (they share bins with the next line's skirt, or reach DC); B-splines need two samples
    per knot interval.
    """
    if family == "fourier":
        room = max(min((spacing - 1) // 2, int(record_bins[0]) - 1), 0)
        if 2 * room + 1 < cap:
            what = (
                f"the next line's, {spacing} record bins ({spacing * fs_hz / n:.3g} Hz) away"
                if (spacing - 1) // 2 <= int(record_bins[0]) - 1
                else f"DC's (the lowest line is record bin {int(record_bins[0])})"
            )
            return 2 * room + 1, (
                f"N_p ≤ {2 * room + 1} of {cap}: harmonic {room + 1} of the record would put "
                f"a line's skirt on {what}; record more periods to allow more"
            )
    if family == "bspline" and n // 2 < cap:
        return n // 2, f"N_p ≤ {n // 2} of {cap}: {n} samples give under 2 per knot beyond"
    return cap, ""


def _conditioning_reason(
    cond: SkirtConditioning, stable: int, n_cap: int, n: int, fs_hz: float
) -> str:
    """One line: why the search stopped at ``stable`` (``cond`` is at ``stable + 1``)."""
    df = cond.spacing_bins * fs_hz / n
    worst = cond.max_variance_inflation
    why = (
        f"the variance ×{worst:.3g} (limit {WARN_VARIANCE_INFLATION:g})"
        if np.isfinite(worst)
        else "them singular"
    )
    return (
        f"N_p ≤ {stable} of {n_cap}: at N_p = {stable + 1} the skirts of lines "
        f"{cond.spacing_bins} record bins ({df:.3g} Hz) apart overlap and inflate {why}; "
        "more periods or lines further apart allow more"
    )


def select_model(
    u: ArrayLike,
    y: ArrayLike,
    fs_hz: float,
    excited_bins: ArrayLike,
    period_samples: int,
    n_periods: int | None = None,
    *,
    families: tuple[str, ...] = BASIS_FAMILIES,
    n_transient: int | None = None,
    window_lines: float = 1.25,
    neighbours: int = 1,
    input_tolerance: float = DEFAULT_INPUT_TOLERANCE,
) -> ModelSelection:
    """Choose the basis family and ``N_p`` from the record: each family's best ``N_p``
    (:func:`select_basis_size`), then the family of best predicted validation VAF.

    A family with no usable ``N_p`` for the line spacing is skipped (``refused`` says why);
    if none is usable the first refusal is raised. Arguments as in :func:`identify_ltv`.

    Only the bins up to the highest line plus 2.5 line spacings enter the local problems,
    so when the record is sampled far above that (a 2500 Hz recording of lines up to 20 Hz)
    the search runs on the record band-limited to the fewest samples per period that keep
    them (exactly, in the DFT: the bins the local problems use are unchanged; the bases
    sampled at the lower rate move ``G_p`` by well under 1 %) and the chosen model is then
    estimated on the whole record. The scores are then predicted VAFs
    of the output in that band (``band_hz``), noise above it excluded.

    Returns
    -------
    ModelSelection
    """
    if not families:
        raise InputDataError("select_model needs at least one basis family")
    full = _SearchRecord.build(u, y, fs_hz, excited_bins, period_samples, n_periods)
    record, decimation, band_hz = _band_limited(full)
    chosen: list[BasisSelection] = []
    refused: list[tuple[str, str]] = []
    options: dict[str, Any] = dict(
        n_transient=n_transient,
        window_lines=window_lines,
        neighbours=neighbours,
        input_tolerance=input_tolerance,
    )
    for family in families:
        search = _search_range(
            check_basis_family(family), None, record, n_transient, window_lines, neighbours
        )
        if search.n_stable < 1:
            refused.append((family, search.reason))
            continue
        chosen.append(_score_candidates(family, search, record, **options))
    if not chosen:
        raise InputDataError(refused[0][1])
    chosen.sort(key=lambda sel: -sel.chosen_vaf)
    best = chosen[0]
    estimate = best.estimate
    if decimation > 1:
        estimate = full.estimate(best.n_basis, best.basis_family, **options)
    return ModelSelection(tuple(chosen), estimate, tuple(refused), decimation, band_hz)


#: How far above the highest excited line (in line spacings) the search keeps the
#: record's spectrum: each local window reaches 1.25 spacings, its neighbours' skirts
#: beyond.
_SEARCH_BAND_SPACINGS = 2.5


def _band_limited(record: _SearchRecord) -> tuple[_SearchRecord, int, float]:
    """The record resampled to ``1/d`` of its samples, ``d`` the largest divisor of the
    period that keeps every bin up to the highest line + :data:`_SEARCH_BAND_SPACINGS`
    spacings below the new Nyquist bin, and the band kept (Hz); ``(record, 1, fs/2)`` when
    no ``d > 1`` does.

    Exact for what the search uses: the DFT bins kept are the record's, scaled by ``1/d``,
    so the excited lines (and the input's check) are unchanged.
    """
    n, period = record.n_samples, record.period_samples
    keep = int(record.record_bins[-1] + _SEARCH_BAND_SPACINGS * record.spacing)
    d = max(
        (d for d in range(1, period + 1) if period % d == 0 and (n // d - 1) // 2 > keep),
        default=1,
    )
    if d == 1:
        return record, 1, record.fs_hz / 2
    n_short = n // d

    def resample(x: FloatArray) -> FloatArray:
        spectrum = np.fft.rfft(x)[: n_short // 2 + 1]
        spectrum[keep + 1 :] = 0.0  # nothing at or near the new Nyquist bin
        return np.asarray(np.fft.irfft(spectrum, n_short) / d, dtype=float)

    short = _SearchRecord(
        resample(record.u),
        resample(record.y),
        record.fs_hz / d,
        record.excited_bins,
        period // d,
        record.n_periods,
        record.record_bins,
        record.spacing,
    )
    return short, d, keep * record.fs_hz / n
