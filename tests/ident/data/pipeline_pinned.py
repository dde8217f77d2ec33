"""The numbers the window pipeline gives, pinned: cases and their regeneration.

``tests/ident/test_pipeline_pinned.py`` recomputes every case below and compares it with
``pipeline_pinned.npz``, which this script wrote. Each case is one call of the public API
(``estimate_window`` or ``sliding_estimates``) on simulated windows with fixed seeds, or on
the shared real recording; what is stored per window is its ``as_dict()`` (NaN for null), the
IRF (``irf``, ``lags_s``, ``fs_hz``), the reason a window was withheld, and for a stream the
tracked K and B. Both kernels are pinned, each with its own numbers: the compiled one and
the numpy fallback (``RTSID_NUMPY_ONLY=1``).

Regenerate (only when a change of the numbers is intended, and say so in the commit):

    PYTHONPATH=$PWD python tests/ident/data/pipeline_pinned.py

It runs itself once more with ``RTSID_NUMPY_ONLY=1`` for the numpy path's numbers; the
shared recording is read from ``../shared/data/reklab_ankle_z.npz`` beside the checkout
(``--reklab PATH`` for another place).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from rtsid.errors import NumericalError, WindowError
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.levinson import HAVE_COMPILED_KERNEL
from rtsid.ident.stream import WindowResult, sliding_estimates
from rtsid.ident.window import EstimatorOptions, Held, WindowEstimate, estimate_window
from rtsid.sim.joint import JointParameters, simulate_impedance

HERE = Path(__file__).resolve().parent
PINNED = HERE / "pipeline_pinned.npz"
REKLAB = HERE.parents[3] / "shared" / "data" / "reklab_ankle_z.npz"
FS = 2500.0
SCALARS = ("I", "B", "K", "I_se", "B_se", "K_se", "vaf", "vaf_irf", "vaf_fit")
TRACKED = ("K", "K_se", "B", "B_se")
#: A stream keeps the whole IRF of every this many windows (all keep its sum and norm).
IRF_EVERY = {"reklab": 10}
IRF_EVERY_SIMULATED = 4


def kernel() -> str:
    """Which kernel this process runs: ``"compiled"`` or ``"numpy"``."""
    return "compiled" if HAVE_COMPILED_KERNEL else "numpy"


def simulated(seed: int, seconds: float = 0.3, noise_percent: float = 10.0) -> Any:
    """Position and torque of the simulated ankle (I 0.015, B 0.8, K 150), 30 Hz noise."""
    rng = np.random.default_rng(seed)
    n = round(seconds * FS)
    theta = filtered_noise(n + 2000, FS, 30.0, peak=0.03, seed=rng)
    tau = simulate_impedance(
        theta, FS, JointParameters(0.015, 0.8, 150.0), noise_percent=noise_percent, seed=rng
    )
    return theta[1000 : 1000 + n].copy(), tau[1000 : 1000 + n].copy()


def lost_mask(n: int, seed: int, runs: int = 3, run_length: int = 4) -> Any:
    """``valid`` with a few short runs of lost samples (within the default limits)."""
    rng = np.random.default_rng(seed)
    valid = np.ones(n, dtype=bool)
    for start in rng.choice(np.arange(50, n - 50, 40), size=runs, replace=False):
        valid[start : start + run_length] = False
    return valid


def window_cases() -> Iterator[tuple[str, Callable[[], WindowEstimate]]]:
    """``estimate_window`` calls: name and a thunk."""
    p, t = simulated(1)
    valid = lost_mask(p.size, 2)
    yield "default", lambda: estimate_window(p, t, FS)
    yield "no_hold_no_se", lambda: estimate_window(p, t, FS, hold="none", uncertainty=False)
    yield "lost", lambda: estimate_window(p, t, FS, valid=valid)
    yield "held_inertia_damping", lambda: estimate_window(p, t, FS, held=Held(0.015, 0.8))
    yield "held_inertia", lambda: estimate_window(p, t, FS, hold="inertia", held=Held(0.02))
    yield "hold_inertia_option", lambda: estimate_window(p, t, FS, hold_inertia=0.018)
    yield "lost_held", lambda: estimate_window(p, t, FS, valid=valid, held=Held(0.015, 0.8))
    yield "relative", lambda: estimate_window(p, t, FS, fit_method="relative")
    yield (
        "relative_no_se",
        lambda: estimate_window(p, t, FS, fit_method="relative", uncertainty=False),
    )
    yield "relative_lost", lambda: estimate_window(p, t, FS, fit_method="relative", valid=valid)
    yield (
        "relative_held",
        lambda: estimate_window(p, t, FS, fit_method="relative", held=Held(0.015, 0.8)),
    )
    yield "logmag", lambda: estimate_window(p, t, FS, fit_method="logmag")
    yield "logmag_lost", lambda: estimate_window(p, t, FS, fit_method="logmag", valid=valid)
    yield "torque_sign", lambda: estimate_window(p, -t, FS, torque_sign=-1)
    yield (
        "explicit_plan",
        lambda: estimate_window(
            p, t, FS, lowpass_hz=60.0, analysis_fs_hz=625.0, fit_band_hz=(2.0, 40.0), lag_s=0.016
        ),
    )
    yield "mean_detrend", lambda: estimate_window(p, t, FS, detrend="mean", ridge=1e-2, refine=1)
    q, s = simulated(3, seconds=0.15, noise_percent=0.0)
    yield "short_noise_free", lambda: estimate_window(q, s, FS, lag_s=0.01)
    yield "no_excitation", lambda: estimate_window(np.zeros(750), t, FS)
    p_nan = p.copy()
    p_nan[100] = np.nan
    yield "nan", lambda: estimate_window(p_nan, t, FS)


def stream_cases(reklab: Path | None) -> Iterator[tuple[str, Callable[[], list[WindowResult]]]]:
    """``sliding_estimates`` runs: name and a thunk."""
    p, t = simulated(4, seconds=2.0)
    valid = lost_mask(p.size, 5, runs=30)
    yield "stream_default", lambda: list(sliding_estimates(p, t, FS, 0.3, 0.05))
    yield "stream_lost", lambda: list(sliding_estimates(p, t, FS, 0.3, 0.05, valid=valid))
    yield (
        "stream_hold_inertia",
        lambda: list(sliding_estimates(p, t, FS, 0.3, 0.1, EstimatorOptions(hold="inertia"))),
    )
    yield (
        "stream_no_hold",
        lambda: list(sliding_estimates(p, t, FS, 0.3, 0.1, EstimatorOptions(hold="none"))),
    )
    yield (
        "stream_relative",
        lambda: list(
            sliding_estimates(p, t, FS, 0.3, 0.1, EstimatorOptions(fit_method="relative"))
        ),
    )
    yield (
        "stream_logmag",
        lambda: list(sliding_estimates(p, t, FS, 0.3, 0.2, EstimatorOptions(fit_method="logmag"))),
    )
    yield (
        "stream_relative_lost",
        lambda: list(
            sliding_estimates(
                p, t, FS, 0.3, 0.1, EstimatorOptions(fit_method="relative"), valid=valid
            )
        ),
    )
    yield (
        "stream_torque_sign",
        lambda: list(
            sliding_estimates(-0.5 * p, 0.5 * t, FS, 0.3, 0.1, EstimatorOptions(torque_sign=-1))
        ),
    )
    if reklab is not None:
        yield (
            "reklab",
            lambda: list(
                sliding_estimates(
                    *reklab_signals(reklab), 0.3, 0.1, EstimatorOptions(torque_sign=-1)
                )
            ),
        )


def reklab_signals(path: Path) -> tuple[Any, Any, float]:
    with np.load(path) as data:
        return data["position_rad"], data["torque_nm"], float(data["fs_hz"])


def reklab_window_cases(path: Path) -> Iterator[tuple[str, Callable[[], WindowEstimate]]]:
    """Single ``estimate_window`` calls on windows of the real recording (each plans its own)."""
    pos, tor, fs = reklab_signals(path)
    for t_end in (5.0, 12.099, 40.0):
        stop = round(t_end * fs) + 1
        p, t = pos[stop - 300 : stop], tor[stop - 300 : stop]
        yield f"reklab_window_{t_end:g}", lambda p=p, t=t: estimate_window(p, t, fs, torque_sign=-1)


def record_estimate(est: WindowEstimate | None, reason: str | None) -> dict[str, Any]:
    """One window's numbers: scalars (NaN for null), texts and the IRF."""
    d = est.as_dict() if est is not None else {}
    return {
        "scalars": np.array(
            [np.nan if d.get(k) is None else d[k] for k in SCALARS], dtype=np.float64
        ),
        "texts": np.array(
            [
                "" if reason is None else str(reason),
                ",".join(str(f) for f in d.get("flags", [])),
                d.get("method", ""),
            ]
        ),
        "ints": np.array(
            [d.get("lost_samples", -1), d.get("I_held", False), d.get("B_held", False)],
            dtype=np.int64,
        ),
        "irf": np.empty(0) if est is None else est.irf,
        "lags_s": np.empty(0) if est is None else est.lags_s,
        "fs_hz": np.array(np.nan if est is None else est.fs_hz),
    }


def record_window(thunk: Callable[[], WindowEstimate]) -> dict[str, Any]:
    try:
        return record_estimate(thunk(), None)
    except WindowError as exc:
        return record_estimate(None, exc.reason)
    except NumericalError:
        return record_estimate(None, "numerical")


def record_stream(results: list[WindowResult], irf_every: int) -> dict[str, Any]:
    """A stream's numbers: one row per window; whole IRFs for every ``irf_every``-th window,
    and every window's IRF sum and norm."""
    rows = [record_estimate(r.estimate, r.reason) for r in results]
    keep = range(0, len(rows), irf_every)
    irfs = [rows[i]["irf"] for i in keep]
    width = max((irf.size for irf in irfs), default=0)
    return {
        "scalars": np.stack([r["scalars"] for r in rows]),
        "texts": np.stack([r["texts"] for r in rows]),
        "ints": np.stack([r["ints"] for r in rows]),
        "t_end_s": np.array([r.t_end_s for r in results]),
        "tracked": np.array(
            [
                [np.nan] * 4 if r.track is None else [getattr(r.track, k) for k in TRACKED]
                for r in results
            ]
        ),
        "irf_rows": np.array(list(keep), dtype=np.int64),
        "irf": np.array(
            [np.pad(irf, (0, width - irf.size), constant_values=np.nan) for irf in irfs]
        ),
        "irf_sum": np.array([np.sum(r["irf"]) if r["irf"].size else np.nan for r in rows]),
        "irf_norm": np.array([np.linalg.norm(r["irf"]) if r["irf"].size else np.nan for r in rows]),
        "fs_hz": np.array([r["fs_hz"] for r in rows]),
    }


def outcomes(reklab: Path | None) -> dict[str, dict[str, Any]]:
    """Every case's numbers in this process's kernel, by case name."""
    out = {name: record_window(thunk) for name, thunk in window_cases()}
    if reklab is not None:
        out.update({name: record_window(thunk) for name, thunk in reklab_window_cases(reklab)})
    for name, thunk in stream_cases(reklab):
        out[name] = record_stream(thunk(), IRF_EVERY.get(name, IRF_EVERY_SIMULATED))
    return out


def flatten(prefix: str, cases: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """``{"<kernel>/<case>/<field>": array}``, the npz's keys."""
    return {
        f"{prefix}/{case}/{key}": value for case, d in cases.items() for key, value in d.items()
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--reklab", type=Path, default=REKLAB)
    parser.add_argument("--part", help=argparse.SUPPRESS)  # the child that writes one kernel
    args = parser.parse_args()
    if not args.reklab.exists():
        sys.exit(f"the shared recording is not at {args.reklab}; pass --reklab PATH")
    if args.part:
        np.savez_compressed(args.part, **flatten(kernel(), outcomes(args.reklab)))
        return
    arrays: dict[str, Any] = {}
    for numpy_only in ("0", "1"):
        part = HERE / f".pinned_{numpy_only}.npz"
        env = {**os.environ, "RTSID_NUMPY_ONLY": numpy_only}
        cmd = [sys.executable, __file__, "--reklab", str(args.reklab), "--part", str(part)]
        subprocess.run(cmd, check=True, env=env)
        with np.load(part) as data:
            arrays.update({key: data[key] for key in data.files})
        part.unlink()
    kernels = sorted({key.split("/")[0] for key in arrays})
    if kernels != ["compiled", "numpy"]:
        sys.exit(f"expected numbers of both kernels, got {kernels} (is the kernel built?)")
    np.savez_compressed(PINNED, **arrays)
    print(f"wrote {PINNED} ({PINNED.stat().st_size} bytes, {len(arrays)} arrays)")


if __name__ == "__main__":
    main()
