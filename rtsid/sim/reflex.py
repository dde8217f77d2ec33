"""A simulated stretch reflex: the torque a muscle adds some 40 ms after it is stretched.

The model is the reflex pathway of the parallel-cascade model (Kearney, Stein & Parameswaran,
IEEE TBME 44(6), 1997) with known parameters:

    τ_r(t) = G · h ∗ max(θ̇(t − δ), 0)

half-wave-rectified joint velocity (only stretch, ``θ̇ > 0``, excites the reflex), delayed by
``δ``, through a second-order low-pass ``h`` of unit static gain (corner ``f_c``, damping ratio
``ζ``; the activation dynamics of the muscle), scaled by the reflex gain ``G`` (N·m·s/rad:
steady torque per rad/s of stretch velocity). It is causal and stateful, so a plant that
generates blocks of samples gets the same torque as one long simulation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import InputDataError
from rtsid.ident.excitation import prbs
from rtsid.sim.joint import JointParameters, add_noise, derivatives, robot_servo, simulate_impedance

__all__ = ["ReflexParameters", "StretchReflex", "prbs_ankle_with_reflex", "reflex_torque"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ReflexParameters:
    """Gain (N·m·s/rad), delay (s), corner frequency (Hz) and damping ratio of a stretch reflex."""

    gain: float = 10.0
    delay_s: float = 0.04
    corner_hz: float = 3.0
    damping_ratio: float = 0.7

    def __post_init__(self) -> None:
        if not (self.delay_s >= 0 and self.corner_hz > 0 and self.damping_ratio > 0):
            raise InputDataError(
                f"a stretch reflex needs delay_s >= 0, corner_hz > 0 and damping_ratio > 0; got "
                f"{self.delay_s}, {self.corner_hz}, {self.damping_ratio}"
            )

    def impulse_response(self, fs_hz: float, duration_s: float) -> FloatArray:
        """The pathway's response to a unit-area pulse of rectified velocity, N·m per rad/s per s,
        lags ``0 … duration_s`` (what a reflex IRF estimate should find)."""
        n = round(duration_s * fs_hz) + 1
        pulse = np.zeros(n)
        pulse[0] = fs_hz
        return StretchReflex(self, fs_hz).torque(pulse)


class StretchReflex:
    """The reflex torque of successive blocks of joint velocity (state carried across blocks).

    Parameters
    ----------
    params : ReflexParameters
    fs_hz : float
        Sample rate, Hz; the delay is rounded to whole samples.
    """

    def __init__(self, params: ReflexParameters, fs_hz: float) -> None:
        from scipy import signal

        if params.corner_hz >= fs_hz / 2:
            raise InputDataError(
                f"the reflex corner {params.corner_hz} Hz must be below the Nyquist rate "
                f"{fs_hz / 2} Hz"
            )
        self.params = params
        w = 2 * np.pi * params.corner_hz
        b, a = signal.bilinear([w * w], [1.0, 2 * params.damping_ratio * w, w * w], fs=fs_hz)
        self._b, self._a = b, a
        self._zi = np.zeros(len(a) - 1)
        self._pending = np.zeros(round(params.delay_s * fs_hz))  # rectified velocity in transit

    def torque(self, velocity: FloatArray) -> FloatArray:
        """Reflex torque (N·m) for the next block of joint velocity (rad/s)."""
        from scipy import signal

        stretch = np.maximum(np.asarray(velocity, dtype=float), 0.0)
        line = np.concatenate([self._pending, stretch])
        delayed, self._pending = line[: stretch.size], line[stretch.size :]
        out, self._zi = signal.lfilter(self._b, self._a, delayed, zi=self._zi)
        return np.asarray(self.params.gain * out, dtype=float)


def reflex_torque(velocity: FloatArray, fs_hz: float, params: ReflexParameters) -> FloatArray:
    """Reflex torque of a whole record of joint velocity, from rest."""
    return StretchReflex(params, fs_hz).torque(velocity)


def prbs_ankle_with_reflex(
    seconds: float,
    fs_hz: float,
    joint: JointParameters,
    reflex: ReflexParameters | None,
    *,
    noise_percent: float = 10.0,
    bandwidth_hz: float = 40.0,
    amplitude_rad: float = 0.03,
    seed: int = 1,
) -> tuple[FloatArray, FloatArray]:
    """A PRBS-perturbed ankle (the virtual plant's default perturbation through a 60 Hz servo)
    with intrinsic ``joint`` dynamics and a stretch ``reflex`` (None: none), torque noise
    ``noise_percent`` % of the clean torque's std. Returns ``(θ, τ)``."""
    rng = np.random.default_rng(seed)
    hold = max(1, round(fs_hz / (2 * bandwidth_hz)))
    theta = robot_servo(prbs(round(seconds * fs_hz), amplitude_rad, min_hold=hold, seed=rng), fs_hz)
    torque = simulate_impedance(theta, fs_hz, joint)
    if reflex is not None:
        velocity, _ = derivatives(theta, fs_hz)
        torque = torque + reflex_torque(velocity, fs_hz, reflex)
    return theta, add_noise(torque, noise_percent, seed=rng)
