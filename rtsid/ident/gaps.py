"""Lost samples in a window: bridged by sums over valid samples only, never interpolated.

A lost sample (a CAN frame that never arrived) is a row with ``valid = False``. Its value is
unknown, so every quantity it would enter is left out instead of guessed:

* the band-limiting FIR's output is *contaminated* wherever its support holds a lost sample
  (:func:`contaminated`); those analysis samples are zero in the correlations, so every sum
  runs over pairs of valid samples only;
* a regression row (the derivative stencils' ±4 samples, the IRF's ±L lags) is used only when
  its whole support is clean (:func:`clean_rows`).

Past a stated limit — more than ``max_lost_percent`` of the window, a run of lost samples longer
than ``max_gap_s``, or too few clean rows left — the window is withheld with ``reason = "gap"``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import WindowError
from rtsid.verdicts import Reason

__all__ = [
    "LostSamples",
    "WindowGaps",
    "clean_rows",
    "contaminated",
    "count_lost",
    "require_rows",
]

BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class LostSamples:
    """The lost samples of one window.

    Attributes
    ----------
    valid : numpy.ndarray of bool, shape (n,)
        True where the sample arrived.
    count : int
        Lost samples.
    longest_run : int
        Longest run of consecutive lost samples.
    """

    valid: BoolArray
    count: int
    longest_run: int

    def longest_valid_stretch(self) -> slice:
        """The longest run of valid samples (to plan an analysis from)."""
        edges = np.flatnonzero(np.diff(np.concatenate(([0], self.valid.view(np.int8), [0]))))
        starts, stops = edges[::2], edges[1::2]
        best = int(np.argmax(stops - starts))
        return slice(int(starts[best]), int(stops[best]))


def count_lost(
    valid: NDArray[np.bool_], fs_hz: float, max_percent: float, max_gap_s: float
) -> LostSamples:
    """Count a window's lost samples and withhold it past the limits.

    Raises
    ------
    WindowError
        ``reason = "gap"``: more than ``max_percent`` % lost, or a run longer than
        ``max_gap_s``.
    """
    lost = ~valid
    count = int(lost.sum())
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate(([0], lost.view(np.int8), [0])))))[::2]
    longest = int(runs.max()) if runs.size else 0
    if 100.0 * count / valid.size > max_percent:
        raise WindowError(
            f"{count} of {valid.size} samples lost ({100.0 * count / valid.size:.1f} %), more "
            f"than max_lost_percent = {max_percent:g}: the window is withheld",
            Reason.GAP,
        )
    if longest > max(1, round(max_gap_s * fs_hz)):
        raise WindowError(
            f"{longest} consecutive samples lost ({longest / fs_hz * 1e3:.3g} ms), longer than "
            f"max_gap_s = {max_gap_s:g}: the window is withheld",
            Reason.GAP,
        )
    return LostSamples(valid=valid, count=count, longest_run=longest)


def contaminated(valid: BoolArray, taps: int, factor: int) -> BoolArray:
    """Analysis samples whose FIR support (``taps`` inputs) holds a lost sample.

    Same length as the band-limited, decimated signal: ``(n − taps) // factor + 1``.
    """
    lost = (~valid).astype(np.float64)
    return np.asarray(np.convolve(lost, np.ones(taps), mode="valid")[::factor] > 0.5)


def clean_rows(bad: BoolArray, half_width: int) -> BoolArray:
    """Rows ``half_width … m − half_width − 1`` whose ``±half_width`` support is clean."""
    window = np.ones(2 * half_width + 1)
    return np.asarray(np.convolve(bad.astype(np.float64), window, mode="valid") < 0.5)


def require_rows(rows: BoolArray, needed: int, what: str) -> None:
    """Withhold (``"gap"``) a window whose lost samples leave fewer than ``needed`` rows."""
    kept = int(rows.sum())
    if kept < needed:
        raise WindowError(
            f"lost samples leave {kept} of {rows.size} {what} usable, fewer than {needed}: "
            "the window is withheld",
            Reason.GAP,
        )


@dataclass(frozen=True)
class WindowGaps:
    """Where a window's lost samples reach after band-limiting (:mod:`rtsid.ident.gaps`).

    Attributes
    ----------
    bad : numpy.ndarray of bool, shape (m,)
        Analysis samples whose FIR support held a lost sample (zeroed in ``u`` and ``y``).
    lost : int
        Lost input samples.
    """

    bad: NDArray[np.bool_]
    lost: int

    def rows(self, half_width: int) -> NDArray[np.bool_]:
        """Rows ``half_width … m − half_width − 1`` whose ``±half_width`` support is clean."""
        return clean_rows(self.bad, half_width)

    def irf_checkable(self, lag: int) -> bool:
        """Enough clean rows over the IRF's lag span to fit and check it (2L + 11)."""
        return int(self.rows(lag).sum()) >= 2 * lag + 11
