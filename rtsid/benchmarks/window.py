"""``rtsid bench window``: cost of one 300 ms window at 2500 Hz, stage by stage.

Stages are the functions :func:`rtsid.estimate_window` runs, timed in turn on the same
windows. The baseline, measured in the same run, is the source's method: the IRF by dense
matrix inversion (no refinement) and the log-magnitude Nelder–Mead fit.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.linalg import toeplitz

from rtsid.benchmarks.table import median_p99, print_table
from rtsid.ident.correlation import auto_correlation, cross_correlation
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.irf import IRF, estimate_irf
from rtsid.ident.window import (
    EstimatorOptions,
    estimate_window,
    fit_parameters,
    predict_torque,
    prepare_window,
    standard_errors,
)
from rtsid.sim.joint import JointParameters, simulate_impedance

FS_HZ = 2500.0
WINDOW_S = 0.3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--windows", type=int, default=2000, help="windows to time (2000)")


def _windows(count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    n = round(WINDOW_S * FS_HZ)
    theta = filtered_noise(n * 50 + 2000, FS_HZ, 30.0, peak=0.03, seed=7)
    tau = simulate_impedance(theta, FS_HZ, JointParameters(), noise_percent=10.0, seed=8)
    starts = np.random.default_rng(9).integers(1000, theta.size - n - 1000, count)
    return [(theta[s : s + n], tau[s : s + n]) for s in starts]


def _staged(
    p: np.ndarray, t: np.ndarray, opts: EstimatorOptions, clock: dict[str, list[float]]
) -> None:
    def timed(name: str, func: Callable[[], Any]) -> Any:
        start = time.perf_counter()
        out = func()
        clock[name].append(time.perf_counter() - start)
        return out

    u, y, fs_a = timed(
        "prepare (detrend, FIR, decimate)", lambda: prepare_window(p, t, FS_HZ, opts)
    )
    lag = round(opts.lag_s * fs_a)
    irf = timed(
        "IRF (correlations + EUREKA ×4)",
        lambda: estimate_irf(u, y, fs_a, lag, ridge=opts.ridge, refine=opts.refine),
    )
    fit = timed("fit I, B, K", lambda: fit_parameters(irf, u, opts))
    pred = timed("predictions + VAF", lambda: predict_torque(irf, u, y, fit))
    timed("standard errors", lambda: standard_errors(irf, u, pred, fit))


def _baseline(p: np.ndarray, t: np.ndarray, opts: EstimatorOptions) -> None:
    """The source's pipeline: IRF by dense inversion, log-magnitude Nelder–Mead fit."""
    u, y, fs_a = prepare_window(p, t, FS_HZ, opts)
    lag = round(opts.lag_s * fs_a)
    phi_uu = auto_correlation(u, 2 * lag)
    h = np.linalg.inv(toeplitz(phi_uu)) @ cross_correlation(u, y, lag) * fs_a
    irf = IRF(h=h, fs_hz=fs_a, phi_uu=phi_uu)
    fit = fit_parameters(irf, u, EstimatorOptions(fit_method="logmag"))
    predict_torque(irf, u, y, fit)


def _time_each(
    windows: list[tuple[np.ndarray, np.ndarray]], func: Callable[..., Any]
) -> list[float]:
    times = []
    for p, t in windows:
        start = time.perf_counter()
        func(p, t)
        times.append(time.perf_counter() - start)
    return times


def run(args: argparse.Namespace) -> int:
    count = min(200, args.windows) if args.quick else args.windows
    windows = _windows(count)
    opts = EstimatorOptions()
    for p, t in windows[:20]:
        estimate_window(p, t, FS_HZ, opts)  # warm caches (filter taps, DFT grids)
    total = _time_each(windows, lambda p, t: estimate_window(p, t, FS_HZ, opts))
    no_se = EstimatorOptions(uncertainty=False)
    without_se = _time_each(windows, lambda p, t: estimate_window(p, t, FS_HZ, no_se))
    baseline = _time_each(windows[: max(20, count // 10)], lambda p, t: _baseline(p, t, opts))
    clock: dict[str, list[float]] = {
        k: []
        for k in (
            "prepare (detrend, FIR, decimate)",
            "IRF (correlations + EUREKA ×4)",
            "fit I, B, K",
            "predictions + VAF",
            "standard errors",
        )
    }
    for p, t in windows:
        _staged(p, t, opts, clock)
    base_median = median_p99(baseline)[0]
    rows = []
    for name, times in [
        *clock.items(),
        ("estimate_window (all)", total),
        ("estimate_window, no SE", without_se),
        ("baseline: source method", baseline),
    ]:
        median, p99 = median_p99(times)
        rows.append([name, median * 1e3, p99 * 1e3, base_median / median])
    print_table(
        f"One {WINDOW_S * 1e3:.0f} ms window at {FS_HZ:.0f} Hz ({count} windows): milliseconds",
        ["stage", "median", "p99", "baseline / this"],
        rows,
        note=(
            "Simulated ankle (I 0.015, B 0.8, K 150), 30 Hz filtered-noise perturbation, "
            "10 % noise. "
            "Defaults: decimate to 500 Hz, ±20 ms IRF (21 lags), 3 refinement sweeps, linear fit. "
            "Baseline = dense inversion IRF + Nelder–Mead log-magnitude fit (the source's method)."
        ),
    )
    return 0
