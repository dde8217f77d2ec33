"""``rtsid bench io``: MCAP logger cost at the daemon's rates and zenoh one-way latency.

Tables:

1. MCAP logger, real time at the daemon's rates (2500 samples/s in 100 ms batches, 50
   estimates/s, 2 status/s): caller-side cost of each ``log_*`` call (median, p99), process
   CPU with the logger against the same loop with the logger disabled (baseline), bytes/s,
   compression, and what the bounded queue dropped.
2. MCAP logger flat out: how many seconds of daemon traffic the writer thread absorbs per
   second of wall time, with the queue's drop counter.
3. zenoh one-way latency, publisher → subscriber in another process (spawn), over
   ``tcp/127.0.0.1``: an 8-byte raw put (baseline) against an estimate published by
   :class:`~rtsid.io.zenoh_link.ZenohPublisher`.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import queue
import socket
import struct
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from rtsid.runtime.power import PM_QOS_DEVICE, cpu_latency_request

FS_HZ = 2500.0
BATCH = 250  # samples per batch: 100 ms
HOP_S = 0.02


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=float, default=20.0, help="real-time MCAP run, s")
    parser.add_argument("--messages", type=int, default=1500, help="zenoh messages per kind")
    parser.add_argument("--directory", default=None, help="where to write (default: a temp dir)")


def _estimate(seq: int) -> dict[str, Any]:
    from rtsid.io.schemas import ESTIMATE_FIELDS

    est: dict[str, Any] = dict.fromkeys(ESTIMATE_FIELDS, 0.0)
    est.update(
        robot="bench",
        joint="ankle",
        seq=seq,
        window_start_index=seq * 50,
        window_end_index=seq * 50 + 749,
        t_start_s=seq * HOP_S,
        t_end_s=seq * HOP_S + 0.2996,
        I=0.0121,
        B=0.93,
        K=118.7,
        I_se=0.0011,
        B_se=0.051,
        K_se=2.31,
        vaf=95.3,
        vaf_irf=97.1,
        vaf_fit=98.0,
        compute_ms=3.1,
        latency_ms=4.2,
        ok=True,
        reason=None,
        flags=[],
        host_time_ns=time.time_ns(),
    )
    return est


def _status(seq: int) -> dict[str, Any]:
    return {
        "robot": "bench",
        "joint": "ankle",
        "host_time_ns": time.time_ns(),
        "uptime_s": seq * 0.5,
        "cpu_percent": 10.0,
        "rss_mb": 80.0,
        "acquisition": {"frames": seq * 2500, "samples": seq * 1250, "gaps": 0},
        "worker": {"estimates": seq * 25, "withheld": {}, "overruns": 0, "deadline_misses": 0},
        "mcap": {"state": "recording", "dropped": 0},
        "zenoh": {"state": "up"},
    }


def _cpu_s() -> float:
    t = os.times()
    return t.user + t.system


def _pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if values else float("nan")


def _daemon_traffic(logger: Any, seconds: float, timings: dict[str, list[float]]) -> None:
    """The daemon's logging pattern on absolute 20 ms deadlines for ``seconds``."""
    from rtsid.io.schemas import encode_estimate

    rng = np.random.default_rng(0)
    pos = rng.normal(size=BATCH) * 0.05
    tq = rng.normal(size=BATCH) * 20.0
    ticks = round(seconds / HOP_S)
    deadline = time.monotonic()
    for tick in range(ticks):
        est = _estimate(tick)
        t0 = time.perf_counter()
        payload = encode_estimate(est)  # once, shared with zenoh in the daemon
        t1 = time.perf_counter()
        logger.log_estimate(payload)
        t2 = time.perf_counter()
        timings["encode_estimate"].append(t1 - t0)
        timings["log_estimate"].append(t2 - t1)
        if tick % 5 == 0:
            k = tick // 5
            t0 = time.perf_counter()
            logger.log_samples(k * BATCH, pos, tq)
            timings["log_samples"].append(time.perf_counter() - t0)
        if tick % 25 == 0:
            t0 = time.perf_counter()
            logger.log_status(_status(tick // 25))
            timings["log_status"].append(time.perf_counter() - t0)
        deadline += HOP_S
        time.sleep(max(0.0, deadline - time.monotonic()))


def _mcap_real_time(directory: Path, seconds: float) -> None:
    from rtsid.io.mcap_log import McapConfig, McapLogger

    rows = []
    results: dict[str, Any] = {}
    for label, enabled in (("logger disabled (baseline)", False), ("logger on", True)):
        cfg = McapConfig(directory=str(directory / label.split()[1]), enabled=enabled)
        timings: dict[str, list[float]] = {
            "log_samples": [],
            "encode_estimate": [],
            "log_estimate": [],
            "log_status": [],
        }
        logger = McapLogger(cfg, robot="bench", joint="ankle", fs_hz=FS_HZ)
        cpu0, wall0 = _cpu_s(), time.monotonic()
        with logger:
            _daemon_traffic(logger, seconds, timings)
        cpu = 100.0 * (_cpu_s() - cpu0) / (time.monotonic() - wall0)
        results[label] = (cpu, timings, logger.stats())
    base_cpu = results["logger disabled (baseline)"][0]
    print(
        f"\nMCAP logger at the daemon's rates for {seconds:g} s "
        "(2500 samples/s in 100 ms batches, 50 estimates/s, 2 status/s)"
    )
    print(f"{'':30}{'CPU % of a core':>16}{'vs baseline':>13}")
    for label, (cpu, _t, _s) in results.items():
        print(f"{label:30}{cpu:>16.1f}{cpu - base_cpu:>+13.1f}")
    cpu, timings, stats = results["logger on"]
    print(f"\n{'caller cost per call':30}{'median µs':>12}{'p99 µs':>10}{'max µs':>10}{'calls':>8}")
    for kind, values in timings.items():
        us = [v * 1e6 for v in values]
        rows.append((kind, _pct(us, 50), _pct(us, 99), max(us), len(us)))
        print(f"{kind:30}{_pct(us, 50):>12.1f}{_pct(us, 99):>10.1f}{max(us):>10.1f}{len(us):>8}")
    size = sum(Path(f).stat().st_size for f in stats["files"])
    from rtsid.io.mcap_read import summarize

    print(
        f"\nfile: {size / seconds / 1024:.1f} KiB/s ({size / seconds * 3600 / 2**20:.0f} MiB/h), "
        f"messages written {stats['written']}, dropped {stats['dropped']}, lost {stats['lost']}, "
        f"errors {stats['errors']}; read back: {summarize(stats['files'][0]).messages} messages"
    )


def _mcap_flat_out(directory: Path, batches: int) -> None:
    from rtsid.io.mcap_log import McapConfig, McapLogger

    rng = np.random.default_rng(1)
    pos = rng.normal(size=BATCH) * 0.05
    tq = rng.normal(size=BATCH) * 20.0
    print(
        f"\nMCAP logger flat out: {batches} batches = {batches * BATCH / FS_HZ:g} s of daemon "
        "traffic pushed without pacing"
    )
    print(
        f"{'queue_size':>12}{'written':>10}{'dropped':>9}{'wall s':>9}{'× real time':>13}"
        f"{'writer msgs/s':>15}"
    )
    for queue_size in (4096, 1_000_000):
        cfg = McapConfig(directory=str(directory / f"flat{queue_size}"), queue_size=queue_size)
        logger = McapLogger(cfg, robot="bench", joint="ankle", fs_hz=FS_HZ)
        t0 = time.perf_counter()
        with logger:
            for k in range(batches):
                logger.log_samples(k * BATCH, pos, tq)
                for j in range(5):
                    logger.log_estimate(_estimate(k * 5 + j))
                if k % 5 == 0:
                    logger.log_status(_status(k // 5))
        wall = time.perf_counter() - t0
        s = logger.stats()
        written = s["written"]
        # daemon traffic: 1 sample batch + 5 estimates + 0.2 status per 100 ms = 62 messages/s
        real_time = written / (62.0 * wall)
        print(
            f"{queue_size:>12}{written:>10}{s['dropped']:>9}{wall:>9.2f}"
            f"{real_time:>13.1f}{written / wall:>15.0f}"
        )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _subscriber(endpoint: str, ready: Any, out: Any) -> None:
    """Child: one-way latencies (µs) of raw puts and estimates, read with a blocking channel
    ``recv()`` in the main thread (callbacks showed a worse tail, see docs/io.md)."""
    import json

    import zenoh

    from rtsid.io.zenoh_link import subscriber_config

    lat: dict[str, list[float]] = {"raw": [], "estimate": []}
    with zenoh.open(subscriber_config((endpoint,), mode="client")) as session:
        sub = session.declare_subscriber(f"{_BASE}/*", zenoh.handlers.FifoChannel(4096))
        ready.set()
        while True:
            sample = sub.recv()
            now = time.time_ns()
            kind = str(sample.key_expr).rsplit("/", 1)[-1]
            data = sample.payload.to_bytes()
            if kind == "raw":
                lat["raw"].append((now - struct.unpack("<q", data)[0]) / 1e3)
            elif kind == "estimate":
                lat["estimate"].append((now - json.loads(data)["host_time_ns"]) / 1e3)
            elif kind == "end":
                break
    out.put(lat)


_BASE = "rtsid/bench/ankle"


def _zenoh_latency(messages: int, cpu_latency_us: int = -1) -> dict[str, list[float]]:
    """One-way latencies (µs) by kind, with the daemon's PM QoS request held as configured."""
    with cpu_latency_request(cpu_latency_us):
        return _zenoh_latency_run(messages, cpu_latency_us)


def _zenoh_latency_run(messages: int, cpu_latency_us: int) -> dict[str, list[float]]:
    import zenoh

    from rtsid.io.schemas import encode_estimate
    from rtsid.io.zenoh_link import ZenohConfig, ZenohPublisher

    port = _free_port()
    cfg = ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",), robot="bench", joint="ankle")
    ctx = mp.get_context("spawn")
    ready, out = ctx.Event(), ctx.Queue()
    warmup = 50
    child = ctx.Process(target=_subscriber, args=(f"tcp/127.0.0.1:{port}", ready, out))
    lat: dict[str, list[float]] = {}
    calls: dict[str, list[float]] = {"raw": [], "estimate": []}  # publisher-side call cost
    try:
        with ZenohPublisher(cfg) as pub:
            session = pub._entities.session if pub._entities is not None else None
            if session is None:
                print(f"zenoh unavailable: {pub.stats()['last_error']}")
                return {}
            raw = session.declare_publisher(
                f"{_BASE}/raw", congestion_control=zenoh.CongestionControl.DROP, express=True
            )
            child.start()
            ready.wait(30)
            time.sleep(0.5)  # let the subscriptions propagate; the first messages warm up
            deadline = time.monotonic()
            for seq in range(warmup + messages):  # raw and estimate alternate, 10 ms apart
                t0 = time.perf_counter()
                raw.put(struct.pack("<q", time.time_ns()))
                calls["raw"].append((time.perf_counter() - t0) * 1e6)
                deadline += HOP_S / 2
                time.sleep(max(0.0, deadline - time.monotonic()))
                est = _estimate(seq)
                est["host_time_ns"] = time.time_ns()
                payload = encode_estimate(est)
                t0 = time.perf_counter()
                pub.publish_estimate(payload)
                calls["estimate"].append((time.perf_counter() - t0) * 1e6)
                deadline += HOP_S / 2
                time.sleep(max(0.0, deadline - time.monotonic()))
            for _ in range(200):  # bounded: until the child reports
                session.put(f"{_BASE}/end", b"")
                try:
                    lat = {k: v[warmup:] for k, v in out.get(timeout=0.1).items()}
                    break
                except queue.Empty:
                    continue
            raw.undeclare()
    finally:
        if child.pid is not None:
            child.join(timeout=30)
        if child.pid is not None and child.is_alive():
            child.kill()
            child.join(timeout=10)
    print(
        f"\nzenoh one-way latency, publisher → subscriber in another process, "
        f"tcp/127.0.0.1, {messages} messages each at 50 Hz, interleaved 10 ms apart, "
        f"cpu_latency_us = {cpu_latency_us}"
    )
    print(
        f"{'payload':38}{'received':>9}{'median µs':>11}{'p99 µs':>9}{'max µs':>9}"
        f"{'× baseline':>12}{'put call median/p99 µs':>24}"
    )
    base = _pct(lat.get("raw", []), 50)
    for label, key in (
        ("8-byte raw put (baseline)", "raw"),
        ("estimate JSON via ZenohPublisher", "estimate"),
    ):
        v = lat.get(key, [])
        med = _pct(v, 50)
        print(
            f"{label:38}{len(v):>9}{med:>11.0f}{_pct(v, 99):>9.0f}"
            f"{(max(v) if v else float('nan')):>9.0f}{med / base:>12.2f}"
            f"{_pct(calls[key], 50):>14.0f} / {_pct(calls[key], 99):<7.0f}"
        )
    return lat


def _compare_pm_qos(without: dict[str, list[float]], held: dict[str, list[float]]) -> None:
    print("\nzenoh estimate latency without and with the PM QoS request (same run)")
    print(
        f"{'cpu_latency_us':>16}{'median µs':>11}{'p99 µs':>9}{'p99.9 µs':>10}{'p99 / without':>15}"
    )
    base = _pct(without.get("estimate", []), 99)
    for label, lat in (("-1 (none)", without), ("0 (poll)", held)):
        v = lat.get("estimate", [])
        print(
            f"{label:>16}{_pct(v, 50):>11.0f}{_pct(v, 99):>9.0f}{_pct(v, 99.9):>10.0f}"
            f"{_pct(v, 99) / base:>15.2f}"
        )


def _load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} CPUs"


def run(args: argparse.Namespace) -> int:
    print(f"rtsid bench io: {_load()}")
    seconds = 3.0 if args.quick else args.seconds
    messages = 200 if args.quick else args.messages
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(args.directory or tmp)
        _mcap_real_time(directory, seconds)
        _mcap_flat_out(directory, 200 if args.quick else 2000)
    without = _zenoh_latency(messages, -1)
    if os.access(PM_QOS_DEVICE, os.W_OK):
        _compare_pm_qos(without, _zenoh_latency(messages, 0))
    else:
        print(f"\n{PM_QOS_DEVICE} is not writable: the PM QoS comparison is skipped")
    print(f"\nafter: {_load()}")
    return 0
