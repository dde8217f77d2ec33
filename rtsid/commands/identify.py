"""``rtsid identify FILE``: estimate I, B, K and VAF window by window from a sample file."""

from __future__ import annotations

import argparse
import csv
import sys
from collections import Counter
from dataclasses import replace

import numpy as np

from rtsid.commands.common import add_fs, add_output
from rtsid.config import load_toml
from rtsid.errors import ConfigError, InputDataError, TorqueSignError
from rtsid.ident.cascade import (
    CascadeFit,
    CascadeSettings,
    fit_parallel_cascade,
    intrinsic_parameters,
    sliding_cascades,
)
from rtsid.ident.reflex import REFLEX_VARIANTS
from rtsid.ident.sign import inverted_torque_message
from rtsid.ident.window import EstimatorOptions, WindowEstimate, estimate_window
from rtsid.identifier import Identifier, config_table, record_windows
from rtsid.io.estimate_csv import encode_value, open_output, write_estimates
from rtsid.io.messages import EstimateMessage
from rtsid.io.sample_files import SampleRecord, load_samples, nonfinite_report
from rtsid.plots import (
    estimate_series,
    plot_cascade,
    plot_cascade_windows,
    plot_impedance_track,
    require_matplotlib,
)
from rtsid.verdicts import format_counts


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="recording: .npz (position_rad, torque_nm, fs_hz) or .csv")
    parser.add_argument(
        "--window",
        type=float,
        metavar="S",
        help="window, s (0.3; with --model cascade: the whole record unless given)",
    )
    parser.add_argument("--hop", type=float, metavar="S", help="hop, s (0.1; cascade: --window/4)")
    add_output(parser, "the estimates' CSV (default: stdout)", old=("--out",))
    parser.add_argument(
        "--torque-sign",
        type=float,
        choices=(1.0, -1.0),
        help="-1 for rigs reporting torque inverted",
    )
    add_fs(parser, "sampling rate of a CSV without t_s")
    parser.add_argument(
        "--fit",
        choices=("output_error", "relative", "logmag"),
        help="fit criterion (output_error)",
    )
    parser.add_argument(
        "--hold",
        choices=("none", "inertia", "inertia_damping"),
        help="parameters held at their running median over 20 s (inertia_damping)",
    )
    parser.add_argument("--lag", type=float, metavar="S", help="IRF lag span ±S (0.02)")
    parser.add_argument(
        "--model",
        choices=("window", "cascade"),
        default="window",
        help="window: I/B/K per sliding window (default); cascade: the parallel-cascade model "
        "of the whole record (intrinsic I/B/K with the reflex pathway's torque removed, "
        "reflex gain, VAFs)",
    )
    parser.add_argument(
        "--reflex",
        choices=REFLEX_VARIANTS,
        default="rect",
        help="cascade reflex pathway: rect (rectified velocity → IRF, default) or hammerstein "
        "(polynomial of velocity → IRF)",
    )
    parser.add_argument(
        "--plot",
        metavar="PNG",
        help="draw a figure here (PNG): windows: K_track with its band, each window's K, B, I "
        "and VAF over time; cascade: both pathways' torque and the reflex IRF (whole record), "
        "or the intrinsic K and the reflex gain window by window (needs rtsid[plot])",
    )
    parser.add_argument(
        "--config",
        metavar="TOML",
        help="a daemon config: its [estimator], [worker], [slow_lane] and [tracker] apply",
    )
    parser.add_argument(
        "--allow-nan",
        action="store_true",
        help="take NaN/inf rows as lost samples (bridged as live, or the window withheld as "
        "'gap') instead of refusing the file",
    )


def _identifier(
    args: argparse.Namespace, fs_hz: float, window_s: float | None, **config: dict[str, object]
) -> Identifier:
    """The stream ``rtsid identify`` runs: the daemon's window path (:class:`rtsid.Identifier`)
    with ``--config`` (a daemon TOML: [estimator], [worker], [slow_lane], [tracker]) and the
    command's switches over it; ``--window`` 0.3 s and ``--hop`` 0.1 s unless the config sets
    [worker] window_s and hop_s."""
    overrides = {
        "torque_sign": args.torque_sign,
        "fit_method": args.fit,
        "hold": args.hold,
        "lag_s": args.lag,
    }
    document = load_toml(args.config) if args.config else {}
    for section, values in config.items():
        config_table(document, section).update(values)
    return Identifier(
        fs_hz,
        document,
        window_s=window_s,
        hop_s=args.hop,
        **{k: v for k, v in overrides.items() if v is not None},
    )


def _summary(windows: list[EstimateMessage]) -> str:
    kept = [w for w in windows if w.ok]
    reasons = format_counts(Counter(str(w.reason) for w in windows if not w.ok))
    if not kept:
        return f"{len(windows)} windows, all withheld ({reasons})"
    withheld = f"{len(windows) - len(kept)} withheld" + (f": {reasons}" if reasons != "0" else "")
    med = {k: float(np.median([getattr(w, k) for w in kept])) for k in ("K", "B", "I", "vaf")}
    tracked = [w.K_track for w in kept if w.K_track is not None]
    lead = f"median K_track = {np.median(tracked):.1f} N·m/rad, " if tracked else ""
    return (
        f"{len(windows)} windows ({withheld}): {lead}K = {med['K']:.1f} N·m/rad, "
        f"B = {med['B']:.3f} N·m·s/rad, I = {med['I']:.4f} kg·m², VAF = {med['vaf']:.1f} %"
    )


def _windows(ident: Identifier, record: SampleRecord) -> list[EstimateMessage]:
    """Every window of the record; an inverted torque sign refused naming the switch."""
    try:
        return record_windows(ident, record.position_rad, record.torque_nm)
    except TorqueSignError as exc:
        other = f"{-exc.torque_sign:g}"
        fix = f"rerun with --torque-sign {other} (or [estimator] torque_sign = {other})"
        raise ConfigError(inverted_torque_message(exc.inverted, exc.estimable, fix)) from None


def _reflex_line(fits: list[dict[str, object]], needed: float) -> str:
    """What the slow lane decided, with its evidence."""
    if not fits:
        return "slow lane: no fit (record shorter than its first horizon, or slow lane off)"
    present = [f for f in fits if f["applied"]]
    gains = [float(g) for f in fits if isinstance(g := f["window_vaf_gain"], float)]
    evidence = (
        f" (window VAF gain {min(gains):+.1f} … {max(gains):+.1f} points, median "
        f"{np.median(gains):+.1f}; present needs ≥ {needed:+g})"
        if gains
        else ""
    )
    if not present:
        return (
            f"slow lane: reflex judged absent in all {len(fits)} fits{evidence}: nothing subtracted"
        )
    return (
        f"slow lane: reflex judged present in {len(present)} of {len(fits)} fits{evidence}: "
        "its torque subtracted before those windows' I, B, K"
    )


def run(args: argparse.Namespace) -> int:
    if args.plot:
        require_matplotlib()  # refuse before the work, not after it
    record = load_samples(args.file, args.fs)
    problem = nonfinite_report(record)
    if problem and not args.allow_nan:
        raise InputDataError(
            f"{record.source}: {problem}; clean the file, or pass --allow-nan to withhold the "
            "windows that contain them"
        )
    if args.model == "cascade":
        return _identify_cascade(record, args)
    ident = _identifier(args, record.fs_hz, args.window)
    windows = _windows(ident, record)
    messages = [w.as_dict() for w in windows]
    with open_output(args.output) as fh:
        write_estimates(messages, fh)
    if args.plot:
        t, series, flagged = estimate_series(messages)
        worker = ident.config.worker
        figure = plot_impedance_track(
            t,
            series,
            args.plot,
            title=f"{record.source}: {worker.window_s * 1e3:.0f} ms windows every "
            f"{worker.hop_s * 1e3:.0f} ms",
            flagged=flagged,
            window_s=worker.window_s,
        )
        print(f"rtsid identify: wrote {figure}", file=sys.stderr)
    if ident.plan is not None:
        print(f"rtsid identify: {ident.plan}", file=sys.stderr)
    needed = ident.config.slow_lane.min_window_vaf_gain_percent
    print(f"rtsid identify: {_reflex_line(ident.reflex, needed)}", file=sys.stderr)
    print(f"rtsid identify: {_summary(windows)}", file=sys.stderr)
    return 0


CASCADE_COLUMNS = (
    "t_start_s",
    "t_end_s",
    "vaf_cascade",
    "vaf_intrinsic_path",
    "vaf_reflex_path",
    "vaf_intrinsic_irf",
    "K",
    "B",
    "I",
    "K_se",
    "B_se",
    "I_se",
    "vaf",
    "K_no_reflex_model",
    "reflex_gain_nm_s_per_rad",
    "reflex_delay_ms",
    "reflex_delay_at_bound",
    "reflex_irf_gain_nm_s_per_rad",
    "reflex_dynamics_vaf",
    "reflex_rank",
    "alternations",
)


def _cascade_row(
    start: int,
    end: int,
    fs_hz: float,
    cascade: CascadeFit,
    intrinsic: WindowEstimate,
    plain_k: float,
) -> dict[str, float | str]:
    reflex = cascade.reflex
    values = (
        start / fs_hz,
        end / fs_hz,
        cascade.vaf_total,
        cascade.vaf_intrinsic_path,
        cascade.vaf_reflex_path,
        cascade.vaf_intrinsic_only,
        intrinsic.K,
        intrinsic.B,
        intrinsic.I,
        intrinsic.K_se,
        intrinsic.B_se,
        intrinsic.I_se,
        intrinsic.vaf,
        plain_k,
        reflex.gain,
        reflex.delay_s * 1e3,
        reflex.dynamics.delay_at_bound or "",
        reflex.irf_gain,
        reflex.dynamics.vaf,
        reflex.rank,
        cascade.iterations,
    )
    return dict(zip(CASCADE_COLUMNS, values, strict=True))


def _write_cascade_rows(rows: list[dict[str, float | str]], out: str | None) -> None:
    with open_output(out) as fh:
        writer = csv.DictWriter(fh, fieldnames=CASCADE_COLUMNS, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: encode_value(v) for k, v in row.items()})


def _identify_cascade(record: SampleRecord, args: argparse.Namespace) -> int:
    """The parallel cascade of the whole record, or of sliding windows (``--window``); the
    intrinsic I/B/K by the window estimator's output-error fit to the torque with the
    reflex pathway's prediction removed."""
    if problem := nonfinite_report(record):
        raise InputDataError(f"{record.source}: {problem}; the cascade needs a clean record")
    # the sign is judged on the record's 300 ms windows, as without --model cascade
    sign_check = _identifier(args, record.fs_hz, 0.3, slow_lane={"enabled": False})
    _windows(sign_check, record)
    options = sign_check.config.estimator
    torque = options.torque_sign * record.torque_nm
    settings = CascadeSettings(variant=args.reflex)
    if args.window is None:
        return _whole_record_cascade(record, torque, options, settings, args)
    hop = args.hop if args.hop is not None else args.window / 4
    fs = record.fs_hz
    whole = replace(options, torque_sign=1.0, hold="none")
    rows = []
    for w in sliding_cascades(record.position_rad, torque, fs, args.window, hop, settings, options):
        span = slice(w.start_index, w.end_index + 1)
        plain = estimate_window(record.position_rad[span], torque[span], fs, whole)
        rows.append(_cascade_row(w.start_index, w.end_index, fs, w.cascade, w.intrinsic, plain.K))
    _write_cascade_rows(rows, args.output)
    if args.plot:
        plot_cascade_windows(rows, args.plot, title=f"{record.source}: {args.reflex} cascade")
    k = np.array([float(r["K"]) for r in rows])
    gain = np.array([float(r["reflex_gain_nm_s_per_rad"]) for r in rows])
    print(
        f"rtsid identify: {len(rows)} cascade windows of {args.window:g} s every {hop:g} s: "
        f"median VAF {np.median([float(r['vaf_cascade']) for r in rows]):.1f} %, intrinsic K "
        f"{np.median(k):.1f} N·m/rad (IQR {np.subtract(*np.percentile(k, [75, 25])):.1f}), "
        f"reflex gain {np.median(gain):.3g} N·m·s/rad{_delays_at_bound(rows)}",
        file=sys.stderr,
    )
    return 0


def _delays_at_bound(rows: list[dict[str, float | str]]) -> str:
    """``"; the reflex delay ended at the lower bound of its search in 5 of 5 windows …"``."""
    bounds = [str(r["reflex_delay_at_bound"]) for r in rows if r["reflex_delay_at_bound"]]
    if not bounds:
        return ""
    which = " or ".join(sorted(set(bounds)))
    return (
        f"; the reflex delay ended at the {which} bound of its search in {len(bounds)} of "
        f"{len(rows)} windows (reflex_delay_at_bound): there it is not a measured delay"
    )


def _whole_record_cascade(
    record: SampleRecord,
    torque: np.ndarray,
    options: EstimatorOptions,
    settings: CascadeSettings,
    args: argparse.Namespace,
) -> int:
    fs = record.fs_hz
    cascade = fit_parallel_cascade(record.position_rad, torque, fs, settings)
    intrinsic = intrinsic_parameters(record.position_rad, torque, fs, cascade.reflex, options)
    plain = estimate_window(
        record.position_rad, torque, fs, replace(options, torque_sign=1.0, hold="none")
    )
    row = _cascade_row(0, record.position_rad.size - 1, fs, cascade, intrinsic, plain.K)
    _write_cascade_rows([row], args.output)
    if args.plot:
        plot_cascade(cascade, args.plot, title=f"{record.source}: {settings.variant} cascade")
    reflex = cascade.reflex
    print(
        f"rtsid identify: parallel cascade ({settings.variant}) of {record.duration_s:g} s at "
        f"{cascade.fs_hz:g} Hz: VAF {cascade.vaf_total:.1f} % (intrinsic IRF alone "
        f"{cascade.vaf_intrinsic_only:.1f} %; pathways alone: intrinsic "
        f"{cascade.vaf_intrinsic_path:.1f} %, reflex {cascade.vaf_reflex_path:.1f} %), "
        f"{cascade.iterations} alternations; intrinsic K = {intrinsic.K:.1f} ± "
        f"{intrinsic.K_se:.1f} N·m/rad, B = {intrinsic.B:.3f}, I = {intrinsic.I:.4f} "
        f"(without the reflex model K = {plain.K:.1f}); reflex gain {reflex.gain:.3g} "
        f"N·m·s/rad (the delayed low-pass explains {reflex.dynamics.vaf:.0f} % of the reflex "
        f"IRF; IRF rank {reflex.rank} by MDL), {reflex.dynamics.describe_delay()}",
        file=sys.stderr,
    )
    return 0
