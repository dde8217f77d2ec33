"""``rtsid bench summary``: how long ``rtsid summary`` takes over a study's folder, beside
``rtsid replay`` on the same recordings (the reference: replay estimates again, summary only
reads).

The study is made as the daemon makes recordings: a simulated ankle per recording (2500 Hz,
filtered-noise perturbation, its own stiffness) through :class:`rtsid.Identifier` at the
daemon's 20 ms hop, written by rtsid's MCAP logger — samples, estimates, the slow lane's fits,
2 Hz status and the ``rtsid.session`` metadata record — one subfolder per recording. Both
commands run as a user runs them, in a fresh interpreter (its start-up included).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rtsid.benchmarks.table import print_table

FS_HZ = 2500.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--recordings", type=int, default=20, help="recordings (20)")
    parser.add_argument("--seconds", type=float, default=60.0, help="length of each, s (60)")
    parser.add_argument(
        "--replay-recordings",
        type=int,
        default=4,
        metavar="N",
        help="replay only the first N, on one core (4; replay costs ~7 s per minute recorded)",
    )
    parser.add_argument(
        "--folder",
        type=Path,
        help="make the study here, or reuse the one already there (default: a temporary one)",
    )


def make_study(folder: Path, recordings: int, seconds: float) -> list[Path]:
    """``recordings`` simulated recordings of ``seconds`` each under ``folder``: subjects of
    four recordings, alternately 'relaxed' (K 120 + 10·subject) and 'active' (K 200 + …)."""
    return [f for i in range(recordings) for f in make_recording(folder, i, seconds)]


def make_recording(folder: Path, i: int, seconds: float) -> list[Path]:
    """Recording ``i`` of :func:`make_study` (its own seed, subject and condition), in
    ``folder/<i>``; its files."""
    from rtsid import Identifier
    from rtsid.ident.excitation import filtered_noise
    from rtsid.io.mcap_log import McapConfig, McapLogger
    from rtsid.io.session import SessionConfig
    from rtsid.sim.joint import JointParameters, simulate_impedance

    n = round(seconds * FS_HZ)
    batch = round(0.1 * FS_HZ)
    subject, condition = f"S{i // 4 + 1:02d}", ("relaxed", "active")[i % 2]
    stiffness = (120.0 if condition == "relaxed" else 200.0) + 10.0 * (i // 4)
    position = filtered_noise(n, FS_HZ, 30.0, peak=0.02, seed=i)
    torque = simulate_impedance(
        position, FS_HZ, JointParameters(0.015, 0.8, stiffness), noise_percent=5.0, seed=i
    )
    names = {"subject": subject, "session": "1", "condition": condition}
    started = {"robot": "robot", "joint": "ankle", "t_s": 0.0, "sample_index": 0}
    config = McapConfig(directory=str(folder / f"{i:03d}"), queue_size=1_000_000)
    identifier = Identifier(FS_HZ, hop_s=0.02)
    with McapLogger(
        config,
        robot="robot",
        joint="ankle",
        fs_hz=FS_HZ,
        session=SessionConfig(**names),
        session_message={**started, **names, "host_time_ns": time.time_ns()},
    ) as logger:
        fits = 0
        for first in range(0, n, batch):
            p, t = position[first : first + batch], torque[first : first + batch]
            logger.log_samples(first, p, t)
            for message in identifier.push(p, t):
                logger.log_estimate(message.as_dict())
            for fit in identifier.reflex[fits:]:
                logger.log_reflex(fit)
            fits = len(identifier.reflex)
            if first % (5 * batch) == 0:
                logger.log_status(
                    {
                        "robot": "robot",
                        "joint": "ankle",
                        "host_time_ns": time.time_ns(),
                        "uptime_s": first / FS_HZ,
                        "acquisition": {"lost_samples": 0},
                    }
                )
    return list(logger.files)


def _timed(argv: list[str]) -> float:
    """Wall time of ``rtsid ARGV`` in a fresh interpreter, s."""
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "rtsid.cli", *argv],
        capture_output=True,
        text=True,
        timeout=3600,
        check=False,
    )
    wall = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(f"rtsid {' '.join(argv)} exited {done.returncode}: {done.stderr}")
    return wall


def run(args: argparse.Namespace) -> int:
    count, seconds = (2, 5.0) if args.quick else (args.recordings, args.seconds)
    replayed = 1 if args.quick else max(1, min(args.replay_recordings, count))
    with tempfile.TemporaryDirectory(prefix="rtsid-bench-summary-") as tmp:
        folder = args.folder or Path(tmp) / "study"
        existing = sorted(folder.rglob("*.mcap")) if folder.exists() else []
        started = time.perf_counter()
        files = existing or make_study(folder, count, seconds)
        made_s = 0.0 if existing else time.perf_counter() - started
        subset = Path(tmp) / "subset"
        subset.mkdir()
        for f in files[:replayed]:
            (subset / f.name).symlink_to(f.resolve())
        mib = sum(f.stat().st_size for f in files) / 2**20
        print(
            f"study: {len(files)} recordings in {folder} ({mib:.1f} MiB)"
            + (f", made in {made_s:.1f} s" if made_s else ", reused")
        )
        rows = []
        for name, argv, n in (
            ("rtsid summary FOLDER", ["summary", str(folder), "-o", f"{tmp}/t.csv"], len(files)),
            ("rtsid summary SUBSET", ["summary", str(subset), "-o", f"{tmp}/s.csv"], replayed),
            ("rtsid replay SUBSET --jobs 1", ["replay", str(subset), "--jobs", "1"], replayed),
        ):
            wall = _timed(argv)
            rows.append([name, n, wall, wall / n])
        print_table(
            "rtsid summary (reads the estimates) against rtsid replay (estimates again), wall "
            "time in a fresh interpreter",
            ["command", "recordings", "wall s", "s per recording"],
            rows,
        )
        per = np.array([rows[1][3], rows[2][3]])
        print(f"replay / summary per recording (same subset): {per[1] / per[0]:.1f}×")
    return 0
