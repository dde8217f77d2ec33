"""EUREKA: the Toeplitz recursion of Levinson (1947) and Wiggins & Robinson (1965).

Solves ``R·x = b`` for a symmetric positive-definite Toeplitz ``R`` (first column ``r``) and
an arbitrary right-hand side ``b`` in O(n²) operations and O(n) memory, instead of the O(n³)
of inversion. Wiener–Hopf deconvolution (``R_uu·h = r_uy``) is such a system.

Two implementations give the same numbers:

* a compiled kernel (``rtsid.ident._eureka``, C, built at install when a compiler exists) —
  the default, faster than ``scipy.linalg.solve_toeplitz`` because the symmetric recursion
  carries a single prediction-error filter where the general Levinson carries two;
* :func:`eureka_numpy`, the reference written in numpy, used when the kernel is absent.

References
----------
.. [1] N. Levinson, "The Wiener RMS error criterion in filter design and prediction",
   J. Math. Phys. 25, 261–278, 1947.
.. [2] R. A. Wiggins and E. A. Robinson, "Recursive solution to the multichannel filtering
   problem", J. Geophys. Res. 70(8), 1885–1891, 1965.
"""

from __future__ import annotations

import importlib
import os
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rtsid.errors import InputDataError, NotPositiveDefiniteError

_eureka: Any = None
if os.environ.get("RTSID_NUMPY_ONLY", "") in ("", "0"):  # "1": the numpy path (CI runs it once)
    try:  # the compiled kernel is optional: see setup.py
        _eureka = importlib.import_module("rtsid.ident._eureka")
    except ImportError:  # pragma: no cover - exercised on machines without a compiler
        _eureka = None

__all__ = [
    "HAVE_COMPILED_KERNEL",
    "compiled_kernel",
    "eureka",
    "eureka_numpy",
    "eureka_unchecked",
    "not_positive_definite",
]

FloatArray = NDArray[np.float64]
HAVE_COMPILED_KERNEL = _eureka is not None


def compiled_kernel() -> Any:
    """The compiled module (``solve``, ``window_irf``, ``xcorr``), or None when not built."""
    return _eureka


def not_positive_definite(step: int, alpha: float) -> NotPositiveDefiniteError:
    return NotPositiveDefiniteError(
        f"Toeplitz matrix is not positive definite: prediction-error variance {alpha:.3g} <= 0 "
        f"at recursion step {step}. The input has too little excitation for this many lags "
        "(or is constant); shorten the lag span, add ridge regularisation, or check the "
        "perturbation",
        step,
    )


def _validated(r: ArrayLike, b: ArrayLike) -> tuple[FloatArray, FloatArray]:
    r_arr = np.ascontiguousarray(r, dtype=np.float64)
    b_arr = np.ascontiguousarray(b, dtype=np.float64)
    if r_arr.ndim != 1 or b_arr.shape != r_arr.shape or r_arr.size == 0:
        raise InputDataError(
            f"eureka needs 1-D r and b of the same non-zero length, got shapes "
            f"{r_arr.shape} and {b_arr.shape}"
        )
    if not (np.all(np.isfinite(r_arr)) and np.all(np.isfinite(b_arr))):
        raise InputDataError("eureka input contains NaN or inf; clean the signals first")
    return r_arr, b_arr


def eureka_numpy(r: ArrayLike, b: ArrayLike) -> FloatArray:
    """Solve ``toeplitz(r) @ x = b`` by the EUREKA recursion, in numpy.

    Parameters
    ----------
    r : array_like, shape (n,)
        First column (and row) of the symmetric Toeplitz matrix.
    b : array_like, shape (n,)
        Right-hand side.

    Returns
    -------
    numpy.ndarray, shape (n,)
        The solution ``x``.

    Raises
    ------
    NotPositiveDefiniteError
        When the prediction-error variance stops being positive.
    """
    r_arr, b_arr = _validated(r, b)
    n = r_arr.size
    a = np.zeros(n)
    x = np.zeros(n)
    alpha = float(r_arr[0])
    if not alpha > 0:
        raise not_positive_definite(0, alpha)
    a[0] = 1.0
    x[0] = b_arr[0] / alpha
    for k in range(1, n):
        r_k = r_arr[k:0:-1]
        refl = -float(a[:k] @ r_k) / alpha
        a[: k + 1] += refl * a[k::-1].copy()
        alpha *= 1.0 - refl * refl
        if not alpha > 0:
            raise not_positive_definite(k, alpha)
        mu = (b_arr[k] - float(x[:k] @ r_k)) / alpha
        x[: k + 1] += mu * a[k::-1]
    return x


def eureka(r: ArrayLike, b: ArrayLike) -> FloatArray:
    """Solve the symmetric Toeplitz system ``toeplitz(r) @ x = b`` by EUREKA.

    Uses the compiled kernel when it was built (see :data:`HAVE_COMPILED_KERNEL`), else
    :func:`eureka_numpy`; both give the same result to rounding.

    Parameters
    ----------
    r : array_like, shape (n,)
        First column of the matrix; ``r[0]`` is the zero-lag autocorrelation.
    b : array_like, shape (n,)
        Right-hand side (e.g. the input–output cross-correlation).

    Returns
    -------
    numpy.ndarray, shape (n,)
        The solution ``x``.

    Raises
    ------
    NotPositiveDefiniteError
        ``R`` is not positive definite (prediction-error variance <= 0); ``.step`` says where.
    InputDataError
        Shapes differ, are empty, or contain NaN/inf.

    Notes
    -----
    Like every Levinson-type recursion it is only weakly stable: for ill-conditioned
    matrices (little excitation at some frequencies) the error grows with the condition
    number; a small ridge on ``r[0]`` restores stability.

    Examples
    --------
    >>> import numpy as np
    >>> from scipy.linalg import toeplitz
    >>> r = np.array([2.0, 0.5, 0.1]); b = np.array([1.0, 0.0, -1.0])
    >>> np.allclose(toeplitz(r) @ eureka(r, b), b)
    True
    """
    r_arr, b_arr = _validated(r, b)
    return eureka_unchecked(r_arr, b_arr)


def eureka_unchecked(r: FloatArray, b: FloatArray) -> FloatArray:
    """:func:`eureka` for inputs already known to be finite, contiguous float64 of equal size.

    The hot path of :func:`rtsid.ident.irf.estimate_irf` calls this several times per
    window on arrays it built itself; skipping the checks saves most of the call's cost.
    Positive definiteness is still checked by the recursion.
    """
    if _eureka is None:
        return eureka_numpy(r, b)
    x = np.empty_like(r)
    status, alpha = _eureka.solve(r, b, x, np.empty(2 * r.size))
    if status >= 0:
        raise not_positive_definite(status, alpha)
    return x
