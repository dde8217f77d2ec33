"""Filter designs without importing scipy.signal: one in numpy, the others cached.

rtsid designs its filters with scipy.signal, but importing it costs a process about 0.6–1 s
of CPU (it imports scipy.stats, scipy.interpolate and scipy.optimize too): more than replaying
half of a 2.5-minute recording, and paid by every process of ``rtsid replay DIR --jobs N``.
A design is computed once and then only read, so:

- :func:`firwin_lowpass` is scipy's ``firwin(numtaps, cutoff, fs=fs, window="hamming")``
  written out in numpy, operation for operation (the same numbers bit for bit, tested against
  scipy over a grid of the arguments rtsid uses). Its cut-off is chosen from the data, so it
  could not be cached once for all.
- :func:`design` returns ``scipy.signal.<function>(*args, **kwargs)`` from the *design cache*:
  scipy's exact output, stored once per (function, arguments, scipy and numpy versions) and
  read back with numpy. The decimator's Chebyshev I, its initial conditions and impulse
  response, the yardstick's Savitzky–Golay and Butterworth filters depend only on rates, so
  the few entries a machine needs are written by its first run.

The cache lives in ``$RTSID_DESIGN_CACHE`` if set (``off``: no cache), else in
``$XDG_CACHE_HOME/rtsid/designs``, else ``~/.cache/rtsid/designs``: one small file per design
(a header line naming the design, its bytes and their SHA-256). Delete the folder to clear it;
the next run writes it again. A missing, corrupt, stale (another scipy or numpy) or unwritable
cache never fails a run: the design is computed with scipy as before (and stored when the
folder is writable). Entries are not shared across machines of another kind (the machine
architecture is in the key).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import sys
from functools import lru_cache
from importlib.util import find_spec
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["CACHE_ENV", "cache_folder", "design", "firwin_lowpass"]

FloatArray = NDArray[np.float64]

#: Environment variable naming the design cache's folder (``off``: compute every design).
CACHE_ENV = "RTSID_DESIGN_CACHE"
_MAGIC = b"rtsid design 1\n"
_HAMMING_ALPHA = 0.54


# ----------------------------------------------------------------------- firwin, in numpy
def firwin_lowpass(numtaps: int, cutoff_hz: float, fs_hz: float) -> FloatArray:
    """scipy's ``signal.firwin(numtaps, cutoff_hz, fs=fs_hz, window="hamming")`` in numpy.

    The same operations in the same order as scipy 1.17's ``firwin`` (a low-pass: the pass
    band ``[0, cutoff]``), ``get_window("hamming", numtaps, fftbins=False)`` and the array
    API ``sinc``, so the same numbers bit for bit (tested against the installed scipy).

    Parameters
    ----------
    numtaps : int
        Length of the filter (odd, >= 3).
    cutoff_hz : float
        −6 dB frequency, Hz (0 < ``cutoff_hz`` < ``fs_hz / 2``; the callers check it).
    fs_hz : float
        Sampling rate, Hz.

    Returns
    -------
    numpy.ndarray, shape (numtaps,)
        Linear-phase taps with unit gain at 0 Hz.
    """
    cutoff = np.asarray(cutoff_hz, dtype=np.float64).reshape(1) / float(0.5 * float(fs_hz))
    left, right = np.zeros(1)[0], cutoff[0]  # the one band [0, cutoff]
    m = np.arange(0, numtaps, dtype=np.float64) - 0.5 * (numtaps - 1)
    h: Any = 0
    h += right * _sinc(right * m)
    h -= left * _sinc(left * m)
    h *= _hamming(numtaps)
    h /= np.sum(h * np.cos(np.pi * m * 0.0))  # unit gain at 0 Hz
    return np.asarray(h, dtype=np.float64)


def _sinc(x: FloatArray) -> FloatArray:
    """The array API's ``sinc`` (scipy's, not numpy's: eps, not 1e-20, stands in for 0)."""
    eps = np.asarray(np.finfo(x.dtype).eps, dtype=x.dtype)
    y = np.pi * np.where(x.astype(bool), x, eps)
    return np.asarray(np.sin(y) / y, dtype=np.float64)


def _hamming(numtaps: int) -> FloatArray:
    """scipy's symmetric Hamming window (its general cosine window, term by term)."""
    a = np.asarray([_HAMMING_ALPHA, 1.0 - _HAMMING_ALPHA], dtype=np.float64)
    fac = np.linspace(-np.pi, np.pi, numtaps, dtype=np.float64)
    w = np.zeros(numtaps, dtype=np.float64)
    for k in range(a.shape[0]):
        w += a[k] * np.cos(k * fac)
    return w


# ---------------------------------------------------------------------------- the cache
def design(function: str, *args: Any, **kwargs: Any) -> FloatArray:
    """``scipy.signal.<function>(*args, **kwargs)`` as float64, from the design cache.

    Computed with scipy (and stored) when the cache has no entry for these arguments under
    the installed scipy and numpy, when the entry is corrupt or unreadable, when the cache is
    off, or when an argument is of a kind the cache does not key (then not stored).

    Parameters
    ----------
    function : str
        A design function of ``scipy.signal`` returning one array (``"cheby1"`` with
        ``output="sos"``, ``"sosfilt_zi"``, ``"savgol_coeffs"`` …).
    *args, **kwargs
        Its arguments: ints, floats, strings, bools, None and numpy arrays.

    Returns
    -------
    numpy.ndarray
        scipy's result, bit for bit (a new writable array each call).
    """
    key = _key(function, args, kwargs)
    entry = _entry_path(key) if key is not None else None
    if key is None or entry is None:
        return _computed(function, args, kwargs)
    stored = _read(entry, key)
    if stored is not None:
        return stored
    result = _computed(function, args, kwargs)
    _store(entry, key, result)
    return result


def cache_folder() -> Path | None:
    """The design cache's folder (see the module notes), or None when it is off."""
    chosen = os.environ.get(CACHE_ENV)
    if chosen is not None:
        return None if chosen.strip().lower() in ("", "off") else Path(chosen)
    base = os.environ.get("XDG_CACHE_HOME")
    if not base:
        try:
            base = str(Path.home() / ".cache")
        except (RuntimeError, KeyError):  # no home directory: no cache
            return None
    return Path(base) / "rtsid" / "designs"


def _computed(function: str, args: tuple[Any, ...], kwargs: dict[str, Any]) -> FloatArray:
    from scipy import signal

    return np.asarray(getattr(signal, function)(*args, **kwargs), dtype=np.float64)


def _key(function: str, args: tuple[Any, ...], kwargs: dict[str, Any]) -> str | None:
    """The entry's text key, or None when an argument cannot be keyed exactly or scipy's
    version cannot be read."""
    versions = _versions()
    tokens = [_token(a) for a in args] + [f"{k}={_token(v)}" for k, v in sorted(kwargs.items())]
    if versions is None or any(t is None for t in tokens):
        return None
    return f"{function}({', '.join(str(t) for t in tokens)}) {versions}"


def _token(value: Any) -> str | None:
    """An exact, typed text of one argument (None: not keyable)."""
    if isinstance(value, np.ndarray):
        digest = hashlib.sha256(np.ascontiguousarray(value).tobytes()).hexdigest()
        return f"ndarray[{value.dtype.str}{list(value.shape)}:{digest}]"
    if value is None or isinstance(value, (bool, int, float, str, np.integer, np.floating)):
        return f"{type(value).__name__}:{value!r}"
    if isinstance(value, tuple):
        inner = [_token(v) for v in value]
        return None if any(t is None for t in inner) else f"({', '.join(map(str, inner))})"
    return None


@lru_cache(maxsize=1)
def _versions() -> str | None:
    """scipy's and numpy's versions and the machine kind, read without importing scipy
    (scipy's ``version.py`` as text); None when scipy's version cannot be read."""
    try:
        spec = find_spec("scipy")
        folders = list(spec.submodule_search_locations or []) if spec else []
        text = (Path(folders[0]) / "version.py").read_text()
    except (OSError, IndexError, ValueError, ImportError):
        return None
    found = {
        name: re.search(rf"^{name}\s*=\s*['\"]([^'\"]+)['\"]", text, re.MULTILINE)
        for name in ("version", "git_revision")
    }
    if found["version"] is None:
        return None
    scipy_version = "+".join(m.group(1) for m in found.values() if m is not None)
    machine = os.uname().machine if hasattr(os, "uname") else "unknown"
    return f"scipy {scipy_version} numpy {np.__version__} {sys.platform} {machine}"


def _entry_path(key: str) -> Path | None:
    folder = cache_folder()
    if folder is None:
        return None
    return folder / f"{hashlib.sha256(key.encode()).hexdigest()[:32]}.design"


def _read(entry: Path, key: str) -> FloatArray | None:
    """The entry's array, or None when it is missing, unreadable, corrupt or another key's."""
    try:
        blob = entry.read_bytes()
    except OSError:
        return None
    if not blob.startswith(_MAGIC):
        return None
    header_line, _, data = blob[len(_MAGIC) :].partition(b"\n")
    try:
        header = json.loads(header_line)
        shape = tuple(int(n) for n in header["shape"])
        stored_key, digest = str(header["key"]), str(header["sha256"])
    except (ValueError, KeyError, TypeError):
        return None
    if stored_key != key or hashlib.sha256(data).hexdigest() != digest:
        return None
    if len(data) != 8 * int(np.prod(shape)):
        return None
    return np.frombuffer(data, dtype="<f8").reshape(shape).astype(np.float64)


def _store(entry: Path, key: str, result: FloatArray) -> None:
    """Write the entry whole or not at all; a folder that cannot be written is passed over."""
    data = np.ascontiguousarray(result, dtype="<f8").tobytes()
    header = {"key": key, "shape": list(result.shape), "sha256": hashlib.sha256(data).hexdigest()}
    blob = _MAGIC + json.dumps(header).encode() + b"\n" + data
    import tempfile

    tmp: str | None = None
    try:
        entry.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{entry.name}.", suffix=".part", dir=entry.parent)
        with os.fdopen(fd, "wb") as fh:
            fh.write(blob)
        os.replace(tmp, entry)
    except OSError:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
