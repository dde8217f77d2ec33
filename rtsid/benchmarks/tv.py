"""``rtsid bench tv``: one benchmark across the time-varying methods (issue 14).

Simulated ankle, K(t) profiles: constant 150 N·m/rad; a square wave (K ×2 for 2 s, then
back); sinusoids 150 ± 50 N·m/rad at 0.1–2 Hz; the source's ramp (+150 % within one 300 ms
window, held 2 s, and back); a slow drift (150 → 250 N·m/rad over the record). I drawn in
0.015–0.03 kg·m² per realisation, B = 0.8 N·m·s/rad, 10 % torque noise, position
perturbation band-limited at 20 and 40 Hz (one table section each), 2500 Hz.

Methods, all at the 20 ms hop grid of window ends (what a user has at each moment):

* ``window 150/300/600 ms`` — the per-window output-error estimates (:func:`sliding_estimates`),
  each published at its window's end;
* ``tracker`` — ``K_track`` of the 300 ms stream (:mod:`rtsid.ident.tracker`, defaults),
  which reads a step from the window's samples (:mod:`rtsid.ident.split`);
* ``oracle 300 ms`` — the true K averaged over each 300 ms window, at its end: the best any
  300 ms windowed estimate can be (no noise, only the window's smearing);
* ``oracle step read-out`` (square wave only) — a bound for any tracker of the 300 ms
  window *estimates* on a step (the tracker, reading the samples, can beat it): it is *told*
  the step instants, and ``j`` hops after a step publishes
  ``K_old + a_j·(z − K_old) + b_j·(z − z_prev)`` with ``(a_j, b_j)`` least-squares fitted to
  the true K over every step of every realisation (hindsight, in sample); nothing at the
  window ending at the step (it holds no sample after it); the mean of the windows since the
  last ramp (≤ 1 s) elsewhere. A causal tracker has to detect the step first.
* ``skirt <family> N_p=…`` — skirt decomposition (offline) of a torque-driven multisine
  experiment on the same plant and K(t) (500 Hz, 2 Hz line spacing to 40 Hz, 20 dB output
  SNR), one row per basis family of :data:`~rtsid.ident.skirt.BASIS_FAMILIES` at the N_p
  :func:`~rtsid.ident.skirt.select_basis_size` chooses from the record (as
  ``rtsid tv -p auto --basis-family F``), its frozen second-order K at the same times.

Metrics over realisations r and times t after the first 2 s (van de Ruit et al. 2021):
bias = RMS over t of the mean error over r; random = RMS over t of the SD over r; total =
RMS over t and r; rise = median 10–90 % rise time over the square wave's steps (mean track
over r); VAF = torque of a fresh realisation predicted with the method's K(t) (true I, B),
against its noiseless torque. Then the tracker on the shared human recording (no true K: its
spread and hop-to-hop jumps against the windows', and the parallel-cascade intrinsic K of the
record as the reference level), and the tracker's cost per hop against the window
estimate's.
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from rtsid.benchmarks.real import DEFAULT_DATA, TORQUE_SIGN
from rtsid.benchmarks.table import format_table, median_p99
from rtsid.errors import NumericalError
from rtsid.ident.cascade import CascadeSettings, fit_parallel_cascade, intrinsic_parameters
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.filters import derivatives
from rtsid.ident.skirt import BASIS_FAMILIES, SkirtConditioningWarning, select_basis_size
from rtsid.ident.stream import WindowStream, sliding_estimates
from rtsid.ident.window import EstimatorOptions
from rtsid.ident.yardstick import least_squares_window
from rtsid.io.sample_files import load_samples
from rtsid.sim.joint import JointParameters, StiffnessProfile, add_noise
from rtsid.sim.ltv import multisine_experiment

FS_HZ = 2500.0
HOP_S = 0.02
K0 = 150.0
DAMPING = 0.8
SETTLE_S = 2.0
WINDOWS_S = (0.15, 0.3, 0.6)
#: Skirt basis families benchmarked (one column each).
SKIRT_FAMILIES: tuple[str, ...] = BASIS_FAMILIES
SINE_HZ = (0.1, 0.25, 0.5, 1.0, 2.0)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--figures", metavar="DIR", help="write one K(t) PNG per profile here")
    parser.add_argument("--seconds", type=float, default=20.0, help="record length, s (20)")
    parser.add_argument(
        "--realisations", type=int, default=3, help="realisations per profile and band (3)"
    )
    parser.add_argument(
        "--data", default=str(DEFAULT_DATA), help="the human recording for the real-data table"
    )


@dataclass(frozen=True)
class Profile:
    """K(t), N·m/rad, as a function of time (s)."""

    name: str
    at: Callable[[np.ndarray], np.ndarray]


def profiles(seconds: float) -> list[Profile]:
    """The benchmark's stiffness profiles over a record of ``seconds``."""

    def square(t: np.ndarray) -> np.ndarray:
        return np.where((t % 4.0) < 2.0, K0, 2 * K0)

    def ramp(t: np.ndarray) -> np.ndarray:  # +150 % within 0.3 s, held 2 s, back
        phase = t % 4.6
        up = np.clip(phase / 0.3, 0, 1) - np.clip((phase - 2.3) / 0.3, 0, 1)
        return K0 * (1 + 1.5 * up)

    out = [
        Profile("constant", lambda t: np.full_like(t, K0)),
        Profile("square 2 s", square),
    ]
    for f in SINE_HZ:
        out.append(Profile(f"sine {f:g} Hz", StiffnessProfile.sinusoid(K0, 50.0, f).at))
    out.append(Profile("ramp +150 %/0.3 s", ramp))
    out.append(Profile("drift", StiffnessProfile.ramp(K0, K0 + 100.0, 0.0, seconds).at))
    return out


def _record(profile: Profile, band_hz: float, seconds: float, seed: int) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    n = round(seconds * FS_HZ)
    theta = filtered_noise(n, FS_HZ, band_hz, peak=0.03, seed=rng)
    inertia = float(rng.uniform(0.015, 0.03))
    t = np.arange(n) / FS_HZ
    d1, d2 = derivatives(theta, FS_HZ)
    clean = inertia * d2 + DAMPING * d1 + profile.at(t) * theta
    torque = add_noise(clean, 10.0, seed=rng)
    return {"theta": theta, "torque": torque, "clean": clean, "d1": d1, "d2": d2, "I": inertia}


def _causal_tracks(rec: dict[str, Any], profile: Profile) -> dict[str, np.ndarray]:
    """Window estimates (each length), the tracker and the oracle at the 300 ms windows' ends."""
    runs = {
        w: list(sliding_estimates(rec["theta"], rec["torque"], FS_HZ, w, HOP_S)) for w in WINDOWS_S
    }
    base = runs[0.3]
    t_end = np.array([r.t_end_s for r in base])
    tracks = {"_t": t_end}
    for window_s, results in runs.items():
        by_end = {r.stop: (r.estimate.K if r.estimate else np.nan) for r in results}
        tracks[f"window {window_s * 1e3:.0f} ms"] = np.array(
            [by_end.get(r.stop, np.nan) for r in base]
        )
    tracks["tracker"] = np.array([r.track.K if r.track else np.nan for r in base])
    tracks["_truth"] = profile.at(t_end)
    fine = np.arange(round(0.3 * FS_HZ)) / FS_HZ
    tracks["oracle 300 ms"] = np.array([profile.at(t - 0.3 + fine).mean() for t in t_end])
    return tracks


def _add_step_oracle(tracks: list[dict[str, np.ndarray]]) -> None:
    """Add ``oracle step read-out`` to each realisation's tracks if the profile has steps."""
    truth = tracks[0]["_truth"]
    steps = np.flatnonzero(np.abs(np.diff(truth)) > 0.5 * K0) + 1  # first window at/after
    if steps.size == 0:
        return
    m = round(0.3 / HOP_S)
    settle = round(1.0 / HOP_S)
    windows = [np.nan_to_num(tr["window 300 ms"], nan=K0) for tr in tracks]
    olds = [
        {int(k0): float(z[max(0, k0 - settle) : k0].mean()) for k0 in steps if k0 > 1}
        for z in windows
    ]
    gains = {}
    for j in range(1, m + 1):
        rows, target = [], []
        for z, old in zip(windows, olds, strict=True):
            for k0, k_old in old.items():
                if k0 + j < z.size:
                    rows.append([z[k0 + j] - k_old, z[k0 + j] - z[k0 + j - 1]])
                    target.append(truth[k0 + j] - k_old)
        if rows:
            gains[j] = np.linalg.lstsq(np.array(rows), np.array(target), rcond=None)[0]
    for tr, z, old in zip(tracks, windows, olds, strict=True):
        out = np.empty(z.size)
        last = 0  # first window after the latest ramp
        for k in range(z.size):
            k0 = int(steps[steps <= k].max()) if (steps <= k).any() else -1
            j = k - k0
            if k0 in old and j <= m:
                gain = gains.get(j)
                step = 0.0 if gain is None else gain @ [z[k] - old[k0], z[k] - z[k - 1]]
                out[k] = old[k0] + step
                last = k
            else:
                out[k] = z[max(last, k - settle) : k + 1].mean()
        tr["oracle step read-out"] = out


def _skirt_tracks(profile: Profile, seconds: float, t_s: np.ndarray) -> dict[str, np.ndarray]:
    """K(t) of the skirt decomposition, one track per basis family, at times ``t_s``."""
    exp = multisine_experiment(
        cast(StiffnessProfile, profile),  # anything with at(t)
        joint=JointParameters(0.02, DAMPING, K0),
        fs_hz=500.0,
        period_s=2.0,
        n_periods=max(1, round(seconds / 2.0)),
        f_max_hz=40.0,
        spacing_hz=2.0,
        snr_db=20.0,
        seed=7,
    )
    out = {}
    for family in SKIRT_FAMILIES:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SkirtConditioningWarning)
            try:
                chosen = select_basis_size(
                    exp.torque_nm,
                    exp.position_rad,
                    exp.fs_hz,
                    exp.excited_bins,
                    exp.period_samples,
                    basis_family=family,
                )
            except NumericalError:
                out[f"skirt {family} (no fit)"] = np.full(t_s.size, np.nan)
                continue
        est = chosen.estimate
        k = est.fit_second_order(np.clip(t_s, 0, est.duration_s)).stiffness
        out[f"skirt {family} N_p={chosen.n_basis}"] = np.asarray(k)
    return out


def _rise_time(t: np.ndarray, k: np.ndarray, truth: np.ndarray) -> float:
    """Median 10–90 % rise time (s) over the steps of ``truth``, each crossing placed by
    linear interpolation between the hops around it (a jump within one hop rises in 0.8
    of a hop)."""
    steps = np.flatnonzero(np.abs(np.diff(truth)) > 0.5 * K0)
    rises = []
    for i in steps:
        lo, hi = truth[i], truth[i + 1]
        frac = (k[i : min(k.size, i + 1 + round(1.5 / HOP_S))] - lo) / (hi - lo)
        t10, t90 = _crossing(frac, 0.1), _crossing(frac, 0.9)
        if np.isfinite(t10) and np.isfinite(t90):
            rises.append((t90 - t10) * HOP_S)
    return float(np.median(rises)) if rises else float("nan")


def _crossing(frac: np.ndarray, level: float) -> float:
    """Where ``frac`` (one value per hop, the first before the step) first reaches
    ``level``, in hops, interpolated; NaN if it never does."""
    above = np.flatnonzero(frac[1:] >= level) + 1
    if above.size == 0:
        return float("nan")
    j = int(above[0])
    before = min(frac[j - 1], level) if np.isfinite(frac[j - 1]) else level
    return j - (frac[j] - level) / max(frac[j] - before, 1e-12)


def _vaf(rec: dict[str, Any], t_est: np.ndarray, k_est: np.ndarray) -> float:
    """VAF (%) of a fresh realisation's torque predicted with K(t) held between estimates."""
    n = rec["theta"].size
    t = np.arange(n) / FS_HZ
    ok = np.isfinite(k_est)
    if not ok.any():
        return float("nan")
    idx = np.clip(np.searchsorted(t_est[ok], t, side="right") - 1, 0, ok.sum() - 1)
    k = k_est[ok][idx]
    keep = t >= SETTLE_S
    pred = rec["I"] * rec["d2"] + DAMPING * rec["d1"] + k * rec["theta"]
    err = (rec["clean"] - pred)[keep]
    return float(100 * (1 - np.var(err) / np.var(rec["clean"][keep])))


def _metrics(t: np.ndarray, runs: list[np.ndarray], truth: np.ndarray) -> tuple[float, ...]:
    keep = t >= SETTLE_S
    err = np.array(runs)[:, keep] - truth[keep]
    bias = float(np.sqrt(np.nanmean(np.nanmean(err, axis=0) ** 2)))
    random = float(np.sqrt(np.nanmean(np.nanvar(err, axis=0)))) if len(runs) > 1 else np.nan
    total = float(np.sqrt(np.nanmean(err**2)))
    return bias, random, total


def run(args: argparse.Namespace) -> int:
    seconds = 8.0 if args.quick else args.seconds
    reps = 2 if args.quick else args.realisations
    print(
        f"bench tv: {seconds:g} s at {FS_HZ:g} Hz, K0 = {K0:g} N·m/rad, B = {DAMPING}, I in "
        f"0.015–0.03, 10 % torque noise, {reps} realisations per profile and band; errors after "
        f"{SETTLE_S:g} s against the true K at each 300 ms window's end (publication time)\n"
    )
    rows: list[list[Any]] = []
    figures: dict[str, dict[str, Any]] = {}
    for profile in profiles(seconds):
        for band in (20.0, 40.0):
            recs = [_record(profile, band, seconds, 1000 * r + int(band)) for r in range(reps)]
            tracks = [_causal_tracks(rec, profile) for rec in recs]
            _add_step_oracle(tracks)
            t = tracks[0]["_t"]
            truth = profile.at(t)
            validation = _record(profile, band, seconds, 999_999)
            methods = [k for k in tracks[0] if not k.startswith("_")]
            skirt = _skirt_tracks(profile, seconds, t) if band == 40.0 else {}
            for name in (*methods, *skirt):
                runs = [tr[name] for tr in tracks] if name in methods else [skirt[name]]
                with warnings.catch_warnings():  # times no realisation estimated (a long
                    warnings.simplefilter("ignore", RuntimeWarning)  # window's start): NaN
                    bias, random, total = _metrics(t, runs, truth)
                    mean_track = np.nanmean(runs, axis=0)
                rise = _rise_time(t, mean_track, truth)
                vaf = _vaf(validation, t, mean_track)
                rows.append([profile.name, f"{band:g}", name, bias, random, total, rise, vaf])
            if band == 40.0:
                figures[profile.name] = {"t": t, "truth": truth, **tracks[0], **skirt}
    table = format_table(
        "K(t) across methods: error N·m/rad, rise s (10–90 %, square wave), validation VAF %",
        ["profile", "band Hz", "method", "bias", "random", "total", "rise s", "VAF %"],
        [[_fmt(v) for v in row] for row in rows],
    )
    print(table)
    print(_floors(rows))
    print(_real_record_table(Path(args.data), 10.0 if args.quick else None))
    print(_cost_table())
    if args.figures:
        for path in _write_figures(Path(args.figures), figures):
            print(f"wrote {path}")
    return 0


def _fmt(v: Any) -> Any:
    if isinstance(v, float):
        return "nan" if not np.isfinite(v) else f"{v:.3g}" if abs(v) < 100 else f"{v:.1f}"
    return v


def _floors(rows: list[list[Any]]) -> str:
    """Tracker against windowed 300 ms in the same run: total-error ratios and rise time."""
    by = {(r[0], r[1], r[2]): r for r in rows}
    lines = ["", "floors (tracker vs window 300 ms, same run):"]
    checks = (("constant", 0.5), ("sine 0.25 Hz", 0.7), ("square 2 s", 0.7))
    for band in ("20", "40"):
        for profile, limit in checks:
            trk, win = by[(profile, band, "tracker")], by[(profile, band, "window 300 ms")]
            ratio = trk[5] / win[5]
            verdict = "ok" if ratio <= limit else "NOT MET"
            lines.append(
                f"  {profile:13s} {band} Hz: total {trk[5]:.3g} / {win[5]:.3g} = {ratio:.2f}× "
                f"(floor ≤ {limit}×) {verdict}"
            )
            bound = by.get((profile, band, "oracle step read-out"))
            if bound is not None:
                lines.append(
                    f"    oracle step read-out (told the steps, fitted in hindsight, reads the "
                    f"window estimates only) {bound[5] / win[5]:.2f}×"
                )
        rise = by[("square 2 s", band, "tracker")][6]
        verdict = "ok" if rise <= 0.3 else "NOT MET"
        lines.append(f"  square rise {band} Hz: {rise * 1e3:.0f} ms (floor ≤ 300 ms) {verdict}")
    return "\n".join(lines)


def _real_record_table(path: Path, seconds: float | None) -> str:
    """The tracker on the shared human recording (no true K): its spread and hop-to-hop
    jumps against the 300 ms windows it filters, every 20 ms, with per-window least squares
    on the same windows and the parallel-cascade model's intrinsic K of the whole record as
    the references."""
    if not path.exists():
        return f"\nreal record: {path} not found, table skipped (pass --data PATH)"
    record = load_samples(path)
    n = record.position_rad.size if seconds is None else round(seconds * record.fs_hz)
    pos, tor, fs = record.position_rad[:n], record.torque_nm[:n], record.fs_hz
    stream = WindowStream(fs, EstimatorOptions(torque_sign=TORQUE_SIGN), HOP_S, window_s=0.3)
    window, track, least_squares, changes, splitting = [], [], [], 0, False
    for r in sliding_estimates(pos, tor, fs, 0.3, HOP_S, stream=stream):
        window.append(r.estimate.K if r.estimate else np.nan)
        signed = TORQUE_SIGN * tor[r.start : r.stop]
        least_squares.append(least_squares_window(pos[r.start : r.stop], signed, fs)[2])
        track.append(r.track.K if r.track else np.nan)
        changes += stream.tracker.stiffness.splitting and not splitting
        splitting = stream.tracker.stiffness.splitting
    cascade = fit_parallel_cascade(pos, TORQUE_SIGN * tor, fs, CascadeSettings())
    k_cascade = intrinsic_parameters(pos, TORQUE_SIGN * tor, fs, cascade.reflex).K
    rows = [
        _spread_row("window 300 ms", np.array(window)),
        _spread_row("least squares, same windows (reference)", np.array(least_squares)),
        _spread_row("tracker", np.array(track)),
    ]
    rows.append(["parallel cascade, whole record (reference)", f"{k_cascade:.1f}", *["—"] * 5])
    return "\n" + format_table(
        f"real record ({n / fs:g} s, every {HOP_S * 1e3:g} ms; {changes} change modes read "
        "from the samples): K N·m/rad",
        ["K of", "median", "IQR", "p1", "p99", "|ΔK| per hop p50", "|ΔK| p99"],
        rows,
    )


def _spread_row(name: str, k: np.ndarray) -> list[str]:
    q = np.nanpercentile(k, [1, 25, 50, 75, 99])
    jumps = np.nanpercentile(np.abs(np.diff(k)), [50, 99])
    return [name, f"{q[2]:.1f}", f"{q[3] - q[1]:.1f}", f"{q[0]:.1f}", f"{q[4]:.1f}"] + [
        f"{j:.2f}" for j in jumps
    ]


def _cost_table() -> str:
    """Tracker update (the window's newest hop, its split scan and both parameters'
    filters) vs window estimate, per hop, measured in the same run (µs), on the square
    wave."""
    rec = _record(profiles(4.0)[1], 40.0, 4.0, 5)
    stream = WindowStream(FS_HZ, EstimatorOptions(), HOP_S, window_s=0.3)
    n_win, n_hop = round(0.3 * FS_HZ), round(HOP_S * FS_HZ)
    window_us, track_us = [], []
    for end in range(n_win, rec["theta"].size, n_hop):
        start = time.perf_counter()
        est = stream.estimate(rec["theta"][end - n_win : end], rec["torque"][end - n_win : end])
        window_us.append((time.perf_counter() - start) * 1e6)
        start = time.perf_counter()
        stream.track(end / FS_HZ, est)
        track_us.append((time.perf_counter() - start) * 1e6)
    wm, wp = median_p99(window_us)
    tm, tp = median_p99(track_us)
    return "\n" + format_table(
        f"cost per hop, µs ({len(track_us)} hops)",
        ["step", "median", "p99", "median / window"],
        [
            ["window estimate (300 ms)", f"{wm:.0f}", f"{wp:.0f}", "1"],
            [
                "tracker update (newest hop, split scan, K, B)",
                f"{tm:.1f}",
                f"{tp:.1f}",
                f"{tm / wm:.3f}",
            ],
        ],
    )


def _write_figures(out_dir: Path, figures: dict[str, dict[str, Any]]) -> list[Path]:
    from rtsid.plots import require_matplotlib

    plt = require_matplotlib()
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, data in figures.items():
        fig, ax = plt.subplots(figsize=(10, 4))
        ax.plot(data["t"], data["truth"], "k", lw=2, label="true K")
        for key, values in data.items():
            if key in ("t", "truth") or key.startswith("_"):
                continue
            ax.plot(data["t"], values, lw=1, label=key)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("K (N·m/rad)")
        ax.set_title(f"K(t): {name}, 40 Hz perturbation")
        ax.legend(fontsize=7, ncol=3)
        path = out_dir / f"tv_{name.replace(' ', '_').replace('/', '_').replace('%', 'pct')}.png"
        fig.savefig(path, dpi=100, bbox_inches="tight")
        plt.close(fig)
        paths.append(path)
    return paths
