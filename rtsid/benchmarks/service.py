"""``rtsid bench service``: the daemon at 2500 Hz (20 ms hops, or ``--hop-ms``), measured
from outside.

The daemon runs as its own process on the embedded virtual plant; this process subscribes
over zenoh (a channel, not a callback) and measures, per estimate, the end-to-end latency from
the window's last sample reaching the daemon to the message reaching this subscriber:
``latency_ms`` (sample arrival → publication, measured by the daemon on its monotonic clock)
plus publication → reception (both on this machine's wall clock). CPU and memory come from
the daemon's own status messages. A second phase repeats it with the other core kept busy by
a CPU-bound process; the ratio columns compare the two phases of the same run.

After each phase the daemon's own recording is replayed in this process (one thread, the same
windows, the same code): its compute per window is the path's cost on the plant's signal, the
baseline the live compute is set against, and its numbers must equal the live ones.
"""

from __future__ import annotations

import argparse
import bisect
import json
import multiprocessing as mp
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rtsid.benchmarks.table import median_p99, print_table
from rtsid.errors import InputDataError
from rtsid.replay import ReplayResult, replay_file
from rtsid.runtime.power import PM_QOS_DEVICE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--duration", type=float, default=600.0, help="seconds per phase (600)")
    parser.add_argument("--no-load-phase", action="store_true", help="skip the loaded phase")
    parser.add_argument(
        "--hop-ms",
        type=float,
        default=20.0,
        help="the daemon's [worker] hop_s in ms (20; 4: 250 estimates/s)",
    )
    parser.add_argument(
        "--no-replay",
        action="store_true",
        help="skip replaying each phase's recording afterwards (the baseline table; it takes "
        "about the phase's CPU time again)",
    )
    parser.add_argument(
        "--lowpass-hz",
        type=float,
        default=None,
        help="the daemon's [estimator] lowpass_hz (default: chosen from the data; the virtual "
        "plant's signal then makes the plan analyse at the full 2500 Hz)",
    )
    parser.add_argument(
        "--switch-interval-ms",
        type=float,
        default=None,
        help="the daemon's [daemon] gil_switch_interval_s in ms (default: the daemon's)",
    )
    parser.add_argument(
        "--transport",
        choices=("socketcand", "embedded"),
        default="socketcand",
        help="socketcand: the simulated robot runs as its own process ('rtsid plant') as a "
        "real rig would; embedded: inside the daemon (the quick-start setup)",
    )
    parser.add_argument(
        "--socketcand-client",
        choices=("rtsid", "python-can"),
        default="rtsid",
        help="the daemon's [link] socketcand_client (python-can: the acquisition before "
        "issue 22, a can.Message per frame)",
    )
    parser.add_argument(
        "--slow-lane",
        default="process",
        help="process (the daemon's default), thread, off, or a comma-separated list run one "
        "after the other: the reflex slow lane's mode (on, the virtual plant also has a "
        "stretch reflex, so the lane judges it present and the fast lane subtracts it)",
    )
    parser.add_argument(
        "--plant-reflex",
        choices=("on", "off"),
        default="on",
        help="with the slow lane on, give the virtual plant a stretch reflex (on: the lane "
        "judges it present and the fast lane subtracts it every window; off: the daemon's "
        "and the plant's defaults, the lane judges it absent)",
    )
    parser.add_argument(
        "--realtime-priority",
        type=int,
        default=0,
        help="the daemon's [daemon] realtime_priority (0: normal scheduling; 1-99: its "
        "acquisition and worker threads in SCHED_FIFO, ahead of the machine's other work)",
    )
    parser.add_argument(
        "--cpu-latency-us",
        type=int,
        default=0,
        help="the daemon's [daemon] cpu_latency_us (0, the lab setting: idle CPUs poll; -1: "
        "no PM QoS request). Falls back to -1 when /dev/cpu_dma_latency is not writable",
    )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _burn(seconds: float) -> None:
    """Keep one core busy for a bounded time (the 'other core loaded' phase)."""
    end = time.monotonic() + seconds
    x = 0
    while time.monotonic() < end:
        x = (x * 1103515245 + 12345) % 2147483648


def _cpu_jiffies() -> tuple[int, int]:
    """(steal, total) jiffies of the whole machine from /proc/stat (0, 0 elsewhere)."""
    try:
        with open("/proc/stat") as fh:
            fields = [int(v) for v in fh.readline().split()[1:]]
    except (OSError, ValueError):
        return 0, 0
    steal = fields[7] if len(fields) > 7 else 0
    return steal, sum(fields)


class StealTimeline:
    """The machine's cumulative steal time, sampled every few ms on a thread of this process,
    so a deadline miss can be set against what the hypervisor took while it happened."""

    def __init__(self, period_s: float = 0.005) -> None:
        self.period_s = period_s
        self.times_ns: list[int] = []
        self.steal_s: list[float] = []
        self._tick_s = 1.0 / os.sysconf("SC_CLK_TCK")
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="steal-sampler", daemon=True)

    def __enter__(self) -> StealTimeline:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self.times_ns.append(time.time_ns())
            self.steal_s.append(_cpu_jiffies()[0] * self._tick_s)

    def stolen_s(self, start_ns: int, end_ns: int) -> float:
        """Steal time (summed over CPUs) between the samples bracketing the interval, s."""
        lo = max(0, bisect.bisect_right(self.times_ns, start_ns) - 1)
        hi = min(len(self.times_ns) - 1, bisect.bisect_left(self.times_ns, end_ns))
        return self.steal_s[hi] - self.steal_s[lo] if hi > lo else 0.0


@dataclass
class Phase:
    name: str
    steal_percent: float = float("nan")
    e2e_ms: list[float] = field(default_factory=list)
    daemon_ms: list[float] = field(default_factory=list)
    transit_ms: list[float] = field(default_factory=list)
    compute_ms: list[float] = field(default_factory=list)
    withheld: int = 0
    estimates: int = 0
    status: list[dict[str, Any]] = field(default_factory=list)
    # (message built ns, compute ms) of every estimate over its budget
    stalls: list[tuple[int, float]] = field(default_factory=list)
    stalls_with_steal: int = 0
    # the daemon's log lines of its deadline misses (what each coincided with)
    miss_lines: list[str] = field(default_factory=list)
    seconds: float = 0.0
    # window end index -> (K, B, I) of every live estimate received
    live_values: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    replay: ReplayResult | None = None
    #: the daemon's hop (its windows' budget), ms
    hop_ms: float = 20.0


#: The daemon's deadline-miss log lines printed per phase at most (those of the most worker CPU).
MISS_LINES_SHOWN = 20

SLOW_LANE_MODES = ("off", "process", "thread")


def _slow_lane_modes(text: str) -> list[str]:
    modes = [m.strip() for m in text.split(",") if m.strip()]
    bad = [m for m in modes if m not in SLOW_LANE_MODES]
    if bad or not modes:
        raise InputDataError(
            f"--slow-lane {text!r}: use a comma-separated list of {', '.join(SLOW_LANE_MODES)}"
        )
    return modes


def _slow_lane_section(mode: str, plant_reflex: bool = True) -> str:
    """Config text for a slow-lane mode: on, the plant also has a stretch reflex unless
    ``plant_reflex`` is false."""
    if mode == "off":
        return "[slow_lane]\nenabled = false\n"
    reflex = "[plant.reflex]\nenabled = true\n" if plant_reflex else ""
    return f'[slow_lane]\nenabled = true\nmode = "{mode}"\n' + reflex


def _config_file(
    folder: Path,
    port: int,
    can_port: int | None,
    cpu_latency_us: int,
    slow_lane: str = "off",
    plant_reflex: bool = True,
    hop_s: float = 0.02,
    switch_interval_s: float | None = None,
    lowpass_hz: float | None = None,
    realtime_priority: int = 0,
    socketcand_client: str = "rtsid",
) -> Path:
    path = folder / "bench.toml"
    estimator = f"[estimator]\nlowpass_hz = {lowpass_hz!r}\n" if lowpass_hz is not None else ""
    switch = (
        f"gil_switch_interval_s = {switch_interval_s!r}\n" if switch_interval_s is not None else ""
    )
    link = (
        f'[link]\ninterface = "socketcand"\nchannel = "can0"\nport = {can_port}\n'
        f'socketcand_client = "{socketcand_client}"\n'
        if can_port is not None
        else ""
    )
    path.write_text(
        f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\nrobot = "bench"\n'
        f'[mcap]\ndirectory = "{folder / "rec"}"\n{link}'
        f"[daemon]\ncpu_latency_us = {cpu_latency_us}\nrealtime_priority = {realtime_priority}\n"
        f"{switch}"
        f"[worker]\nhop_s = {hop_s!r}\n{estimator}" + _slow_lane_section(slow_lane, plant_reflex)
    )
    return path


def _start_plant(can_port: int, config: Path) -> subprocess.Popen[bytes]:
    """The virtual plant behind socketcand, with the run's [plant] (a reflex, say)."""
    plant = subprocess.Popen(
        [
            sys.executable,
            *("-m", "rtsid.cli", "plant", "--config", str(config), "--port", str(can_port)),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", can_port), timeout=0.5):
                return plant
        except OSError:
            time.sleep(0.1)
    plant.kill()
    raise RuntimeError(f"rtsid plant did not listen on 127.0.0.1:{can_port}")


def _stop(proc: subprocess.Popen[bytes], log: Any = None) -> str:
    """SIGTERM (then SIGKILL after 30 s); returns what the process wrote to ``log`` (the
    binary file its stderr went to), if given."""
    proc.send_signal(signal.SIGTERM)
    try:
        proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate(timeout=10)
    if log is None:
        return ""
    log.seek(0)
    return bytes(log.read()).decode("utf-8", "replace")


def end_to_end_ms(message: dict[str, Any], received_ns: int) -> tuple[float, float, float]:
    """(in-daemon, transit, end-to-end) latency of one received estimate, ms.

    In-daemon: the window's last sample arriving → the message built (``latency_ms``, the
    daemon's monotonic clock); transit: built (``host_time_ns``) → ``received_ns`` (this
    machine's wall clock, shared by both processes); end to end: their sum.
    """
    transit_ms = (received_ns - message["host_time_ns"]) / 1e6
    return message["latency_ms"], transit_ms, message["latency_ms"] + transit_ms


def _subscribe(port: int, seconds: float, phase: Phase) -> None:
    import zenoh

    from rtsid.io.zenoh_link import open_when_reachable, subscriber_config

    conf = subscriber_config((f"tcp/127.0.0.1:{port}",), mode="client")
    with open_when_reachable(conf) as session:
        est = session.declare_subscriber(
            "rtsid/bench/ankle/estimate", zenoh.handlers.FifoChannel(4096)
        )
        stat = session.declare_subscriber(
            "rtsid/bench/ankle/status", zenoh.handlers.FifoChannel(256)
        )
        start = time.monotonic()
        end = start + seconds
        while time.monotonic() < end:
            sample = est.recv()  # blocks until the next estimate (50 per second)
            received_ns = time.time_ns()
            msg = json.loads(sample.payload.to_bytes())
            if "over_budget" in msg["flags"]:
                phase.stalls.append((msg["host_time_ns"], msg["compute_ms"]))
            if msg["ok"]:
                phase.estimates += 1
                phase.compute_ms.append(msg["compute_ms"])
                daemon_ms, transit_ms, e2e_ms = end_to_end_ms(msg, received_ns)
                phase.daemon_ms.append(daemon_ms)
                phase.transit_ms.append(transit_ms)
                phase.e2e_ms.append(e2e_ms)
                phase.live_values[msg["window_end_index"]] = (msg["K"], msg["B"], msg["I"])
            else:
                phase.withheld += 1
            while (s := stat.try_recv()) is not None:
                phase.status.append(json.loads(s.payload.to_bytes()))
        phase.seconds = time.monotonic() - start
        est.undeclare()
        stat.undeclare()


def _run_phase(
    name: str,
    seconds: float,
    burn: bool,
    transport: str,
    cpu_latency_us: int,
    slow_lane: str = "off",
    plant_reflex: bool = True,
    hop_s: float = 0.02,
    switch_interval_s: float | None = None,
    lowpass_hz: float | None = None,
    *,
    replay: bool = True,
    realtime_priority: int = 0,
    socketcand_client: str = "rtsid",
) -> Phase:
    phase = Phase(name, hop_ms=hop_s * 1e3)
    with tempfile.TemporaryDirectory(prefix="rtsid-bench-") as tmp:
        port = _free_port()
        can_port = _free_port() if transport == "socketcand" else None
        config = _config_file(
            Path(tmp),
            port,
            can_port,
            cpu_latency_us,
            slow_lane,
            plant_reflex,
            hop_s,
            switch_interval_s,
            lowpass_hz,
            realtime_priority,
            socketcand_client,
        )
        plant = _start_plant(can_port, config) if can_port is not None else None
        # the daemon's stderr goes to a file, not a pipe read only at the end: a run that
        # logs many misses would fill the pipe and block the thread that logs them
        # (housekeeping, which forwards the samples to the recording)
        daemon_log = (Path(tmp) / "daemon-stderr.log").open("w+b")
        daemon = subprocess.Popen(
            [sys.executable, "-m", "rtsid.cli", "run", "--config", str(config), "--quiet"],
            stdout=subprocess.DEVNULL,
            stderr=daemon_log,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        burner = None
        try:
            if burn:
                burner = mp.get_context("spawn").Process(target=_burn, args=(seconds + 40.0,))
                burner.start()
            steal0, total0 = _cpu_jiffies()
            with StealTimeline() as steal:
                _subscribe(port, seconds, phase)
            steal1, total1 = _cpu_jiffies()
            phase.stalls_with_steal = stalls_with_steal(phase.stalls, steal, hop_s * 1e3)
            if total1 > total0:
                phase.steal_percent = 100.0 * (steal1 - steal0) / (total1 - total0)
        finally:
            logged = _stop(daemon, daemon_log)
            daemon_log.close()
            phase.miss_lines = [ln for ln in logged.splitlines() if "deadline miss:" in ln]
            if plant is not None:
                _stop(plant)
            if burner is not None:
                burner.terminate()
                burner.join(10)
        recordings = sorted((Path(tmp) / "rec").glob("*.mcap"))
        if replay and recordings:  # the same windows again, on one thread of this process
            phase.replay = replay_file(recordings[0])
    return phase


def stalls_with_steal(
    stalls: list[tuple[int, float]], steal: StealTimeline, hop_ms: float = 20.0
) -> int:
    """Over-budget windows during which the hypervisor took at least the overrun."""
    count = 0
    for built_ns, compute_ms in stalls:
        stolen = steal.stolen_s(built_ns - int(compute_ms * 1e6), built_ns)
        if len(stalls) <= 50:
            print(f"  over budget: compute {compute_ms:.1f} ms, host steal {stolen * 1e3:.0f} ms")
        count += stolen * 1e3 >= compute_ms - hop_ms
    return count


def worker_cpu_per_window_ms(status: dict[str, Any]) -> tuple[float, float]:
    """(CPU, wall) ms per window the worker evaluated, from one status message's totals."""
    worker = status.get("worker") or {}
    windows = int(worker.get("estimates", 0)) + sum((worker.get("withheld") or {}).values())
    if not windows or "compute_cpu_s" not in worker:
        return float("nan"), float("nan")
    return (
        1e3 * float(worker["compute_cpu_s"]) / windows,
        1e3 * float(worker["compute_s"]) / windows,
    )


def identical_to_live(phase: Phase) -> tuple[int, int]:
    """(equal, compared): live estimates whose K, B, I the replay reproduced exactly."""
    if phase.replay is None:
        return 0, 0
    replayed = {m["window_end_index"]: (m["K"], m["B"], m["I"]) for m in phase.replay.messages}
    common = [end for end in phase.live_values if end in replayed]
    return sum(phase.live_values[end] == replayed[end] for end in common), len(common)


def acquisition_cpu_percent(status: list[dict[str, Any]]) -> float:
    """The acquisition thread's CPU, % of a core, between the first and the last status
    (its ``thread_cpu_s`` against the statuses' ``host_time_ns``)."""
    if len(status) < 2:
        return float("nan")
    first, last = status[0], status[-1]
    seconds = (last["host_time_ns"] - first["host_time_ns"]) / 1e9
    cpu = last["acquisition"]["thread_cpu_s"] - first["acquisition"]["thread_cpu_s"]
    return 100.0 * cpu / seconds if seconds > 0 else float("nan")


#: Statuses of a phase's first seconds left out of its RSS growth (start-up, the slow lane's
#: process, zenoh's first connections), s.
RSS_SLOPE_SKIP_S = 30.0
#: The spans the RSS growth is read over, s.
RSS_SPAN_S = 10.0


def rss_growth_mib_per_min(status: list[dict[str, Any]]) -> float:
    """The daemon's steady RSS growth, MiB a minute: the median over consecutive
    :data:`RSS_SPAN_S` spans of the statuses' ``rss_mb`` change (read at the spans' ends by
    linear interpolation over ``host_time_ns``), leaving out the first
    :data:`RSS_SLOPE_SKIP_S`. NaN with fewer than two whole spans.

    A median of spans rather than end minus start: a one-time step (zenoh maps its
    shared-memory segments and starts their watchdog threads when a peer first uses them,
    +27 MiB at 30–60 s into 7 of 11 runs) falls in one or two spans and leaves the
    median alone, so 60–120 s of a run read the growth a minute.
    """
    if not status:
        return float("nan")
    t0 = status[0]["host_time_ns"]
    seconds = np.array([(s["host_time_ns"] - t0) / 1e9 for s in status])
    rss = np.array([s["rss_mb"] for s in status], dtype=float)
    ends = np.arange(RSS_SLOPE_SKIP_S, seconds[-1] + 1e-9, RSS_SPAN_S)
    if len(ends) < 3:
        return float("nan")
    changes = np.diff(np.interp(ends, seconds, rss))
    return float(np.median(changes) * 60.0 / RSS_SPAN_S)


def _row(phase: Phase, base: Phase | None) -> list[Any]:
    e2e50, e2e99 = median_p99(phase.e2e_ms)
    c50, c99 = median_p99(phase.compute_ms)
    steady = phase.status[2:] or phase.status
    cpu = float(np.median([s["cpu_percent"] for s in steady])) if steady else float("nan")
    rss = [s["rss_mb"] for s in steady]
    last = phase.status[-1] if phase.status else {}
    worker = last.get("worker", {})
    acq = last.get("acquisition", {})
    mcap = last.get("mcap", {})
    ratio = (e2e99 / median_p99(base.e2e_ms)[1]) if base else 1.0
    cpu_ms, wall_ms = worker_cpu_per_window_ms(last)
    return [
        phase.name,
        phase.estimates / phase.seconds if phase.seconds else 0.0,
        phase.withheld,
        worker.get("deadline_misses", "—"),
        f"{phase.stalls_with_steal} of {len(phase.stalls)}",
        worker.get("overruns", "—"),
        e2e50,
        e2e99,
        float(np.percentile(phase.e2e_ms, 99.9)) if phase.e2e_ms else float("nan"),
        max(phase.e2e_ms) if phase.e2e_ms else float("nan"),
        c50,
        c99,
        cpu_ms,
        wall_ms / cpu_ms,
        median_p99(phase.daemon_ms)[1],
        median_p99(phase.transit_ms)[1],
        cpu,
        acquisition_cpu_percent(steady),
        rss[0] if rss else float("nan"),
        rss[-1] if rss else float("nan"),
        rss_growth_mib_per_min(phase.status),
        acq.get("lost_samples", "—"),
        mcap.get("dropped", "—"),
        longest_gc_ms(worker),
        phase.steal_percent,
        ratio,
    ]


def _pause(pause: Any) -> str:
    """``gen 2, 3.10 ms (CPU 2.95 ms)`` from a status's ``[generation, ms, CPU ms]``."""
    if not pause:
        return "none"
    generation, ms, cpu_ms = pause
    return f"gen {int(generation)}, {ms:.2f} ms (CPU {cpu_ms:.2f} ms)"


def gc_pauses(worker: dict[str, Any]) -> str:
    """The daemon's longest garbage collection while it ran windows, with its generation,
    beside the start-up's and the objects frozen out of the collector's view."""
    return (
        f"longest garbage collection while running windows: {_pause(worker.get('gc_longest'))}"
        f"; at start-up: {_pause(worker.get('gc_longest_startup'))}; objects frozen "
        f"{worker.get('gc_frozen', '—')}"
    )


def longest_gc_ms(worker: dict[str, Any]) -> str:
    """The table's cell: the longest collection while running windows, ms (generation)."""
    pause = worker.get("gc_longest")
    return "—" if not pause else f"{pause[1]:.2f} (gen {int(pause[0])})"


def replayed_compute_ms(phase: Phase) -> dict[int, float]:
    """Each replayed window's compute, ms, by its last sample's index ({} without a replay)."""
    if phase.replay is None:
        return {}
    return {m["window_end_index"]: m["compute_ms"] for m in phase.replay.messages}


def replayed_misses(miss_lines: list[str], replayed: dict[int, float], hop_ms: float) -> str:
    """How many missed windows the replay computed within the hop: for those the window's
    own work (the same numbers, the same code) was not what made it miss, whatever the
    worker's CPU clock charged to a stage live (a host stall is charged to the thread that
    was running)."""
    again = [_replayed_ms(line, replayed) for line in miss_lines]
    found = [ms for ms in again if ms is not None]
    within = sum(ms <= hop_ms for ms in found)
    longest = f"; the longest {max(found):.3g} ms" if found else ""
    return (
        f"missed windows replayed within the {hop_ms:g} ms hop on one thread: {within} of "
        f"{len(found)} found in the replay ({len(miss_lines)} logged){longest}"
    )


def _replayed_ms(miss_line: str, replayed: dict[int, float]) -> float | None:
    """The replayed compute of the window a miss line names (None: not in the replay)."""
    found = re.search(r"window ending (\d+)", miss_line)
    return replayed.get(int(found.group(1))) if found else None


def _own_cpu_ms(miss_line: str) -> float:
    """The worker's CPU over a missed window, from its log line (0: not in it)."""
    found = re.search(r"on CPU ([0-9.]+) ms", miss_line)
    return float(found.group(1)) if found else 0.0


def print_miss_causes(phase: Phase) -> None:
    """What the phase's deadline misses coincided with, from the daemon's last status
    (:class:`~rtsid.runtime.stalls.StallJournal`), and its garbage collections."""
    worker = (phase.status[-1] if phase.status else {}).get("worker") or {}
    causes = worker.get("miss_causes") or {}
    listed = ", ".join(f"{name}: {count}" for name, count in sorted(causes.items())) or "none"
    print(
        f"  {phase.name}: misses by what overlapped them: {listed}; garbage collections by "
        f"generation {worker.get('gc_collections')} taking {worker.get('gc_ms')} ms"
    )
    waits = worker.get("miss_waits") or {}
    listed = ", ".join(f"{name}: {count}" for name, count in sorted(waits.items())) or "none"
    print(f"  {phase.name}: misses by where most of their time went: {listed}")
    stages = worker.get("miss_stages") or {}
    listed = ", ".join(f"{name}: {count}" for name, count in sorted(stages.items())) or "none"
    print(f"  {phase.name}: misses by the stage furthest above its usual CPU: {listed}")
    costly = worker.get("costly_stages") or {}
    listed = ", ".join(f"{name}: {count}" for name, count in sorted(costly.items())) or "none"
    print(
        f"  {phase.name}: windows of over 3× the usual CPU (missed or not) by that stage "
        f"and the CPU's pace (the compiled call's fixed work): {listed}"
    )
    for key, what in (("miss_cpu_causes", "misses"), ("costly_causes", "windows of over 3×")):
        causes = worker.get(key) or {}
        listed = ", ".join(f"{name}: {count}" for name, count in sorted(causes.items()))
        print(
            f"  {phase.name}: {what} by why the worker's CPU ran long (its getrusage counters "
            f"over the window and the compiled call): {listed or 'none'}"
        )
    print(
        f"  {phase.name}: windows whose worker took page faults: "
        f"{worker.get('faulted_windows', '—')} of {worker.get('estimates', '—')} estimates "
        f"({worker.get('window_faults', '—')} faults); of them in the compiled call "
        f"{worker.get('faulted_calls', '—')} ({worker.get('call_faults', '—')} faults)"
    )
    print(f"  {phase.name}: {gc_pauses(worker)}")
    overruns = worker.get("overrun_causes") or {}
    listed = ", ".join(f"{name}: {count}" for name, count in sorted(overruns.items())) or "none"
    print(f"  {phase.name}: overruns (windows skipped) by cause: {listed}")
    replayed = replayed_compute_ms(phase)
    if replayed and phase.miss_lines:
        print(f"  {phase.name}: {replayed_misses(phase.miss_lines, replayed, phase.hop_ms)}")
    for line in sorted(phase.miss_lines, key=_own_cpu_ms, reverse=True)[:MISS_LINES_SHOWN]:
        again = _replayed_ms(line, replayed)
        tail = "" if again is None else f"; replayed: {again:.3g} ms"
        print(f"    {line.split('deadline miss:', 1)[1].strip()}{tail}")
    steady = phase.status[2:] or phase.status
    if len(steady) >= 2:  # RSS growth beside what the zenoh history ring took meanwhile
        first, last = steady[0], steady[-1]
        history_mib = ((last.get("zenoh") or {}).get("history_bytes", 0) or 0) - (
            (first.get("zenoh") or {}).get("history_bytes", 0) or 0
        )
        print(
            f"  {phase.name}: RSS {first['rss_mb']:.1f} → {last['rss_mb']:.1f} MiB "
            f"(steady growth {rss_growth_mib_per_min(phase.status):.2f} MiB a minute), of it the "
            f"zenoh history ring {history_mib / 2**20:+.1f} MiB"
        )


def _replay_row(phase: Phase) -> list[Any]:
    """The phase's windows replayed on one thread, against the live ones."""
    replay = phase.replay
    if replay is None:
        return [phase.name, 0, "—", *[float("nan")] * 6]
    ok = [m["compute_ms"] for m in replay.messages if m["ok"]]
    r50, r99 = median_p99(ok)
    l50, _ = median_p99(phase.compute_ms)
    windows = len(replay.messages)
    cpu_ms = 1e3 * replay.compute_cpu_s / windows if windows else float("nan")
    live_cpu_ms, _ = worker_cpu_per_window_ms(phase.status[-1] if phase.status else {})
    equal, compared = identical_to_live(phase)
    return [
        phase.name,
        windows,
        f"{equal} of {compared}",
        r50,
        r99,
        cpu_ms,
        l50 / r50,
        live_cpu_ms / cpu_ms,
        replay.speed,
    ]


def _floors(hop_s: float) -> str:
    """The floors the run is held to, by hop."""
    if hop_s <= 0.004:
        return (
            "Floors (issue 22, 4 ms hop, slow lane on): 250 estimates/s, 0 deadline misses "
            "while the host steals nothing, e2e p99 ≤ 4 ms, CPU ≤ 40 %."
        )
    return "Floors: 0 deadline misses idle, e2e p99 ≤ 5 ms, CPU ≤ 30 %."


def _lane_row(phase: Phase, mode: str) -> list[Any]:
    last = phase.status[-1] if phase.status else {}
    lane = last.get("slow_lane") or {}
    flagged = (last.get("worker") or {}).get("reflex_flagged") or {}
    return [
        phase.name,
        mode,
        lane.get("fits", 0),
        lane.get("applied", 0),
        lane.get("failed", 0),
        lane.get("last_fit_ms"),
        flagged.get("reflex_stale", 0),
    ]


def run(args: argparse.Namespace) -> int:
    seconds = 20.0 if args.quick else args.duration
    hop_s = args.hop_ms / 1e3
    switch_s = None if args.switch_interval_ms is None else args.switch_interval_ms / 1e3
    qos = args.cpu_latency_us
    if qos >= 0 and not os.access(PM_QOS_DEVICE, os.W_OK):
        print(f"note: {PM_QOS_DEVICE} is not writable here; running with cpu_latency_us = -1")
        qos = -1
    rows, lanes, replays = [], [], []
    reflex = args.plant_reflex == "on"
    for mode in _slow_lane_modes(args.slow_lane):
        suffix = "" if mode == "off" else f", slow lane {mode}"
        if mode != "off":
            suffix += ", plant reflex" if reflex else ", plant without reflex"
        idle = _run_phase(
            f"idle machine{suffix}",
            *(seconds, False, args.transport, qos, mode, reflex, hop_s, switch_s, args.lowpass_hz),
            replay=not args.no_replay,
            realtime_priority=args.realtime_priority,
            socketcand_client=args.socketcand_client,
        )
        rows.append(_row(idle, None))
        print_miss_causes(idle)
        lanes.append(_lane_row(idle, mode))
        replays.append(_replay_row(idle))
        if not args.no_load_phase:
            loaded = _run_phase(
                f"other core loaded{suffix}",
                *(
                    seconds,
                    True,
                    args.transport,
                    qos,
                    mode,
                    reflex,
                    hop_s,
                    switch_s,
                    args.lowpass_hz,
                ),
                replay=not args.no_replay,
                realtime_priority=args.realtime_priority,
                socketcand_client=args.socketcand_client,
            )
            rows.append(_row(loaded, idle))
            print_miss_causes(loaded)
            lanes.append(_lane_row(loaded, mode))
            replays.append(_replay_row(loaded))
    print_table(
        f"Daemon at 2500 Hz, 300 ms windows every {args.hop_ms:g} ms, {seconds:g} s per phase "
        f"(virtual plant via {args.transport}; subscriber in another process; "
        f"cpu_latency_us = {qos}"
        + ("" if switch_s is None else f"; GIL switch interval {args.switch_interval_ms:g} ms")
        + ("" if args.lowpass_hz is None else f"; [estimator] lowpass_hz = {args.lowpass_hz:g}")
        + (
            ""
            if not args.realtime_priority
            else f"; [daemon] realtime_priority = {args.realtime_priority}"
        )
        + ")",
        [
            "phase",
            "estimates/s",
            "withheld",
            "deadline misses",
            "misses with host steal",
            "overruns",
            "e2e p50 ms",
            "e2e p99 ms",
            "e2e p99.9 ms",
            "e2e max ms",
            "compute p50 ms",
            "compute p99 ms",
            "worker CPU ms/window",
            "compute wall / CPU",
            "in-daemon p99 ms",
            "zenoh transit p99 ms",
            "daemon CPU %",
            "acquisition thread CPU %",
            "RSS start MiB",
            "RSS end MiB",
            "RSS MiB/min",
            "lost samples",
            "MCAP dropped",
            "longest gc ms (gen)",
            "VM steal %",
            "e2e p99 / idle",
        ],
        rows,
        note=(
            "e2e = window's last sample arriving at the daemon → estimate received here; "
            "in-daemon = that sample's arrival → the estimate message built (wake-up + "
            "compute); zenoh transit = message built → received here (encode, put, loopback "
            "TCP, the subscriber's wake-up). "
            "With --transport embedded the daemon's CPU includes the simulated robot, which a "
            "real rig does not cost. VM steal = CPU time the hypervisor took from this machine "
            "during the phase (/proc/stat): host preemption, not the daemon. "
            "cpu_latency_us = 0: the daemon holds a PM QoS request keeping idle CPUs polling "
            "(rtsid.runtime.power); -1: none. Misses with host steal = over-budget windows "
            "(seen by the subscriber) during which the hypervisor took at least the overrun "
            "(steal time of all CPUs, sampled every 5 ms here). Worker CPU ms/window = the "
            "worker thread's CPU time per evaluated window (status totals); compute wall / CPU "
            "> 1 is time the worker was ready but not running (the GIL, or a CPU given to "
            "others). Longest gc = the daemon's longest garbage collection after its start-up "
            "(wall; it holds the GIL). RSS MiB/min = the median RSS change over 10 s spans "
            "after the first 30 s, a minute's worth (a one-time step falls in one span). "
            f"{_floors(hop_s)}"
        ),
    )
    if not args.no_replay:
        print_table(
            "The same windows replayed on one thread of this process after each phase (the "
            "daemon's recording, its own configuration)",
            [
                "phase",
                "windows",
                "K, B, I equal to live",
                "compute p50 ms",
                "compute p99 ms",
                "CPU ms/window",
                "live / replay compute p50",
                "live / replay CPU",
                "replay × real time",
            ],
            replays,
            note="The replay's compute is the window path's cost on the plant's own signal with "
            "nothing else in the process; the live / replay ratios are what running inside the "
            "daemon adds (other threads, the GIL, the machine's other work). Replay × real time "
            "includes the slow lane's fits, run in line.",
        )
    if any(mode != "off" for mode in _slow_lane_modes(args.slow_lane)):
        print_table(
            "The slow lane in the same phases (from the daemon's last status)",
            ["phase", "mode", "fits", "applied", "failed", "last fit ms", "reflex_stale windows"],
            [row for row in lanes if row[1] != "off"],
            note="A fit runs every 2 s over the last 20 s; fit time includes handing the data "
            "to the worker process in process mode. Floor (issue 11): 0 deadline misses in the "
            "fast lane and e2e p99 ≤ 5 ms with the slow lane on.",
        )
    return 0
