"""Estimates as CSV rows: one per window, withheld windows included with their reason."""

from __future__ import annotations

import contextlib
import csv
import os
import sys
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

from rtsid.errors import RecordingError
from rtsid.ident.stream import WindowResult

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
    row.update(ok=1, reason="", flags=";".join(est.flags))
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
    """Standard output, or a file written atomically (a temporary file renamed on success).

    If the body raises, the temporary file is removed and the destination is untouched, so
    nothing partial is ever left under the requested name.
    """
    if path is None or str(path) == "-":
        yield sys.stdout
        return
    dest = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".part", dir=dest.parent or ".")
    except OSError as exc:
        raise RecordingError(f"cannot write to {dest.parent or '.'}: {exc.strerror}") from None
    try:
        with os.fdopen(fd, "w", newline="") as fh:
            yield fh
        os.replace(tmp, dest)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
