"""``rtsid bench calibrate``: robot-dynamics calibration, ours against the source's method.

A no-person run of the virtual plant (robot inertia only) is calibrated two ways:

* **source**: position differentiated twice, each step followed by a 10 Hz low-pass
  (2nd-order Butterworth, zero phase), then an acceleration → torque IRF;
* **rtsid**: :func:`rtsid.ident.robot.identify_robot` (8th-order stencils, the same
  zero-phase FIR on acceleration and torque, IRF by EUREKA).

For each, the table gives the VAF on the calibration run (full band and below 100 Hz),
its static gain against the simulated robot inertia, and what matters downstream: the median
error of the ankle's I, B, K over 300 ms windows of a run with a person attached after the
predicted robot torque is subtracted ("none": nothing subtracted).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from scipy import signal

from rtsid.benchmarks.table import print_table
from rtsid.ident.correlation import detrend
from rtsid.ident.irf import estimate_irf
from rtsid.ident.robot import (
    ATTACHED_MIN_K,
    ATTACHED_MIN_T,
    baseline_stiffness,
    identify_robot,
    robot_filter_taps,
)
from rtsid.ident.stream import WindowStream
from rtsid.ident.vaf import vaf
from rtsid.ident.window import EstimatorOptions
from rtsid.link.config import PlantConfig
from rtsid.link.protocol import POSITION_SCALE_RAD, TORQUE_SCALE_NM
from rtsid.link.signals import SimSource

Predictor = Callable[[np.ndarray], np.ndarray]
ROBOT_INERTIA = 0.05


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--baseline-s", type=float, default=20.0, help="no-person run, s (20)")
    parser.add_argument("--person-s", type=float, default=10.0, help="run with a person, s (10)")


def _simulate(cfg: PlantConfig, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    source = SimSource(cfg)
    blocks = [source.next_block() for _ in range(max(1, round(seconds / cfg.block_s)))]
    position = np.concatenate([b.position_rad for b in blocks])
    torque = np.concatenate([b.torque_nm for b in blocks])
    quantised = np.rint(position / POSITION_SCALE_RAD) * POSITION_SCALE_RAD
    return quantised, np.rint(torque / TORQUE_SCALE_NM) * TORQUE_SCALE_NM


def _source_acceleration(position: np.ndarray, fs: float) -> np.ndarray:
    sos = signal.butter(2, 10.0, fs=fs, output="sos")
    velocity = signal.sosfiltfilt(sos, np.gradient(position) * fs)
    return np.asarray(signal.sosfiltfilt(sos, np.gradient(velocity) * fs))


def _source_method(position: np.ndarray, torque: np.ndarray, fs: float) -> tuple[Predictor, float]:
    """The source's calibration: its predictor and its static gain (kg·m²)."""
    lag = round(0.01 * fs)
    acc = _source_acceleration(position, fs)
    irf = estimate_irf(detrend(acc), detrend(torque), fs, lag, ridge=1e-3)
    return (lambda p: irf.predict(_source_acceleration(p, fs))), float(np.sum(irf.h) / fs)


def _vafs(
    predict: Predictor, position: np.ndarray, torque: np.ndarray, fs: float
) -> tuple[float, float]:
    """VAF of the predicted robot torque: full band, and both low-passed (rtsid's FIR)."""
    inner = slice(100, -100)
    measured, predicted = detrend(torque)[inner], detrend(predict(position))[inner]
    taps = robot_filter_taps(fs, 100.0)
    low = (np.convolve(measured, taps, "valid"), np.convolve(predicted, taps, "valid"))
    return vaf(measured, predicted), vaf(*low)


def _ankle_errors(
    position: np.ndarray,
    torque: np.ndarray,
    fs: float,
    truth: PlantConfig,
    offset: Predictor | None,
    band_hz: float,
) -> list[float]:
    """Median I/B/K errors (%) of the worker's stream, analysed within the calibration's band
    (as the daemon does with a calibration)."""
    n = round(0.3 * fs)
    stream = WindowStream(fs, EstimatorOptions(), (n // 2) / fs, max_lowpass_hz=band_hz)
    rows = []
    for start in range(0, position.size - n, n // 2):
        p, t = position[start : start + n], torque[start : start + n]
        if offset is not None:
            t = t - offset(p)
        e = stream.estimate(p, t)
        rows.append((e.I, e.B, e.K))
    med = np.median(rows, axis=0)
    true = np.array([truth.inertia, truth.damping, truth.stiffness])
    return [float(v) for v in 100.0 * (med - true) / true]


def run(args: argparse.Namespace) -> int:
    baseline_s = 6.0 if args.quick else args.baseline_s
    person_s = 3.0 if args.quick else args.person_s
    scenarios = [
        (
            "noise 8 Hz (the source's regime), 3 % noise",
            PlantConfig(perturbation="filtered_noise", bandwidth_hz=8.0, amplitude_rad=0.05),
        ),
        (
            "noise 30 Hz, 3 % torque noise",
            PlantConfig(perturbation="filtered_noise", bandwidth_hz=30.0),
        ),
        ("PRBS 40 Hz, 3 % torque noise", PlantConfig(perturbation="prbs", bandwidth_hz=40.0)),
        (
            "PRBS 40 Hz, 10 % noise, encoder 20 µrad",
            PlantConfig(noise_percent=10.0, position_noise_rad=2e-5),
        ),
    ]
    rows = []
    checks = []
    for label, base in scenarios:
        person = replace(base, robot_inertia=ROBOT_INERTIA, seed=5)
        nobody = replace(person, inertia=0.0, damping=0.0, stiffness=0.0, seed=6)
        fs = base.fs_hz
        p0, t0 = _simulate(nobody, baseline_s)
        p1, t1 = _simulate(person, person_s)
        robot = identify_robot([(p0, t0)], fs)
        for who, (p, t) in (("nobody", (p0, t0)), ("ankle attached", (p1, t1))):
            found = baseline_stiffness([(p, t)], fs)
            refused = "refused" if found.joint_attached else "calibrated"
            checks.append([label, who, found.K, found.t, refused])
        methods: list[tuple[str, Predictor | None, float]] = [
            ("none", None, float("nan")),
            ("source (10 Hz double diff.)", *_source_method(p0, t0, fs)),
            ("rtsid (stencils + same FIR)", robot.predict_torque, robot.inertia),
        ]
        for name, predict, gain in methods:
            nan = float("nan")
            fit_vaf = (nan, nan) if predict is None else _vafs(predict, p0, t0, fs)
            errors = _ankle_errors(p1, t1, fs, person, predict, robot.analysis_cutoff_hz)
            rows.append([label, name, *fit_vaf, gain, *errors])
    print_table(
        f"Robot calibration (robot inertia {ROBOT_INERTIA} kg·m², ankle I 0.015, B 0.8, K 150; "
        f"baseline {baseline_s:g} s, person {person_s:g} s, 300 ms windows)",
        [
            "scenario",
            "method",
            "VAF %",
            "VAF ≤100 Hz %",
            "gain kg·m²",
            "I err %",
            "B err %",
            "K err %",
        ],
        rows,
        note="VAF: the calibration's prediction of the measured robot torque on the no-person "
        "run, full band and with both low-passed at 100 Hz (the estimator's band). gain: the "
        f"IRF's static gain, i.e. the identified inertia (truth {ROBOT_INERTIA}). I/B/K err: "
        "median over windows of a run with a person, after subtracting the predicted robot "
        "torque.",
    )
    print_table(
        "Is a joint attached? (the baseline's stiffness beside the robot's inertia)",
        ["scenario", "run used as baseline", "K N·m/rad", "t", "rtsid calibrate"],
        checks,
        note=f"K: least squares τ = I·θ̈ + B·θ̇ + K·θ on the filtered run; t: K over its "
        f"standard error. Refused (unless --force) when K ≥ {ATTACHED_MIN_K:g} and "
        f"t ≥ {ATTACHED_MIN_T:g}.",
    )
    return 0
