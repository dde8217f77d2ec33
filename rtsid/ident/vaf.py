"""Variance accounted for."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from rtsid.errors import InputDataError

__all__ = ["vaf"]


def vaf(measured: ArrayLike, predicted: ArrayLike) -> float:
    """``max(0, 1 − var(y − ŷ)/var(y))·100``, percent.

    Parameters
    ----------
    measured, predicted : array_like, shape (n,)
        ``y`` and ``ŷ``.

    Returns
    -------
    float
        VAF in percent, 0…100; 0 when ``y`` has no variance.

    Examples
    --------
    >>> vaf([1.0, -1.0, 1.0, -1.0], [0.9, -0.9, 0.9, -0.9])
    99.0
    """
    y = np.asarray(measured, dtype=np.float64)
    y_hat = np.asarray(predicted, dtype=np.float64)
    if y.shape != y_hat.shape:
        raise InputDataError(f"VAF needs equal shapes, got {y.shape} and {y_hat.shape}")
    n = y.size
    y_c = y - y.sum() / n
    total = float(y_c @ y_c)
    if total <= 0:
        return 0.0
    err = y - y_hat
    err -= err.sum() / n
    return round(max(0.0, 1.0 - float(err @ err) / total) * 100.0, 12)
