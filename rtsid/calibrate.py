"""Robot-dynamics calibration: identify the robot alone, save it, subtract it later.

``rtsid calibrate BASELINE -o CAL.json`` reads a run made with **no person attached** (an
rtsid MCAP recording, or an ``.npz``/``.csv`` sample file), identifies the robot's
acceleration → torque IRF (:func:`rtsid.ident.robot.identify_robot`), reports its VAF and
writes a calibration file. With ``[worker] calibration_file`` set, the daemon and replay
subtract the robot torque it predicts from every window before identifying the ankle
(:meth:`Calibration.torque_offset`).

The calibration file is JSON::

    {"format": "rtsid-calibration", "format_version": 1,
     "fs_hz": 2500.0, "lowpass_hz": 100.0, "lags_s": [...], "irf": [...],
     "inertia_kgm2": 0.05, "vaf": 99.9, "samples": 25000, "segments": 1,
     "source": "baseline.mcap", "software": "rtsid 0.1.0", "created_utc": "..."}

``irf`` is in N·m per rad/s² per s (``Σ irf·Δt`` = ``inertia_kgm2``), ``vaf`` in percent.
Imports only :mod:`rtsid.ident` and :mod:`rtsid.io` (the runtime loads calibration files).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid import __version__
from rtsid.errors import ConfigError, InputDataError, RecordingError
from rtsid.ident.robot import RobotDynamics, identify_robot
from rtsid.io.files import atomic_write
from rtsid.io.recording import read_recording
from rtsid.io.sample_files import load_samples
from rtsid.link.protocol import (
    STATUS_DISCONTINUITY,
    STATUS_POSITION_SATURATED,
    STATUS_TORQUE_SATURATED,
)

__all__ = [
    "Calibration",
    "calibrate_file",
    "calibration_record",
    "contiguous_segments",
    "load_calibration",
    "read_samples",
    "robot_calibration",
    "save_calibration",
    "with_recorded_calibration",
]

FORMAT = "rtsid-calibration"
FORMAT_VERSION = 1
FloatArray = NDArray[np.float64]
_BAD_STATUS = STATUS_POSITION_SATURATED | STATUS_TORQUE_SATURATED


@dataclass(frozen=True)
class Calibration:
    """A saved robot-dynamics calibration.

    Attributes
    ----------
    robot : RobotDynamics
        The acceleration → torque IRF at ``robot.fs_hz``.
    source : str
        The baseline run it was identified from.
    software : str
        ``rtsid <version>`` that made it.
    created_utc : str
        ISO time of creation.
    """

    robot: RobotDynamics
    source: str = ""
    software: str = f"rtsid {__version__}"
    created_utc: str = field(default_factory=lambda: datetime.now(UTC).isoformat())

    @property
    def fs_hz(self) -> float:
        """Sample rate the calibration applies to, Hz."""
        return self.robot.fs_hz

    @property
    def vaf(self) -> float:
        """Percent of the baseline's robot torque the IRF predicts."""
        return self.robot.vaf

    def torque_offset(self, position_rad: NDArray[np.float64]) -> NDArray[np.float64]:
        """Predicted robot torque (N·m) for a window of joint angle (rad), same shape.

        This is the ``torque_offset`` callable of :class:`rtsid.runtime.worker.WindowWorker`.
        """
        return self.robot.predict_torque(position_rad)

    def check_rate(self, fs_hz: float) -> Calibration:
        """This calibration, or a :class:`ConfigError` if it was made at another rate."""
        if not math.isclose(self.fs_hz, fs_hz, rel_tol=1e-9):
            raise ConfigError(
                f"worker.calibration_file was identified at {self.fs_hz:g} Hz but the samples "
                f"are at {fs_hz:g} Hz; calibrate from a baseline recorded at {fs_hz:g} Hz"
            )
        return self

    def as_text(self) -> str:
        """The file's text: :meth:`as_dict` as indented JSON (what ``rtsid calibrate`` writes)."""
        return json.dumps(self.as_dict(), indent=1) + "\n"

    def as_dict(self) -> dict[str, Any]:
        """The JSON document (see the module docstring)."""
        r = self.robot
        return {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "fs_hz": r.fs_hz,
            "lowpass_hz": r.lowpass_hz,
            "lags_s": r.lags_s.tolist(),
            "irf": r.irf.tolist(),
            "inertia_kgm2": r.inertia,
            "vaf": r.vaf,
            "samples": r.samples,
            "segments": r.segments,
            "source": self.source,
            "software": self.software,
            "created_utc": self.created_utc,
        }


def save_calibration(calibration: Calibration, path: str | Path) -> Path:
    """Write the calibration as JSON, atomically (:func:`rtsid.io.files.atomic_write`)."""
    out = Path(path)
    with atomic_write(out, what="calibration", make_folder=True) as fh:
        fh.write(calibration.as_text())
    return out


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration file written by :func:`save_calibration`.

    Raises
    ------
    InputDataError
        Missing, unreadable or not an rtsid calibration file (the message says which).
    """
    p = Path(path)
    try:
        document = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputDataError(
            f"calibration file {str(p)!r} does not exist; make one with "
            "'rtsid calibrate BASELINE -o CAL.json'"
        ) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputDataError(f"calibration file {str(p)!r} is not readable JSON: {exc}") from None
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        raise InputDataError(
            f'{str(p)!r} is not an rtsid calibration file (no "format": "{FORMAT}"); '
            "make one with 'rtsid calibrate'"
        )
    try:
        irf = np.asarray(document["irf"], dtype=np.float64)
        fs_hz = float(document["fs_hz"])
        robot = RobotDynamics(
            irf=irf,
            fs_hz=fs_hz,
            lowpass_hz=float(document["lowpass_hz"]),
            vaf=float(document["vaf"]),
            samples=int(document.get("samples", 0)),
            segments=int(document.get("segments", 0)),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise InputDataError(f"calibration file {str(p)!r} lacks or garbles {exc}") from None
    if irf.ndim != 1 or irf.size % 2 != 1 or not np.all(np.isfinite(irf)) or not fs_hz > 0:
        raise InputDataError(
            f"calibration file {str(p)!r}: irf must be an odd-length list of finite numbers "
            "and fs_hz > 0; recreate it with 'rtsid calibrate'"
        )
    return Calibration(
        robot=robot,
        source=str(document.get("source", "")),
        software=str(document.get("software", "")),
        created_utc=str(document.get("created_utc", "")),
    )


@dataclass(frozen=True)
class SampleRows:
    """Rows of a run: values, and which rows may be used (valid, finite, unsaturated)."""

    position_rad: FloatArray
    torque_nm: FloatArray
    usable: NDArray[np.bool_]
    breaks: NDArray[np.bool_]  # row does not continue the previous one
    fs_hz: float
    config: dict[str, Any]


def read_samples(path: str | Path, fs_hz: float | None = None) -> SampleRows:
    """All rows of an rtsid MCAP recording or an ``.npz``/``.csv`` file (gaps as unusable rows).

    Parameters
    ----------
    path : str or Path
        ``.mcap`` (read by :func:`rtsid.io.recording.read_recording`: every part of a rotated
        session; rows lost by the link or the logger become unusable rows), ``.npz`` or
        ``.csv`` (non-finite values are unusable).
    fs_hz : float, optional
        Rate of a CSV without a time column.
    """
    p = Path(path)
    if p.suffix.lower() != ".mcap":
        record = load_samples(p, fs_hz)
        usable = np.isfinite(record.position_rad) & np.isfinite(record.torque_nm)
        breaks = np.zeros(usable.size, dtype=bool)
        return SampleRows(record.position_rad, record.torque_nm, usable, breaks, record.fs_hz, {})
    return _read_mcap_rows(p)


def _read_mcap_rows(path: Path) -> SampleRows:
    recording = read_recording(path)
    rows = recording.samples.all_rows()
    status = rows.status
    usable = (
        rows.valid
        & ((status & _BAD_STATUS) == 0)
        & np.isfinite(rows.position_rad)
        & np.isfinite(rows.torque_nm)
    )
    breaks = (status & STATUS_DISCONTINUITY) != 0
    return SampleRows(
        rows.position_rad, rows.torque_nm, usable, breaks, rows.fs_hz, recording.config
    )


def contiguous_segments(rows: SampleRows) -> Iterator[tuple[FloatArray, FloatArray]]:
    """``(position_rad, torque_nm)`` of each stretch of usable rows without a break."""
    usable = rows.usable
    if usable.size == 0:
        return
    starts = np.flatnonzero(usable & (np.r_[True, ~usable[:-1]] | rows.breaks))
    enders = np.flatnonzero(~usable | rows.breaks)  # rows that cannot continue a stretch
    stops = np.r_[enders, usable.size][np.searchsorted(enders, starts, side="right")]
    for start, stop in zip(starts.tolist(), stops.tolist(), strict=True):
        yield rows.position_rad[start:stop], rows.torque_nm[start:stop]


def calibrate_file(
    path: str | Path,
    *,
    fs_hz: float | None = None,
    lowpass_hz: float | None = None,
    lag_s: float = 0.01,
    ridge: float = 1e-3,
) -> Calibration:
    """Identify the robot from a run with no person attached.

    Parameters
    ----------
    path : str or Path
        An rtsid ``.mcap`` recording, or an ``.npz``/``.csv`` sample file.
    fs_hz : float, optional
        Rate of a CSV without a time column.
    lowpass_hz : float, optional
        FIR pass-band edge, Hz. Default: the recording's ``estimator.lowpass_hz`` when it
        has one, else 100 Hz (at most ``fs/4``).
    lag_s, ridge : float
        IRF lag span (s) and relative ridge (see :func:`rtsid.ident.robot.identify_robot`).

    Returns
    -------
    Calibration
    """
    rows = read_samples(path, fs_hz)
    if lowpass_hz is None:
        stored = rows.config.get("estimator", {}).get("lowpass_hz")
        lowpass_hz = float(stored) if stored else min(100.0, rows.fs_hz / 5)
    robot = identify_robot(
        contiguous_segments(rows), rows.fs_hz, lowpass_hz=lowpass_hz, lag_s=lag_s, ridge=ridge
    )
    return Calibration(robot=robot, source=str(path))


def robot_calibration(calibration_file: str, fs_hz: float) -> Calibration | None:
    """The calibration of ``[worker] calibration_file`` (None if ""), checked for ``fs_hz``:
    the window worker subtracts its ``torque_offset`` and analyses no higher than its
    ``robot.analysis_cutoff_hz``.

    Raises
    ------
    ConfigError
        The file does not load, or was made at another sample rate.
    """
    if not calibration_file:
        return None
    try:
        calibration = load_calibration(calibration_file)
    except InputDataError as exc:
        raise ConfigError(f"config key 'worker.calibration_file': {exc}") from None
    return calibration.check_rate(fs_hz)


def calibration_record(
    calibration: Calibration | None, calibration_file: str
) -> dict[str, dict[str, str]]:
    """The ``calibration`` metadata record the daemon writes into every recording file: the
    calibration it loaded, as its file's text, so a replay needs no file of its own ({}
    without one)."""
    if calibration is None:
        return {}
    return {"calibration": {"json": calibration.as_text(), "file": calibration_file}}


def with_recorded_calibration(
    document: dict[str, Any], recorded: dict[str, str] | None
) -> dict[str, Any]:
    """A stored run configuration pointing at the calibration its recording carries.

    Unless the file at the stored path still holds exactly the recorded text (moved, edited,
    or never copied to this machine), the recorded text is written once to the user cache
    (``$XDG_CACHE_HOME/rtsid/calibrations/<sha256>.json``) and the configuration points
    there — so a replay uses what the live run used. Recordings without the record (older
    ones) keep the stored path.

    Raises
    ------
    RecordingError
        The cache folder cannot be written (the message names it).
    """
    worker = document.get("worker")
    text = (recorded or {}).get("json")
    if not isinstance(worker, dict) or not worker.get("calibration_file") or text is None:
        return document
    stored = str(worker["calibration_file"])
    try:
        if Path(stored).read_text(encoding="utf-8") == text:
            return document
    except (OSError, UnicodeDecodeError):
        pass
    copy = _cached_calibration(text)
    return {**document, "worker": {**worker, "calibration_file": str(copy)}}


def _cached_calibration(text: str) -> Path:
    import hashlib

    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    path = cache / "rtsid" / "calibrations" / f"{hashlib.sha256(text.encode()).hexdigest()}.json"
    if path.is_file():
        return path
    try:
        with atomic_write(path, what="cached calibration", make_folder=True) as fh:
            fh.write(text)
    except RecordingError as exc:
        raise RecordingError(
            f"{exc} (the recording's calibration is cached there: or set XDG_CACHE_HOME)"
        ) from None
    return path
