"""``rtsid bench replay``: replay speed of a long recording, as fast as possible, on one core.

A simulated ankle recording (2500 Hz, 20 ms hops, time-varying stiffness) is written with the
converter's writer (the daemon's MCAP layout) and replayed with ``rtsid replay``'s code path.
The baseline, measured in the same run, is the estimator alone over the same windows from
arrays in memory (no MCAP decoding, no messages) — the ratio shows what replay itself costs.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from rtsid.benchmarks.table import print_table
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.stream import sliding_estimates
from rtsid.io.convert import ImportedSamples, read_sample_file, write_recording
from rtsid.replay import replay_file
from rtsid.runtime.daemon import DaemonConfig
from rtsid.sim.joint import JointParameters, StiffnessProfile, simulate_impedance

FS_HZ = 2500.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--minutes", type=float, default=10.0, help="recording length (10)")


def _recording(folder: Path, seconds: float) -> tuple[Path, np.ndarray, np.ndarray]:
    n = round(seconds * FS_HZ)
    rng = np.random.default_rng(3)
    theta = filtered_noise(n, FS_HZ, 30.0, peak=0.03, seed=rng)
    profile = StiffnessProfile.sinusoid(150.0, 50.0, 0.2)
    tau = simulate_impedance(theta, FS_HZ, JointParameters(), profile, noise_percent=5.0, seed=rng)
    npz = folder / "sim.npz"
    np.savez(npz, position_rad=theta, torque_nm=tau, fs_hz=FS_HZ)
    samples: ImportedSamples = read_sample_file(npz)
    config = DaemonConfig.from_mapping({"link": {"fs_hz": FS_HZ}})
    out = write_recording(
        samples,
        folder / "sim.mcap",
        run_config=config.as_dict(),
        batch_samples=250,
        source=str(npz),
    )
    return out, theta, tau


def run(args: argparse.Namespace) -> int:
    seconds = 30.0 if args.quick else args.minutes * 60.0
    with tempfile.TemporaryDirectory(prefix="rtsid-bench-replay-") as tmp:
        started = time.perf_counter()
        path, theta, tau = _recording(Path(tmp), seconds)
        build_s = time.perf_counter() - started
        size_mb = path.stat().st_size / 2**20
        result = replay_file(path)
        config = DaemonConfig()
        start = time.perf_counter()
        windows = sum(
            1
            for _ in sliding_estimates(
                theta, tau, FS_HZ, config.worker.window_s, config.worker.hop_s, config.estimator
            )
        )
        bare_s = time.perf_counter() - start
    rows = [
        [
            "rtsid replay (MCAP → worker → messages)",
            len(result.messages),
            result.elapsed_s,
            result.elapsed_s / len(result.messages) * 1e3,
            result.speed,
            1.0,
        ],
        [
            "baseline: estimator alone, arrays in memory",
            windows,
            bare_s,
            bare_s / windows * 1e3,
            seconds / bare_s,
            bare_s / result.elapsed_s,
        ],
    ]
    print_table(
        f"Replay of a {seconds / 60:g}-minute recording at {FS_HZ:g} Hz, 300 ms windows every "
        f"20 ms, one process (MCAP {size_mb:.0f} MiB, written in {build_s:.0f} s)",
        ["path", "windows", "seconds", "ms per window", "× real time", "time vs replay"],
        rows,
        note="Floor: ≥ 30× real time per core at the default hop.",
    )
    return 0
