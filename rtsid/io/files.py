"""Files on disk: the one atomic writer and the one ``.npz`` reader.

* :func:`atomic_write` — every file rtsid writes whole (calibrations, converted and recovered
  recordings, estimate tables, simulated experiments) goes through it: a temporary file beside
  the destination, flushed and ``fsync``-ed, then renamed over it with :func:`os.replace`. A
  crash or an error leaves the destination as it was and no temporary file behind.
* :func:`read_npz` — every ``.npz`` rtsid reads (sample files, time-varying experiments) is
  opened here, so a missing, empty, truncated or incomplete file is the same one-line
  :class:`~rtsid.errors.InputDataError` everywhere.
* The caps on what an import may hold in memory, checked before anything is allocated:
  :data:`MAX_SAMPLE_FILE_BYTES` (a ``.csv`` file's size, an ``.npz`` file's arrays as their
  headers declare them) and :data:`MAX_ROWS` (rows of samples a conversion or load holds,
  duration × rate, gaps included); :func:`check_file_size` and :func:`check_rows` refuse more
  with one line that names the cap.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any, Literal, overload

import numpy as np

from rtsid.errors import InputDataError, RecordingError

__all__ = [
    "MAX_ROWS",
    "MAX_SAMPLE_FILE_BYTES",
    "atomic_write",
    "check_file_size",
    "check_rows",
    "read_npz",
]

#: Most rows of samples one import holds (gaps included): 2 h 13 min at 2500 Hz. An import
#: needs at most about 100 bytes per row at its peak, so about 2 GB at the cap (docs/io.md).
MAX_ROWS = 20_000_000
#: Largest sample file read: a ``.csv`` file's size, or the sum of an ``.npz`` file's arrays
#: as their headers declare them (uncompressed), bytes (1 GiB).
MAX_SAMPLE_FILE_BYTES = 1 << 30


def _size_text(n_bytes: float) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n_bytes >= scale:
            return f"{n_bytes / scale:.1f} {unit}"
    return f"{int(n_bytes)} bytes"


def check_file_size(path: str | Path, n_bytes: int, what: str, fix: str) -> None:
    """Refuse ``n_bytes`` of ``what`` above :data:`MAX_SAMPLE_FILE_BYTES` (before reading it).

    Raises
    ------
    InputDataError
        Names the file, its size, the cap and ``fix``.
    """
    if n_bytes > MAX_SAMPLE_FILE_BYTES:
        raise InputDataError(
            f"{str(path)!r}: {what} of {_size_text(n_bytes)} exceed the "
            f"{_size_text(MAX_SAMPLE_FILE_BYTES)} rtsid reads at once; {fix}"
        )


def check_rows(source: str | Path, rows: float, fs_hz: float | None = None) -> None:
    """Refuse an import of more than :data:`MAX_ROWS` rows (``rows`` = duration × rate), before
    they are allocated.

    Raises
    ------
    InputDataError
        Names the rows (and their duration at ``fs_hz``), the cap and what to do.
    """
    if rows > MAX_ROWS or rows != rows:  # NaN counts as too many
        at = "" if fs_hz is None else f" at {fs_hz:g} Hz ({rows / fs_hz:.4g} s)"
        raise InputDataError(
            f"{source}: {rows:.4g} rows{at} exceed the {MAX_ROWS} rows "
            f"({MAX_ROWS / 2500 / 3600:.2f} h at 2500 Hz) one import holds; check the rate "
            "(--fs) or split the recording"
        )


@overload
def atomic_write(
    path: str | Path, mode: Literal["w"] = "w", *, what: str = "file", make_folder: bool = False
) -> contextlib.AbstractContextManager[IO[str]]: ...


@overload
def atomic_write(
    path: str | Path, mode: Literal["wb"], *, what: str = "file", make_folder: bool = False
) -> contextlib.AbstractContextManager[IO[bytes]]: ...


def atomic_write(
    path: str | Path, mode: str = "w", *, what: str = "file", make_folder: bool = False
) -> Any:
    """Open ``path`` for writing so that it appears whole or not at all.

    Parameters
    ----------
    path : str or Path
        The destination.
    mode : {"w", "wb"}
        Text (UTF-8, ``\\n`` line ends kept as written) or binary.
    what : str
        What the file is, for the error message (``"calibration"``, ``"recording"`` …).
    make_folder : bool
        Create the destination's folder if missing (else a missing folder is an error).

    Returns
    -------
    context manager
        Yields the open temporary file. On a normal exit it is flushed, ``fsync``-ed and
        renamed to ``path``; if the body raises, it is removed and ``path`` is untouched.

    Raises
    ------
    RecordingError
        The folder is missing or not writable, or the disk is full (names the path).
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_write mode must be 'w' or 'wb', not {mode!r}")
    return _atomic_write(Path(path), mode, what, make_folder)


@contextlib.contextmanager
def _atomic_write(dest: Path, mode: str, what: str, make_folder: bool) -> Iterator[IO[Any]]:
    import tempfile  # here: a replay's children write nothing (shutil, random, hashlib: 3 ms)

    try:
        if make_folder:
            dest.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".part", dir=dest.parent)
    except OSError as exc:
        raise _write_error(dest, what, exc) from None
    try:
        encoding = None if mode == "wb" else "utf-8"
        newline = None if mode == "wb" else ""
        with os.fdopen(fd, mode, encoding=encoding, newline=newline) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, dest)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, RecordingError):
            raise _write_error(dest, what, exc) from None
        raise


def _write_error(dest: Path, what: str, exc: OSError) -> RecordingError:
    reason = exc.strerror or str(exc)
    return RecordingError(
        f"cannot write {what} {str(dest)!r}: {reason}; choose a writable folder with free space"
    )


def read_npz(
    path: str | Path, required: Iterable[str], *, hint: str, content: bytes | None = None
) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file, after checking the ``required`` ones are there.

    Parameters
    ----------
    path : str or Path
        The file (never unpickled).
    required : iterable of str
        Arrays the caller needs.
    hint : str
        How to make a good file, appended to the error about missing arrays.
    content : bytes, optional
        The ``.npz`` itself, already in memory (e.g. an MCAP attachment); ``path`` then only
        names it in errors.

    Returns
    -------
    dict of str to numpy.ndarray

    Raises
    ------
    InputDataError
        Missing, empty, truncated or not an ``.npz`` file, or a required array missing.
    """
    import zipfile  # here: a replay reads no .npz

    p = Path(path)
    if content is None and not p.is_file():
        raise InputDataError(f"{str(p)!r} does not exist or is not a file; check the path")
    try:
        with p.open("rb") if content is None else io.BytesIO(content) as fh:
            check_file_size(p, _npz_declared_bytes(fh), "arrays", "split it into smaller files")
            fh.seek(0)
            loaded = np.load(fh, allow_pickle=False)
            if not isinstance(loaded, np.lib.npyio.NpzFile):
                raise ValueError("it holds a single array, not named arrays")
            with loaded as data:
                arrays = {k: np.asarray(data[k]) for k in data.files}
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, ValueError, OSError) as exc:
        raise InputDataError(
            f"{str(p)!r} is not a readable .npz file ({exc or type(exc).__name__}); "
            "is it empty, truncated or of another format?"
        ) from None
    except MemoryError:
        raise InputDataError(f"{str(p)!r}: its arrays do not fit in memory; split it") from None
    missing = [k for k in required if k not in arrays]
    if missing:
        found = ", ".join(arrays) or "none"
        names = ", ".join(missing)
        raise InputDataError(f"{str(p)!r} lacks {names} (arrays found: {found}); {hint}")
    return arrays


def _npz_declared_bytes(fh: IO[bytes]) -> int:
    """Bytes the arrays of an ``.npz`` declare in their ``.npy`` headers (other members: their
    uncompressed size), read without loading any array.

    Raises
    ------
    zipfile.BadZipFile, ValueError, EOFError
        Not a zip file, or a member whose header does not read.
    """
    magic = fh.read(6)
    if magic == b"\x93NUMPY":
        raise ValueError("it holds a single array, not named arrays")
    if magic[:4] != b"PK\x03\x04":
        raise ValueError("it is not a zip archive of arrays")
    import zipfile

    fh.seek(0)
    total = 0
    with zipfile.ZipFile(fh) as archive:
        for info in archive.infolist():
            if not info.filename.endswith(".npy"):
                total += info.file_size
                continue
            with archive.open(info) as member:
                version = np.lib.format.read_magic(member)
                header = (
                    np.lib.format.read_array_header_1_0
                    if version == (1, 0)
                    else np.lib.format.read_array_header_2_0
                )
                shape, _fortran, dtype = header(member)
            total += math.prod(shape) * dtype.itemsize
    return total
