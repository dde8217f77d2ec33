"""``rtsid bench accuracy``: the source's accuracy analyses on the simulated ankle.

(a) error of I, B, K against window length × noise; (b) 1 − VAF against the stiffness change
within the window × noise; (c) tracking a sinusoidally varying K; (d) perturbation bandwidth,
which decides what can be identified at all. Noise is white Gaussian on the torque, its
standard deviation a percentage of the clean torque's; the estimator's own low-pass removes the
part above 100 Hz, so (e) repeats the floor case with noise confined to the signal band.
"""

from __future__ import annotations

import argparse
import functools
from collections.abc import Callable

import numpy as np

from rtsid.benchmarks.table import print_table
from rtsid.errors import RtsidError
from rtsid.ident.excitation import filtered_noise, prbs
from rtsid.ident.filters import derivatives
from rtsid.ident.stream import sliding_estimates
from rtsid.ident.window import EstimatorOptions, Held, estimate_window
from rtsid.ident.yardstick import least_squares_window
from rtsid.sim.joint import JointParameters, StiffnessProfile, robot_servo, simulate_impedance

FS_HZ = 2500.0
ANKLE = JointParameters(inertia=0.015, damping=0.8, stiffness=150.0)
PERTURBATION = "filtered Gaussian noise, 30 Hz 4th-order Butterworth, ±0.03 rad peak"
MARGIN = 1000  # samples simulated before and after each window (no edge effects)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--realisations", type=int, default=30, help="per cell (30)")


def _perturbation(n: int, rng: np.random.Generator, kind: str = "noise", bw_hz: float = 30.0):
    if kind == "prbs":
        hold = max(1, round(FS_HZ / (2 * bw_hz)))
        return robot_servo(prbs(n, 0.03, min_hold=hold, seed=rng), FS_HZ, bw_hz)
    return filtered_noise(n, FS_HZ, bw_hz, peak=0.03, seed=rng)


def _window(
    seed: int,
    window_s: float,
    noise: float,
    *,
    stiffness: StiffnessProfile | None = None,
    kind: str = "noise",
    bw_hz: float = 30.0,
    noise_band_hz: float | None = None,
    joint: JointParameters = ANKLE,
) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    n = round(window_s * FS_HZ)
    theta = _perturbation(n + 2 * MARGIN, rng, kind, bw_hz)
    tau = simulate_impedance(
        theta,
        FS_HZ,
        joint,
        stiffness,
        noise_percent=noise,
        seed=rng,
        noise_band_hz=noise_band_hz,
        t0_s=-MARGIN / FS_HZ,
    )
    return theta[MARGIN : MARGIN + n], tau[MARGIN : MARGIN + n]


def _median_errors(
    make: Callable[[int], tuple[np.ndarray, np.ndarray]],
    reps: int,
    joint: JointParameters = ANKLE,
    options: EstimatorOptions | None = None,
) -> tuple[np.ndarray, float, int]:
    """Median |relative error| (%) of I, B, K, median VAF, and windows withheld."""
    truth = np.array([joint.inertia, joint.damping, joint.stiffness])
    errors, vafs, withheld = [], [], 0
    for seed in range(reps):
        try:
            est = estimate_window(*make(seed), FS_HZ, options)
        except RtsidError:
            withheld += 1
            continue
        errors.append(np.abs(np.array([est.I, est.B, est.K]) - truth) / truth * 100)
        vafs.append(est.vaf)
    if not errors:
        return np.full(3, np.nan), float("nan"), withheld
    return np.median(errors, axis=0), float(np.median(vafs)), withheld


def _table_window_noise(reps: int) -> None:
    rows = []
    for window_s in (0.1, 0.2, 0.3, 0.5, 1.0):
        options = EstimatorOptions(lag_s=min(0.02, window_s / 8))
        for noise in (0.0, 5.0, 10.0, 20.0):
            make = functools.partial(_window, window_s=window_s, noise=noise)
            med, vaf, withheld = _median_errors(make, reps, options=options)
            rows.append(
                [
                    f"{window_s * 1e3:.0f}",
                    options.lag_s * 1e3,
                    noise,
                    med[2],
                    med[1],
                    med[0],
                    vaf,
                    withheld,
                ]
            )
    print_table(
        f"(a) median |error| % of K, B, I vs window length × noise ({reps} realisations)",
        ["window ms", "lag ±ms", "noise %", "K", "B", "I", "VAF %", "withheld"],
        rows,
        note=(
            f"Perturbation: {PERTURBATION}. Truth I 0.015, B 0.8, K 150. The IRF lag span "
            "shrinks to window/8 for windows under 160 ms (the default ±20 ms needs more samples)."
        ),
    )


def _floor_check(reps: int) -> None:
    cases = {
        "filtered noise 30 Hz, white torque noise": lambda s: _window(s, 0.3, 10.0),
        "filtered noise 30 Hz, in-band torque noise (≤ 30 Hz)": lambda s: _window(
            s, 0.3, 10.0, noise_band_hz=30.0
        ),
        "PRBS through a 40 Hz servo, white torque noise": lambda s: _window(
            s, 0.3, 10.0, kind="prbs", bw_hz=40.0
        ),
    }
    rows = []
    for name, make in cases.items():
        med, vaf, _ = _median_errors(make, reps)
        ok = med[2] <= 3 and med[1] <= 5 and med[0] <= 10
        rows.append([name, med[2], med[1], med[0], vaf, "PASS" if ok else "FAIL"])
    print_table(
        "(e) floor at 300 ms, 10 % noise: median |error| K ≤ 3 %, B ≤ 5 %, I ≤ 10 %",
        ["perturbation", "K %", "B %", "I %", "VAF %", "floor"],
        rows,
    )


def _source_window(
    seed: int, noise: float, profile: StiffnessProfile
) -> tuple[np.ndarray, np.ndarray]:
    """The source's simulation: Gaussian noise low-passed at 200 Hz, ±0.05 rad."""
    rng = np.random.default_rng(seed)
    n = round(0.3 * FS_HZ)
    theta = filtered_noise(n + 2 * MARGIN, FS_HZ, 200.0, peak=0.05, seed=rng)
    tau = simulate_impedance(
        theta, FS_HZ, ANKLE, profile, noise_percent=noise, seed=rng, t0_s=-MARGIN / FS_HZ
    )
    return theta[MARGIN : MARGIN + n], tau[MARGIN : MARGIN + n]


def _table_stiffness_change(reps: int) -> None:
    rows = []
    makers = {
        "30 Hz": lambda seed, noise, prof: _window(seed, 0.3, noise, stiffness=prof),
        "source 200 Hz": _source_window,
    }
    for change in (0.0, 25.0, 50.0, 100.0, 150.0):
        profile = StiffnessProfile.ramp(150.0, 150.0 * (1 + change / 100), 0.0, 0.3)
        cells: list[object] = [change]
        for make in makers.values():
            for noise in (0.0, 10.0, 20.0):
                one_minus_vaf = [
                    100.0 - estimate_window(*make(seed, noise, profile), FS_HZ).vaf
                    for seed in range(reps)
                ]
                cells.append(float(np.median(one_minus_vaf)))
        rows.append(cells)
    print_table(
        f"(b) median 1 − VAF (%) vs stiffness change within a 300 ms window ({reps} realisations)",
        ["K change %"] + [f"{name}, noise {nz:g} %" for name in makers for nz in (0.0, 10.0, 20.0)],
        rows,
        note=(
            "K ramps linearly from 150 N·m/rad across the window. Perturbations: 30 Hz = "
            f"{PERTURBATION}; source 200 Hz = Gaussian noise low-passed at 200 Hz, ±0.05 rad "
            "(the source's simulation). Floor: VAF ≥ 95 % (1 − VAF ≤ 5 %) at +150 %. VAF of an "
            "LTI fit to a time-varying joint depends on how much of the torque is elastic: with "
            "the 30 Hz perturbation K·θ carries more of it than with 200 Hz, where inertia "
            "dominates."
        ),
    )


def _table_sinusoidal_tracking(reps: int) -> None:
    rows = []
    duration = 8.0
    n = round(duration * FS_HZ)
    for freq in (0.1, 0.25, 0.5, 1.0, 2.0):
        profile = StiffnessProfile.sinusoid(150.0, 60.0, freq)
        rms, lagged = [], []
        for seed in range(max(1, reps // 10)):
            rng = np.random.default_rng(seed)
            theta = _perturbation(n, rng)
            tau = simulate_impedance(theta, FS_HZ, ANKLE, profile, noise_percent=10.0, seed=rng)
            est, mean_k = [], []
            for res in sliding_estimates(theta, tau, FS_HZ, 0.3, 0.02, EstimatorOptions()):
                if res.estimate is None:
                    continue
                est.append(res.estimate.K)
                mean_k.append(float(np.mean(profile.at(np.arange(res.start, res.stop) / FS_HZ))))
            err = np.array(est) - np.array(mean_k)
            rms.append(float(np.sqrt(np.mean(err**2))))
            lagged.append(float(np.corrcoef(est, mean_k)[0, 1]))
        rows.append(
            [
                freq,
                60.0,
                float(np.mean(rms)),
                float(np.mean(rms)) / 150 * 100,
                float(np.mean(lagged)),
            ]
        )
    print_table(
        "(c) tracking K(t) = 150 + 60·sin(2π·f·t) N·m/rad, 300 ms windows every 20 ms, 10 % noise",
        ["f Hz", "amplitude", "RMS error N·m/rad", "RMS / mean %", "correlation"],
        rows,
        note="Truth per window = mean K over the window (what a 300 ms LTI fit can see).",
    )


def _table_bandwidth(reps: int) -> None:
    rows = []
    for bw in (5.0, 10.0, 20.0, 30.0, 60.0, 150.0):
        make = functools.partial(_window, window_s=0.3, noise=10.0, bw_hz=bw)
        med, vaf, withheld = _median_errors(make, reps)
        rows.append([bw, med[2], med[1], med[0], vaf, withheld])
    soft = JointParameters(0.03, 2.0, 30.0)
    med, vaf, withheld = _median_errors(lambda s: _window(s, 0.3, 10.0, joint=soft), reps, soft)
    rows.append(["30 (soft ankle)", med[2], med[1], med[0], vaf, withheld])
    print_table(
        "(d) median |error| % vs perturbation bandwidth, 300 ms, 10 % noise",
        ["bandwidth Hz", "K", "B", "I", "VAF %", "withheld"],
        rows,
        note=(
            "Identification needs power around the joint's corner frequencies: below ~20 Hz "
            "inertia is barely excited; at 150 Hz inertial torque (I·ω²) swamps stiffness. "
            "Soft ankle: I 0.03, B 2, K 30 resonates at 5 Hz, which a 300 ms window barely "
            "holds — its estimates carry the 'stiffness_uncertain' flag."
        ),
    )


ANKLES = (
    JointParameters(0.015, 0.8, 150.0),
    JointParameters(0.03, 2.0, 50.0),
    JointParameters(0.02, 0.5, 400.0),
    JointParameters(0.025, 1.2, 250.0),
)
CRITERIA = {
    "output error": EstimatorOptions(hold="none"),
    "output error, I held at truth": EstimatorOptions(hold="none"),
    "relative": EstimatorOptions(fit_method="relative", hold="none"),
    "logmag": EstimatorOptions(fit_method="logmag", hold="none"),
}


def _criterion_errors(bw_hz: float, seeds: int) -> dict[str, np.ndarray]:
    """|relative error| (%) of (I, B, K) per window for each criterion and for least squares
    with the simulation's exact derivatives, on the same windows."""
    errors: dict[str, list[np.ndarray]] = {name: [] for name in (*CRITERIA, "least squares")}
    for case, joint in enumerate(ANKLES):
        truth = np.array([joint.inertia, joint.damping, joint.stiffness])
        for seed in range(seeds):  # independent realisations for every ankle
            theta, tau = _window(10_000 * (case + 1) + seed, 0.3, 10.0, bw_hz=bw_hz, joint=joint)
            ls = least_squares_window(theta, tau, FS_HZ, derivatives(theta, FS_HZ))
            errors["least squares"].append(np.abs(ls - truth) / truth * 100)
            for name, options in CRITERIA.items():
                held = Held(joint.inertia) if "held" in name else Held()
                est = estimate_window(theta, tau, FS_HZ, options, held=held)
                errors[name].append(np.abs(np.array([est.I, est.B, est.K]) - truth) / truth * 100)
    return {name: np.median(np.array(e), axis=0) for name, e in errors.items()}


def _table_criteria(seeds: int) -> None:
    rows = []
    for bw in (20.0, 40.0):
        medians = _criterion_errors(bw, seeds)
        ls = medians["least squares"]
        rows.append([bw, "least squares (reference)", ls[2], ls[1], ls[0], 1.0, 1.0, 1.0, ""])
        for name in CRITERIA:
            med = medians[name]
            ratio = med / ls
            held = "held" in name
            ok = ratio[2] <= 1.3 and ratio[1] <= 1.3 and (held or ratio[0] <= 1.3)
            verdict = "PASS" if ok else "MISS"
            i_ratio = float("nan") if held else ratio[0]
            rows.append([bw, name, med[2], med[1], med[0], ratio[2], ratio[1], i_ratio, verdict])
    print_table(
        f"(f) fit criteria against per-window least squares on the same windows: median "
        f"|error| % ({len(ANKLES)} ankles × {seeds} seeds, 300 ms at 2500 Hz, 10 % noise)",
        ["band Hz", "criterion", "K %", "B %", "I %", "K / LS", "B / LS", "I / LS", "≤ 1.3×"],
        rows,
        note=(
            "Ankles (I, B, K): (0.015, 0.8, 150), (0.03, 2, 50), (0.02, 0.5, 400), "
            "(0.025, 1.2, 250); position = white noise through a 4th-order low-pass at the "
            "band. Least squares uses the simulation's exact derivatives and an offset and "
            "trend; the estimator sees only position and torque. 'I held at truth' shows what "
            "holding inertia (the two-time-scale option) does to K and B."
        ),
    )


def _table_sample_loss(windows: int) -> None:
    """(g) random sample loss: windows estimated and K's error against the same windows
    without loss (the lost samples' values are overwritten: they must not matter)."""
    rows = []
    lossless = []
    # (share lost, max_lost_percent): the default limit, and 5 % with the limit raised to 10 %
    outcomes: dict[tuple[float, float], list[float | None]] = {
        (0.001, 2.0): [],
        (0.01, 2.0): [],
        (0.05, 2.0): [],
        (0.05, 10.0): [],
    }
    for seed in range(windows):
        theta, tau = _window(seed, 0.3, 10.0)
        lossless.append(abs(estimate_window(theta, tau, FS_HZ, hold="none").K - 150.0) / 1.5)
        rng = np.random.default_rng(50_000 + seed)
        draws = rng.random(theta.size)
        for (loss, limit), results in outcomes.items():
            valid = draws >= loss
            p, t = np.where(valid, theta, np.nan), np.where(valid, tau, np.nan)
            try:
                est = estimate_window(p, t, FS_HZ, hold="none", valid=valid, max_lost_percent=limit)
            except RtsidError:
                results.append(None)
                continue
            results.append(abs(est.K - 150.0) / 1.5)
    base = float(np.median(lossless))
    for (loss, limit), results in outcomes.items():
        kept = [r for r in results if r is not None]
        share = 100.0 * len(kept) / len(results)
        median = float(np.median(kept)) if kept else float("nan")
        ratio = median / base
        verdict = ("PASS" if share >= 90 and ratio <= 1.5 else "MISS") if loss == 0.01 else ""
        rows.append([100 * loss, limit, share, median, ratio, verdict])
    print_table(
        f"(g) random sample loss, 300 ms windows, 10 % noise ({windows} windows): windows "
        f"estimated and median |K error| % (lossless: {base:.3g} %)",
        [
            "lost %",
            "max_lost_percent",
            "estimated %",
            "K error %",
            "÷ lossless",
            "floor (1 %: ≥ 90 %, ≤ 1.5×)",
        ],
        rows,
        note=(
            f"Perturbation: {PERTURBATION}. Lost samples are bridged by sums over valid "
            "samples only (never interpolated) up to max_lost_percent (default 2 %) and runs "
            "of max_gap_s = 4 ms; beyond, or with too few clean rows left, the window is "
            "withheld as 'gap'."
        ),
    )


def run(args: argparse.Namespace) -> int:
    reps = 5 if args.quick else args.realisations
    _table_criteria(3 if args.quick else 50)
    _table_sample_loss(10 if args.quick else 200)
    _floor_check(reps)
    _table_window_noise(reps)
    _table_stiffness_change(reps)
    _table_sinusoidal_tracking(reps)
    _table_bandwidth(reps)
    return 0
