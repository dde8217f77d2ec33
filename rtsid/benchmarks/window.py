"""``rtsid bench window``: cost of one 300 ms window at 2500 Hz, stage by stage.

Stages are the functions :func:`rtsid.estimate_window` runs, timed in turn on the same
windows. The baseline, measured in the same run, is the source's method: the IRF by dense
matrix inversion (no refinement) and the log-magnitude Nelder–Mead fit.
"""

from __future__ import annotations

import argparse
import functools
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.linalg import toeplitz

from rtsid.benchmarks.table import median_p99, print_table
from rtsid.ident.analysis import AnalysisPlan, resolve_plan
from rtsid.ident.assess import predict_torque
from rtsid.ident.correlation import auto_correlation, cross_correlation
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.front import front_end, prepare_window
from rtsid.ident.irf import IRF, estimate_irf
from rtsid.ident.legacy import fit_parameters, standard_errors
from rtsid.ident.options import EstimatorOptions
from rtsid.ident.window import back_end, estimate_window
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


STAGES = (
    "plan the analysis (once per stream)",
    "front end, compiled (detrend, FIR, correlations, EUREKA ×4)",
    "  same in numpy: prepare (detrend, FIR, decimate)",
    "  same in numpy: IRF (correlations + EUREKA ×4)",
    "back end: output-error fit, VAFs, SEs (default)",
    "back end: relative fit, compiled (fit, predictions, VAFs, SEs)",
    "  same in numpy: relative fit I, B, K",
    "  same in numpy: predictions",
    "  same in numpy: standard errors",
)
RELATIVE = EstimatorOptions(fit_method="relative")


def _staged(
    p: np.ndarray, t: np.ndarray, opts: EstimatorOptions, clock: dict[str, list[float]]
) -> None:
    def timed(name: str, func: Callable[[], Any]) -> Any:
        start = time.perf_counter()
        out = func()
        clock[name].append(time.perf_counter() - start)
        return out

    plan = timed(STAGES[0], functools.partial(resolve_plan, p, FS_HZ, opts))
    u, y, irf = timed(STAGES[1], functools.partial(front_end, p, t, FS_HZ, opts, plan))
    u_np, y_np = timed(STAGES[2], functools.partial(prepare_window, p, t, opts, plan))
    timed(
        STAGES[3],
        functools.partial(
            estimate_irf,
            u_np,
            y_np,
            plan.analysis_fs_hz,
            plan.lag,
            ridge=opts.ridge,
            refine=opts.refine,
        ),
    )
    timed(STAGES[4], functools.partial(back_end, irf, u, y, opts, plan))
    timed(STAGES[5], functools.partial(back_end, irf, u, y, RELATIVE, plan))
    fit = timed(STAGES[6], functools.partial(fit_parameters, irf, u, RELATIVE, plan))
    pred = timed(STAGES[7], functools.partial(predict_torque, irf, u, y, fit.params))
    timed(STAGES[8], functools.partial(standard_errors, irf, u, pred, fit))


def _baseline(p: np.ndarray, t: np.ndarray, plan: AnalysisPlan) -> None:
    """The source's pipeline: IRF by dense inversion, log-magnitude Nelder–Mead fit."""
    opts = EstimatorOptions(fit_method="logmag")
    u, y = prepare_window(p, t, opts, plan)
    fs_a, lag = plan.analysis_fs_hz, plan.lag
    phi_uu = auto_correlation(u, 2 * lag)
    h = np.linalg.inv(toeplitz(phi_uu)) @ cross_correlation(u, y, lag) * fs_a
    irf = IRF(h=h, fs_hz=fs_a, phi_uu=phi_uu)
    fit = fit_parameters(irf, u, opts, plan)
    predict_torque(irf, u, y, fit.params)


def _timed(func: Callable[[], Any]) -> float:
    start = time.perf_counter()
    func()
    return time.perf_counter() - start


def run(args: argparse.Namespace) -> int:
    count = min(200, args.windows) if args.quick else args.windows
    windows = _windows(count)
    opts = EstimatorOptions()
    no_se = EstimatorOptions(uncertainty=False)
    plan = resolve_plan(windows[0][0], FS_HZ, opts)  # a stream plans once
    for p, t in windows[:20]:
        estimate_window(p, t, FS_HZ, opts)  # warm caches (filter taps, DFT grids)
    clock: dict[str, list[float]] = {k: [] for k in STAGES}
    total, planned, without_se, baseline = [], [], [], []
    every_baseline = max(1, count // max(20, count // 10))
    # Interleaved: every variant sees each window under the same conditions.
    for k, (p, t) in enumerate(windows):
        total.append(_timed(functools.partial(estimate_window, p, t, FS_HZ, opts, plan=plan)))
        planned.append(_timed(functools.partial(estimate_window, p, t, FS_HZ, opts)))
        without_se.append(_timed(functools.partial(estimate_window, p, t, FS_HZ, no_se, plan=plan)))
        _staged(p, t, opts, clock)
        if k % every_baseline == 0:
            baseline.append(_timed(functools.partial(_baseline, p, t, plan)))
    base_median = median_p99(baseline)[0]
    rows = []
    for name, times in [
        *clock.items(),
        ("estimate_window (all, stream's plan)", total),
        ("estimate_window, planning its own window", planned),
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
            f"Defaults: {plan.describe()}; 3 refinement sweeps, output-error fit. "
            "The compiled front end's numpy reference is tested equal to 1e-9, as is the "
            "relative fit's compiled back end. "
            "Baseline = dense inversion IRF + Nelder–Mead log-magnitude fit (the source's method)."
        ),
    )
    return 0
