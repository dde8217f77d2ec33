"""``rtsid bench lab``: a router, N daemons on virtual plants and one subscriber on 127.0.0.1.

Every process is real: ``rtsid router`` (eclipse-zenoh's router mode), N ``rtsid run`` daemons
(embedded virtual plants, ``[zenoh] mode = "client"``), and this process as the subscriber
(a zenoh client of the router, channels not callbacks). The end-to-end latency of each estimate
is measured as in ``rtsid bench service`` (:func:`rtsid.benchmarks.service.end_to_end_ms`):
the window's last sample reaching its daemon → the estimate received here, through the router.

Phases, one after the other in the same run, each ``--duration`` long:

1. ``router``: the lab topology.
2. ``router + queries``: the same processes while another process asks every daemon for its
   history (``--query-since``) ``--query-rate`` times a second, through the router: what a
   query costs the fast lane (deadline misses, e2e) against phase 1.
3. ``TLS router``: the daemons and router restarted with the secure lab profile that
   ``rtsid certs`` writes (zenoh's mutual TLS on a ``tls/`` listener, access control by
   certificate common name; docs/lab.md), the subscriber a viewer of that profile. Its
   ``e2e p99 / router`` column is the price of the security against phase 1 (floor ≤ 1.5).
4. ``peer-to-peer``: the daemons restarted as peers, the subscriber connected to each.

After phases 1, 3 and 4, a late joiner opens a new session and asks for every joint's latest
estimate (``rtsid/lab/*/estimate``), ``--late-trials`` times: time from opening the session
(and from the query) to the last joint's answer. Router CPU comes from /proc/<pid>/stat;
daemon CPU and deadline counters from the daemons' own status messages (counted over the phase).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
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

from rtsid.benchmarks.service import StealTimeline, end_to_end_ms, stalls_with_steal
from rtsid.benchmarks.table import median_p99, print_table
from rtsid.runtime.power import PM_QOS_DEVICE

ROBOT = "lab"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--duration", type=float, default=300.0, help="seconds per phase (300)")
    parser.add_argument("--joints", type=int, default=4, help="daemons (4)")
    parser.add_argument(
        "--query-rate", type=float, default=10.0, help="history queries per second in phase 2"
    )
    parser.add_argument(
        "--query-since", default="10s", help="history each query asks for (10s of every joint)"
    )
    parser.add_argument("--no-query-phase", action="store_true", help="skip phase 2")
    parser.add_argument(
        "--no-tls-phase", action="store_true", help="skip phase 3 (the TLS + ACL router)"
    )
    parser.add_argument("--late-trials", type=int, default=20, help="late-joiner trials (20)")
    parser.add_argument(
        "--cpu-latency-us",
        type=int,
        default=0,
        help="the daemons' [daemon] cpu_latency_us (0 as in `bench service`; -1: none). Falls "
        "back to -1 when /dev/cpu_dma_latency is not writable",
    )


# ---------------------------------------------------------------------- processes
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_listening(port: int, proc: subprocess.Popen[bytes], what: str) -> None:
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"{what} exited with status {proc.returncode}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.1)
    raise RuntimeError(f"{what} did not listen on 127.0.0.1:{port}")


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.terminate()
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=10)


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "rtsid.cli", *args]


def _daemon_config(folder: Path, joint: str, zenoh: str, qos: int) -> Path:
    path = folder / f"{joint}.toml"
    path.write_text(
        f'[zenoh]\nrobot = "{ROBOT}"\njoint = "{joint}"\n{zenoh}\n'
        f'[mcap]\ndirectory = "{folder / "rec"}"\n'
        f"[daemon]\ncpu_latency_us = {qos}\n"
    )
    return path


def _proc_cpu_s(pid: int) -> float:
    """User + system CPU time of a process, s (NaN where /proc is unavailable)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Lab:
    """The processes of one topology: an optional router and the daemons."""

    def __init__(
        self, folder: Path, joints: list[str], routed: bool, qos: int, secure: bool = False
    ) -> None:
        self.joints = joints
        self.routed = routed
        self.secure = secure
        #: The subscriber's zenoh json5 (the secure profile's viewer); "": built from endpoints.
        self.client_config = ""
        self.router: subprocess.Popen[bytes] | None = None
        self.daemons: list[subprocess.Popen[bytes]] = []
        self.endpoints: tuple[str, ...] = ()
        folder.mkdir(parents=True, exist_ok=True)
        try:
            self._start(folder, qos)
        except BaseException:
            self.stop()
            raise

    def _start(self, folder: Path, qos: int) -> None:
        joints, routed = self.joints, self.routed
        if routed and self.secure:
            configs = self._start_secure(folder, qos)
        elif routed:
            port = _free_port()
            self.endpoints = (f"tcp/127.0.0.1:{port}",)
            self.router = subprocess.Popen(
                _cli("router", "--listen", self.endpoints[0]),
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            _wait_listening(port, self.router, "rtsid router")
            configs = [
                _daemon_config(
                    folder, j, f'mode = "client"\nconnect = ["{self.endpoints[0]}"]', qos
                )
                for j in joints
            ]
        else:
            ports = [_free_port() for _ in joints]
            self.endpoints = tuple(f"tcp/127.0.0.1:{p}" for p in ports)
            configs = [
                _daemon_config(folder, j, f'listen = ["{e}"]', qos)
                for j, e in zip(joints, self.endpoints, strict=True)
            ]
        for config in configs:
            self.daemons.append(
                subprocess.Popen(
                    _cli("run", "--config", str(config), "--quiet"),
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )

    def _start_secure(self, folder: Path, qos: int) -> list[Path]:
        """The router and daemons of the secure lab profile (``rtsid certs``), TLS on loopback."""
        from rtsid.runtime.lab_security import LabProfile, write_lab_profile

        port = _free_port()
        self.endpoints = (f"tls/127.0.0.1:{port}",)
        certs = folder / "certs"
        profile = LabProfile(
            daemons=tuple((ROBOT, j) for j in self.joints),
            viewers=("bench",),
            listen=self.endpoints,
        )
        write_lab_profile(certs, profile)
        self.client_config = str(certs / "viewer-bench.json5")
        self.router = subprocess.Popen(
            _cli("router", "--config", str(certs / "router.toml")),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        _wait_listening(port, self.router, "rtsid router (TLS)")
        return [
            _daemon_config(folder, j, f'config_file = "{certs / f"daemon-{ROBOT}-{j}.json5"}"', qos)
            for j in self.joints
        ]

    @property
    def mode(self) -> str:
        return "client" if self.routed else "peer"

    def check(self) -> None:
        """Raise if the router or a daemon exited."""
        named = [(f"daemon {j}", p) for j, p in zip(self.joints, self.daemons, strict=True)]
        if self.router is not None:
            named.append(("router", self.router))
        for name, proc in named:
            if proc.poll() is not None:
                raise RuntimeError(f"{name} exited with status {proc.returncode}")

    def stop(self) -> None:
        for proc in self.daemons:
            _stop(proc)
        if self.router is not None:
            _stop(self.router)


# ---------------------------------------------------------------------- measuring
@dataclass
class JointFigures:
    e2e_ms: list[float] = field(default_factory=list)
    transit_ms: list[float] = field(default_factory=list)
    estimates: int = 0
    withheld: int = 0
    first_status: dict[str, Any] | None = None
    last_status: dict[str, Any] | None = None
    cpu: list[float] = field(default_factory=list)

    def counter(self, part: str, name: str) -> int:
        """Growth of a status counter over the phase."""
        if self.first_status is None or self.last_status is None:
            return 0
        first = self.first_status.get(part, {}).get(name, 0)
        return int(self.last_status.get(part, {}).get(name, 0)) - int(first)


@dataclass
class Phase:
    name: str
    joints: dict[str, JointFigures]
    seconds: float = 0.0
    router_cpu_percent: float = float("nan")
    late_open_ms: list[float] = field(default_factory=list)
    late_query_ms: list[float] = field(default_factory=list)
    queries: dict[str, Any] = field(default_factory=dict)
    # (message built ns, compute ms) of every estimate over its budget, and how many of those
    # the host's steal time covers (as in bench service)
    stalls: list[tuple[int, float]] = field(default_factory=list)
    stalls_with_steal: int = 0


def _open(endpoints: tuple[str, ...], mode: str, config_file: str = "") -> Any:
    from rtsid.io.zenoh_link import open_when_reachable, subscriber_config

    return open_when_reachable(subscriber_config(endpoints, mode, config_file))


def _wait_for_all(session: Any, joints: list[str], timeout_s: float = 60.0) -> None:
    """Until every daemon answers with a latest estimate (all up and estimating)."""
    from rtsid.io.zenoh_link import query

    deadline = time.monotonic() + timeout_s
    while True:
        answer = query(session, f"rtsid/{ROBOT}/*/estimate", timeout_s=2.0)
        if len({k.split("/")[2] for k, _ in answer.replies}) == len(joints):
            return
        if time.monotonic() > deadline:
            raise RuntimeError("not every daemon answered within 60 s")
        time.sleep(0.5)


def _measure(lab: Lab, name: str, seconds: float, session: Any) -> Phase:
    """Subscribe through ``session`` for ``seconds`` and collect per-joint figures."""
    import zenoh

    phase = Phase(name, {j: JointFigures() for j in lab.joints})
    est = session.declare_subscriber(f"rtsid/{ROBOT}/*/estimate", zenoh.handlers.FifoChannel(8192))
    stat = session.declare_subscriber(f"rtsid/{ROBOT}/*/status", zenoh.handlers.FifoChannel(1024))
    done = threading.Event()
    stalled = threading.Event()
    last_rx = [time.monotonic()]

    def watchdog() -> None:  # a blocked recv() is released by undeclaring its subscriber
        while not done.wait(1.0):
            if time.monotonic() - last_rx[0] > 15.0:
                stalled.set()
                est.undeclare()
                return

    guard = threading.Thread(target=watchdog, name="lab-watchdog", daemon=True)
    guard.start()
    router_cpu0 = _proc_cpu_s(lab.router.pid) if lab.router else float("nan")
    start = time.monotonic()
    try:
        while time.monotonic() < start + seconds:
            sample = est.recv()  # 50 per second per joint
            received_ns = time.time_ns()
            last_rx[0] = time.monotonic()
            msg = json.loads(sample.payload.to_bytes())
            figures = phase.joints[msg["joint"]]
            if "over_budget" in msg["flags"]:
                phase.stalls.append((msg["host_time_ns"], msg["compute_ms"]))
            if msg["ok"]:
                figures.estimates += 1
                _, transit, e2e = end_to_end_ms(msg, received_ns)
                figures.e2e_ms.append(e2e)
                figures.transit_ms.append(transit)
            else:
                figures.withheld += 1
            while (s := stat.try_recv()) is not None:
                status = json.loads(s.payload.to_bytes())
                figures = phase.joints[status["joint"]]
                figures.first_status = figures.first_status or status
                figures.last_status = status
                if status.get("cpu_percent") is not None:
                    figures.cpu.append(status["cpu_percent"])
    except zenoh.ZError as exc:
        if not stalled.is_set():
            raise
        lab.check()
        raise RuntimeError(f"no estimate for 15 s in phase {name!r}") from exc
    finally:
        done.set()
        guard.join(5)
    phase.seconds = time.monotonic() - start
    if lab.router is not None:
        phase.router_cpu_percent = (
            100.0 * (_proc_cpu_s(lab.router.pid) - router_cpu0) / phase.seconds
        )
    if not stalled.is_set():
        est.undeclare()
    stat.undeclare()
    return phase


def _late_joiners(lab: Lab, phase: Phase, trials: int) -> None:
    """A new session asking for every joint's latest estimate, ``trials`` times."""
    import zenoh

    from rtsid.io.zenoh_link import subscriber_config

    wanted = len(lab.joints)
    for _ in range(trials):
        t_open = time.perf_counter()
        with zenoh.open(subscriber_config(lab.endpoints, lab.mode, lab.client_config)) as session:
            t_query = time.perf_counter()
            joints: set[str] = set()
            replies = session.get(
                f"rtsid/{ROBOT}/*/estimate",
                zenoh.handlers.FifoChannel(64),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=5.0,
            )
            for reply in replies:
                if reply.ok is not None:
                    joints.add(str(reply.ok.key_expr).split("/")[2])
                if len(joints) == wanted:
                    done = time.perf_counter()
                    phase.late_open_ms.append((done - t_open) * 1e3)
                    phase.late_query_ms.append((done - t_query) * 1e3)
                    break
        time.sleep(0.2)


def _flood(endpoint: str, since: str, rate_hz: float, seconds: float, out: Any) -> None:
    """History queries through the router at ``rate_hz`` for ``seconds`` (another process)."""
    from rtsid.io.zenoh_link import query

    times: list[float] = []
    sizes: list[int] = []
    errors = 0
    with _open((endpoint,), "client") as session:
        period = 1.0 / rate_hz
        start = time.monotonic()
        next_at = start
        while time.monotonic() < start + seconds:
            t0 = time.perf_counter()
            answer = query(session, f"rtsid/{ROBOT}/*/history?since={since}", timeout_s=10.0)
            times.append((time.perf_counter() - t0) * 1e3)
            sizes.append(sum(len(p) for _, p in answer.replies))
            errors += len(answer.errors)
            next_at += period
            delay = next_at - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_at = time.monotonic()
        out.put({"times_ms": times, "bytes": sizes, "errors": errors, "seconds": seconds})


def _run_topology(
    folder: Path,
    joints: list[str],
    routed: bool,
    phases: list[str],
    args: argparse.Namespace,
    secure: bool = False,
) -> list[Phase]:
    seconds = args.duration if not args.quick else 15.0
    lab = Lab(folder, joints, routed, args.qos, secure)
    results = []
    try:
        with _open(lab.endpoints, lab.mode, lab.client_config) as session:
            _wait_for_all(session, joints)
            time.sleep(2.0)  # past start-up: plans chosen, first status periods
            for name in phases:
                flood = None
                queue: Any = None
                if name == "router + queries":
                    ctx = mp.get_context("spawn")
                    queue = ctx.Queue()
                    flood = ctx.Process(
                        target=_flood,
                        args=(lab.endpoints[0], args.query_since, args.query_rate, seconds, queue),
                    )
                    flood.start()
                try:
                    with StealTimeline() as steal:
                        phase = _measure(lab, name, seconds, session)
                    phase.stalls_with_steal = stalls_with_steal(phase.stalls, steal)
                finally:
                    if flood is not None:
                        phase_queries = queue.get(timeout=60)
                        flood.join(30)
                if flood is not None:
                    phase.queries = phase_queries
                if name != "router + queries":
                    _late_joiners(lab, phase, 5 if args.quick else args.late_trials)
                lab.check()
                results.append(phase)
    finally:
        lab.stop()
    return results


# ---------------------------------------------------------------------- tables
def _phase_row(phase: Phase, base: Phase | None) -> list[Any]:
    e2e = [v for f in phase.joints.values() for v in f.e2e_ms]
    transit = [v for f in phase.joints.values() for v in f.transit_ms]
    rates = [f.estimates / phase.seconds for f in phase.joints.values()]
    e50, e99 = median_p99(e2e)
    base99 = median_p99([v for f in base.joints.values() for v in f.e2e_ms])[1] if base else e99
    cpu = [float(np.median(f.cpu)) for f in phase.joints.values() if f.cpu]
    return [
        phase.name,
        min(rates),
        max(rates),
        e50,
        e99,
        float(np.percentile(e2e, 99.9)) if e2e else float("nan"),
        max(e2e) if e2e else float("nan"),
        median_p99(transit)[1],
        sum(f.counter("worker", "deadline_misses") for f in phase.joints.values()),
        f"{phase.stalls_with_steal} of {len(phase.stalls)}",
        sum(f.counter("worker", "overruns") for f in phase.joints.values()),
        sum(f.withheld for f in phase.joints.values()),
        sum(f.counter("acquisition", "lost_samples") for f in phase.joints.values()),
        phase.router_cpu_percent,
        float(np.median(cpu)) if cpu else float("nan"),
        e99 / base99,
    ]


def run(args: argparse.Namespace) -> int:
    if args.joints < 1:
        print("rtsid bench lab: --joints must be >= 1", file=sys.stderr)
        return 2
    qos = args.cpu_latency_us
    if qos >= 0 and not os.access(PM_QOS_DEVICE, os.W_OK):
        print(f"note: {PM_QOS_DEVICE} is not writable here; running with cpu_latency_us = -1")
        qos = -1
    args.qos = qos
    joints = [f"j{i}" for i in range(args.joints)]
    routed_phases = ["router"] + ([] if args.no_query_phase else ["router + queries"])
    with tempfile.TemporaryDirectory(prefix="rtsid-bench-lab-") as tmp:
        phases = _run_topology(Path(tmp) / "routed", joints, True, routed_phases, args)
        if not args.no_tls_phase:
            phases += _run_topology(
                Path(tmp) / "tls", joints, True, ["TLS router"], args, secure=True
            )
        phases += _run_topology(Path(tmp) / "peer", joints, False, ["peer-to-peer"], args)
    seconds = phases[0].seconds
    base = phases[0]
    print_table(
        f"Lab: {len(joints)} daemons (virtual plants, 2500 Hz, 20 ms hops) and one subscriber on "
        f"127.0.0.1, {seconds:.0f} s per phase (cpu_latency_us = {qos})",
        [
            "phase",
            "estimates/s per joint, min",
            "max",
            "e2e p50 ms",
            "e2e p99 ms",
            "e2e p99.9 ms",
            "e2e max ms",
            "transit p99 ms",
            "deadline misses",
            "misses with host steal",
            "overruns",
            "withheld",
            "lost samples",
            "router CPU %",
            "daemon CPU % (median)",
            "e2e p99 / router",
        ],
        [_phase_row(p, base) for p in phases],
        note=(
            "e2e = a window's last sample arriving at its daemon → the estimate received by the "
            "subscriber (through the router, or straight from the daemon peer-to-peer); transit "
            "= estimate built → received. Deadline misses, overruns and lost samples: growth of "
            "the daemons' counters over the phase, summed over joints. Router CPU: % of one core "
            "(/proc). Daemon CPU includes its simulated robot. Misses with host steal: "
            "over-budget windows seen by the subscriber during which the hypervisor took at "
            "least the overrun (steal time of all CPUs, as in bench service). TLS router: the "
            "secure lab profile (zenoh mutual TLS + access control, `rtsid certs`). Floors "
            "(router phase): every joint ≥ 45 estimates/s, e2e p99 ≤ 10 ms, 0 deadline misses; "
            "TLS router e2e p99 ≤ 1.5 × the router's."
        ),
    )
    rows = []
    for phase in phases:
        for joint, f in phase.joints.items():
            e50, e99 = median_p99(f.e2e_ms)
            rows.append(
                [
                    phase.name,
                    joint,
                    f.estimates / phase.seconds,
                    e50,
                    e99,
                    f.counter("worker", "deadline_misses"),
                    float(np.median(f.cpu)) if f.cpu else float("nan"),
                ]
            )
    print_table(
        "Per joint",
        ["phase", "joint", "estimates/s", "e2e p50 ms", "e2e p99 ms", "deadline misses", "CPU %"],
        rows,
    )
    late = [p for p in phases if p.late_open_ms]
    print_table(
        "Late joiner: a new session asks rtsid/lab/*/estimate (every joint's latest)",
        [
            "topology",
            "trials",
            "open → all latest p50 ms",
            "p99 ms",
            "max ms",
            "query → all latest p50 ms",
            "p99 ms",
        ],
        [
            [
                p.name,
                len(p.late_open_ms),
                *median_p99(p.late_open_ms),
                max(p.late_open_ms),
                *median_p99(p.late_query_ms),
            ]
            for p in late
        ],
        note="Floor: every joint's latest estimate in ≤ 100 ms.",
    )
    flooded = [p for p in phases if p.queries]
    if flooded:
        q = flooded[0].queries
        t50, t99 = median_p99(q["times_ms"])
        print_table(
            f"History queries in phase 'router + queries' (since={args.query_since}, every joint)",
            ["queries", "queries/s", "reply p50 ms", "reply p99 ms", "MB per query", "errors"],
            [
                [
                    len(q["times_ms"]),
                    len(q["times_ms"]) / q["seconds"],
                    t50,
                    t99,
                    float(np.median(q["bytes"])) / 1e6 if q["bytes"] else float("nan"),
                    q["errors"],
                ]
            ],
            note=(
                "Queries are answered from a lock-free copy of each daemon's history ring on "
                "zenoh's threads; compare the phase's deadline misses and e2e p99 with 'router'."
            ),
        )
    return 0
