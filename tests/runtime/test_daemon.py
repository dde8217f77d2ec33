"""The daemon end to end: plant → acquisition → worker → zenoh + MCAP, in-process and as a
separate process with a subscriber, SIGTERM and SIGKILL."""

from __future__ import annotations

import gc
import itertools
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader

from rtsid.errors import ConfigError
from rtsid.io.mcap_read import iter_estimates, iter_sample_batches, iter_status, recover
from rtsid.io.zenoh_link import subscriber_config
from rtsid.runtime.daemon import Daemon, DaemonConfig

TRUTH = {"I": 0.015, "B": 0.8, "K": 150.0}  # the embedded plant's defaults


def write_config(tmp_path: Path, port: int, extra: str = "") -> Path:
    path = tmp_path / "rtsid.toml"
    path.write_text(
        f"""
[zenoh]
listen = ["tcp/127.0.0.1:{port}"]
robot = "testbot"

[mcap]
directory = "{tmp_path / "rec"}"
flush_interval_s = 0.2

[plant]
perturbation = "filtered_noise"
bandwidth_hz = 30.0
{extra}
"""
    )
    return path


def only_recording(tmp_path: Path) -> Path:
    files = sorted((tmp_path / "rec").glob("*.mcap"))
    assert len(files) == 1, files
    return files[0]


def sample_rows(path: Path) -> tuple[int, int]:
    """Valid and invalid sample rows in a recording."""
    valid = invalid = 0
    for batch in iter_sample_batches(path):
        valid += int(np.count_nonzero(batch.valid))
        invalid += int(np.count_nonzero(~batch.valid))
    return valid, invalid


@pytest.mark.slow  # a real-time daemon run of seconds
def test_daemon_logs_every_sample_and_every_estimate(tmp_path, free_port):
    config = DaemonConfig.load(write_config(tmp_path, free_port))
    summary = Daemon(config).run(duration_s=2.0)
    assert summary.clean_shutdown and summary.mcap_dropped == 0
    path = only_recording(tmp_path)
    valid, invalid = sample_rows(path)
    assert valid == summary.samples and invalid == summary.lost_samples == 0
    estimates = list(iter_estimates(path))
    assert [e["seq"] for e in estimates] == list(range(len(estimates)))
    ok = [e for e in estimates if e["ok"]]
    assert len(ok) == summary.estimates > 40
    for key, truth in TRUTH.items():
        assert np.median([e[key] for e in ok]) == pytest.approx(truth, rel=0.1), key
    final = list(iter_status(path))[-1]
    assert final["acquisition"]["samples"] == valid
    assert final["worker"]["estimates"] == summary.estimates
    assert all(type(reason) is str for reason in summary.withheld)  # values, not Reason members


def gate_waits_and_steps(
    daemon: Daemon, step_name: str, monkeypatch: pytest.MonkeyPatch
) -> tuple[set[str], list[str | None]]:
    """Record which threads wait on the worker's window gate, and for each ``step_name``
    step of the journal whether the housekeeping thread's last act before it was a gate wait
    (``"MainThread"``) or another step (None)."""
    from rtsid.runtime.gate import WindowGate

    waiters: set[str] = set()
    last_wait: list[str | None] = [None]
    before_step: list[str | None] = []
    original_wait, journal_step = WindowGate.after_next_window, daemon.stalls.step

    def after_next_window(gate: WindowGate, timeout_s: float) -> bool:
        name = threading.current_thread().name
        waiters.add(name)
        answer = original_wait(gate, timeout_s)
        if name == "MainThread":
            last_wait[0] = name
        return answer

    def step(name: str):
        if name == step_name:
            before_step.append(last_wait[0])
        if threading.current_thread().name == "MainThread":
            last_wait[0] = None  # a housekeeping step since the wait
        return journal_step(name)

    monkeypatch.setattr(daemon.stalls, "step", step)
    monkeypatch.setattr(WindowGate, "after_next_window", after_next_window)
    return waiters, before_step


@pytest.mark.slow  # a real-time daemon run of seconds
def test_the_history_holds_the_recorded_estimates_deflated_on_the_housekeeping_thread(
    tmp_path, free_port, monkeypatch
):
    """At a 4 ms hop the history seals blocks of estimates; the housekeeping tick (never the
    worker) deflates them, each after a wait for the worker to go to sleep, and what the
    history gives back is byte for byte the file's."""
    from rtsid.io import history

    stores: list[history.HistoryStore] = []
    packed_on: set[str] = set()
    original_init, original_pack = history.HistoryStore.__init__, history._PackedBlock.__init__

    def keep(self, *args, **kw):
        original_init(self, *args, **kw)
        stores.append(self)

    def pack(self, block, compressor):
        packed_on.add(threading.current_thread().name)
        original_pack(self, block, compressor)

    monkeypatch.setattr(history.HistoryStore, "__init__", keep)
    monkeypatch.setattr(history._PackedBlock, "__init__", pack)
    monkeypatch.setattr(history.MessageRing, "BLOCK_MESSAGES", 32)  # blocks within seconds
    extra = "[worker]\nhop_s = 0.004\n[slow_lane]\nenabled = false\n"
    daemon = Daemon(DaemonConfig.load(write_config(tmp_path, free_port, extra)))
    waiters, deflates = gate_waits_and_steps(daemon, "housekeeping: history deflate", monkeypatch)
    summary = daemon.run(3.0)
    assert summary.clean_shutdown
    # each deflate in a gap of its own: the housekeeping waited on the gate just before it
    assert deflates and all(last == "MainThread" for last in deflates)
    assert "rtsid-mcap" in waiters  # the MCAP writer keeps to the gate too
    (store,) = stores
    with only_recording(tmp_path).open("rb") as fh:
        recorded = [m.data for _, c, m in make_reader(fh).iter_messages() if c.topic == "/estimate"]
    held, _, _ = store._rings["estimate"].snapshot(0, 2**63 - 1)
    assert len(recorded) > 2 * 32
    assert held == recorded
    assert packed_on == {"MainThread"}  # the housekeeping loop runs on the calling thread


@pytest.mark.slow  # a real-time daemon run of seconds
def test_each_half_of_the_status_tick_begins_as_the_worker_goes_to_sleep(
    tmp_path, free_port, monkeypatch
):
    """Issue 22: the status tick's build and its encoding and publication each wait for the
    worker to finish its window and go to wait for the next one, so neither shares the GIL
    with a window from its start; the status content is unchanged (a recorded status has
    every part, and the worker's counters). Garbage collection, off while the daemon runs,
    is run by the housekeeping tick alone."""
    extra = "[worker]\nhop_s = 0.004\n[slow_lane]\nenabled = false\n"
    daemon = Daemon(DaemonConfig.load(write_config(tmp_path, free_port, extra)))
    halves: list[tuple[int, int]] = []  # (worker's sleeps begun, waits run out) at each half
    journal_step = daemon.stalls.step

    def step(name: str):
        if name == "housekeeping: status" and daemon.worker is not None:
            gate = daemon.worker.gate
            halves.append((gate.idle, gate.waited_out))
        return journal_step(name)

    daemon.stalls.step = step  # type: ignore[method-assign]
    disabled_at: list[float] = []  # when the daemon turned automatic collection off

    def disable() -> None:
        disabled_at.append(time.perf_counter())
        gc_disable()

    gc_disable = gc.disable
    monkeypatch.setattr(gc, "disable", disable)
    thresholds = gc.get_threshold()
    gc.set_threshold(100, 10, 10)  # collections due every few ticks
    try:
        summary = daemon.run(duration_s=2.5)
    finally:
        gc.set_threshold(*thresholds)
    assert summary.clean_shutdown and summary.estimates > 100
    assert gc.isenabled()  # automatic collection is back after the run
    # every collection ran on the housekeeping thread, right after its gate wait: none
    # inside a window on the worker (nor on the acquisition or writer threads)
    (off_s,) = disabled_at
    collections = [s for s in daemon.stalls.spans() if s.name.startswith("gc gen")]
    after = [s for s in collections if s.start_s > off_s]
    assert len(after) >= 2
    assert {s.name.split(" (")[1] for s in after} == {"MainThread)"}
    assert len(halves) >= 4 and len(halves) % 2 == 0  # build, then publish, per status
    for (idle, out), (next_idle, next_out) in itertools.pairwise(halves):
        # the worker went to sleep between the two (or the wait's bound ran out, counted)
        assert next_idle > idle or next_out > out
    assert any(b[0] > a[0] for a, b in itertools.pairwise(halves))
    statuses = list(iter_status(only_recording(tmp_path)))
    assert len(statuses) >= len(halves) // 2
    final = statuses[-1]
    assert {"acquisition", "worker", "mcap", "zenoh", "session"} <= set(final)
    assert final["worker"]["estimates"] == summary.estimates
    assert set(final["worker"]) >= {"miss_causes", "overrun_causes", "gc_collections"}
    assert set(final["worker"]) >= {"miss_cpu_causes", "costly_causes", "gc_frozen"}
    # the start-up's full collections apart from the running daemon's, which are young here
    assert final["worker"]["gc_longest_startup"][0] == 2
    assert final["worker"]["gc_frozen"] > 10_000  # the start-up's objects, frozen


@pytest.mark.slow  # a real-time daemon run of seconds
def test_realtime_priority_puts_the_acquisition_and_the_worker_first(tmp_path, free_port):
    extra = "[daemon]\nrealtime_priority = 7\n[slow_lane]\nenabled = false\n"
    seen: list[tuple[int, int, int]] = []

    def on_status(status, estimate):
        worker, acquisition = daemon.worker, daemon.acquisition
        if worker is None or acquisition is None or not (worker.running and acquisition.running):
            return  # the last status comes after the threads stopped
        tids = (worker.native_id, acquisition.native_id, 0)
        seen.append(tuple(os.sched_getscheduler(tid) for tid in tids))  # type: ignore[arg-type]

    daemon = Daemon(DaemonConfig.load(write_config(tmp_path, free_port, extra)), on_status)
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except OSError:
        pytest.skip("no scheduling control here")
    try:
        summary = daemon.run(duration_s=1.5)
    except ConfigError as exc:  # an unprivileged machine: the one-line refusal
        assert "daemon.realtime_priority" in str(exc)
        pytest.skip("this machine does not allow real-time scheduling (not root)")
    assert summary.clean_shutdown and seen
    assert set(seen) == {(os.SCHED_FIFO, os.SCHED_FIFO, os.SCHED_OTHER)}


def test_realtime_priority_is_1_to_99_or_0(tmp_path):
    path = tmp_path / "rtsid.toml"
    path.write_text("[daemon]\nrealtime_priority = 100\n")
    with pytest.raises(ConfigError, match=r"daemon\.realtime_priority.*<= 99"):
        DaemonConfig.load(path)


class Sink:
    """Records what the daemon hands to a publisher or logger, in order."""

    def __init__(self) -> None:
        self.got: list[bytes] = []
        self.batches = 0

    def publish_estimate(self, payload: bytes) -> None:
        self.got.append(payload)

    def log_estimate(self, payload: bytes, *, log_time_ns: int) -> bool:
        self.got.append(payload)
        return True

    def log_estimates(self, batch: list[tuple[bytes, int, dict]]) -> bool:
        self.batches += 1
        self.got.extend(payload for payload, _, _ in batch)
        return True


def estimate_message(seq: int) -> dict:
    return {"seq": seq, "host_time_ns": 1_000 + seq, "ok": False, "reason": "stale"}


def test_estimates_reach_zenoh_at_once_and_the_mcap_writer_on_the_housekeeping_tick(
    monkeypatch,
):
    import rtsid.runtime.daemon as daemon_module

    monkeypatch.setattr(daemon_module, "encode_estimate", lambda m: str(m["seq"]).encode())
    monkeypatch.setattr(daemon_module, "ESTIMATES_HELD", 3)
    daemon, zenoh_sink, mcap_sink = Daemon(DaemonConfig()), Sink(), Sink()
    for seq in range(2):
        daemon._publish_estimate(estimate_message(seq), mcap_sink, zenoh_sink)
    assert zenoh_sink.got == [b"0", b"1"] and mcap_sink.got == []  # no writer wake-up yet
    daemon._log_estimates(mcap_sink)
    assert mcap_sink.got == [b"0", b"1"] and mcap_sink.batches == 1  # one hand-over a tick
    for seq in range(2, 6):  # housekeeping stuck: past the hold the worker hands them over
        daemon._publish_estimate(estimate_message(seq), mcap_sink, zenoh_sink)
    assert mcap_sink.got == [b"0", b"1", b"5"]
    daemon._log_estimates(mcap_sink)
    assert sorted(mcap_sink.got) == [str(k).encode() for k in range(6)]
    assert zenoh_sink.got == [str(k).encode() for k in range(6)]
    assert daemon.last_estimate == estimate_message(5)


def open_files() -> set[str]:
    return {os.path.realpath(f"/proc/self/fd/{fd}") for fd in os.listdir("/proc/self/fd")}


def test_cpu_latency_request_is_held_while_the_daemon_runs(tmp_path, free_port, monkeypatch):
    from rtsid.runtime import power

    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    monkeypatch.setattr(power, "PM_QOS_DEVICE", str(device))
    config = DaemonConfig.load(write_config(tmp_path, free_port, "[daemon]\ncpu_latency_us = 0"))
    held = []
    Daemon(config, on_status=lambda *_: held.append(str(device) in open_files())).run(1.0)
    assert held and all(held)
    assert device.read_bytes() == b"\0\0\0\0"
    assert str(device) not in open_files()
    monkeypatch.setattr(power, "PM_QOS_DEVICE", str(tmp_path / "missing" / "device"))
    with pytest.raises(ConfigError, match=r"daemon\.cpu_latency_us"):
        Daemon(config).run(duration_s=1.0)


def test_bad_config_is_one_clear_error(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[workr]\nhop_s = 0.02\n")
    with pytest.raises(ConfigError, match=r"unknown config section \[workr\].*\[worker\]"):
        DaemonConfig.load(bad)
    bad.write_text("[worker]\nhop_s = -1\n")
    with pytest.raises(ConfigError, match=r"worker\.hop_s"):
        DaemonConfig.load(bad)


def start_daemon(config: Path) -> subprocess.Popen[bytes]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "rtsid.cli", "run", "--config", str(config), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
    )


def collect_estimates(port: int, wanted: int, timeout_s: float) -> list[dict]:
    """Subscribe from this process until ``wanted`` ok estimates arrived (or the timeout)."""
    received: list[dict] = []
    conf = subscriber_config((f"tcp/127.0.0.1:{port}",), mode="client")
    deadline = time.monotonic() + timeout_s
    while True:  # the daemon's listener may not be up yet: retry opening
        try:
            session = zenoh.open(conf)
            break
        except zenoh.ZError:
            assert time.monotonic() < deadline, "daemon never listened"
            time.sleep(0.1)
    with session:
        sub = session.declare_subscriber(
            "rtsid/testbot/ankle/estimate", zenoh.handlers.FifoChannel(1024)
        )
        while sum(e["ok"] for e in received) < wanted and time.monotonic() < deadline:
            sample = sub.try_recv()
            if sample is None:
                time.sleep(0.005)
                continue
            received.append(json.loads(sample.payload.to_bytes()))
        sub.undeclare()
    return received


def stop_process(proc: subprocess.Popen[bytes], sig: int) -> tuple[int, str]:
    try:
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=20)
        return proc.returncode, err.decode()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)


def test_separate_process_publishes_to_a_subscriber_and_sigterm_leaves_a_valid_file(
    tmp_path, free_port
):
    proc = start_daemon(write_config(tmp_path, free_port))
    try:
        received = collect_estimates(free_port, wanted=25, timeout_s=30)
    finally:
        code, err = stop_process(proc, signal.SIGTERM)
    assert code == 0, err
    ok = [e for e in received if e["ok"]]
    assert len(ok) >= 25
    assert np.median([e["K"] for e in ok]) == pytest.approx(TRUTH["K"], rel=0.1)
    path = only_recording(tmp_path)
    with path.open("rb") as fh:  # a finished file: the indexed reader needs the footer
        topics = {ch.topic for _, ch, _ in make_reader(fh).iter_messages()}
    assert {"/estimate", "/samples", "/status"} <= topics
    logged = {e["seq"]: e for e in iter_estimates(path)}
    for e in received:
        assert logged[e["seq"]]["K"] == e["K"]


@pytest.mark.slow  # a real-time daemon run of seconds
def test_sigkill_leaves_a_recoverable_file_missing_at_most_about_a_second(tmp_path, free_port):
    proc = start_daemon(write_config(tmp_path, free_port))
    try:
        received = collect_estimates(free_port, wanted=60, timeout_s=30)
    finally:
        stop_process(proc, signal.SIGKILL)
    last_seen = max(e["window_end_index"] for e in received)
    damaged = only_recording(tmp_path)
    fixed = tmp_path / "fixed.mcap"
    recover(damaged, fixed)
    valid, _ = sample_rows(fixed)
    fs = 2500.0
    # Samples up to the newest window a subscriber saw, less ~1 s of unflushed data.
    assert valid >= last_seen + 1 - 1.0 * fs
    with fixed.open("rb") as fh:
        assert sum(1 for _ in make_reader(fh).iter_messages(topics=["/estimate"])) > 0


def test_zenoh_unavailable_does_not_stop_acquisition_or_logging(tmp_path, free_port):
    import socket

    with socket.socket() as blocker:  # something else already listens on the zenoh port
        blocker.bind(("127.0.0.1", free_port))
        blocker.listen()
        config = DaemonConfig.load(write_config(tmp_path, free_port))
        summary = Daemon(config).run(duration_s=1.5)
    assert summary.estimates > 20 and summary.samples > 3000
    path = only_recording(tmp_path)
    assert sample_rows(path)[0] == summary.samples
    zenoh_state = list(iter_status(path))[-1]["zenoh"]
    assert zenoh_state["state"] != "up" and zenoh_state["errors"] >= 1


def _numeric_keys(table: dict, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    """Every float-valued key of a config document, as paths (section, [sub,] key)."""
    keys = []
    for key, value in table.items():
        if isinstance(value, dict):
            keys += _numeric_keys(value, (*prefix, key))
        elif isinstance(value, float):
            keys.append((*prefix, key))
    return keys


@pytest.mark.parametrize("path", _numeric_keys(DaemonConfig().as_dict()), ids=".".join)
def test_nan_in_any_numeric_key_is_one_line_naming_the_key(path):
    document: dict = {}
    table = document
    for part in path[:-1]:
        table = table.setdefault(part, {})
    table[path[-1]] = float("nan")
    with pytest.raises(ConfigError) as info:
        DaemonConfig.from_mapping(document)
    message = str(info.value)
    assert ".".join(path) in message and "finite" in message and "\n" not in message


def test_window_longer_than_the_ring_is_refused_with_the_fix():
    off = {"enabled": False}  # the slow lane needs a longer ring: refused for that alone
    document = {"link": {"ring_capacity_s": 1.0}, "worker": {"window_s": 2.0}, "slow_lane": off}
    with pytest.raises(ConfigError) as info:
        DaemonConfig.from_mapping(document)
    message = str(info.value)
    assert "worker.window_s" in message and "link.ring_capacity_s" in message
    assert "\n" not in message
    DaemonConfig.from_mapping(
        {"link": {"ring_capacity_s": 1.0}, "worker": {"window_s": 0.5}, "slow_lane": off}
    )


def _injected(*_args: object, **_kwargs: object) -> None:
    raise RuntimeError("injected failure")


@pytest.mark.parametrize(
    ("thread", "owner", "method"),
    [
        ("rtsid-acquisition", "rtsid.link.acquisition.Acquisition", "_handle"),
        ("rtsid-worker", "rtsid.runtime.worker.WindowWorker", "process_window"),
        ("rtsid-mcap", "rtsid.io.mcap_log.McapLogger", "_write"),
    ],
)
def test_a_dying_thread_stops_the_daemon_with_a_failure(
    tmp_path, free_port, monkeypatch, thread, owner, method
):
    monkeypatch.setattr(f"{owner}.{method}", _injected)
    config = DaemonConfig.load(write_config(tmp_path, free_port))
    summary = Daemon(config).run(duration_s=60.0)  # only the failure can end it before that
    assert not summary.clean_shutdown
    assert summary.failure is not None
    assert thread in summary.failure and "injected failure" in summary.failure


def test_rtsid_run_exits_1_naming_the_dead_thread(tmp_path, free_port, monkeypatch, capsys):
    from rtsid.cli import main

    monkeypatch.setattr("rtsid.runtime.worker.WindowWorker.process_window", _injected)
    config = write_config(tmp_path, free_port)
    assert main(["run", "--config", str(config), "--quiet", "--duration", "60"]) == 1
    err = capsys.readouterr().err
    assert "rtsid run: error: thread rtsid-worker failed: RuntimeError: injected failure" in err


def test_rtsid_run_prints_the_withheld_reasons_as_their_values(
    tmp_path, free_port, monkeypatch, capsys
):
    from rtsid.cli import main
    from rtsid.runtime.daemon import RunSummary
    from rtsid.verdicts import Reason

    class OneGap:
        """A daemon whose run withheld one window for a gap (as the worker counts it)."""

        def __init__(self, *args: object, **kwargs: object) -> None:
            pass

        def request_stop(self) -> None:
            pass

        def run(self, duration_s: float | None = None) -> RunSummary:
            return RunSummary(
                estimates=9,
                withheld={Reason.GAP: 1},
                deadline_misses=0,
                overruns=0,
                samples=2500,
                lost_samples=0,
                mcap_files=[],
                mcap_dropped=0,
                clean_shutdown=True,
            )

    monkeypatch.setattr("rtsid.commands.run.Daemon", OneGap)
    config = write_config(tmp_path, free_port)
    assert main(["run", "--config", str(config), "--quiet", "--duration", "1"]) == 0
    err = capsys.readouterr().err
    assert "9 estimates, withheld gap: 1, 0 deadline misses" in err and "<Reason" not in err


def test_an_unwritable_recordings_folder_stops_start_up_naming_the_key(tmp_path, free_port, capsys):
    from rtsid.cli import main

    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    config = write_config(tmp_path, free_port)
    config.write_text(config.read_text().replace(str(tmp_path / "rec"), str(blocker / "rec")))
    assert main(["run", "--config", str(config), "--quiet", "--duration", "60"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mcap.directory" in err[0] and "mcap.enabled = false" in err[0]
    assert not (blocker.parent / "rec").exists()


@pytest.mark.slow  # a real-time daemon run of seconds
def test_a_mute_socketcand_server_neither_hangs_start_up_nor_stop(tmp_path, free_port):
    import socket

    with socket.create_server(("127.0.0.1", 0)) as mute:  # accepts, never greets
        extra = f'[link]\ninterface = "socketcand"\nport = {mute.getsockname()[1]}\n'
        config = DaemonConfig.load(write_config(tmp_path, free_port, extra))
        daemon = Daemon(config)

        def stop_once_the_open_failed(status: dict, _estimate: object) -> None:
            if status["acquisition"]["bus_errors"] >= 1:
                daemon.request_stop()

        daemon.on_status = stop_once_the_open_failed
        summary = daemon.run(duration_s=60.0)  # returns through request_stop, not the duration
    assert daemon.acquisition is not None and "did not greet" in daemon.acquisition.last_error
    assert summary.samples == 0 and summary.failure is None


def test_an_inverted_torque_sign_stops_the_daemon_naming_the_key(tmp_path, free_port, capsys):
    # issue 19: a rig whose torque reads inverted gave K, B, I < 0 and ran on. The embedded
    # plant reports the torque as it is; [estimator] torque_sign = -1 inverts it.
    from rtsid.cli import main

    config = write_config(tmp_path, free_port, "[estimator]\ntorque_sign = -1.0\n")
    assert main(["run", "--config", str(config), "--quiet", "--duration", "60"]) == 1
    err = capsys.readouterr().err
    failed = "rtsid run: error: thread rtsid-worker failed: TorqueSignError: most windows read K, B"
    assert failed in err
    assert "[estimator] torque_sign = 1 " in err


def console_lines_until(config: DaemonConfig, done, duration_s: float = 60.0) -> list[str]:
    """Run the daemon, keeping each console line (``rtsid run``'s), until ``done(line,
    status)``; the last line returned is the one that was done (not the one at shutdown)."""
    from rtsid.commands.run import link_where, status_line

    lines: list[str] = []
    daemon = Daemon(config)

    def show(status: dict, estimate: dict | None) -> None:
        if daemon.stop_event.is_set():
            return
        lines.append(status_line(status, estimate, link_where(config.link)))
        if done(lines[-1], status):
            daemon.request_stop()

    daemon.on_status = show
    summary = daemon.run(duration_s=duration_s)  # ends through request_stop, not the duration
    assert summary.failure is None, summary.failure
    return lines


def socketcand_config(tmp_path: Path, zenoh_port: int, port: int) -> DaemonConfig:
    extra = f'[link]\ninterface = "socketcand"\nport = {port}\n[daemon]\nstatus_period_s = 0.1\n'
    return DaemonConfig.load(write_config(tmp_path, zenoh_port, extra))


@pytest.mark.slow  # a real-time daemon run of seconds
def test_the_console_says_why_it_waits_for_a_server_that_never_greets_or_is_not_there(
    tmp_path, free_port
):
    # issue 20: the console said only "waiting for the first window" while /status knew
    # connected: false, bus_errors: 4
    import re
    import socket

    with socket.create_server(("127.0.0.1", 0)) as mute:  # accepts, never greets
        port = mute.getsockname()[1]
        config = socketcand_config(tmp_path, free_port, port)
        lines = console_lines_until(config, lambda _, s: s["acquisition"]["bus_errors"] >= 2)
    line = lines[-1]
    pattern = rf"waiting: connected to 127\.0\.0\.1:{port} but socketcand has not greeted "
    assert re.search(pattern + r"\(bus errors 2\)", line), line
    assert "waiting for the first window" not in "".join(lines)
    port = free_port + 1 if free_port < 65535 else free_port - 1
    with socket.socket() as closed:  # nothing listens there
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
    config = socketcand_config(tmp_path, free_port, port)
    line = console_lines_until(config, lambda _, s: s["acquisition"]["bus_errors"] >= 1)[-1]
    assert f"waiting: not connected to 127.0.0.1:{port} (bus errors " in line, line
    assert f"no socketcand server at 127.0.0.1:{port}" in line


@pytest.mark.slow  # a real-time daemon run of seconds
def test_the_console_says_no_frames_no_state_frames_and_stale(tmp_path, free_port):
    import can

    from rtsid.link.protocol import STATE_ID, encode_state_block
    from rtsid.link.socketcand import SocketcandServer

    def frames(ident: int, n: int) -> list[can.Message]:
        payload = encode_state_block(*(np.arange(n, dtype=np.int64),) * 3, np.zeros(n, np.int64))
        return [
            can.Message(arbitration_id=ident, data=p.tobytes(), is_extended_id=False)
            for p in payload
        ]

    seen: list[str] = []

    def step(line: str, status: dict) -> bool:
        """Walk through the phases: each sends what the next one needs, once it is seen."""
        for phase, text, then in (
            ("no_frames", "no frames yet from the bus", frames(0x7FF, 5)),
            ("no_state_frames", "5 frames from 127.0.0.1", frames(STATE_ID, 20)),
        ):
            if text in line and phase not in seen:
                server.send_frames(then)
                if server.counters().frames_out:  # not sent during the client's handshake
                    seen.append(phase)
        if "stale: no state frame from 127.0.0.1" in line:
            seen.append("stale")
        return "stale" in seen

    with SocketcandServer(port=0) as server:
        config = socketcand_config(tmp_path, free_port, server.port)
        lines = console_lines_until(config, step)
    assert seen == ["no_frames", "no_state_frames", "stale"], lines
    assert any(
        f"waiting: connected to 127.0.0.1:{server.port}, no frames yet from the bus" in line
        for line in lines
    )
    assert any(
        "waiting: 5 frames from 127.0.0.1" in line
        and "but no state frame (5 unknown id, 0 malformed)" in line
        for line in lines
    )


def test_the_run_summary_prints_reasons_as_their_values(tmp_path, free_port, capsys):
    from rtsid.cli import main
    from rtsid.verdicts import Reason, format_counts

    assert format_counts({Reason.GAP: 1}) == "gap: 1"
    assert format_counts({Reason.STALE: 3, Reason.GAP: 1}) == "gap: 1, stale: 3"
    assert format_counts({}) == "0"
    # the embedded plant falls silent for 0.4 s of every 1 s: windows withheld as gaps
    extra = "[plant.faults]\nsilence_every_s = 0.6\nsilence_s = 0.2\n"
    config = write_config(tmp_path, free_port, extra)
    assert main(["run", "--config", str(config), "--quiet", "--duration", "2"]) == 0
    err = capsys.readouterr().err
    assert re.search(r"withheld (gap: \d+|stale: \d+)", err), err
    assert "Reason" not in err and "{" not in err


def test_a_taken_zenoh_port_is_one_prefixed_warning_without_zenohs_source_paths(
    tmp_path, free_port
):
    # `rtsid run --quiet` printed zenoh's failure bare (no `rtsid run:`), with the Rust source
    # locations zenoh appends (`at /root/.cargo/…/unicast.rs:338.`)
    import socket

    config = write_config(tmp_path, free_port)
    argv = ["run", "--config", str(config), "--quiet", "--duration", "1.5"]
    with socket.socket() as taken:
        taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        taken.bind(("127.0.0.1", free_port))
        taken.listen()
        done = subprocess.run(
            [sys.executable, "-m", "rtsid.cli", *argv],
            capture_output=True,
            text=True,
            timeout=90,
        )
    assert done.returncode == 0, done.stderr  # acquisition and recording go on
    lines = [line for line in done.stderr.splitlines() if "could not open" in line]
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("rtsid run: warning: zenoh session on tcp/127.0.0.1:")
    assert "Address already in use" in lines[0] and "set zenoh.listen to a free one" in lines[0]
    assert ".rs:" not in lines[0]
    assert only_recording(tmp_path).stat().st_size > 0


def test_the_duration_counts_from_the_first_samples_not_from_the_end_of_start_up(
    tmp_path, free_port, monkeypatch
):
    # `rtsid run --duration 8` recorded 12 s on a busy machine: the plant sent while the rest
    # started, and the duration was counted only after that
    from rtsid.runtime import daemon as daemon_module

    def slow_start(*args, **kwargs):
        time.sleep(1.5)  # a slow start-up (a slow lane's process on a busy machine)
        return None

    monkeypatch.setattr(daemon_module.Daemon, "_slow_lane", slow_start)
    config = DaemonConfig.load(write_config(tmp_path, free_port))
    summary = Daemon(config).run(duration_s=2.0)
    assert summary.clean_shutdown
    fs = config.link.fs_hz
    assert 1.5 * fs < summary.samples < 3.2 * fs  # the 2 s asked for (and the stop), not 3.5 s
