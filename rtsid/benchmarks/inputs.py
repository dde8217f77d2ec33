"""``rtsid bench inputs``: peak memory of ``rtsid convert`` on hostile and large inputs.

Each case runs ``rtsid convert`` in a child process under an address-space cap
(``--cap-gib``, 4 GiB by default) and reports its exit status and peak RSS. The baseline is a
refused conversion in the same run (``--fs 1e9``, refused before a frame is read: the
interpreter and rtsid's imports); the growth of the accepted cases above it, per row, is the
figure docs/io.md documents (about 100 bytes per row at most, 2 GB at the 20 000 000-row cap).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from rtsid.benchmarks.table import print_table

FS_HZ = 2500.0
T0 = 1_763_000_000.0

_CHILD = """
import resource, sys
cap = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
from rtsid.cli import main
code = main(sys.argv[2:])
# VmHWM: this process's own peak (ru_maxrss would carry the forking parent's over exec)
with open("/proc/self/status") as fh:
    hwm = next(line.split()[1] for line in fh if line.startswith("VmHWM:"))
print("maxrss_kib", hwm, file=sys.stderr)
sys.exit(code)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--rows", type=int, default=1_000_000, help="rows of the large inputs")
    parser.add_argument("--cap-gib", type=float, default=4.0, help="address-space cap, GiB")


def write_csv(path: Path, rows: int) -> None:
    t = np.arange(rows) / FS_HZ
    with path.open("w") as fh:
        fh.write("t_s,position_rad,torque_nm\n")
        np.savetxt(fh, np.column_stack([t, np.sin(t), np.cos(t)]), fmt="%.7f", delimiter=",")


def write_candump(path: Path, frames: int, step_s: float = 1 / FS_HZ) -> None:
    """A candump -L capture of ``frames`` AnkleState frames ``step_s`` apart."""
    from rtsid.link.protocol import COUNTER_MODULO, STATE_ID, encode_state_block

    k = np.arange(frames)
    payload = encode_state_block(
        k % 1000, -(k % 1000), k % COUNTER_MODULO, np.zeros(frames, dtype=np.int64)
    )
    with path.open("w") as fh:
        for i in range(frames):
            data = payload[i].tobytes().hex().upper()
            fh.write(f"({T0 + i * step_s:.6f}) can0 {STATE_ID:03X}#{data}\n")


def convert_peak(argv: list[str], out: Path, cap_bytes: int) -> tuple[int, float, float, str]:
    """Exit status, peak RSS (MiB), seconds and the first stderr line of one conversion."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    command = [sys.executable, "-c", _CHILD, str(cap_bytes), "convert", *argv, "-o", str(out)]
    started = time.monotonic()
    run = subprocess.run(command, capture_output=True, text=True, env=env, check=False)
    seconds = time.monotonic() - started
    lines = run.stderr.strip().splitlines()
    rss = next((int(x.split()[1]) / 1024 for x in lines if x.startswith("maxrss_kib")), 0.0)
    said = next((x for x in lines if x.startswith("rtsid")), "")
    out.unlink(missing_ok=True)
    return run.returncode, rss, seconds, said[:80]


def run(args: argparse.Namespace) -> int:
    rows = 20_000 if args.quick else args.rows
    cap = int(args.cap_gib * (1 << 30))
    with tempfile.TemporaryDirectory(prefix="rtsid-bench-inputs-") as tmp:
        d = Path(tmp)
        write_candump(d / "good.log", 5000)
        write_candump(d / "silence.log", 50, step_s=3600.0)
        write_csv(d / "large.csv", rows)
        write_candump(d / "large.log", rows)
        cases: list[tuple[str, list[str], int]] = [
            ("--fs 1e9, 5000 frames (baseline)", [str(d / "good.log"), "--fs", "1e9"], 0),
            ("--fs 1e7, 5000 frames", [str(d / "good.log"), "--fs", "1e7"], 0),
            ("frames 1 h apart at 2500 Hz", [str(d / "silence.log"), "--fs", "2500"], 0),
            (f"CSV, {rows} rows", [str(d / "large.csv")], rows),
            (f"candump, {rows} frames", [str(d / "large.log"), "--fs", "2500"], rows),
        ]
        results: list[list[Any]] = []
        baseline = 0.0
        for label, argv, n in cases:
            code, rss, seconds, said = convert_peak(argv, d / "out.mcap", cap)
            baseline = baseline or rss
            per_row = f"{(rss - baseline) * 2**20 / n:.0f}" if n else "-"
            results.append([label, code, f"{rss:.0f}", per_row, f"{seconds:.1f}", said])
    print_table(
        "rtsid convert: peak RSS under a cap",
        ["input", "exit", "peak RSS MiB", "B/row above baseline", "s", "stderr"],
        results,
        note=f"address-space cap {args.cap_gib:g} GiB; rows cap 20 000 000 (docs/io.md)",
    )
    return 0
