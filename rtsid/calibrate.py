"""Robot-dynamics calibration: identify the robot alone, save it, subtract it later.

``rtsid calibrate BASELINE -o CAL.json`` reads a run made with **no person attached** (an
rtsid MCAP recording, or an ``.npz``/``.csv`` sample file), identifies the robot's
acceleration → torque IRF (:func:`rtsid.ident.robot.identify_robot`), reports its VAF and
writes a calibration file. A baseline whose torque follows position like a spring (a joint
attached: :func:`rtsid.ident.robot.baseline_stiffness`) is refused unless forced. With
``[worker] calibration_file`` set, the daemon and replay subtract the robot torque it
predicts from every window before identifying the ankle (:meth:`Calibration.torque_offset`).

The calibration as a value (file format, loading, what a run does with it) lives in
:mod:`rtsid.io.calibration`, which the runtime imports; this module makes calibrations.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import InputDataError, JointAttachedWarning
from rtsid.ident.robot import BaselineStiffness, baseline_stiffness, identify_robot
from rtsid.io.calibration import (
    Calibration,
    calibration_record,
    load_calibration,
    robot_calibration,
    save_calibration,
    with_recorded_calibration,
)
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
    "check_nobody_attached",
    "contiguous_segments",
    "load_calibration",
    "read_samples",
    "robot_calibration",
    "save_calibration",
    "with_recorded_calibration",
]

_BAD_STATUS = STATUS_POSITION_SATURATED | STATUS_TORQUE_SATURATED
FloatArray = NDArray[np.float64]


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
    force: bool = False,
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
    force : bool
        Calibrate even from a baseline with a joint attached (a warning says so).

    Returns
    -------
    Calibration

    Raises
    ------
    InputDataError
        The baseline has a joint attached (and not ``force``), or cannot be calibrated from.
    """
    rows = read_samples(path, fs_hz)
    if lowpass_hz is None:
        stored = rows.config.get("estimator", {}).get("lowpass_hz")
        lowpass_hz = float(stored) if stored else min(100.0, rows.fs_hz / 5)
    check_nobody_attached(rows, lowpass_hz, force=force)
    robot = identify_robot(
        contiguous_segments(rows), rows.fs_hz, lowpass_hz=lowpass_hz, lag_s=lag_s, ridge=ridge
    )
    return Calibration(robot=robot, source=str(path))


def joint_attached_message(found: BaselineStiffness) -> str:
    """What was found in a baseline that reads as a joint attached."""
    return (
        f"the baseline's torque follows position like a spring: K = {found.K:.1f} N·m/rad beside "
        f"the inertia ({found.t:.0f} standard errors from 0), where a robot alone has none: a "
        "joint seems attached"
    )


def check_nobody_attached(rows: SampleRows, lowpass_hz: float, *, force: bool) -> None:
    """Refuse (or, forced, warn about) a baseline with a joint attached."""
    found = baseline_stiffness(contiguous_segments(rows), rows.fs_hz, lowpass_hz=lowpass_hz)
    if not found.joint_attached:
        return
    said = joint_attached_message(found)
    if not force:
        raise InputDataError(
            f"{said}; record the baseline with nobody attached, or pass --force to calibrate "
            "from it anyway"
        )
    warnings.warn(f"{said}; calibrating anyway (--force)", JointAttachedWarning, stacklevel=2)
