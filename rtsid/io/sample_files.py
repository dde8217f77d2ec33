"""Sample files: ``.npz`` and ``.csv`` recordings of joint angle and torque.

* ``.npz``: arrays ``position_rad`` and ``torque_nm`` (1-D, equal length) and scalar
  ``fs_hz`` — the format of ``shared/data/reklab_ankle_z.npz``.
* ``.csv``: a header row with columns ``position_rad`` and ``torque_nm``, and either a
  time column (``t_s`` or ``time_s``, uniformly spaced) or a sampling rate given by the caller.

Every problem is a :class:`~rtsid.errors.InputDataError` naming the file, what is wrong and
what to do about it.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import InputDataError
from rtsid.io.files import read_npz

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


def _load_npz(path: Path) -> SampleRecord:
    data = read_npz(
        path,
        SAMPLE_ARRAYS,
        hint="an .npz recording needs position_rad, torque_nm and fs_hz",
    )
    position = np.asarray(data["position_rad"], dtype=np.float64)
    torque = np.asarray(data["torque_nm"], dtype=np.float64)
    fs_arr = np.asarray(data["fs_hz"], dtype=np.float64)
    if fs_arr.size != 1:
        raise InputDataError(f"{path}: fs_hz must be a scalar, got shape {fs_arr.shape}")
    return _checked(position, torque, float(fs_arr.reshape(())), str(path))


def _csv_rows(path: Path) -> tuple[list[str], FloatArray]:
    try:
        with path.open(newline="") as fh:
            reader = csv.reader(row for row in fh if row.strip() and not row.startswith("#"))
            header = [h.strip() for h in next(reader, [])]
            rows = list(reader)
    except UnicodeDecodeError:
        raise InputDataError(f"{path}: not a text CSV file") from None
    if not header:
        raise InputDataError(f"{path}: empty CSV; expected a header row and samples")
    try:
        values = np.array(
            [[float(v) if v.strip() else np.nan for v in row] for row in rows], dtype=np.float64
        )
    except ValueError as exc:
        raise InputDataError(f"{path}: a value is not a number ({exc})") from None
    if values.size and (values.ndim != 2 or values.shape[1] != len(header)):
        raise InputDataError(f"{path}: rows do not all have {len(header)} columns like the header")
    return header, values.reshape(-1, len(header))


def _load_csv(path: Path, fs_hz: float | None) -> SampleRecord:
    header, values = _csv_rows(path)
    missing = [c for c in ("position_rad", "torque_nm") if c not in header]
    if missing:
        raise InputDataError(
            f"{path}: missing column(s) {', '.join(missing)}; the header has "
            f"{', '.join(header)}. Name the columns position_rad and torque_nm"
        )
    column = {name: values[:, i] for i, name in enumerate(header)}
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
    steps = np.diff(t)
    step = float(np.median(steps))
    if step <= 0 or np.max(np.abs(steps - step)) > 1e-3 * step:
        raise InputDataError(
            f"{path}: the time column is not uniformly spaced (steps from {steps.min():.6g} to "
            f"{steps.max():.6g} s); resample the data or pass --fs to ignore the column"
        )
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
