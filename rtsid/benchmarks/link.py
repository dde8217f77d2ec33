"""``rtsid bench link``: the acquisition path through each transport and protocol.

Transports: ``virtual`` (the built-in ankle protocol at 2500 Hz, python-can ``virtual`` with
the embedded plant in this process), ``socketcand`` (the same, with ``rtsid plant`` as a
separate process on 127.0.0.1), ``twoframe`` (the second protocol, ``twoframe.dbc``: two
big-endian frames per sample, no counter, 2000 Hz, embedded plant on ``virtual``) and
``udp`` (datagrams of 10 samples at 2500 Hz from the embedded plant on 127.0.0.1). Each
streams the simulated ankle for ``--duration`` and reports:

* samples received, lost, and lost *unexplained* (not accounted for by the plant's own
  counters — the floor is 0);
* receive latency, frame send (the frame's bus timestamp, wall clock) → ring write (the
  row's host time), p50/p99/p99.9/max, from a preallocated histogram (5 µs bins);
* CPU of the acquisition thread (``time.thread_time()`` read inside the thread), % of one
  core, and the same for a bare ``bus.recv()`` loop on the same transport (baseline, ratio);
* resident memory of this process over time (start, end, slope);
* a ramp: the frame rate doubled from 2500 Hz in bounded steps until a step loses a sample,
  falls behind, or the plant cannot send that fast; the highest passing rate is reported
  (``virtual`` and ``socketcand``);
* with ``--faults P``: P % of the samples (UDP: datagrams) dropped, P % duplicated and P %
  reordered by the plant, and a table of the injected faults beside what the acquisition
  counted (they must be equal: lost = dropped, duplicates = duplicated, nothing
  out of order).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import selectors
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from rtsid.benchmarks.table import print_table
from rtsid.commands.common import add_duration
from rtsid.errors import ConfigError
from rtsid.link.acquisition import Acquisition, LinkCounters
from rtsid.link.config import FaultConfig, LinkConfig, PlantConfig, ProtocolConfig, UdpConfig
from rtsid.link.open import bus_factory, link_protocol, open_link
from rtsid.link.ring import RingBuffer

BIN_S = 5e-6
MAX_LATENCY_S = 1.0
RAMP_RATES_HZ = (2500, 5000, 10_000, 20_000, 40_000, 80_000)
TRANSPORTS = ("virtual", "socketcand", "twoframe", "udp")
RAMPED = ("virtual", "socketcand")  # the ramp measures the built-in protocol's transports
#: Steady rate of each transport, Hz (the second protocol runs at 2 kHz).
STEADY_RATE_HZ = {"virtual": 2500.0, "socketcand": 2500.0, "twoframe": 2000.0, "udp": 2500.0}
_PLANT_END_WAIT_S = 30.0  # how long stop() waits for a bounded plant to send its last block
SUSTAINED_P99_S = 0.050  # a step whose p99 latency exceeds this is falling behind


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_duration(parser, "steady run per transport (600)", default=600.0)
    parser.add_argument(
        "--transport",
        choices=(*TRANSPORTS, "both", "all"),
        default="both",
        help="which transport(s) to measure (both: virtual and socketcand; all: the four)",
    )
    parser.add_argument(
        "--faults",
        type=float,
        default=0.0,
        metavar="PERCENT",
        help="drop, duplicate and reorder this %% of samples/datagrams (0..50) and compare "
        "the counters with the injected faults",
    )
    parser.add_argument("--ramp-step-s", type=float, default=5.0, help="length of a ramp step")
    parser.add_argument("--no-ramp", action="store_true", help="skip the highest-rate ramp")
    parser.add_argument("--baseline-s", type=float, default=20.0, help="bare recv() loop run")
    parser.add_argument(
        "--reads",
        type=int,
        default=0,
        metavar="N",
        help="instead of streaming: the acquisition's work on N socketcand reads of 4 frames "
        "each, in this thread over loopback, through python-can's client (frame by frame) "
        "and rtsid's (batches), the same bytes; CPU µs per frame of each and of a bare "
        "socket read. --read-path runs one path only (for callgrind: N and 0 reads)",
    )
    parser.add_argument(
        "--socketcand-client",
        default="rtsid",
        help="[link] socketcand_client of the socketcand run: rtsid, python-can, or "
        "'python-can,rtsid' (both, one after the other in the same run: the before/after)",
    )
    parser.add_argument(
        "--read-path", choices=("bare", "python-can", "rtsid", "all"), default="all"
    )


# --------------------------------------------------------------------------- measurements
class LatencyHistogram:
    """Fixed 5 µs bins up to 1 s (preallocated; the last bin collects the overflow)."""

    def __init__(self) -> None:
        self.counts = np.zeros(int(MAX_LATENCY_S / BIN_S) + 1, dtype=np.int64)
        self.max_s = 0.0
        self.negative = 0

    def add(self, latency_s: np.ndarray) -> None:
        if latency_s.size == 0:
            return
        self.negative += int(np.count_nonzero(latency_s < 0))
        bins = np.clip((latency_s / BIN_S).astype(np.int64), 0, self.counts.size - 1)
        self.counts += np.bincount(bins, minlength=self.counts.size)
        self.max_s = max(self.max_s, float(latency_s.max()))

    def quantile_s(self, q: float) -> float:
        total = int(self.counts.sum())
        if total == 0:
            return float("nan")
        k = int(np.searchsorted(np.cumsum(self.counts), q * total, side="left"))
        return (k + 0.5) * BIN_S


def rss_mb() -> float:
    """Resident set size of this process, MB."""
    with open("/proc/self/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


@dataclass
class RunResult:
    """One steady run of one transport."""

    transport: str
    rate_hz: float
    duration_s: float
    received: int
    lost: int
    lost_explained: int
    sent: int
    latency: LatencyHistogram
    cpu_percent: float
    rss_mb: list[tuple[float, float]]
    counters: LinkCounters | None = None
    plant_rate_hz: float = float("nan")
    plant: PlantReport | None = None
    first_index: int = -1

    @property
    def lost_in_span(self) -> int:
        """Samples the plant destroyed between the first and the newest sample received
        (a drop before the first or in the last frames, still held, is not a gap yet)."""
        p, c = self.plant, self.counters
        if p is None or p.lost_indices is None or c is None:
            return self.lost_explained
        k = p.lost_indices
        return int(np.count_nonzero((k > self.first_index) & (k < c.newest_index)))

    @property
    def unexplained(self) -> int:
        return self.lost - self.lost_explained

    @property
    def rss_slope_mb_per_min(self) -> float:
        if len(self.rss_mb) < 3:
            return float("nan")
        t, m = np.array(self.rss_mb).T
        half = len(t) // 2  # after warm-up: the second half of the run
        return float(np.polyfit(t[half:] / 60.0, m[half:], 1)[0]) if t[-1] > t[half] else 0.0


# --------------------------------------------------------------------------- plants
@dataclass
class PlantReport:
    """What the plant says it did (sent samples, and losses it caused itself)."""

    samples: int
    lost: int
    achieved_hz: float
    duplicated: int = 0
    reordered: int = 0
    lost_indices: np.ndarray | None = None  # samples the plant destroyed (embedded plants)


PlantControl = tuple[Callable[[], None], Callable[[], PlantReport]]


def twoframe_protocol() -> ProtocolConfig:
    """``[link.protocol]`` of the second protocol (the packaged copy of its DBC)."""
    dbc = resources.files("rtsid.link").joinpath("twoframe.dbc")
    return ProtocolConfig(
        dbc=str(dbc),
        position="JointPosition.Position",
        torque="JointTorque.Torque",
        counter="",
        position_saturated="JointPosition.PositionSaturated",
        torque_saturated="JointTorque.TorqueSaturated",
        perturbation_on="JointPosition.PerturbationOn",
        discontinuity="JointPosition.Discontinuity",
        marker="JointPosition.TrialMarker",
        command="PerturbationCommand",
        diagnostics="",
        checksum="none",
    )


def _link_for(transport: str, rate_hz: float) -> LinkConfig:
    queue = int(4 * rate_hz) + 100
    if transport == "twoframe":
        return LinkConfig(
            interface="embedded", fs_hz=rate_hz, rx_queue_frames=queue, protocol=twoframe_protocol()
        )
    if transport == "udp":
        udp = UdpConfig(port=0, embedded_plant=True, receive_buffer_bytes=1 << 22)
        return LinkConfig(interface="udp", fs_hz=rate_hz, udp=udp)
    return LinkConfig(interface="embedded", fs_hz=rate_hz, rx_queue_frames=queue)


def _faults(percent: float) -> FaultConfig:
    rate = percent / 100.0
    return FaultConfig(drop_rate=rate, duplicate_rate=rate, reorder_rate=rate, seed=2026)


@contextlib.contextmanager
def embedded_plant(
    rate_hz: float,
    frames_per_tick: int,
    transport: str = "virtual",
    faults_percent: float = 0.0,
    max_samples: int = 0,
) -> Iterator[tuple[LinkConfig, PlantControl]]:
    """The embedded virtual plant; yields the link config and a stop() → PlantReport.

    With ``max_samples`` the plant ends by itself after that many samples and ``stop()``
    waits for it (bounded), so every fault it counted was on a sample it sent (it decides
    the faults of a whole block before pacing the block out).
    """
    link = _link_for(transport, rate_hz)
    plant_cfg = PlantConfig(
        fs_hz=rate_hz,
        frames_per_tick=frames_per_tick,
        diagnostics_hz=0.0,
        max_samples=max_samples,
        faults=_faults(faults_percent),
    )
    with open_link(link, plant_cfg, start_plant=False) as handle:
        plant = handle.plant
        assert plant is not None
        started: dict[str, float] = {}

        def start() -> None:
            started["t"] = time.monotonic()
            plant.start()

        def stop() -> PlantReport:
            if max_samples:
                plant.done.wait(_PLANT_END_WAIT_S)
            plant.stop()
            c = plant.counters()
            elapsed = time.monotonic() - started["t"]
            rate = c.samples / elapsed
            return PlantReport(
                c.samples, c.lost_by_plant, rate, c.duplicated, c.reordered, plant.lost_indices()
            )

        yield dataclasses.replace(handle.config, channel=handle.channel), (start, stop)


@contextlib.contextmanager
def subprocess_plant(
    rate_hz: float,
    frames_per_tick: int,
    transport: str = "socketcand",
    faults_percent: float = 0.0,
    max_samples: int = 0,
) -> Iterator[tuple[LinkConfig, PlantControl]]:
    """``rtsid plant`` in its own process on a free loopback port."""
    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "plant.toml"
        rate = faults_percent / 100.0
        config.write_text(
            f"[plant]\nfs_hz = {rate_hz}\nframes_per_tick = {frames_per_tick}\n"
            f"diagnostics_hz = 0.0\nmax_samples = {max_samples}\n[plant.faults]\n"
            f"drop_rate = {rate}\nduplicate_rate = {rate}\nreorder_rate = {rate}\nseed = 2026\n"
        )
        cmd = [sys.executable, "-m", "rtsid.cli", "plant", "--port", "0", "--config", str(config)]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            port = _read_port(proc)
            link = LinkConfig(
                interface="socketcand",
                port=port,
                fs_hz=rate_hz,
                ring_capacity_s=10.0,
                reconnect_after_stale_s=0.0,
            )
            started: dict[str, float] = {}

            def start() -> None:
                started["t"] = time.monotonic()

            def stop() -> PlantReport:
                proc.send_signal(signal.SIGTERM)
                out, _ = proc.communicate(timeout=30)
                report = json.loads(out.strip().splitlines()[-1])
                p, s = report["plant"], report["server"]
                lost = p["dropped"] + p["corrupted"] + p["shortened"] + p["silenced"]
                lost += p["skipped"] + p["tx_overflows"] + s["dropped_slow_client"]
                rate = p["samples"] / report["elapsed_s"]
                return PlantReport(s["frames_out"], lost, rate, p["duplicated"], p["reordered"])

            yield link, (start, stop)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=10)


def _read_port(proc: subprocess.Popen[str]) -> int:
    assert proc.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        if not sel.select(30.0):
            raise RuntimeError("rtsid plant did not start within 30 s")
    line = proc.stdout.readline()
    if "127.0.0.1:" not in line:
        raise RuntimeError(f"unexpected output of rtsid plant: {line!r}")
    return int(line.split("127.0.0.1:")[1].split()[0])


PLANTS = {
    "virtual": embedded_plant,
    "socketcand": subprocess_plant,
    "twoframe": embedded_plant,
    "udp": embedded_plant,
}


# --------------------------------------------------------------------------- one run
def measure(
    transport: str,
    rate_hz: float,
    duration_s: float,
    *,
    rss_every_s: float = 10.0,
    progress: bool = False,
    faults_percent: float = 0.0,
    socketcand_client: str = "rtsid",
) -> RunResult:
    """Stream ``duration_s`` at ``rate_hz`` through ``transport`` and measure."""
    frames_per_tick = max(4, int(rate_hz // 625))
    latency = LatencyHistogram()
    rss: list[tuple[float, float]] = []
    bounded = round(duration_s * rate_hz) if faults_percent else 0
    plant = PLANTS[transport](rate_hz, frames_per_tick, transport, faults_percent, bounded)
    with plant as (link, (start, stop)):
        link = dataclasses.replace(link, socketcand_client=socketcand_client)
        ring = RingBuffer(link.capacity_rows)
        acq = Acquisition(
            bus_factory(link),
            ring,
            fs_hz=rate_hz,
            stale_after_s=0.1,
            receive_timeout_s=link.receive_timeout_s,
            reconnect_after_stale_s=0.0,
            protocol=link_protocol(link),
        )
        with acq:
            offset = time.time() - time.monotonic()
            start()
            t0 = time.monotonic()
            cursor, next_rss, cpu0 = -1, t0, acq.counters().thread_cpu_s
            while (now := time.monotonic()) < t0 + duration_s:
                cursor = _drain(ring, cursor, latency, offset)
                if now >= next_rss:
                    rss.append((now - t0, rss_mb()))
                    next_rss += rss_every_s
                    if progress:
                        _progress(transport, now - t0, acq.counters(), latency)
                time.sleep(0.2)
            elapsed = time.monotonic() - t0
            cpu = acq.counters().thread_cpu_s - cpu0
            report = stop()
            _settle(acq)
            cursor = _drain(ring, cursor, latency, offset)
            counters = acq.counters()
    rss.append((elapsed, rss_mb()))
    return RunResult(
        transport,
        rate_hz,
        elapsed,
        counters.samples,
        counters.lost_samples,
        report.lost,
        report.samples,
        latency,
        100.0 * cpu / elapsed,
        rss,
        counters,
        report.achieved_hz,
        report,
        acq.anchor_index,
    )


def _drain(ring: RingBuffer, cursor: int, latency: LatencyHistogram, offset: float) -> int:
    while True:
        snap = ring.read_since(max(cursor, 0), 20_000)
        if len(snap) == 0:
            return cursor
        ok = snap.valid
        latency.add((snap.host_time_s[ok] + offset) - snap.bus_time_s[ok])
        cursor = snap.next_index


def _settle(acq: Acquisition, quiet_s: float = 0.5, limit_s: float = 30.0) -> None:
    """Wait until no frame arrived for ``quiet_s`` (the backlog is drained)."""
    end = time.monotonic() + limit_s
    while time.monotonic() < end and acq.counters().last_frame_age_s < quiet_s:
        time.sleep(0.05)


def _progress(transport: str, t: float, c: LinkCounters, lat: LatencyHistogram) -> None:
    print(
        f"  [{transport}] t={t:6.0f} s samples={c.samples} lost={c.lost_samples} "
        f"p99={lat.quantile_s(0.99) * 1e3:.2f} ms rss={rss_mb():.1f} MB",
        flush=True,
    )


def baseline_cpu_percent(transport: str, duration_s: float) -> float:
    """CPU of a bare ``bus.recv()`` loop (no decoding, no ring) on the same transport."""
    with PLANTS[transport](STEADY_RATE_HZ[transport], 4, transport) as (link, (start, stop)):
        bus = bus_factory(link)()
        result: dict[str, float] = {}
        done = threading.Event()

        def loop() -> None:
            c0, t0 = time.thread_time(), time.monotonic()
            while not done.is_set():
                bus.recv(0.05)
            result["cpu"] = (time.thread_time() - c0) / (time.monotonic() - t0)

        thread = threading.Thread(target=loop, name="rtsid-bench-recv")
        try:
            start()
            thread.start()
            time.sleep(duration_s)
            done.set()
            thread.join(5.0)
            stop()
        finally:
            done.set()
            if thread.is_alive():
                thread.join(5.0)
            bus.shutdown()
    return 100.0 * result.get("cpu", float("nan"))


def ramp(transport: str, step_s: float) -> list[tuple[RunResult, bool, str]]:
    """Double the rate until a step fails; each step is one bounded :func:`measure`."""
    steps = []
    for rate in RAMP_RATES_HZ:
        res = measure(transport, rate, step_s, rss_every_s=step_s)
        ok, why = _sustained(res)
        steps.append((res, ok, why))
        if not ok:
            break
    return steps


def _sustained(res: RunResult) -> tuple[bool, str]:
    if res.lost or res.lost_explained:
        return False, f"{res.lost} lost ({res.lost_explained} by the sender)"
    if res.received < res.sent:
        return False, f"{res.sent - res.received} not received"
    if res.plant_rate_hz < 0.98 * res.rate_hz:
        return False, f"sender reached only {res.plant_rate_hz:.0f} Hz"
    p99 = res.latency.quantile_s(0.99)
    if p99 > SUSTAINED_P99_S:
        return False, f"p99 latency {p99 * 1e3:.1f} ms: falling behind"
    return True, "ok"


# --------------------------------------------------------------------------- tables
def _ms(x: float) -> str:
    return f"{x * 1e3:.3f}"


def print_steady(results: list[RunResult], baselines: dict[str, float]) -> None:
    print("\nSteady rate (latency = frame send -> ring write; udp: datagram arrival -> ring)\n")
    print(
        "| transport | rate Hz | duration s | received | lost | lost unexplained | p50 ms "
        "| p99 ms | p99.9 ms | max ms | acq CPU % | bare recv CPU % | ratio "
        "| RSS start/end MB | RSS slope MB/min |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        base = baselines.get(r.transport, float("nan"))
        lat = r.latency
        print(
            f"| {r.transport} | {r.rate_hz:.0f} | {r.duration_s:.0f} | {r.received} | {r.lost} "
            f"| {r.unexplained} "
            f"| {_ms(lat.quantile_s(0.5))} | {_ms(lat.quantile_s(0.99))} "
            f"| {_ms(lat.quantile_s(0.999))} | {_ms(lat.max_s)} | {r.cpu_percent:.2f} "
            f"| {base:.2f} | {r.cpu_percent / base:.2f} "
            f"| {r.rss_mb[0][1]:.1f} / {r.rss_mb[-1][1]:.1f} | {r.rss_slope_mb_per_min:+.3f} |"
        )
    for r in results:
        print(
            f"\nRSS over time, {r.transport} (s: MB): "
            + ", ".join(f"{t:.0f}: {m:.1f}" for t, m in r.rss_mb[:: max(1, len(r.rss_mb) // 12)])
        )


def fault_mismatches(r: RunResult) -> list[str]:
    """What the acquisition counted differently from what the plant injected."""
    c, p = r.counters, r.plant
    if c is None or p is None:
        return ["no counters"]
    if p.lost_indices is None:  # a plant in its own process: only totals, compared below
        return []
    wrong = []
    if c.lost_samples != r.lost_in_span:
        wrong.append(f"lost {c.lost_samples} != dropped {r.lost_in_span}")
    if c.duplicates != p.duplicated:
        wrong.append(f"duplicates {c.duplicates} != duplicated {p.duplicated}")
    if c.out_of_order or c.unpaired or c.malformed:
        wrong.append(
            f"out of order {c.out_of_order}, unpaired {c.unpaired}, malformed {c.malformed}"
        )
    return wrong


def print_faults(results: list[RunResult], percent: float) -> None:
    print(f"\nInjected faults ({percent:g} % drop, duplicate, reorder) vs counted\n")
    print(
        "| transport | samples sent | dropped (plant) | of them inside the stream | lost (acq) "
        "| duplicated (plant) | duplicates (acq) | reordered (plant) | out of order (acq) "
        "| unpaired | result |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        c, p = r.counters, r.plant
        if c is None or p is None:
            continue
        wrong = fault_mismatches(r)
        result = "equal" if not wrong else "DIFFER: " + "; ".join(wrong)
        if p.lost_indices is None:
            result = "not compared: the plant runs in its own process and its totals include "
            result += "faults on samples sent before the client joined"
        print(
            f"| {r.transport} | {p.samples} | {p.lost} | {r.lost_in_span} | {c.lost_samples} "
            f"| {p.duplicated} "
            f"| {c.duplicates} | {p.reordered} | {c.out_of_order} | {c.unpaired} "
            f"| {result} |"
        )


def print_ramp(transport: str, steps: list[tuple[RunResult, bool, str]]) -> None:
    print(f"\nRamp, {transport} (each step {steps[0][0].duration_s:.0f} s)\n")
    print("| rate Hz | sender Hz | received | lost | p50 ms | p99 ms | acq CPU % | result |")
    print("|---|---|---|---|---|---|---|---|")
    for res, ok, why in steps:
        print(
            f"| {res.rate_hz:.0f} | {res.plant_rate_hz:.0f} | {res.received} | {res.lost} "
            f"| {_ms(res.latency.quantile_s(0.5))} | {_ms(res.latency.quantile_s(0.99))} "
            f"| {res.cpu_percent:.1f} | {'pass' if ok else 'FAIL: ' + why} |"
        )
    best = max((r.rate_hz for r, ok, _ in steps if ok), default=0.0)
    print(f"\nHighest rate sustained without loss, {transport}: {best:.0f} frames/s")


def _transports(choice: str) -> tuple[str, ...]:
    if choice == "both":
        return ("virtual", "socketcand")
    if choice == "all":
        return TRANSPORTS
    return (choice,)


# --------------------------------------------------------------------------- per-read cost
READ_PATHS = ("bare", "python-can", "rtsid")


def _read_stream(reads: int, per_read: int) -> list[bytes]:
    """The plant's socketcand bytes for ``reads`` reads of ``per_read`` frames (2500 Hz)."""
    from rtsid.link.mapping import builtin_protocol
    from rtsid.link.socketcand import format_frame

    n = reads * per_read
    index = np.arange(n, dtype=np.int64)
    position = np.round(20_000 * np.sin(index / 50.0)).astype(np.int64)
    torque = np.round(9_000 * np.cos(index / 70.0)).astype(np.int64)
    frames = builtin_protocol().encode_samples(index, position, torque, np.zeros(n, np.int64))
    t0 = 1_764_000_000.0
    lines = [format_frame(g[0], t0 + k / 2500.0) for k, g in enumerate(frames)]
    return ["".join(lines[r * per_read : (r + 1) * per_read]).encode("ascii") for r in range(reads)]


def _handshake_peer(listener: Any, out: dict[str, Any]) -> None:
    """Accept one client and answer its handshake one reply per command (python-can reads
    each reply with one recv)."""
    import socket

    conn, _ = listener.accept()
    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    conn.sendall(b"< hi >")
    for _ in range(2):  # < open can0 >, < rawmode >
        seen = b""
        while b">" not in seen:
            seen += conn.recv(64)
        conn.sendall(b"< ok >")
    out["conn"] = conn


def read_path_cpu_us(path: str, reads: int, per_read: int = 4) -> float:
    """CPU µs per frame of ``path`` handling ``reads`` reads of ``per_read`` frames.

    The frames are written to a loopback connection one read's worth at a time and read
    back at once by ``path``: ``bare`` (``socket.recv`` only), ``python-can`` (python-can's
    socketcand client, one ``recv`` and one :meth:`Acquisition._handle` per frame, the
    acquisition before issue 22) or ``rtsid`` (:class:`~rtsid.link.socketcand.SocketcandBus`
    ``recv_chunk`` and :meth:`Acquisition._on_chunk`). Includes writing the bytes.
    """
    import socket

    from rtsid.link.socketcand import SocketcandBus

    chunks = _read_stream(reads, per_read)
    with socket.create_server(("127.0.0.1", 0)) as listener:
        port = listener.getsockname()[1]
        peer: dict[str, Any] = {}
        helper = threading.Thread(target=_handshake_peer, args=(listener, peer))
        helper.start()
        if path == "python-can":
            import can

            bus: Any = can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="can0")
        else:
            bus = SocketcandBus("can0", "127.0.0.1", port)
        helper.join(10.0)
        feeder = peer["conn"]
        ring = RingBuffer(25_000)
        acq = Acquisition(bus, ring)
        raw = getattr(bus, "_sock", None)
        try:
            cpu0 = time.thread_time()
            for chunk in chunks:
                feeder.sendall(chunk)
                if path == "bare":
                    assert raw is not None
                    got = 0
                    while got < len(chunk):
                        got += len(raw.recv(1 << 16))
                elif path == "rtsid":
                    done = 0
                    while done < per_read:
                        done += acq._on_chunk(bus.recv_chunk(1.0), time.monotonic())
                else:
                    for _ in range(per_read):
                        acq._handle(bus.recv(1.0), time.monotonic())
            cpu = time.thread_time() - cpu0
        finally:
            feeder.close()
            bus.shutdown()
    if path != "bare" and reads:
        assert acq.counters().samples == reads * per_read, acq.counters()
    return 1e6 * cpu / max(1, reads * per_read)


def print_read_paths(reads: int, which: str) -> None:
    paths = READ_PATHS if which == "all" else (which,)
    costs = {p: read_path_cpu_us(p, reads) for p in paths}
    rows = [[p, reads * 4, costs[p], costs[p] * 2500 / 1e4] for p in paths]
    print_table(
        f"The acquisition's work per frame, {reads} socketcand reads of 4 frames (the plant's "
        "tick), one thread, loopback",
        ["path", "frames", "CPU µs/frame", "% of a core at 2500 frames/s"],
        rows,
        note="bare: writing the bytes and one socket read (the floor); python-can: its client "
        "parses each frame into a can.Message, then the acquisition handles it (before issue "
        "22); rtsid: one read parsed at once, the state frames decoded together and written "
        "to the ring as one block. CPU is thread time: noisy on a loaded machine; run it "
        "under callgrind (--read-path P, N and 0 reads) for instruction counts.",
    )


def run(args: argparse.Namespace) -> int:
    if args.reads:
        print_read_paths(args.reads, args.read_path)
        return 0
    duration = 5.0 if args.quick else args.duration
    step = 1.0 if args.quick else args.ramp_step_s
    base_s = 2.0 if args.quick else args.baseline_s
    if not 0.0 <= args.faults <= 50.0:
        raise ConfigError(f"--faults {args.faults} is not a percentage in 0..50")
    transports = _transports(args.transport)
    print(f"rtsid bench link: {duration:.0f} s per transport, pid {os.getpid()}", flush=True)
    results, baselines = [], {}
    clients = [c.strip() for c in args.socketcand_client.split(",") if c.strip()]
    for transport in transports:
        baselines[transport] = baseline_cpu_percent(transport, base_s)
        for client in clients if transport == "socketcand" else ["rtsid"]:
            result = measure(
                transport,
                STEADY_RATE_HZ[transport],
                duration,
                progress=not args.quick,
                rss_every_s=1.0 if args.quick else 10.0,
                faults_percent=args.faults,
                socketcand_client=client,
            )
            if transport == "socketcand":
                baselines[f"socketcand ({client})"] = baselines[transport]
                result = dataclasses.replace(result, transport=f"socketcand ({client})")
            results.append(result)
    print_steady(results, baselines)
    if args.faults:
        print_faults(results, args.faults)
    if not args.no_ramp:
        for transport in (t for t in transports if t in RAMPED):
            print_ramp(transport, ramp(transport, step))
    # with faults, a plant in its own process may have destroyed samples before the client
    # joined: fewer lost than it injected is that, more would be the acquisition's doing
    bad = [
        r.transport
        for r in results
        if (r.unexplained > 0 if args.faults else r.unexplained != 0) or fault_mismatches(r)
    ]
    return 1 if bad else 0
