"""Sample sources of the virtual plant: a simulated ankle and a player for recordings.

:class:`SimSource` moves the ankle with a position perturbation (impedance: torque out);
:class:`TorqueMultisineSource` drives it with a multisine torque (admittance: angle out).

Each source yields consecutive blocks of samples (``next_block()``) that continue one another
exactly: the perturbation, the servo filter and the derivative stencils carry their state
across blocks, so a stream cut into blocks equals the same stream generated at once.
No threads, no I/O except reading the player's file once.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from fractions import Fraction
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import InputDataError
from rtsid.ident.excitation import multisine, prbs
from rtsid.io.files import read_npz
from rtsid.link.config import PlantConfig, StiffnessConfig
from rtsid.link.protocol import Command
from rtsid.sim.joint import (
    JointParameters,
    StiffnessProfile,
    add_noise,
    derivatives,
    simulate_impedance,
)
from rtsid.sim.ltv import simulate_ltv_block
from rtsid.sim.reflex import ReflexParameters, StretchReflex

__all__ = [
    "Block",
    "PlantTruth",
    "PlayerSource",
    "SimSource",
    "TorqueMultisineSource",
    "load_recording",
    "servo_coefficients",
    "stiffness_profile",
]

FloatArray = NDArray[np.float64]
_STENCIL_HALF = 4  # simulate_impedance's central stencils reach 4 samples each side


@dataclass(frozen=True)
class Block:
    """Consecutive samples ``first_index .. first_index + n - 1``.

    Attributes
    ----------
    first_index : int
        Sample index of the first row.
    position_rad, torque_nm : numpy.ndarray, shape (n,)
        What the robot measures (before quantisation).
    discontinuity : numpy.ndarray of bool, shape (n,)
        Samples that do not continue the previous one.
    perturbation_on : bool
        Whether the perturbation is applied during this block.
    """

    first_index: int
    position_rad: FloatArray
    torque_nm: FloatArray
    discontinuity: NDArray[np.bool_]
    perturbation_on: bool


@dataclass(frozen=True)
class PlantTruth:
    """The simulated joint's true parameters (for tests and accuracy checks).

    Attributes
    ----------
    inertia : float
        Ankle inertia, kg·m² (the robot's own inertia is ``robot_inertia``).
    damping : float
        N·m·s/rad.
    robot_inertia : float
        kg·m², adds to the measured torque's inertial term.
    fs_hz : float
        Sample rate; sample ``k`` is at ``k / fs_hz`` s.
    """

    inertia: float
    damping: float
    robot_inertia: float
    fs_hz: float
    profile: StiffnessProfile
    period_s: float = 0.0
    reflex: ReflexParameters | None = None

    @classmethod
    def from_config(cls, cfg: PlantConfig) -> PlantTruth:
        """The joint a ``[plant]`` section simulates."""
        return cls(
            cfg.inertia,
            cfg.damping,
            cfg.robot_inertia,
            cfg.fs_hz,
            stiffness_profile(cfg.stiffness_profile, cfg.stiffness),
            cfg.stiffness_profile.period_s,
            cfg.reflex.parameters() if cfg.mode == "sim" else None,
        )

    def stiffness_at(self, t_s: FloatArray | float) -> FloatArray:
        """Stiffness K at times ``t_s`` (s since sample 0), N·m/rad."""
        t = np.asarray(t_s, dtype=float)
        if self.period_s > 0:
            t = np.mod(t, self.period_s)
        return self.profile.at(t)


def stiffness_profile(cfg: StiffnessConfig, constant_k: float) -> StiffnessProfile:
    """The :class:`StiffnessProfile` a ``[plant.stiffness_profile]`` table describes."""
    if cfg.kind == "constant":
        return StiffnessProfile.constant(constant_k)
    if cfg.kind == "sinusoidal":
        return StiffnessProfile.sinusoid(cfg.k0, cfg.amplitude, cfg.freq_hz)
    return StiffnessProfile(cfg.kind, k0=cfg.k0, k1=cfg.k1, t0=cfg.t0_s, t1=cfg.t1_s)


def servo_coefficients(fs_hz: float, bandwidth_hz: float) -> tuple[FloatArray, FloatArray]:
    """``(b, a)`` of :func:`rtsid.sim.robot_servo` (critically damped, two poles)."""
    pole = np.exp(-2 * np.pi * bandwidth_hz / fs_hz)
    return np.array([(1 - pole) ** 2]), np.array([1.0, -2 * pole, pole**2])


class _Perturbation:
    """Streaming perturbation command of one kind (state carried between blocks)."""

    def __init__(self, cfg: PlantConfig, command: Command, rng: np.random.Generator) -> None:
        from scipy import signal

        self.fs_hz = cfg.fs_hz
        self.kind = command.kind if command.enable else "off"
        self.amplitude = command.amplitude_rad
        self.bandwidth = min(max(command.bandwidth_hz, 1.0), 0.45 * cfg.fs_hz)
        self.rng = rng
        self.position = 0  # samples produced so far
        if self.kind == "filtered_noise":
            self.sos = signal.butter(4, self.bandwidth, fs=self.fs_hz, output="sos")
            self.zi = np.zeros((self.sos.shape[0], 2))
            impulse = np.zeros(int(20 * self.fs_hz / self.bandwidth) + 64)
            impulse[0] = 1.0
            self.gain = self.amplitude / (
                3.0 * np.sqrt(np.sum(signal.sosfilt(self.sos, impulse) ** 2))
            )
        elif self.kind == "multisine":
            ms = multisine(
                self.fs_hz,
                cfg.multisine_period_s,
                self.bandwidth,
                seed=int(rng.integers(1 << 31)),
            )
            one = ms.samples(1)
            self.period = one * (self.amplitude / np.max(np.abs(one)))

    def next(self, n: int) -> FloatArray:
        from scipy import signal

        if self.kind == "off" or self.amplitude == 0:
            out = np.zeros(n)
        elif self.kind == "prbs":
            hold = max(1, round(self.fs_hz / (2 * self.bandwidth)))
            out = prbs(n, self.amplitude, min_hold=hold, seed=self.rng)
        elif self.kind == "filtered_noise":
            white = self.rng.standard_normal(n)
            filtered, self.zi = signal.sosfilt(self.sos, white, zi=self.zi)
            out = np.clip(filtered * self.gain, -self.amplitude, self.amplitude)
        else:
            idx = (self.position + np.arange(n)) % self.period.size
            out = self.period[idx]
        self.position += n
        return np.asarray(out, dtype=float)


class SimSource:
    """Simulated robot + ankle: perturbation → servo → ``τ = (I+I_r)θ̈ + Bθ̇ + K(t)θ`` (+ the
    stretch reflex of ``[plant.reflex]``) + noise.

    Parameters
    ----------
    cfg : PlantConfig
        Joint, perturbation, servo, noise and block length.
    """

    def __init__(self, cfg: PlantConfig) -> None:
        self.cfg = cfg
        self.fs_hz = cfg.fs_hz
        self.n = cfg.block_samples
        self.rng = np.random.default_rng(cfg.seed)
        self.truth = PlantTruth.from_config(cfg)
        self.joint = JointParameters(cfg.inertia + cfg.robot_inertia, cfg.damping, 0.0)
        self.command = Command(
            enable=cfg.perturbation != "off",
            kind=cfg.perturbation if cfg.perturbation != "off" else "prbs",
            amplitude_rad=cfg.amplitude_rad,
            bandwidth_hz=min(cfg.bandwidth_hz, 255.0),
        )
        self._perturbation = _Perturbation(cfg, self.command, self.rng)
        self._b, self._a = servo_coefficients(cfg.fs_hz, cfg.servo_bandwidth_hz)
        self._zi = np.zeros(2)  # servo at rest at 0 rad
        # positions of samples [g - 2·half, g + n - 2·half) where g = generated so far
        self._segment = np.zeros(self.n + 2 * _STENCIL_HALF)
        self._next_index = 0
        reflex = self.truth.reflex
        self._reflex = StretchReflex(reflex, cfg.fs_hz) if reflex is not None else None

    def apply(self, command: Command) -> None:
        """Use ``command`` from the next block on (kind/bandwidth changes restart the signal)."""
        old = self.command
        self.command = command
        if (command.enable, command.kind, command.bandwidth_hz) != (
            old.enable,
            old.kind,
            old.bandwidth_hz,
        ):
            self._perturbation = _Perturbation(self.cfg, command, self.rng)
        else:
            self._perturbation.amplitude = command.amplitude_rad
            if command.kind == "multisine" and old.amplitude_rad > 0:
                self._perturbation.period *= command.amplitude_rad / old.amplitude_rad
            elif command.kind == "filtered_noise" and old.amplitude_rad > 0:
                self._perturbation.gain *= command.amplitude_rad / old.amplitude_rad

    def _servo(self, cmd: FloatArray) -> FloatArray:
        from scipy import signal

        out, self._zi = signal.lfilter(self._b, self._a, cmd, zi=self._zi)
        return np.asarray(out, dtype=float)

    def next_block(self) -> Block:
        """The next ``block_s`` of samples."""
        h2 = 2 * _STENCIL_HALF
        seg = self._segment
        seg[:h2] = seg[-h2:]
        seg[h2:] = self._servo(self._perturbation.next(self.n))
        first = self._next_index
        # seg holds samples first-4 .. first+n+3; the stencils are exact for first..first+n-1
        inertial = simulate_impedance(seg, self.fs_hz, self.joint)[_STENCIL_HALF:-_STENCIL_HALF]
        theta = seg[_STENCIL_HALF:-_STENCIL_HALF].copy()
        t = (first + np.arange(self.n)) / self.fs_hz
        torque = inertial + self.truth.stiffness_at(t) * theta
        if self._reflex is not None:
            velocity, _ = derivatives(seg, self.fs_hz)
            torque = torque + self._reflex.torque(velocity[_STENCIL_HALF:-_STENCIL_HALF])
        if self.cfg.noise_percent > 0:
            torque = add_noise(torque, self.cfg.noise_percent, seed=self.rng)
        position = theta
        if self.cfg.position_noise_rad > 0:
            position = theta + self.cfg.position_noise_rad * self.rng.standard_normal(self.n)
        discontinuity = np.zeros(self.n, dtype=bool)
        discontinuity[0] = first == 0
        self._next_index += self.n
        on = self.command.enable and self.command.kind != "off" and self.command.amplitude_rad > 0
        return Block(first, position, torque, discontinuity, on)

    @property
    def lookahead_samples(self) -> int:
        """Samples by which the torque lags the newest generated position (stencil reach)."""
        return _STENCIL_HALF


class TorqueMultisineSource:
    """Simulated joint driven by a periodic multisine torque: ``I·φ̈ = τ − B·φ̇ − K(t)·φ``.

    The torque is :meth:`TorqueMultisineConfig.multisine` from sample ``start_index`` on
    (zero before), the angle comes from :func:`rtsid.sim.ltv.simulate_ltv_block` block by
    block with the state carried across blocks (the same samples as one long simulation),
    with ``I = inertia + robot_inertia``. Measurement noise: ``position_noise_rad`` (encoder,
    rad std) on the angle and ``noise_percent`` % of the multisine's RMS on the torque.
    Commands are accepted and ignored (the experiment is scripted by the config).

    Parameters
    ----------
    cfg : PlantConfig
        ``mode = "torque_multisine"`` with ``[plant.torque_multisine]`` and
        ``[plant.stiffness_profile]``.
    """

    #: RK4 steps per second of simulated time (at least): 8 per sample at 200 Hz.
    STEP_RATE_HZ = 1600.0

    def __init__(self, cfg: PlantConfig) -> None:
        self.cfg = cfg
        self.fs_hz = cfg.fs_hz
        self.n = cfg.block_samples
        self.rng = np.random.default_rng(cfg.seed)
        self.multisine = cfg.torque_multisine.multisine(cfg.fs_hz)
        self.start_index = cfg.torque_multisine.start_index
        self._period = self.multisine.samples(1)
        self.truth = PlantTruth.from_config(cfg)
        self._k = _TruthStiffness(self.truth)
        self.joint = JointParameters(cfg.inertia + cfg.robot_inertia, cfg.damping, 0.0)
        self.substeps = max(1, int(np.ceil(self.STEP_RATE_HZ / cfg.fs_hz)))
        self.command = Command(enable=True, kind="multisine", amplitude_rad=0.0, bandwidth_hz=0.0)
        self._state = (0.0, 0.0)  # angle (rad) and velocity (rad/s) at the next sample
        self._next_index = 0

    def apply(self, command: Command) -> None:
        """The experiment is scripted by the config: commands are accepted and ignored."""
        self.command = replace(command)

    def torque_at(self, t_s: FloatArray) -> FloatArray:
        """Applied torque at times ``t_s`` (s since sample 0), N·m: 0 before the start."""
        t0 = self.start_index / self.fs_hz
        t = np.asarray(t_s, dtype=float)
        return np.where(t >= t0, self.multisine.evaluate(t - t0), 0.0)

    def next_block(self) -> Block:
        """The next ``block_s`` of samples."""
        first, n = self._next_index, self.n
        angle, self._state = simulate_ltv_block(
            self.torque_at,
            self.fs_hz,
            first,
            n,
            self.joint,
            self._k,
            state=self._state,
            substeps=self.substeps,
        )
        index = first + np.arange(n)
        started = index >= self.start_index
        torque = np.where(started, self._period[(index - self.start_index) % self._period.size], 0)
        cfg = self.cfg
        if cfg.noise_percent > 0:
            rms = cfg.torque_multisine.rms_nm
            torque = torque + (cfg.noise_percent / 100 * rms) * self.rng.standard_normal(n)
        if cfg.position_noise_rad > 0:
            angle = angle + cfg.position_noise_rad * self.rng.standard_normal(n)
        discontinuity = np.zeros(n, dtype=bool)
        discontinuity[0] = first == 0
        self._next_index += n
        return Block(
            first, angle, np.asarray(torque, dtype=float), discontinuity, bool(started[-1])
        )


class _TruthStiffness:
    """``K(t)`` of a :class:`PlantTruth` (periodic profile included) as ``.at(t)``."""

    def __init__(self, truth: PlantTruth) -> None:
        self.truth = truth

    def at(self, t_s: FloatArray | float) -> FloatArray:
        return self.truth.stiffness_at(t_s)


class PlayerSource:
    """Streams a recording (``.npz`` with ``position_rad``, ``torque_nm``, ``fs_hz``).

    Resampled to the bus rate with :func:`scipy.signal.resample_poly`; with ``loop`` the
    first sample of every pass is flagged as a discontinuity.
    """

    def __init__(self, cfg: PlantConfig) -> None:
        self.cfg = cfg
        self.fs_hz = cfg.fs_hz
        self.n = cfg.block_samples
        self.truth = None
        self.command = Command(enable=True, kind="prbs", amplitude_rad=0.0, bandwidth_hz=0.0)
        self.position, self.torque = load_recording(Path(cfg.player_file), cfg.fs_hz)
        self.torque = self.torque * cfg.player_torque_sign
        self._cursor = 0
        self._next_index = 0
        self.finished = False

    def apply(self, command: Command) -> None:
        """A recording cannot be re-excited: commands are accepted and ignored."""
        self.command = replace(command)

    def next_block(self) -> Block:
        n = self.n
        total = self.position.size
        take = np.arange(self._cursor, self._cursor + n)
        discontinuity = take % total == 0
        if not self.cfg.player_loop:
            take = take[take < total]
            self.finished = self._cursor + n >= total
        idx = take % total
        first = self._next_index
        self._cursor += idx.size
        self._next_index += idx.size
        return Block(first, self.position[idx], self.torque[idx], discontinuity[: idx.size], True)


def load_recording(path: Path, fs_hz: float) -> tuple[FloatArray, FloatArray]:
    """Position (rad) and torque (N·m) of an ``.npz`` recording resampled to ``fs_hz``.

    Raises
    ------
    InputDataError
        The file is missing, lacks an array, or the arrays disagree.
    """
    from scipy import signal

    data = read_npz(
        path,
        ("position_rad", "torque_nm", "fs_hz"),
        hint="a player file needs position_rad, torque_nm and fs_hz arrays ([plant] player_file)",
    )
    position = np.asarray(data["position_rad"], dtype=float).ravel()
    torque = np.asarray(data["torque_nm"], dtype=float).ravel()
    fs_file = float(data["fs_hz"])
    if position.size != torque.size or position.size < 16:
        raise InputDataError(
            f"player file {str(path)!r}: position ({position.size}) and torque ({torque.size}) "
            "need the same length of at least 16 samples"
        )
    if not (np.all(np.isfinite(position)) and np.all(np.isfinite(torque))):
        raise InputDataError(f"player file {str(path)!r} contains NaN or infinite samples")
    ratio = Fraction(fs_hz / fs_file).limit_denominator(1000)
    if abs(float(ratio) - fs_hz / fs_file) > 1e-9 * fs_hz / fs_file:
        raise InputDataError(
            f"cannot resample {fs_file} Hz to {fs_hz} Hz with a rational ratio of small terms"
        )
    if ratio != 1:
        position = signal.resample_poly(position, ratio.numerator, ratio.denominator)
        torque = signal.resample_poly(torque, ratio.numerator, ratio.denominator)
    return np.asarray(position, dtype=float), np.asarray(torque, dtype=float)
