"""``rtsid bench markers``: trial markers against a daemon in another process, then kill -9.

A daemon (``rtsid run`` on the embedded plant, zenoh on loopback, multicast off) runs in its
own process; this process sends N marks at random intervals as ``rtsid mark`` does (a zenoh
query with a marker_id) and times each:

- **round trip**: query sent → acknowledgement received (stamp, MCAP write + flush, reply), ms;
- **to stamp**: query sent → the daemon's host time in the marker (``host_time_ns``, taken when
  the session desk stamped it; same machine, same clock), ms.

Then the daemon is killed with SIGKILL, its recording recovered and read with
:func:`rtsid.io.recording.read_session`: every acknowledged marker must be there once, on the
sample its acknowledgement named.
"""

from __future__ import annotations

import argparse
import json
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

from rtsid.benchmarks.table import median_p99, print_table


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--marks", type=int, default=1000, help="marks to send (1000)")
    parser.add_argument(
        "--max-gap-ms", type=float, default=20.0, help="random wait before each mark, 0…this ms"
    )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _send_marks(port: int, marks: int, max_gap_s: float) -> list[tuple[str, int, int, int, int]]:
    """``(marker_id, sample_index, sent_ns, acked_ns, stamped_ns)`` of each acknowledged mark."""
    import zenoh

    from rtsid.io.zenoh_link import open_when_reachable, query, subscriber_config

    conf = subscriber_config((f"tcp/127.0.0.1:{port}",), mode="client")
    deadline = time.monotonic() + 60.0
    session = open_when_reachable(conf, timeout_s=60.0)
    rng = random.Random(1)
    acked = []
    with session:
        while not query(session, "rtsid/bench/ankle/session", timeout_s=2.0).replies:
            if time.monotonic() > deadline:
                raise RuntimeError("the daemon never answered")
        markers = session.declare_subscriber(
            "rtsid/bench/ankle/marker", zenoh.handlers.FifoChannel(marks + 16)
        )
        for k in range(marks):
            time.sleep(rng.uniform(0.0, max_gap_s))
            marker_id = uuid.uuid4().hex
            body = json.dumps({"label": f"trial {k}", "marker_id": marker_id}).encode()
            sent = time.time_ns()
            answer = query(session, "rtsid/bench/ankle/mark", timeout_s=5.0, payload=body)
            done = time.time_ns()
            if len(answer.replies) == 1:
                index = json.loads(answer.replies[0][1])["sample_index"]
                acked.append((marker_id, index, sent, done))
        stamped = {}
        for _ in range(len(acked)):
            sample = markers.recv()
            message = json.loads(sample.payload.to_bytes())
            stamped[message["marker_id"]] = message["host_time_ns"]
        markers.undeclare()
    return [(m, i, s, d, stamped.get(m, 0)) for m, i, s, d in acked]


def run(args: argparse.Namespace) -> int:
    from rtsid.io.mcap_read import recover
    from rtsid.io.recording import read_session

    marks = 100 if args.quick else args.marks
    port = _free_port()
    with tempfile.TemporaryDirectory(prefix="rtsid-bench-markers-") as tmp:
        folder = Path(tmp)
        config = folder / "daemon.toml"
        config.write_text(
            f'[zenoh]\nrobot = "bench"\nlisten = ["tcp/127.0.0.1:{port}"]\n'
            f'[mcap]\ndirectory = "{folder / "rec"}"\n[session]\nsubject = "bench"\n'
        )
        daemon = subprocess.Popen(
            [sys.executable, "-m", "rtsid.cli", "run", "--config", str(config), "--quiet"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            acked = _send_marks(port, marks, args.max_gap_ms / 1e3)
        finally:
            daemon.send_signal(signal.SIGKILL)
            daemon.wait(timeout=30)
        (damaged,) = sorted((folder / "rec").glob("*.mcap"))
        fixed = folder / "recovered.mcap"
        recover(damaged, fixed)
        recorded = [(m["marker_id"], m["sample_index"]) for m in read_session(fixed).markers]
    on_sample = {m: i for m, i, *_ in acked}
    lost = sum(1 for m in on_sample if m not in dict(recorded))
    wrong = sum(1 for m, i in recorded if m in on_sample and on_sample[m] != i)
    ids = [m for m, _ in recorded]
    trips = [(d - s) / 1e6 for _, _, s, d, _ in acked]
    stamps = [(t - s) / 1e6 for _, _, s, _, t in acked if t]
    rows = []
    for name, values in (("round trip (ms)", trips), ("to stamp (ms)", stamps)):
        med, p99 = median_p99(values)
        rows.append([name, len(values), med, p99, max(values)])
    print_table(
        f"{marks} marks at random 0–{args.max_gap_ms:g} ms gaps, daemon in another process "
        "(loopback zenoh, client session)",
        ["", "n", "median", "p99", "max"],
        rows,
    )
    print_table(
        "After kill -9 and rtsid recover",
        ["sent", "acknowledged", "recorded", "lost (acked, not recorded)", "twice", "wrong sample"],
        [[marks, len(acked), len(recorded), lost, len(ids) - len(set(ids)), wrong]],
    )
    return 0 if lost == 0 and wrong == 0 and len(ids) == len(set(ids)) else 1
