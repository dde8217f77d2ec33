"""``rtsid bench toeplitz``: EUREKA against dense inversion and scipy, the source's table.

The source reports, for its own EUREKA: n = 800: 15 ms (inversion 28 ms); n = 6400: 0.50 s
(2.4 s); n = 12800: 2.17 s (15.8 s). All solvers here get the same positive-definite
system (biased autocorrelation of low-pass noise) and right-hand side.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.linalg import solve_toeplitz, toeplitz

from rtsid.benchmarks.table import median_p99, print_table, time_calls
from rtsid.ident.correlation import auto_correlation, cross_correlation
from rtsid.ident.levinson import HAVE_COMPILED_KERNEL, eureka, eureka_numpy

SIZES = (100, 200, 400, 800, 1600, 3200, 6400, 12800)
SOURCE_MS = {800: (15.0, 28.0), 6400: (500.0, 2400.0), 12800: (2170.0, 15800.0)}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--dense-max", type=int, default=3200, help="largest n for dense inversion (3200)"
    )
    parser.add_argument("--sizes", type=int, nargs="+", help="system sizes (default 100…12800)")


def _system(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = np.convolve(rng.standard_normal(4 * n + 64), np.ones(4) / 4, mode="same")
    y = np.convolve(u, rng.standard_normal(16), mode="same")
    half = (n - 1) // 2
    r = auto_correlation(u, n - 1)
    r[0] *= 1.0 + 1e-6
    b = cross_correlation(u, y, half)
    return r, np.resize(b, n)


def _dense_inverse(r: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.inv(toeplitz(r)) @ b


def _row(n: int, dense_max: int, quick: bool) -> list[object]:
    r, b = _system(n)
    budget = 0.05 if quick else 0.3
    solvers = {
        "eureka": lambda: eureka(r, b),
        "numpy": lambda: eureka_numpy(r, b),
        "scipy": lambda: solve_toeplitz(r, b),
    }
    if n <= dense_max:
        solvers["inverse"] = lambda: _dense_inverse(r, b)
    ms = {}
    for name, func in solvers.items():
        median, p99 = median_p99(time_calls(func, min_calls=3, min_total_s=budget))
        ms[name] = (median * 1e3, p99 * 1e3)
    inv = ms.get("inverse", (float("nan"),) * 2)[0]
    src = SOURCE_MS.get(n, (float("nan"), float("nan")))
    error = float(np.max(np.abs(eureka(r, b) - solve_toeplitz(r, b))) / np.max(np.abs(b)))
    return [
        n,
        ms["eureka"][0],
        ms["eureka"][1],
        ms["numpy"][0],
        ms["scipy"][0],
        inv,
        ms["scipy"][0] / ms["eureka"][0],
        inv / ms["eureka"][0],
        src[0],
        src[1],
        error,
    ]


def run(args: argparse.Namespace) -> int:
    sizes = args.sizes or (SIZES[:5] if args.quick else SIZES)
    rows = [_row(n, args.dense_max, args.quick) for n in sizes]
    print_table(
        "Toeplitz solve R·x = b: milliseconds per solve (median; p99)",
        [
            "n",
            "EUREKA C",
            "p99",
            "EUREKA numpy",
            "scipy",
            "inverse",
            "scipy/EUREKA",
            "inverse/EUREKA",
            "source EUREKA",
            "source inverse",
            "max rel diff",
        ],
        rows,
        note=(
            f"EUREKA C = compiled kernel (built: {HAVE_COMPILED_KERNEL}), the default; "
            "'inverse' = numpy.linalg.inv(toeplitz(r)) @ b; source columns quote its paper. "
            f"Dense inversion is skipped above n = {args.dense_max} (--dense-max)."
        ),
    )
    return 0
