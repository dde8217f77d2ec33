"""``rtsid identify FILE``: estimate I, B, K and VAF window by window from a sample file."""

from __future__ import annotations

import argparse
import csv
import sys
from dataclasses import replace

import numpy as np

from rtsid.config import load_toml, section_from_mapping
from rtsid.errors import InputDataError
from rtsid.ident.cascade import fit_parallel_cascade
from rtsid.ident.stream import WindowResult, WindowStream, sliding_estimates
from rtsid.ident.window import EstimatorOptions, estimate_window
from rtsid.io.estimate_csv import open_output, write_estimates
from rtsid.io.sample_files import SampleRecord, load_samples, nonfinite_report


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="recording: .npz (position_rad, torque_nm, fs_hz) or .csv")
    parser.add_argument("--window", type=float, default=0.3, metavar="S", help="window, s (0.3)")
    parser.add_argument("--hop", type=float, default=0.1, metavar="S", help="hop, s (0.1)")
    parser.add_argument("--out", "-o", metavar="PATH", help="CSV output (default: stdout)")
    parser.add_argument(
        "--torque-sign",
        type=float,
        choices=(1.0, -1.0),
        help="-1 for rigs reporting torque inverted",
    )
    parser.add_argument("--fs", type=float, metavar="HZ", help="sampling rate of a CSV without t_s")
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
    parser.add_argument("--config", metavar="TOML", help="take [estimator] options from this file")
    parser.add_argument(
        "--allow-nan",
        action="store_true",
        help="take NaN/inf rows as lost samples (bridged as live, or the window withheld as "
        "'gap') instead of refusing the file",
    )


def _options(args: argparse.Namespace) -> EstimatorOptions:
    table = load_toml(args.config).get("estimator") if args.config else None
    options = section_from_mapping(EstimatorOptions, table, "estimator")
    overrides = {
        "torque_sign": args.torque_sign,
        "fit_method": args.fit,
        "hold": args.hold,
        "lag_s": args.lag,
    }
    return replace(options, **{k: v for k, v in overrides.items() if v is not None})


def _summary(results: list[WindowResult]) -> str:
    kept = [r.estimate for r in results if r.estimate is not None]
    withheld = len(results) - len(kept)
    if not kept:
        return f"{len(results)} windows, all withheld"
    med = {k: float(np.median([getattr(e, k) for e in kept])) for k in ("K", "B", "I", "vaf")}
    return (
        f"{len(results)} windows ({withheld} withheld): median K = {med['K']:.1f} N·m/rad, "
        f"B = {med['B']:.3f} N·m·s/rad, I = {med['I']:.4f} kg·m², VAF = {med['vaf']:.1f} %"
    )


def run(args: argparse.Namespace) -> int:
    options = _options(args)
    record = load_samples(args.file, args.fs)
    problem = nonfinite_report(record)
    if problem and not args.allow_nan:
        raise InputDataError(
            f"{record.source}: {problem}; clean the file, or pass --allow-nan to withhold the "
            "windows that contain them"
        )
    if args.model == "cascade":
        return _identify_cascade(record, options, args.out)
    stream = WindowStream(record.fs_hz, options, args.hop)
    valid = np.isfinite(record.position_rad) & np.isfinite(record.torque_nm) if problem else None
    results = list(
        sliding_estimates(
            record.position_rad,
            record.torque_nm,
            record.fs_hz,
            args.window,
            args.hop,
            options,
            stream=stream,
            valid=valid,
        )
    )
    with open_output(args.out) as fh:
        write_estimates(results, fh)
    if stream.plan is not None:
        print(f"rtsid identify: {stream.plan.describe()}", file=sys.stderr)
    print(f"rtsid identify: {_summary(results)}", file=sys.stderr)
    return 0


CASCADE_COLUMNS = (
    "vaf_cascade",
    "vaf_intrinsic_irf",
    "K",
    "B",
    "I",
    "K_se",
    "vaf",
    "K_no_reflex_model",
    "reflex_gain_nm_s_per_rad",
)


def _identify_cascade(record: SampleRecord, options: EstimatorOptions, out: str | None) -> int:
    """The whole record's parallel cascade; the intrinsic I/B/K by the window estimator on
    the torque with the reflex pathway's prediction removed."""
    if problem := nonfinite_report(record):
        raise InputDataError(f"{record.source}: {problem}; the cascade needs a clean record")
    torque = options.torque_sign * record.torque_nm
    cascade = fit_parallel_cascade(record.position_rad, torque, record.fs_hz)
    reflex = cascade.reflex_torque_at(record.position_rad, record.fs_hz)
    whole = replace(options, torque_sign=1.0, hold="none")
    intrinsic = estimate_window(record.position_rad, torque - reflex, record.fs_hz, whole)
    plain = estimate_window(record.position_rad, torque, record.fs_hz, whole)
    row = dict(
        zip(
            CASCADE_COLUMNS,
            (
                cascade.vaf_total,
                cascade.vaf_intrinsic_only,
                intrinsic.K,
                intrinsic.B,
                intrinsic.I,
                intrinsic.K_se,
                intrinsic.vaf,
                plain.K,
                cascade.reflex_gain,
            ),
            strict=True,
        )
    )
    with open_output(out) as fh:
        writer = csv.DictWriter(fh, fieldnames=CASCADE_COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerow({k: f"{v:.6g}" for k, v in row.items()})
    print(
        f"rtsid identify: parallel cascade of {record.duration_s:g} s at 100 Hz: VAF "
        f"{cascade.vaf_total:.1f} % (intrinsic IRF alone {cascade.vaf_intrinsic_only:.1f} %), "
        f"{cascade.iterations} alternations; intrinsic K = {intrinsic.K:.1f} ± "
        f"{intrinsic.K_se:.1f} N·m/rad, B = {intrinsic.B:.3f}, I = {intrinsic.I:.4f} "
        f"(without the reflex model K = {plain.K:.1f}); reflex gain "
        f"{cascade.reflex_gain:.3g} N·m·s/rad",
        file=sys.stderr,
    )
    return 0
