"""The robot calibration as a value: the file format, loading and saving, and what a run does
with it (subtract it, record it, find it again on replay).

``rtsid calibrate`` (:mod:`rtsid.calibrate`) makes calibrations; the daemon and replay load
one here, once, and pass the value down (:class:`rtsid.runtime.worker.WindowEvaluator`).

The calibration file is JSON::

    {"format": "rtsid-calibration", "format_version": 1,
     "fs_hz": 2500.0, "lowpass_hz": 100.0, "lags_s": [...], "irf": [...],
     "inertia_kgm2": 0.05, "vaf": 99.9, "samples": 25000, "segments": 1,
     "source": "baseline.mcap", "software": "rtsid 0.1.0", "created_utc": "..."}

``irf`` is in N·m per rad/s² per s (``Σ irf·Δt`` = ``inertia_kgm2``), ``vaf`` in percent.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from rtsid import __version__
from rtsid.errors import ConfigError, InputDataError, RecordingError
from rtsid.io.files import atomic_write

if TYPE_CHECKING:  # imported where a calibration is read: most recordings carry none
    from rtsid.ident.robot import RobotDynamics

__all__ = [
    "Calibration",
    "calibration_record",
    "load_calibration",
    "robot_calibration",
    "save_calibration",
    "with_recorded_calibration",
]

FORMAT = "rtsid-calibration"
FORMAT_VERSION = 1
FloatArray = NDArray[np.float64]


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
    from rtsid.ident.robot import RobotDynamics

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
