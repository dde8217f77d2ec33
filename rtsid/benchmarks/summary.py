"""``rtsid bench summary``: how long ``rtsid summary`` takes over a study's folder — from the
recordings' summary tables, and from their messages (the path of files without a table) in
the same run — beside ``rtsid replay`` on some of the recordings (replay estimates again,
summary only reads).

The study is made as the daemon makes recordings: a simulated ankle per recording (2500 Hz,
filtered-noise perturbation, its own stiffness) through :class:`rtsid.Identifier` at the
daemon's 20 ms hop, written by rtsid's MCAP logger — samples, estimates, the slow lane's fits,
2 Hz status, the ``rtsid.session`` metadata record and the summary table — one subfolder per
recording. Every command runs as a user runs it, in a fresh interpreter (its start-up
included): wall time (median and p99 of ``--runs``) and peak RSS of that process. Made once,
a study is reused with ``--folder`` (one ten-minute recording takes 5–10 min to make on one
core).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rtsid.benchmarks.table import median_p99, print_table

FS_HZ = 2500.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--recordings", type=int, default=20, help="recordings (20)")
    parser.add_argument("--seconds", type=float, default=60.0, help="length of each, s (60)")
    parser.add_argument(
        "--replay-recordings",
        type=int,
        default=4,
        metavar="N",
        help="replay only the first N, on one core (4; 0: no replay; replay costs ~7 s per "
        "minute recorded)",
    )
    parser.add_argument(
        "--runs", type=int, default=5, help="runs of each summary command (5; median, p99)"
    )
    parser.add_argument(
        "--reference-runs",
        type=int,
        default=1,
        metavar="N",
        help="runs of the summary from the messages (1; ~2 s per ten-minute recording)",
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


#: ``rtsid summary`` reads every recording's messages, as for files without a summary table.
FROM_MESSAGES = {"RTSID_SUMMARY_FROM_MESSAGES": "1"}


def _timed(argv: list[str], env: dict[str, str] | None = None) -> tuple[float, float]:
    """Wall time (s) and peak RSS (MiB) of ``rtsid ARGV`` in a fresh interpreter (``env``
    added to this one's)."""
    with tempfile.TemporaryFile() as err:
        started = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-m", "rtsid.cli", *argv],
            stdout=subprocess.DEVNULL,
            stderr=err,
            env={**os.environ, **(env or {})},
        )
        _pid, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - started
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            err.seek(0)
            raise RuntimeError(
                f"rtsid {' '.join(argv)} exited {proc.returncode}: {err.read().decode()[-2000:]}"
            )
    return wall, usage.ru_maxrss / 1024


def run(args: argparse.Namespace) -> int:
    count, seconds = (2, 5.0) if args.quick else (args.recordings, args.seconds)
    replayed = 1 if args.quick else max(0, min(args.replay_recordings, count))
    runs = 1 if args.quick else max(1, args.runs)
    reference_runs = 1 if args.quick else max(1, args.reference_runs)
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
        table = ["summary", str(folder), "-o", f"{tmp}/tables.csv"]
        messages = ["summary", str(folder), "-o", f"{tmp}/messages.csv"]
        cases: list[tuple[str, list[str], dict[str, str] | None, int, int]] = [
            ("rtsid summary FOLDER (summary tables)", table, None, len(files), runs),
            (
                "... from the messages (no table)",
                messages,
                FROM_MESSAGES,
                len(files),
                reference_runs,
            ),
        ]
        if replayed:
            subset_csv = ["summary", str(subset), "-o", f"{tmp}/s.csv"]
            cases.append(("rtsid summary SUBSET", subset_csv, None, replayed, runs))
            replay = ["replay", str(subset), "--jobs", "1"]
            cases.append(("rtsid replay SUBSET --jobs 1", replay, None, replayed, 1))
        rows: list[list[object]] = []
        medians: list[float] = []
        for name, argv, env, n, repeat in cases:
            measured = [_timed(argv, env) for _ in range(repeat)]
            median, p99 = median_p99([wall for wall, _rss in measured])
            rss = max(rss for _wall, rss in measured)
            rows.append([name, n, repeat, median, p99, median / n, rss])
            medians.append(median)
        print_table(
            "rtsid summary from the recordings' summary tables, from their messages, and rtsid "
            "replay (estimates again): wall time and peak RSS of a fresh interpreter",
            ["command", "recordings", "runs", "median s", "p99 s", "s per recording", "RSS MiB"],
            rows,
        )
        same = Path(f"{tmp}/tables.csv").read_bytes() == Path(f"{tmp}/messages.csv").read_bytes()
        print(f"the two tables are byte for byte the same: {'yes' if same else 'NO'}")
        print(
            "from the messages / from the tables (medians, same run): "
            f"{medians[1] / medians[0]:.1f}×"
        )
        if replayed:
            print(f"replay / summary per recording (same subset): {medians[3] / medians[2]:.1f}×")
    return 0 if same else 1
