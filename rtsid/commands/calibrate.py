"""``rtsid calibrate BASELINE -o CAL.json``: identify the robot from a run with nobody attached."""

from __future__ import annotations

import argparse
from pathlib import Path

from rtsid.commands.common import add_fs, add_output


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "baseline", type=Path, help="a run with no person attached: .mcap, .npz or .csv"
    )
    add_output(parser, "calibration file to write (JSON)", required=True, kind=Path)
    add_fs(parser, "sampling rate of a CSV without t_s")
    parser.add_argument(
        "--lowpass",
        type=float,
        metavar="HZ",
        help="FIR pass-band edge on acceleration and torque (default: the recording's "
        "estimator.lowpass_hz, else 100 Hz)",
    )
    parser.add_argument("--lag", type=float, default=0.01, metavar="S", help="IRF lags ±S (0.01)")
    parser.add_argument(
        "--force",
        action="store_true",
        help="calibrate even when the baseline's torque has a stiffness (a joint attached)",
    )


def run(args: argparse.Namespace) -> int:
    from rtsid.calibrate import calibrate_file, save_calibration

    calibration = calibrate_file(
        args.baseline, fs_hz=args.fs, lowpass_hz=args.lowpass, lag_s=args.lag, force=args.force
    )
    robot = calibration.robot
    save_calibration(calibration, args.output)
    print(
        f"{args.baseline}: robot acceleration → torque IRF over ±{robot.max_lag / robot.fs_hz:g} s "
        f"at {robot.fs_hz:g} Hz from {robot.samples} samples in {robot.segments} segment(s), "
        f"low-pass {robot.lowpass_hz:g} Hz"
    )
    print(f"VAF {robot.vaf:.1f} %, inertia (static gain) {robot.inertia:.4g} kg·m²")
    print(f'wrote {args.output}; use it with [worker] calibration_file = "{args.output}"')
    return 0
