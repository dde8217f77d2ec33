"""Sample files: ``.npz`` and ``.csv`` recordings of joint angle and torque.

* ``.npz``: arrays ``position_rad`` and ``torque_nm`` (1-D, equal length) and scalar
  ``fs_hz`` — the format of ``shared/data/reklab_ankle_z.npz``.
* ``.csv``: a header row with columns ``position_rad`` and ``torque_nm``, and either a
  time column (``t_s`` or ``time_s``, uniformly spaced) or a sampling rate given by the caller.

Every problem is a :class:`~rtsid.errors.InputDataError` naming the file, what is wrong and
what to do about it.
"""

from __future__ import annotations

import array
import csv
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import InputDataError
from rtsid.io.files import check_file_size, check_rows, read_npz

__all__ = ["SampleRecord", "load_samples", "nonfinite_report"]

FloatArray = NDArray[np.float64]
TIME_COLUMNS = ("t_s", "time_s")
SAMPLE_ARRAYS = ("position_rad", "torque_nm", "fs_hz")


@dataclass(frozen=True)
class SampleRecord:
    """A uniformly sampled recording of joint angle and torque.

    Attributes
    ----------
    position_rad : numpy.ndarray, shape (n,)
        Joint angle, rad.
    torque_nm : numpy.ndarray, shape (n,)
        Torque, N·m (as recorded: apply the rig's sign convention when estimating).
    fs_hz : float
        Sampling rate, Hz.
    source : str
        Where it came from (file path).
    """

    position_rad: FloatArray
    torque_nm: FloatArray
    fs_hz: float
    source: str

    @property
    def duration_s(self) -> float:
        """Length of the record, s."""
        return self.position_rad.size / self.fs_hz


def nonfinite_report(record: SampleRecord) -> str | None:
    """Describe NaN/inf samples (count and first index), or None when all are finite."""
    bad = ~(np.isfinite(record.position_rad) & np.isfinite(record.torque_nm))
    count = int(np.count_nonzero(bad))
    if count == 0:
        return None
    first = int(np.argmax(bad))
    t_first = first / record.fs_hz
    return f"{count} sample(s) are NaN or inf, the first at index {first} (t = {t_first:.4f} s)"


def _checked(position: FloatArray, torque: FloatArray, fs_hz: float, source: str) -> SampleRecord:
    if position.ndim != 1 or torque.ndim != 1 or position.size != torque.size:
        raise InputDataError(
            f"{source}: position_rad and torque_nm must be 1-D and equally long, got shapes "
            f"{position.shape} and {torque.shape}"
        )
    if position.size == 0:
        raise InputDataError(f"{source}: the file holds no samples")
    if not np.isfinite(fs_hz) or fs_hz <= 0:
        raise InputDataError(f"{source}: sampling rate {fs_hz!r} Hz is not a positive number")
    return SampleRecord(position, torque, float(fs_hz), source)


def _float_column(data: dict[str, np.ndarray], name: str, path: Path) -> FloatArray:
    """Array ``name`` as float64; strings, objects, complex or structured data are refused."""
    array = data[name]
    if array.dtype.kind not in "biuf":
        raise InputDataError(
            f"{path}: {name} holds {array.dtype} values, not real numbers; store it as a "
            "float array (e.g. numpy.asarray(x, dtype=float))"
        )
    return np.asarray(array, dtype=np.float64)


def _load_npz(path: Path) -> SampleRecord:
    data = read_npz(
        path,
        SAMPLE_ARRAYS,
        hint="an .npz recording needs position_rad, torque_nm and fs_hz",
    )
    fs_arr = _float_column(data, "fs_hz", path)
    if fs_arr.size != 1:
        raise InputDataError(f"{path}: fs_hz must be a scalar, got shape {fs_arr.shape}")
    fs_hz = float(fs_arr.reshape(()))
    check_rows(path, data["position_rad"].size, fs_hz)
    position = _float_column(data, "position_rad", path)
    torque = _float_column(data, "torque_nm", path)
    return _checked(position, torque, fs_hz, str(path))


#: Longest line of a CSV sample file, characters (a row of numbers is far shorter).
MAX_CSV_LINE_CHARS = 1 << 16


def _data_lines(fh: TextIO, path: Path) -> Iterator[str]:
    """Lines of ``fh`` that are neither blank nor ``#`` comments, each read with a length cap
    so that a file without line breaks is refused, not held whole."""
    number = 0
    while line := fh.readline(MAX_CSV_LINE_CHARS + 1):
        number += 1
        if len(line) > MAX_CSV_LINE_CHARS:
            raise InputDataError(
                f"{path}: line {number} is longer than {MAX_CSV_LINE_CHARS} characters; "
                "is it a CSV of samples (one row of numbers per line)?"
            )
        if line.strip() and not line.startswith("#"):
            yield line


def _number(text: str, path: Path, line: int, column: str) -> float:
    if not text.strip():
        return math.nan
    try:
        return float(text)
    except ValueError:
        raise InputDataError(
            f"{path}: line {line}, column {column}: {text[:40]!r} is not a number; "
            "write plain decimal numbers (empty for a missing value)"
        ) from None


def _csv_rows(path: Path, wanted: Sequence[str]) -> tuple[list[str], dict[str, FloatArray]]:
    """The header and the ``wanted`` columns present in it, read row by row into compact
    columns (other columns are only counted), at most :data:`MAX_ROWS` rows."""
    check_file_size(path, path.stat().st_size, "a CSV file", "split it or save it as .npz")
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.reader(_data_lines(fh, path))
            header = [h.strip() for h in next(reader, [])]
            keep = {name: header.index(name) for name in wanted if name in header}
            columns = {name: array.array("d") for name in keep}
            for rows, row in enumerate(reader, start=1):
                check_rows(path, rows)
                if len(row) != len(header):
                    raise InputDataError(
                        f"{path}: line {reader.line_num} has {len(row)} columns, the header "
                        f"{len(header)}; give every row a value (or an empty one) per column"
                    )
                for name, index in keep.items():
                    columns[name].append(_number(row[index], path, reader.line_num, name))
    except UnicodeDecodeError:
        raise InputDataError(f"{path}: not a UTF-8 text CSV file; export it as text") from None
    except csv.Error as exc:
        raise InputDataError(f"{path}: not a readable CSV file ({exc})") from None
    if not header or header == [""]:
        raise InputDataError(f"{path}: empty CSV; expected a header row and samples")
    return header, {name: np.frombuffer(col, dtype=np.float64) for name, col in columns.items()}


def _load_csv(path: Path, fs_hz: float | None) -> SampleRecord:
    header, column = _csv_rows(path, ("position_rad", "torque_nm", *TIME_COLUMNS))
    missing = [c for c in ("position_rad", "torque_nm") if c not in header]
    if missing:
        shown = ", ".join(h[:40] for h in header[:20])
        raise InputDataError(
            f"{path}: missing column(s) {', '.join(missing)}; the header has "
            f"{shown}. Name the columns position_rad and torque_nm"
        )
    time_name = next((c for c in TIME_COLUMNS if c in column), None)
    if fs_hz is None:
        if time_name is None:
            raise InputDataError(
                f"{path}: no time column ({' or '.join(TIME_COLUMNS)}) and no sampling rate; "
                "add a t_s column or pass --fs"
            )
        fs_hz = _rate_from_times(column[time_name], path)
    return _checked(column["position_rad"], column["torque_nm"], fs_hz, str(path))


def _rate_from_times(t: FloatArray, path: Path) -> float:
    if t.size < 2:
        raise InputDataError(f"{path}: need at least two samples to infer the sampling rate")
    if not np.all(np.isfinite(t)):
        raise InputDataError(f"{path}: the time column has empty, NaN or inf values; fill it")
    with np.errstate(over="ignore", invalid="ignore"):  # overflowing steps are irregular
        steps = np.diff(t)
        step = float(np.median(steps))
        irregular = not np.max(np.abs(steps - step)) <= 1e-3 * step
    if not step > 0 or irregular:
        raise InputDataError(
            f"{path}: the time column is not uniformly spaced (steps from {steps.min():.6g} to "
            f"{steps.max():.6g} s); resample the data or pass --fs to ignore the column"
        )
    if step < 1e-9:
        raise InputDataError(f"{path}: time steps of {step:.3g} s are too short; use seconds")
    return 1.0 / step


def load_samples(path: str | Path, fs_hz: float | None = None) -> SampleRecord:
    """Load a ``.npz`` or ``.csv`` sample file.

    Parameters
    ----------
    path : str or Path
        The file.
    fs_hz : float, optional
        Sampling rate for a CSV without a time column (ignored for ``.npz``).

    Returns
    -------
    SampleRecord
        The samples; NaN/inf are kept (see :func:`nonfinite_report`).

    Raises
    ------
    InputDataError
        Missing file, unknown format, missing arrays or columns, bad rate.
    """
    p = Path(path)
    if not p.is_file():
        raise InputDataError(f"{p}: no such file")
    suffix = p.suffix.lower()
    if suffix == ".npz":
        return _load_npz(p)
    if suffix == ".csv":
        return _load_csv(p, fs_hz)
    raise InputDataError(
        f"{p}: unknown sample file type {suffix!r}; "
        "use .npz (position_rad, torque_nm, fs_hz) or .csv"
    )
