"""Tables and timing statistics shared by every benchmark."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

__all__ = ["format_table", "median_p99", "print_table", "time_calls"]


def median_p99(values: Sequence[float]) -> tuple[float, float]:
    """Median and 99th percentile of ``values`` (NaN for an empty sequence)."""
    if len(values) == 0:
        return float("nan"), float("nan")
    arr = np.asarray(values, dtype=float)
    return float(np.median(arr)), float(np.percentile(arr, 99))


def time_calls(
    func: Callable[[], Any],
    *,
    min_calls: int = 5,
    min_total_s: float = 0.2,
    max_calls: int = 10_000,
) -> list[float]:
    """Wall-clock seconds of repeated ``func()`` calls (after one warm-up call).

    Calls until both ``min_calls`` and ``min_total_s`` are reached, never more than
    ``max_calls``.
    """
    func()
    times: list[float] = []
    total = 0.0
    while len(times) < max_calls and (len(times) < min_calls or total < min_total_s):
        start = time.perf_counter()
        func()
        elapsed = time.perf_counter() - start
        times.append(elapsed)
        total += elapsed
    return times


def _cell(value: Any) -> str:
    if isinstance(value, float):
        if not np.isfinite(value):
            return "—"
        return f"{value:.3g}" if abs(value) < 1000 else f"{value:,.0f}"
    return str(value)


def format_table(title: str, headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A Markdown table (readable in a terminal and pasteable into docs)."""
    cells = [[_cell(v) for v in row] for row in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) for i, h in enumerate(headers)]

    def line(vals: Sequence[str]) -> str:
        return "| " + " | ".join(v.rjust(w) for v, w in zip(vals, widths, strict=True)) + " |"

    out = [f"### {title}", "", line(list(headers))]
    out.append("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    out.extend(line(r) for r in cells)
    return "\n".join(out)


def print_table(
    title: str, headers: Sequence[str], rows: Sequence[Sequence[Any]], note: str | None = None
) -> None:
    """Print :func:`format_table` followed by an optional note and a blank line."""
    print(format_table(title, headers, rows))
    if note:
        print(f"\n{note}")
    print(flush=True)
