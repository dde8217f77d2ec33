"""Estimates as CSV: one row per window, withheld windows included with their reason.

One schema for every output of estimates. The columns are the estimate message's fields
(:class:`rtsid.io.messages.EstimateMessage`, whose JSON is what zenoh publishes and MCAP
records), in the message's order, without its envelope (``robot``, ``joint``,
``host_time_ns``): the window's time, the tracked stiffness, K, B, I with their standard errors
and held markers, the VAF, the verdict, then the rest. ``rtsid identify`` and ``rtsid replay``
write them with :func:`write_estimates`; the values are encoded as in the JSON, one way:

- booleans ``true`` / ``false`` (``ok``, ``I_held``, ``B_held``);
- ``reason`` and each flag as its :mod:`rtsid.verdicts` value (``gap``, ``low_vaf``), flags
  joined by ``;``;
- numbers as Python's shortest round-trip repr (the digits the JSON carries);
- null, NaN and infinity as an empty field.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import math
import sys
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from rtsid.io.files import atomic_write
from rtsid.io.messages import EstimateMessage
from rtsid.verdicts import Reason

if TYPE_CHECKING:  # the estimator (scipy) is imported only by who runs it, not by readers
    from rtsid.ident.stream import WindowResult

__all__ = [
    "COLUMNS",
    "encode_value",
    "estimate_row",
    "open_output",
    "window_messages",
    "write_estimates",
]

#: Message fields that describe the stream, not the window (one file is one stream).
ENVELOPE = ("robot", "joint", "host_time_ns")
#: The CSV columns: the estimate message's fields in its order, without the envelope.
COLUMNS: tuple[str, ...] = tuple(
    f.name for f in dataclasses.fields(EstimateMessage) if f.name not in ENVELOPE
)


def encode_value(value: Any) -> str:
    """One field as CSV text: ``true``/``false``, enum values, shortest-repr numbers, and an
    empty field for null/NaN/inf."""
    if value is None:
        return ""
    if isinstance(value, bool | np.bool_):
        return "true" if value else "false"
    if isinstance(value, str):  # a StrEnum member is its value
        return str(value)
    if isinstance(value, list | tuple):
        return ";".join(str(v) for v in value)
    if isinstance(value, int | np.integer):
        return str(int(value))
    number = float(value)
    return repr(number) if math.isfinite(number) else ""


def estimate_row(message: Mapping[str, Any]) -> dict[str, str]:
    """The CSV row of one estimate message (keys missing from older recordings: empty)."""
    return {k: encode_value(message.get(k)) for k in COLUMNS}


def write_estimates(messages: Iterable[Mapping[str, Any]], fh: IO[str]) -> int:
    """Write the header and one row per estimate message; returns the number of rows."""
    writer = csv.DictWriter(fh, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    count = 0
    for message in messages:
        writer.writerow(estimate_row(message))
        count += 1
    return count


def window_messages(results: Iterable[WindowResult], fs_hz: float) -> Iterator[dict[str, Any]]:
    """The estimate messages of :func:`rtsid.ident.stream.sliding_estimates`' windows (what
    ``rtsid identify`` writes): the live worker's message, without robot, joint or timing."""
    for seq, result in enumerate(results):
        yield EstimateMessage.window_dict(
            result.estimate,
            Reason(result.reason) if result.estimate is None and result.reason else None,
            result.track,
            seq=seq,
            first=result.start,
            last=result.stop - 1,
            fs_hz=fs_hz,
        )


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
