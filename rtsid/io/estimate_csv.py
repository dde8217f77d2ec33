"""Estimates as CSV rows: one per window, withheld windows included with their reason."""

from __future__ import annotations

import contextlib
import csv
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

from rtsid.ident.stream import WindowResult
from rtsid.io.files import atomic_write

__all__ = ["COLUMNS", "estimate_row", "open_output", "write_estimates"]

COLUMNS = (
    "t_end_s",
    "K",
    "B",
    "I",
    "vaf",
    "K_se",
    "B_se",
    "I_se",
    "vaf_irf",
    "vaf_fit",
    "ok",
    "reason",
    "flags",
    "lost_samples",
)


def _fmt(value: float) -> str:
    return f"{value:.6g}"


def estimate_row(result: WindowResult) -> dict[str, Any]:
    """CSV row of one window (empty numbers and ``ok=0`` when withheld)."""
    row: dict[str, Any] = dict.fromkeys(COLUMNS, "")
    row["t_end_s"] = f"{result.t_end_s:.6f}"
    est = result.estimate
    if est is None:
        row.update(ok=0, reason=result.reason or "")
        return row
    for key in ("K", "B", "I", "vaf", "K_se", "B_se", "I_se", "vaf_irf", "vaf_fit"):
        row[key] = _fmt(float(getattr(est, key)))
    row.update(ok=1, reason="", flags=";".join(est.flags), lost_samples=est.lost_samples)
    return row


def write_estimates(results: Iterable[WindowResult], fh: IO[str]) -> int:
    """Write a header and one row per window; returns the number of rows."""
    writer = csv.DictWriter(fh, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    count = 0
    for result in results:
        writer.writerow(estimate_row(result))
        count += 1
    return count


@contextlib.contextmanager
def open_output(path: str | Path | None) -> Iterator[IO[str]]:
    """Standard output, or a file written atomically (:func:`rtsid.io.files.atomic_write`).

    If the body raises, the temporary file is removed and the destination is untouched, so
    nothing partial is ever left under the requested name.
    """
    if path is None or str(path) == "-":
        yield sys.stdout
        return
    with atomic_write(path, what="estimates") as fh:
        yield fh
