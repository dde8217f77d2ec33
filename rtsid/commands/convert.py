"""``rtsid convert IN -o OUT.mcap``: CAN captures and sample files as rtsid MCAP recordings."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from rtsid.commands.common import add_fs, add_output
from rtsid.errors import InputDataError
from rtsid.io.convert import (
    CAN_LOG_SUFFIXES,
    SAMPLE_FILE_SUFFIXES,
    check_estimable,
    read_source,
    write_recording,
)
from rtsid.runtime.daemon import DaemonConfig


def add_arguments(parser: argparse.ArgumentParser) -> None:
    kinds = ", ".join(CAN_LOG_SUFFIXES + SAMPLE_FILE_SUFFIXES)
    parser.add_argument("input", type=Path, help=f"a CAN capture or sample file ({kinds})")
    add_output(parser, "the .mcap to write", required=True, kind=Path)
    add_fs(
        parser,
        "sample rate: the robot's state-frame rate for CAN captures (default: the "
        "--config's [link] fs_hz, else derived from the frames' timestamps), or the rate of a "
        "CSV without a t_s column",
    )
    parser.add_argument(
        "--config",
        metavar="TOML",
        help="settings stored in the recording for replay (e.g. an [estimator] preset)",
    )
    parser.add_argument(
        "--torque-sign",
        type=float,
        choices=(1.0, -1.0),
        help="store estimator.torque_sign = -1 for rigs reporting torque inverted "
        "(the samples themselves are written as recorded)",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace OUTPUT if it exists")


def _rate(args: argparse.Namespace, config: DaemonConfig) -> float | None:
    if args.fs is not None:
        return float(args.fs)
    if args.input.suffix.lower() in CAN_LOG_SUFFIXES and args.config:
        return config.link.fs_hz
    return None


def stored_config(config: DaemonConfig, fs_hz: float, torque_sign: float | None) -> DaemonConfig:
    """``config`` with the recording's rate (link and plant) and an optional torque sign."""
    if not fs_hz > 0:
        raise InputDataError(f"sample rate {fs_hz!r} Hz must be > 0")
    plant = config.plant
    plant = replace(
        plant,
        fs_hz=fs_hz,
        bandwidth_hz=min(plant.bandwidth_hz, 0.4 * fs_hz),
        servo_bandwidth_hz=min(plant.servo_bandwidth_hz, 0.4 * fs_hz),
    )
    estimator = config.estimator
    if torque_sign is not None:
        estimator = replace(estimator, torque_sign=torque_sign)
    return replace(config, link=replace(config.link, fs_hz=fs_hz), plant=plant, estimator=estimator)


def run(args: argparse.Namespace) -> int:
    config = DaemonConfig.load(args.config) if args.config else DaemonConfig()
    samples = read_source(args.input, _rate(args, config))
    check_estimable(samples, config.worker.window_s, str(args.input))
    config = stored_config(config, samples.fs_hz, args.torque_sign)
    batch = max(1, round(config.daemon.sample_batch_s * samples.fs_hz))
    out = write_recording(
        samples,
        args.output,
        run_config=config.as_dict(),
        batch_samples=batch,
        source=str(args.input),
        robot=config.zenoh.robot,
        joint=config.zenoh.joint,
        overwrite=args.overwrite,
    )
    c = samples.counters
    valid = int(samples.valid.sum())
    if samples.rate_note:
        print(f"{args.input}: {samples.rate_note}")
    print(
        f"{args.input}: {len(samples)} rows at {samples.fs_hz:g} Hz "
        f"({len(samples) / samples.fs_hz:.1f} s), {valid} valid"
    )
    if samples.source_format not in ("npz", "csv"):
        print(
            f"frames {c.frames}: gaps {c.gaps} ({c.lost_samples} samples lost), duplicates "
            f"{c.duplicates}, out of order {c.out_of_order}, malformed {c.malformed}, "
            f"unknown id {c.unknown_id}, error frames {c.error_frames}"
        )
    print(f"wrote {out}; next: rtsid replay {out}")
    return 0
