"""Files on disk: the one atomic writer and the one ``.npz`` reader.

* :func:`atomic_write` — every file rtsid writes whole (calibrations, converted and recovered
  recordings, estimate tables, simulated experiments) goes through it: a temporary file beside
  the destination, flushed and ``fsync``-ed, then renamed over it with :func:`os.replace`. A
  crash or an error leaves the destination as it was and no temporary file behind.
* :func:`read_npz` — every ``.npz`` rtsid reads (sample files, time-varying experiments) is
  opened here, so a missing, empty, truncated or incomplete file is the same one-line
  :class:`~rtsid.errors.InputDataError` everywhere.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import zipfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any, Literal, overload

import numpy as np

from rtsid.errors import InputDataError, RecordingError

__all__ = ["atomic_write", "read_npz"]


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


def read_npz(path: str | Path, required: Iterable[str], *, hint: str) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file, after checking the ``required`` ones are there.

    Parameters
    ----------
    path : str or Path
        The file (never unpickled).
    required : iterable of str
        Arrays the caller needs.
    hint : str
        How to make a good file, appended to the error about missing arrays.

    Returns
    -------
    dict of str to numpy.ndarray

    Raises
    ------
    InputDataError
        Missing, empty, truncated or not an ``.npz`` file, or a required array missing.
    """
    p = Path(path)
    if not p.is_file():
        raise InputDataError(f"{str(p)!r} does not exist or is not a file; check the path")
    try:
        with p.open("rb") as fh:
            loaded = np.load(fh, allow_pickle=False)
            if not isinstance(loaded, np.lib.npyio.NpzFile):
                raise ValueError("it holds a single array, not named arrays")
            with loaded as data:
                arrays = {k: np.asarray(data[k]) for k in data.files}
    except (zipfile.BadZipFile, EOFError, ValueError, OSError) as exc:
        raise InputDataError(
            f"{str(p)!r} is not a readable .npz file ({exc or type(exc).__name__}); "
            "is it empty, truncated or of another format?"
        ) from None
    missing = [k for k in required if k not in arrays]
    if missing:
        found = ", ".join(arrays) or "none"
        names = ", ".join(missing)
        raise InputDataError(f"{str(p)!r} lacks {names} (arrays found: {found}); {hint}")
    return arrays
