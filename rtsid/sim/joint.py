"""Simulated joints with (time-varying) impedance, for tests, benchmarks and the virtual plant.

Two forms of the same intrinsic model, inertia ``I`` (kg·m²), damping ``B`` (N·m·s/rad) and
stiffness ``K(t)`` (N·m/rad):

* impedance (position-driven, what a position-controlled robot imposes):
  ``τ(t) = I·θ̈ + B·θ̇ + K(t)·θ`` — :func:`simulate_impedance`;
* admittance (torque-driven, for time-varying studies):
  ``I·φ̈ = τ(t) − B·φ̇ − K(t)·φ`` integrated as an ODE — :func:`simulate_admittance`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import InputDataError
from rtsid.ident.filters import derivatives

__all__ = [
    "JointParameters",
    "StiffnessProfile",
    "add_noise",
    "derivatives",
    "robot_servo",
    "simulate_admittance",
    "simulate_impedance",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class JointParameters:
    """Intrinsic joint parameters in SI units (defaults: a human ankle at moderate activation)."""

    inertia: float = 0.015
    damping: float = 0.8
    stiffness: float = 150.0


@dataclass(frozen=True)
class StiffnessProfile:
    """Stiffness over time, N·m/rad.

    Attributes
    ----------
    kind : str
        ``"constant"`` (``k0``), ``"linear"`` (``k0`` at ``t0`` to ``k1`` at ``t1``, held outside),
        ``"hyperbolic"`` (``1/K`` linear from ``1/k0`` to ``1/k1``), ``"sinusoidal"``
        (``bias + amplitude·sin(2π·freq·t + phase)``) or ``"raised_cosine"`` (``k0`` at
        ``t0`` and ``t1``, ``k1`` at the midpoint: one cycle).
    """

    kind: str = "constant"
    k0: float = 150.0
    k1: float = 150.0
    t0: float = 0.0
    t1: float = 1.0
    bias: float = 150.0
    amplitude: float = 0.0
    freq_hz: float = 1.0
    phase_rad: float = 0.0

    def __post_init__(self) -> None:
        kinds = ("constant", "linear", "hyperbolic", "sinusoidal", "raised_cosine")
        if self.kind not in kinds:
            raise InputDataError(f"stiffness profile kind {self.kind!r} is not one of {kinds}")
        if self.kind in ("linear", "hyperbolic", "raised_cosine") and self.t1 <= self.t0:
            raise InputDataError(f"stiffness profile needs t1 > t0, got t0={self.t0}, t1={self.t1}")
        if self.kind == "hyperbolic" and (self.k0 <= 0 or self.k1 <= 0):
            raise InputDataError("a hyperbolic stiffness profile needs k0 > 0 and k1 > 0")

    @classmethod
    def constant(cls, k: float) -> StiffnessProfile:
        """Constant stiffness ``k``."""
        return cls("constant", k0=k, k1=k)

    @classmethod
    def ramp(cls, k0: float, k1: float, t0: float, t1: float) -> StiffnessProfile:
        """Linear change from ``k0`` at ``t0`` to ``k1`` at ``t1`` seconds."""
        return cls("linear", k0=k0, k1=k1, t0=t0, t1=t1)

    @classmethod
    def sinusoid(
        cls, bias: float, amplitude: float, freq_hz: float, phase_rad: float = 0.0
    ) -> StiffnessProfile:
        """``bias + amplitude·sin(2π·freq_hz·t + phase_rad)``."""
        return cls(
            "sinusoidal", bias=bias, amplitude=amplitude, freq_hz=freq_hz, phase_rad=phase_rad
        )

    def at(self, t_s: FloatArray | float) -> FloatArray:
        """Stiffness at times ``t_s`` (seconds), N·m/rad."""
        t = np.asarray(t_s, dtype=float)
        if self.kind == "constant":
            return np.full_like(t, self.k0)
        if self.kind == "sinusoidal":
            return self.bias + self.amplitude * np.sin(
                2 * np.pi * self.freq_hz * t + self.phase_rad
            )
        s = np.clip((t - self.t0) / (self.t1 - self.t0), 0.0, 1.0)
        if self.kind == "linear":
            return self.k0 + (self.k1 - self.k0) * s
        if self.kind == "hyperbolic":
            return 1.0 / (1.0 / self.k0 + (1.0 / self.k1 - 1.0 / self.k0) * s)
        return self.k0 + (self.k1 - self.k0) * 0.5 * (1 - np.cos(2 * np.pi * s))


def robot_servo(command: FloatArray, fs_hz: float, bandwidth_hz: float = 60.0) -> FloatArray:
    """Position a position-controlled robot actually reaches for a command (causal).

    Models the servo as a critically damped second-order low-pass (two real poles at
    ``bandwidth_hz``), which turns PRBS steps into the smooth trajectories real actuators
    produce.
    """
    from scipy import signal

    if bandwidth_hz >= fs_hz / 2:
        raise InputDataError(
            f"servo bandwidth {bandwidth_hz} Hz must be below the Nyquist rate {fs_hz / 2} Hz"
        )
    pole = np.exp(-2 * np.pi * bandwidth_hz / fs_hz)
    b = [(1 - pole) ** 2]
    a = [1.0, -2 * pole, pole**2]
    zi = signal.lfilter_zi(b, a) * command[0]
    out, _ = signal.lfilter(b, a, command, zi=zi)
    return np.asarray(out, dtype=float)


def add_noise(
    y: FloatArray,
    percent: float,
    *,
    seed: int | np.random.Generator | None = None,
    band_hz: float | None = None,
    fs_hz: float | None = None,
) -> FloatArray:
    """Add Gaussian noise whose standard deviation is ``percent`` % of ``std(y)``.

    ``band_hz`` (with ``fs_hz``) low-pass filters the noise first, so that it falls in the
    same band as the signal and cannot be removed by the estimator's own filter.
    """
    from scipy import signal

    if percent < 0:
        raise InputDataError(f"noise percent must be >= 0, got {percent}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    noise = rng.standard_normal(y.size)
    if band_hz is not None:
        if fs_hz is None:
            raise InputDataError("band-limited noise needs fs_hz")
        sos = signal.butter(4, band_hz, fs=fs_hz, output="sos")
        noise = signal.sosfiltfilt(sos, noise)
    scale = percent / 100.0 * float(np.std(y)) / max(float(np.std(noise)), 1e-300)
    return np.asarray(y + scale * noise, dtype=float)


def simulate_impedance(
    position_rad: FloatArray,
    fs_hz: float,
    joint: JointParameters | None = None,
    stiffness: StiffnessProfile | None = None,
    *,
    noise_percent: float = 0.0,
    noise_band_hz: float | None = None,
    seed: int | np.random.Generator | None = None,
    t0_s: float = 0.0,
) -> FloatArray:
    """Torque of a position-driven joint: ``τ = I·θ̈ + B·θ̇ + K(t)·θ`` plus noise.

    Parameters
    ----------
    position_rad : numpy.ndarray, shape (n,)
        Joint angle imposed by the robot, rad (about its operating point).
    fs_hz : float
        Sampling rate, Hz.
    joint : JointParameters, optional
        ``I``, ``B`` and the constant ``K`` used when ``stiffness`` is not given.
    stiffness : StiffnessProfile, optional
        Time-varying stiffness, evaluated at ``t0_s + k/fs_hz``.
    noise_percent : float
        Output noise standard deviation as a percentage of the clean torque's.
    noise_band_hz : float, optional
        Low-pass the noise to this band (default: white).
    seed : int or numpy.random.Generator, optional
        Noise source.
    t0_s : float
        Time of the first sample, s.

    Returns
    -------
    numpy.ndarray, shape (n,)
        Torque, N·m.
    """
    joint = joint or JointParameters()
    theta = np.asarray(position_rad, dtype=float)
    d1, d2 = derivatives(theta, fs_hz)
    t = t0_s + np.arange(theta.size) / fs_hz
    k = stiffness.at(t) if stiffness is not None else joint.stiffness
    torque = joint.inertia * d2 + joint.damping * d1 + k * theta
    if noise_percent > 0:
        torque = add_noise(torque, noise_percent, seed=seed, band_hz=noise_band_hz, fs_hz=fs_hz)
    return np.asarray(torque, dtype=float)


def simulate_admittance(
    torque: Callable[[float], float],
    t_eval_s: FloatArray,
    joint: JointParameters,
    stiffness: StiffnessProfile,
    *,
    rtol: float = 1e-9,
    atol: float = 1e-12,
) -> FloatArray:
    """Angle of a torque-driven joint, ``I·φ̈ = τ(t) − B·φ̇ − K(t)·φ``, from rest.

    Integrated with an adaptive 8th-order Runge–Kutta (DOP853), so the input must be
    evaluable at any time (e.g. :meth:`Multisine.evaluate`).

    Parameters
    ----------
    torque : callable
        ``τ(t)`` in N·m for a time in seconds.
    t_eval_s : numpy.ndarray, shape (n,)
        Increasing output times, s; integration starts at ``t_eval_s[0]`` from rest.
    joint : JointParameters
        Inertia and damping (its stiffness is ignored: ``stiffness`` gives ``K(t)``).
    stiffness : StiffnessProfile
        ``K(t)``.
    rtol, atol : float
        Integration tolerances.

    Returns
    -------
    numpy.ndarray, shape (n,)
        Angle ``φ``, rad.
    """
    from scipy import integrate

    t_eval = np.asarray(t_eval_s, dtype=float)
    inertia, damping = joint.inertia, joint.damping

    def rhs(t: float, state: FloatArray) -> list[float]:
        phi, omega = state
        k = float(stiffness.at(t))
        return [omega, (torque(t) - damping * omega - k * phi) / inertia]

    sol = integrate.solve_ivp(
        rhs,
        (t_eval[0], t_eval[-1]),
        [0.0, 0.0],
        method="DOP853",
        t_eval=t_eval,
        rtol=rtol,
        atol=atol,
    )
    if not sol.success:
        raise InputDataError(f"admittance simulation failed: {sol.message}")
    return np.asarray(sol.y[0], dtype=float)
