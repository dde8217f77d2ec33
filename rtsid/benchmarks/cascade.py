"""``rtsid bench cascade``: intrinsic and reflex stiffness, whole records, windows, the slow lane.

1. The shared recording, whole record, on the field's basis (torque decimated to 100 Hz, VAF
   after the first reflex-IRF length): an intrinsic IRF alone, the parallel cascade (rect
   and Hammerstein reflex pathways) and plain I/B/K least squares.
2. The shared recording, 300 ms windows every 100 ms through the daemon's own code
   (:func:`rtsid.replay.replay_batches`): the fast lane alone, the fast lane with the slow
   lane (its reflex prediction subtracted, and added back to score the window's model), and
   per-window least squares, on the window VAF basis of ``rtsid bench real``.
3. The simulated ankle with a known stretch reflex (gain 10 N·m·s/rad, 40 ms, 3 Hz; 10 %
   torque noise): errors of the cascade's intrinsic I, B, K, reflex gain and delay against
   plain least squares (no reflex model) on the same records; and the windows' K error with
   and without the slow lane.
4. Cost: one slow-lane update (20 s at 2500 Hz) and the fast lane's per-window reflex
   prediction, against one window estimate measured in the same run.
"""

from __future__ import annotations

import argparse
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rtsid.benchmarks.real import DEFAULT_DATA, TORQUE_SIGN
from rtsid.benchmarks.table import median_p99, print_table, time_calls
from rtsid.errors import InputDataError
from rtsid.ident.cascade import CascadeSettings, fit_parallel_cascade, intrinsic_parameters
from rtsid.ident.reflex import ReflexPathway, ReflexStream, decimated
from rtsid.ident.reflex_lane import SlowLaneSettings, fit_reflex_update, predict_reflex_torque
from rtsid.ident.vaf import vaf
from rtsid.ident.window import EstimatorOptions, estimate_window
from rtsid.ident.yardstick import WindowVafBasis, least_squares_window, savgol_derivatives
from rtsid.io.sample_files import load_samples
from rtsid.io.schemas import SampleBatch
from rtsid.replay import ReplayResult, replay_batches
from rtsid.runtime.daemon import DaemonConfig
from rtsid.runtime.worker import WindowEvaluator
from rtsid.sim.joint import JointParameters, derivatives
from rtsid.sim.reflex import ReflexParameters, prbs_ankle_with_reflex

SIM_FS = 2500.0
SIM_JOINT = JointParameters(0.015, 0.8, 150.0)
SIM_REFLEX = ReflexParameters(gain=10.0, delay_s=0.04, corner_hz=3.0, damping_ratio=0.7)
FLOORS = {"K": 5.0, "gain": 15.0, "delay_ms": 5.0}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", default=str(DEFAULT_DATA), help="the .npz recording")
    parser.add_argument("--seeds", type=int, default=10, help="simulated records (10)")


def run(args: argparse.Namespace) -> int:
    if not Path(args.data).exists():
        raise InputDataError(f"{args.data}: recording not found; pass --data PATH")
    record = load_samples(args.data)
    pos, tor = record.position_rad, TORQUE_SIGN * record.torque_nm
    _whole_record_table(pos, tor, record.fs_hz)
    _window_table(pos, record.torque_nm, record.fs_hz)
    seeds = 3 if args.quick else args.seeds
    _simulation_tables(seeds, 20.0 if not args.quick else 12.0)
    _cost_table()
    return 0


# ----------------------------------------------------------------------------- 1. whole record
def _plain_vaf_on_field_basis(pos: np.ndarray, tor: np.ndarray, fs: float, skip: int) -> float:
    """VAF of whole-record I/B/K least squares, scored as the cascade is (100 Hz, after
    ``skip`` samples)."""
    d1, d2 = savgol_derivatives(pos, fs)
    i, b, k = least_squares_window(pos, tor, fs)
    factor = max(1, round(fs / 100.0))
    measured = decimated(tor - tor.mean(), factor)
    predicted = decimated(i * d2 + b * d1 + k * pos, factor)
    return vaf(measured[skip:], predicted[skip:])


def _whole_record_table(pos: np.ndarray, tor: np.ndarray, fs: float) -> None:
    rows = []
    k_plain = float(least_squares_window(pos, tor, fs)[2])
    for variant in ("rect", "hammerstein"):
        fit = fit_parallel_cascade(pos, tor, fs, CascadeSettings(variant=variant))
        intrinsic = intrinsic_parameters(pos, tor, fs, fit.reflex)
        rows.append(
            [
                f"parallel cascade ({variant})",
                fit.vaf_total,
                intrinsic.K,
                fit.reflex.gain,
                fit.reflex.delay_s * 1e3,
                fit.reflex.dynamics.vaf,
            ]
        )
    rows.insert(0, ["intrinsic IRF alone", fit.vaf_intrinsic_only, "—", "—", "—", "—"])
    plain = _plain_vaf_on_field_basis(pos, tor, fs, fit.first_scored)
    rows.append(["plain I/B/K least squares (reference)", plain, k_plain, "—", "—", "—"])
    print_table(
        "Shared recording, whole record (torque at 100 Hz, VAF after the first second)",
        [
            "model",
            "VAF %",
            "intrinsic K N·m/rad",
            "reflex gain N·m·s/rad",
            "delay ms",
            "low-pass fits IRF %",
        ],
        rows,
        note="Floor: cascade VAF ≥ 92 %. The intrinsic K of a cascade is the output-error fit "
        "to the torque with the reflex prediction removed; the plain row's K is least squares "
        "on the measured torque.",
    )


# ----------------------------------------------------------------------------- 2. windows
@dataclass
class _Windows:
    params: list[np.ndarray]
    bounds: list[tuple[int, int]]
    reflex: list[np.ndarray | None]
    vaf: list[float] = field(default_factory=list)  # the published vaf (NaN: withheld)
    fits: list[dict[str, Any]] = field(default_factory=list)  # the slow lane's /reflex


def array_batch(position: np.ndarray, torque: np.ndarray, fs: float) -> SampleBatch:
    """A whole record as one batch of valid samples (the replay's input)."""
    n = position.size
    return SampleBatch(0, fs, position, torque, np.ones(n, dtype=bool), np.zeros(n, dtype=np.uint8))


def record_config(fs: float, torque_sign: float, slow_lane: bool, **lane: Any) -> DaemonConfig:
    """The daemon's defaults for a record at ``fs`` (300 ms windows every 100 ms)."""
    return DaemonConfig.from_mapping(
        {
            "link": {"fs_hz": fs, "ring_capacity_s": 60.0},
            "plant": {"fs_hz": fs},
            "estimator": {"torque_sign": torque_sign},
            "worker": {"hop_s": 0.1},
            "slow_lane": {"enabled": slow_lane, **lane},
        }
    )


def replay_windows(position: np.ndarray, torque: np.ndarray, config: DaemonConfig) -> _Windows:
    """Every window's I/B/K and the reflex torque subtracted in it (signed), in order."""
    fs = config.link.fs_hz
    result = ReplayResult(source="array", samples=position.size)
    reflex: list[np.ndarray | None] = []

    def keep_reflex(evaluator: WindowEvaluator) -> None:
        used = evaluator.last_reflex.torque
        reflex.append(None if used is None else config.estimator.torque_sign * used)

    replay_batches([array_batch(position, torque, fs)], config, result, evaluated=keep_reflex)
    params = [
        np.array([m["I"], m["B"], m["K"]]) if m["ok"] else np.full(3, np.nan)
        for m in result.messages
    ]
    bounds = [(m["window_start_index"], m["window_end_index"] + 1) for m in result.messages]
    vafs = [m["vaf"] if m["ok"] else float("nan") for m in result.messages]
    return _Windows(params, bounds, reflex, vafs, result.reflex)


def _scores(windows: _Windows, basis: WindowVafBasis, with_reflex: bool) -> dict[str, float]:
    vafs = np.array(
        [
            basis.vaf(p, a, b, r if with_reflex else None)
            for p, (a, b), r in zip(windows.params, windows.bounds, windows.reflex, strict=True)
        ]
    )
    ok = np.isfinite(vafs)
    k = np.array([p[2] for p in windows.params])[ok]
    q25, q50, q75 = np.percentile(k, [25, 50, 75])
    return {
        "median window VAF %": float(np.median(vafs[ok])),
        "windows below 50 % (%)": float(100 * np.mean(vafs[ok] < 50)),
        "K median N·m/rad": float(q50),
        "K IQR / median %": float(100 * (q75 - q25) / q50),
        "windows with a reflex model": float(sum(r is not None for r in windows.reflex)),
    }


def _window_table(pos: np.ndarray, raw_torque: np.ndarray, fs: float) -> None:
    signed = TORQUE_SIGN * raw_torque
    basis = WindowVafBasis(pos, signed, fs)
    alone = replay_windows(pos, raw_torque, record_config(fs, TORQUE_SIGN, False))
    lane = replay_windows(pos, raw_torque, record_config(fs, TORQUE_SIGN, True))
    reference = _Windows(
        [least_squares_window(pos[a:b], signed[a:b], fs) for a, b in alone.bounds],
        alone.bounds,
        [None] * len(alone.bounds),
    )
    columns = {
        "fast lane alone": _scores(alone, basis, False),
        "defaults (the slow lane decides)": _scores(lane, basis, True),
        "least squares (reference)": _scores(reference, basis, False),
    }
    quantities = list(next(iter(columns.values())))
    print_table(
        "Shared recording, 300 ms windows every 100 ms (the daemon's code; window VAF basis "
        "of bench real: torque low-passed at 40 Hz, each window's own model)",
        ["quantity", *columns],
        [[q, *(c[q] for c in columns.values())] for q in quantities],
        note="With the slow lane a window's model is its I/B/K plus the reflex torque the fast "
        "lane subtracted (the slow lane's 20 s rect cascade, refitted every 2 s, applied 1 s "
        "after its data end, and only while it judges a reflex present; no model during the "
        f"first 4 s). Fits judged present: {sum(bool(f['applied']) for f in lane.fits)} of "
        f"{len(lane.fits)}. Floor: median window VAF ≥ the fast lane alone − 0.3 points.",
    )


# ----------------------------------------------------------------------------- 3. simulation
def _percent(x: float, truth: float) -> float:
    return 100.0 * abs(x - truth) / truth


def _simulation_tables(seeds: int, seconds: float) -> None:
    errors: dict[str, list[list[float]]] = {"rect": [], "hammerstein": [], "plain": []}
    for seed in range(seeds):
        theta, torque = prbs_ankle_with_reflex(seconds, SIM_FS, SIM_JOINT, SIM_REFLEX, seed=seed)
        for variant in ("rect", "hammerstein"):
            fit = fit_parallel_cascade(theta, torque, SIM_FS, CascadeSettings(variant=variant))
            e = intrinsic_parameters(theta, torque, SIM_FS, fit.reflex)
            errors[variant].append(
                [
                    _percent(e.K, SIM_JOINT.stiffness),
                    _percent(e.B, SIM_JOINT.damping),
                    _percent(e.I, SIM_JOINT.inertia),
                    _percent(fit.reflex.gain, SIM_REFLEX.gain),
                    abs(fit.reflex.delay_s - SIM_REFLEX.delay_s) * 1e3,
                ]
            )
        plain = estimate_window(theta, torque, SIM_FS, EstimatorOptions(hold="none"))
        errors["plain"].append(
            [
                _percent(plain.K, SIM_JOINT.stiffness),
                _percent(plain.B, SIM_JOINT.damping),
                _percent(plain.I, SIM_JOINT.inertia),
                float("nan"),
                float("nan"),
            ]
        )
    names = ["K error %", "B error %", "I error %", "reflex gain error %", "delay error ms"]
    rows = []
    for j, name in enumerate(names):
        row: list[Any] = [name]
        for key in ("rect", "hammerstein", "plain"):
            values = [e[j] for e in errors[key]]
            row += [float(np.median(values)), float(np.max(values))]
        rows.append(row)
    print_table(
        f"Simulated ankle with a stretch reflex ({seeds} records of {seconds:g} s at 2500 Hz, "
        "PRBS 40 Hz band, 10 % torque noise; truth K 150, B 0.8, I 0.015, gain 10, delay 40 ms)",
        [
            "error",
            "cascade rect median",
            "rect max",
            "hammerstein median",
            "hammerstein max",
            "no reflex model (reference) median",
            "reference max",
        ],
        rows,
        note="Floors: intrinsic K within 5 %, reflex gain within 15 %, delay within 5 ms. The "
        "reference is the output-error fit of the whole record with no reflex pathway.",
    )
    _simulated_windows(min(seeds, 3))


#: The simulated reflexes of the defaults' window table: (gain N·m·s/rad, delay s), or none.
SIM_WINDOW_REFLEXES: tuple[tuple[float, float] | None, ...] = (
    (10.0, 0.03),
    (10.0, 0.05),
    (25.0, 0.03),
    (25.0, 0.05),
    None,
)


def _simulated_windows(seeds: int) -> None:
    """Each simulated reflex (and none): the windows' K error and VAF with the defaults
    against the fast lane alone, and when the slow lane decides."""
    rows = []
    for case in SIM_WINDOW_REFLEXES:
        reflex = None
        if case is not None:
            reflex = ReflexParameters(
                gain=case[0], delay_s=case[1], corner_hz=3.0, damping_ratio=0.7
            )
        errors: dict[str, list[float]] = {"alone": [], "defaults": [], "ls": []}
        vafs, decided = [], []
        for seed in range(seeds):
            theta, torque = prbs_ankle_with_reflex(40.0, SIM_FS, SIM_JOINT, reflex, seed=seed)
            d1, d2 = derivatives(theta, SIM_FS)  # the simulation's own: the reference's best
            for label, lane in (("alone", False), ("defaults", True)):
                windows = replay_windows(theta, torque, record_config(SIM_FS, 1.0, lane))
                late = [i for i, (a, _) in enumerate(windows.bounds) if a > 25 * SIM_FS]
                errors[label] += [
                    windows.params[i][2] - SIM_JOINT.stiffness
                    for i in late
                    if np.isfinite(windows.params[i][2])
                ]
                if lane:
                    vafs += [windows.vaf[i] for i in late if np.isfinite(windows.vaf[i])]
                    decided.append(_first_decision_s(windows.fits, reflex is not None))
                    errors["ls"] += [
                        least_squares_window(theta[a:b], torque[a:b], SIM_FS, (d1[a:b], d2[a:b]))[2]
                        - SIM_JOINT.stiffness
                        for a, b in (windows.bounds[i] for i in late)
                    ]
        rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in errors.items()}
        label = "none" if case is None else f"gain {case[0]:g}, delay {case[1] * 1e3:.0f} ms"
        rows.append(
            [
                label,
                rms["alone"],
                rms["defaults"],
                rms["defaults"] / rms["alone"],
                rms["ls"],
                float(np.median(vafs)),
                float(np.percentile(vafs, 5)),
                float(np.max(decided)),
            ]
        )
    print_table(
        f"Simulated ankle, 300 ms windows every 100 ms after 25 s ({seeds} records of 40 s per "
        "reflex; truth K 150; defaults: the slow lane on, deciding from the data)",
        [
            "reflex",
            "K RMS error, fast lane alone",
            "K RMS error, defaults",
            "ratio",
            "least squares RMS error (reference)",
            "defaults' median window vaf %",
            "5th percentile vaf %",
            "decision settled by (s, worst record)",
        ],
        rows,
        note="Floors: with a reflex, K RMS error ≤ 0.3 × the fast lane alone and window VAF "
        "≥ 90 %; without one, the decision 'absent' within 30 s and the windows equal the "
        "fast lane alone (ratio 1). The vaf is the published one (the reflex torque "
        "subtracted counts as part of the model). Decision settled: the data end of the "
        "first fit after which every fit decides right (present with a reflex, absent "
        "without).",
    )


def _first_decision_s(fits: list[dict[str, Any]], present: bool) -> float:
    """The data end (s) of the first fit from which every fit decided ``present``."""
    settled = float("nan")
    for fit in fits:
        if bool(fit["applied"]) == present:
            if np.isnan(settled):
                settled = fit["end_index"] / SIM_FS
        else:
            settled = float("nan")
    return settled


# ----------------------------------------------------------------------------- 4. cost
def _streamed_hops(
    pathway: ReflexPathway,
    theta: np.ndarray,
    n: int,
    history: int,
    settings: SlowLaneSettings,
) -> Callable[[], object]:
    """One call: the fast lane's next 20 ms hop of the reflex prediction (the stream carries
    what the earlier hops formed; back to the record's start after its end)."""
    stream = ReflexStream()
    hop = round(0.02 * SIM_FS)
    ends = itertools.cycle(range(n + history, theta.size + 1, hop))

    def next_hop() -> object:
        end = next(ends)
        first = end - n - history
        segment = theta[first:end]
        return predict_reflex_torque(
            pathway, segment, None, SIM_FS, n, settings, first_index=first, stream=stream
        )

    return next_hop


def _cost_table() -> None:
    settings = SlowLaneSettings(enabled=True)
    theta, torque = prbs_ankle_with_reflex(20.0, SIM_FS, SIM_JOINT, SIM_REFLEX, seed=0)
    update = fit_reflex_update(0, 0, theta, torque, None, SIM_FS, settings)
    pathway = update.pathway
    assert pathway is not None
    n = round(0.3 * SIM_FS)
    history = round(pathway.history_s * SIM_FS)
    segment = theta[-(n + history) :]
    options = EstimatorOptions(hold="none")
    window = (theta[-n:], torque[-n:])
    timings = {
        "one window estimate (baseline)": time_calls(
            lambda: estimate_window(*window, SIM_FS, options), min_calls=50
        ),
        "reflex prediction per 20 ms hop (fast lane, streamed)": time_calls(
            _streamed_hops(pathway, theta, n, history, settings), min_calls=50
        ),
        "reflex prediction of one window formed afresh (lost samples)": time_calls(
            lambda: predict_reflex_torque(pathway, segment, None, SIM_FS, n, settings),
            min_calls=50,
        ),
        "one slow-lane update (20 s at 2500 Hz)": time_calls(
            lambda: fit_reflex_update(0, 0, theta, torque, None, SIM_FS, settings),
            min_calls=10,
            min_total_s=1.0,
        ),
    }
    base = float(np.median(timings["one window estimate (baseline)"]))
    rows = []
    for label, t in timings.items():
        med, p99 = median_p99(t)
        rows.append([label, len(t), med * 1e3, p99 * 1e3, med / base])
    print_table(
        "Cost (this machine, one thread)",
        ["step", "calls", "median ms", "p99 ms", "× window estimate"],
        rows,
    )
