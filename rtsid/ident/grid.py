"""The window grid: which windows a stream of samples is cut into, the same everywhere.

A window of ``n`` samples ends on a fixed grid of sample indices — every ``hop`` samples, with
``end + 1`` a multiple of the hop — so the windows depend neither on thread timing nor on who
cuts them: the live worker, ``rtsid replay`` and ``rtsid identify`` give the same windows, and
so the same numbers, for the same samples.
"""

from __future__ import annotations

__all__ = ["first_window_end", "window_ends"]


def first_window_end(first_index: int, window_samples: int, hop_samples: int) -> int:
    """The first grid window end whose window starts at or after ``first_index``."""
    earliest = first_index + window_samples - 1
    return -(-(earliest + 1) // hop_samples) * hop_samples - 1


def window_ends(first_index: int, last_index: int, window_samples: int, hop_samples: int) -> range:
    """Every grid window end within ``first_index … last_index``, oldest first."""
    start = first_window_end(first_index, window_samples, hop_samples)
    return range(start, last_index + 1, hop_samples)
