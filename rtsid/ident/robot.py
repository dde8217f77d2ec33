"""The robot's own dynamics: an acceleration → torque IRF from a run with no person attached.

The torque sensor sits between the motor and the footplate, so the measured torque includes
the footplate's (and any fixture's) inertial torque. With nobody attached, the measured
torque is that robot torque alone; its impulse response from joint acceleration is
identified here and later subtracted from every window before the ankle is identified.

Compared with the source (position differentiated twice with a 10 Hz low-pass at each
step, VAF ≈ 90 %), acceleration comes from 8th-order central-difference stencils of the
raw position, and acceleration and torque then pass through the *same* zero-phase FIR
(:func:`rtsid.ident.filters.lowpass_taps`): the filter cancels from the input→output
relation instead of adding 10 Hz of its own dynamics to it, and the bandwidth kept is the
perturbation's, not 10 Hz. The two-sided IRF is solved from the Wiener–Hopf equations by
EUREKA, with correlations summed over contiguous segments (a gap is never bridged).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rtsid.errors import InputDataError
from rtsid.ident.correlation import detrend
from rtsid.ident.filters import derivatives, lowpass_taps, stencil_derivatives
from rtsid.ident.levinson import eureka

__all__ = [
    "ATTACHED_MIN_K",
    "ATTACHED_MIN_T",
    "BaselineStiffness",
    "RobotDynamics",
    "baseline_stiffness",
    "identify_robot",
    "robot_filter_taps",
]

FloatArray = NDArray[np.float64]
_STENCIL_HALF = 4


@dataclass(frozen=True)
class RobotDynamics:
    """The robot's acceleration → torque impulse response.

    Attributes
    ----------
    irf : numpy.ndarray, shape (2L+1,)
        ``h(τ)`` at lags ``−L..L`` samples, N·m per rad/s² per s (``Σ h·Δt`` is the
        robot's inertia, kg·m²).
    fs_hz : float
        Sample rate of the lag grid (the recording's rate), Hz.
    lowpass_hz : float
        Pass-band edge of the FIR applied to acceleration and torque, Hz.
    vaf : float
        Percent of the (filtered, detrended) robot torque the IRF predicts.
    samples : int
        Samples that entered the correlations.
    segments : int
        Contiguous segments used.
    """

    irf: FloatArray = field(repr=False)
    fs_hz: float
    lowpass_hz: float
    vaf: float
    samples: int
    segments: int

    @property
    def max_lag(self) -> int:
        """``L``, samples."""
        return (self.irf.size - 1) // 2

    @property
    def analysis_cutoff_hz(self) -> float:
        """Highest cut-off the ankle estimator may use after subtracting this robot's torque.

        The prediction is good up to ``lowpass_hz`` and fades through the FIR's transition
        (``lowpass_hz … 2·lowpass_hz``); above it the robot's torque is unexplained and, the
        robot being heavier than an ankle, would bias the ankle's inertia. The estimator's
        band-limiting filter stops at about three times its cut-off
        (:func:`rtsid.ident.filters.band_limit_taps`), so half of ``lowpass_hz`` ends its
        stop band inside that transition. Measured (``rtsid bench calibrate``, PRBS 40 Hz):
        at the full ``lowpass_hz`` K erred by 2.7 %, at half by 0.02 %.
        """
        return self.lowpass_hz / 2

    @property
    def lags_s(self) -> FloatArray:
        """Lag of each IRF value, s."""
        return np.arange(-self.max_lag, self.max_lag + 1) / self.fs_hz

    @property
    def inertia(self) -> float:
        """Static gain ``Σ h·Δt``: the robot's inertia, kg·m²."""
        return float(np.sum(self.irf) / self.fs_hz)

    def predict_torque(self, position_rad: ArrayLike) -> FloatArray:
        """Robot torque (N·m) for a contiguous stretch of joint angle (rad), same length.

        Acceleration by central differences (lower order at the four samples at each end),
        mirrored across each end for the ``L`` samples the IRF reaches beyond the stretch,
        then convolved with the IRF. Everything the IRF did not see excited (above the
        filter's band) it maps to almost nothing.

        Parameters
        ----------
        position_rad : array_like, shape (n,)
            Joint angle, rad; ``n >= max(9, L + 1)``.

        Returns
        -------
        numpy.ndarray, shape (n,)
            Predicted robot torque, N·m (no constant offset: the IRF has none).
        """
        pos = np.asarray(position_rad, dtype=np.float64)
        lag = self.max_lag
        if pos.ndim != 1 or pos.size < max(9, lag + 1):
            raise InputDataError(
                f"robot torque prediction needs a 1-D stretch of at least {max(9, lag + 1)} "
                f"samples, got shape {pos.shape}"
            )
        _, acc = derivatives(pos, self.fs_hz)
        if lag:
            acc = np.concatenate((acc[lag:0:-1], acc, acc[-2 : -lag - 2 : -1]))
        return np.asarray(np.convolve(acc, self.irf / self.fs_hz, mode="valid"), np.float64)


def robot_filter_taps(fs_hz: float, lowpass_hz: float) -> FloatArray:
    """The zero-phase FIR used on acceleration and torque (stop band from ``2·lowpass_hz``).

    Returns
    -------
    numpy.ndarray, shape (m,), m odd
        Linear-phase taps from :func:`rtsid.ident.filters.lowpass_taps`.
    """
    factor = max(1, int(fs_hz // (4.0 * lowpass_hz)))
    return lowpass_taps(float(fs_hz), float(lowpass_hz), factor)


def _filtered_pair(
    position: FloatArray, torque: FloatArray, fs_hz: float, taps: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Acceleration and torque, aligned, detrended and low-passed (edges dropped)."""
    _, acc = stencil_derivatives(position, fs_hz)
    tq = torque[_STENCIL_HALF:-_STENCIL_HALF]
    u = np.convolve(detrend(acc, "linear"), taps, mode="valid")
    y = np.convolve(detrend(tq, "linear"), taps, mode="valid")
    return u, y


def _lag_sums(u: FloatArray, y: FloatArray, max_lag: int) -> tuple[FloatArray, FloatArray]:
    """``Σ u(t)·u(t+k)`` for ``k = 0..2L`` and ``Σ u(t−k)·y(t)`` for ``k = −L..L`` (O(N·L))."""
    n = u.size
    auto = np.array([u[: n - k] @ u[k:] for k in range(2 * max_lag + 1)])
    cross = np.array(
        [
            u[: n - k] @ y[k:] if k >= 0 else u[-k:] @ y[: n + k]
            for k in range(-max_lag, max_lag + 1)
        ]
    )
    return auto, cross


def identify_robot(
    segments: Iterable[tuple[ArrayLike, ArrayLike]],
    fs_hz: float,
    *,
    lowpass_hz: float = 100.0,
    lag_s: float = 0.01,
    ridge: float = 1e-3,
) -> RobotDynamics:
    """Identify the robot's acceleration → torque IRF from runs with no person attached.

    Parameters
    ----------
    segments : iterable of (position_rad, torque_nm)
        Contiguous stretches of valid samples (split the recording at gaps), each a pair
        of equally long 1-D arrays (rad, N·m). Stretches too short for the filter and the
        lag span are skipped.
    fs_hz : float
        Sample rate, Hz.
    lowpass_hz : float
        Pass-band edge of the zero-phase FIR on acceleration and torque, Hz; keep it at or
        above the estimator's ``lowpass_hz``.
    lag_s : float
        IRF lags ``−lag_s..+lag_s``.
    ridge : float
        Relative diagonal loading of the autocorrelation (keeps unexcited frequencies,
        e.g. above the filter's band, near zero in the IRF).

    Returns
    -------
    RobotDynamics
        The IRF, its VAF and what went into it.

    Raises
    ------
    InputDataError
        No stretch long enough, or no acceleration at all (no perturbation in the run).
    NotPositiveDefiniteError
        The run does not excite the lag span (add ``ridge`` or perturb more widely).
    """
    if not fs_hz > 0 or not 0 < lowpass_hz < fs_hz / 4:
        raise InputDataError(
            f"robot calibration needs fs_hz > 0 and 0 < lowpass_hz < fs_hz/4 "
            f"(got fs_hz={fs_hz}, lowpass_hz={lowpass_hz}); lower the low-pass"
        )
    taps = robot_filter_taps(fs_hz, lowpass_hz)
    max_lag = max(1, round(lag_s * fs_hz))
    needed = taps.size + 2 * _STENCIL_HALF + 4 * max_lag + 1
    pairs: list[tuple[FloatArray, FloatArray]] = []
    for position, torque in segments:
        pos = np.asarray(position, dtype=np.float64)
        tq = np.asarray(torque, dtype=np.float64)
        if pos.ndim != 1 or pos.shape != tq.shape:
            raise InputDataError(
                f"position and torque segments must be 1-D and equally long, got {pos.shape} "
                f"and {tq.shape}"
            )
        if pos.size >= needed:
            pairs.append(_filtered_pair(pos, tq, fs_hz, taps))
    if not pairs:
        raise InputDataError(
            f"no contiguous stretch of at least {needed} valid samples "
            f"({needed / fs_hz:.3f} s) to calibrate from; record a longer run with no person"
        )
    auto = np.zeros(2 * max_lag + 1)
    cross = np.zeros(2 * max_lag + 1)
    count = 0
    for u, y in pairs:
        a, c = _lag_sums(u, y, max_lag)
        auto += a
        cross += c
        count += u.size
    if auto[0] <= 0:
        raise InputDataError(
            "the calibration run has no acceleration: enable the perturbation with nobody "
            "attached and record again"
        )
    auto /= count
    cross /= count
    auto[0] *= 1.0 + ridge
    h = eureka(auto, cross) * fs_hz
    return RobotDynamics(
        irf=h,
        fs_hz=float(fs_hz),
        lowpass_hz=float(lowpass_hz),
        vaf=_vaf(pairs, h, fs_hz, max_lag),
        samples=count,
        segments=len(pairs),
    )


def _vaf(
    pairs: Sequence[tuple[FloatArray, FloatArray]], h: FloatArray, fs: float, lag: int
) -> float:
    """Percent of the filtered torque's variance the IRF predicts (fully supported samples)."""
    err = total = 0.0
    for u, y in pairs:
        predicted = np.convolve(u, h / fs, mode="valid")  # aligned with y[lag:-lag]
        measured = y[lag : y.size - lag]
        residual = measured - predicted
        err += float(residual @ residual)
        total += float(measured @ measured)
    return max(0.0, 1.0 - err / total) * 100.0 if total > 0 else 0.0


# ----------------------------------------------------------------------------- is a joint on?
#: A baseline whose position → torque stiffness is at least this (N·m/rad) ...
ATTACHED_MIN_K = 10.0
#: ... and this many standard errors from zero has a joint attached.
ATTACHED_MIN_T = 3.0


@dataclass(frozen=True)
class BaselineStiffness:
    """How much the torque of a calibration baseline follows position like a spring.

    A robot alone has inertia (and a little damping), no stiffness; a joint attached adds
    ``K·θ``. ``τ = I·θ̈ + B·θ̇ + K·θ`` is fitted by least squares to the baseline, filtered
    as the calibration is (:func:`robot_filter_taps`), and ``K`` is tested against zero.

    Measured on the virtual plant (``rtsid bench calibrate``'s scenarios: filtered noise 8
    and 30 Hz, PRBS 40 Hz with 3 % and with 10 % torque noise and 20 µrad encoder noise,
    multisine 40 Hz; robot inertia 0.05 kg·m²; baselines of 4 and 20 s): with nobody
    attached, also with 30 % torque noise or a 0.2 kg·m² robot, ``|t| ≤ 1.5`` (``K`` from
    −14.3 to 24.6 N·m/rad); with an ankle of K 20 N·m/rad (B 0.3) ``t`` 4.3–1020 (the lowest:
    4 s of PRBS with encoder noise), of K 150 ``t`` 26.8–7900. A joint is called attached when
    ``K ≥`` :data:`ATTACHED_MIN_K` and ``t ≥`` :data:`ATTACHED_MIN_T`: twice the largest
    ``|t|`` without one, 0.7× the smallest with one. The floor on ``K`` leaves room for a
    footplate's own gravity torque, a small stiffness.

    Attributes
    ----------
    K : float
        Stiffness of the torque on position, N·m/rad, in the sign of the inertia fitted beside
        it (so a rig that reports torque inverted reads as any other).
    t : float
        ``K`` over its standard error (least squares, samples counted by the filter's
        bandwidth: ``n·2·lowpass_hz/fs_hz`` independent ones).
    share_percent : float
        Of the filtered torque's variance, the part ``K·θ`` explains beyond ``I·θ̈ + B·θ̇``.
    """

    K: float
    t: float
    share_percent: float

    @property
    def joint_attached(self) -> bool:
        """Whether the baseline reads as a joint attached (see the class notes)."""
        return self.K >= ATTACHED_MIN_K and self.t >= ATTACHED_MIN_T


def baseline_stiffness(
    segments: Iterable[tuple[ArrayLike, ArrayLike]], fs_hz: float, *, lowpass_hz: float = 100.0
) -> BaselineStiffness:
    """Fit ``τ = I·θ̈ + B·θ̇ + K·θ`` to a calibration baseline and test ``K``.

    Parameters
    ----------
    segments : iterable of (position_rad, torque_nm)
        Contiguous stretches, as for :func:`identify_robot`.
    fs_hz, lowpass_hz : float
        Rate and the FIR's pass-band edge, Hz (as for :func:`identify_robot`).

    Returns
    -------
    BaselineStiffness
    """
    taps = robot_filter_taps(fs_hz, lowpass_hz)
    columns: list[FloatArray] = []
    outputs: list[FloatArray] = []
    for position, torque in segments:
        pos = np.asarray(position, dtype=np.float64)
        if pos.size < taps.size + 2 * _STENCIL_HALF + 1:
            continue
        vel, acc = stencil_derivatives(pos, fs_hz)
        inner = slice(_STENCIL_HALF, pos.size - _STENCIL_HALF)
        signals = (acc, vel, pos[inner], np.asarray(torque, dtype=np.float64)[inner])
        a, v, p, y = (np.convolve(detrend(x, "linear"), taps, mode="valid") for x in signals)
        columns.append(np.stack([a, v, p], axis=1))
        outputs.append(y)
    if not outputs:
        return BaselineStiffness(0.0, 0.0, 0.0)
    x, y = np.concatenate(columns), np.concatenate(outputs)
    coefficients, *_ = np.linalg.lstsq(x, y, rcond=None)
    residual = y - x @ coefficients
    sse = float(residual @ residual)
    independent = max(4.0, y.size * min(1.0, 2.0 * lowpass_hz / fs_hz))
    covariance = np.linalg.inv(x.T @ x) * sse / (y.size - 3) * (y.size / independent)
    # in the inertia's sign: a rig that reports torque inverted inverts both
    k = float(coefficients[2]) * (-1.0 if coefficients[0] < 0 else 1.0)
    t = k / float(np.sqrt(covariance[2, 2])) if covariance[2, 2] > 0 else 0.0
    without_k, *_ = np.linalg.lstsq(x[:, :2], y, rcond=None)
    rest = y - x[:, :2] @ without_k
    total = float(y @ y)
    share = 100.0 * (float(rest @ rest) - sse) / total if total > 0 else 0.0
    return BaselineStiffness(k, t, share)
