"""Markers and condition changes end to end: an embedded-plant daemon with zenoh on loopback
(multicast off), ``rtsid mark`` / ``rtsid condition`` acknowledged, what lands in the
recording, wire markers, hostile labels, no daemon, and kill -9 after acknowledgements."""

from __future__ import annotations

import dataclasses
import json
import signal
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from rtsid.cli import main
from rtsid.io.mcap_log import McapConfig
from rtsid.io.mcap_read import recover
from rtsid.io.recording import read_recording, read_session
from rtsid.io.zenoh_link import query, subscriber_config
from rtsid.link.markers import WireMarker
from rtsid.runtime.daemon import Daemon, DaemonConfig

from .test_daemon import only_recording, start_daemon, stop_process, write_config

SESSION = '\n[session]\nsubject = "S01"\nsession = "2"\ncondition = "baseline"\n'


@pytest.fixture
def daemon(tmp_path: Path, free_port: int, wait_for) -> Iterator[Daemon]:
    """An embedded-plant daemon running on a thread until the test ends."""
    config = DaemonConfig.load(write_config(tmp_path, free_port, SESSION))
    d = Daemon(config)
    runner = threading.Thread(target=d.run, kwargs={"duration_s": 60.0}, name="test-daemon")
    runner.start()
    try:
        wait_for(lambda: d.desk is not None and d.desk.running and d.desk.next_sample() > 0, 20)
        yield d
    finally:
        d.request_stop()
        runner.join(30)
    assert not runner.is_alive()


def client(port: int) -> zenoh.Session:
    return zenoh.open(subscriber_config((f"tcp/127.0.0.1:{port}",), mode="client"))


def mark(session: zenoh.Session, body: bytes | dict, key: str = "rtsid/testbot/ankle/mark"):
    payload = body if isinstance(body, bytes) else json.dumps(body).encode()
    return query(session, key, timeout_s=5.0, payload=payload)


def acknowledged(session: zenoh.Session, label: str, marker_id: str, attempts: int = 3) -> int:
    """Mark until acknowledged, resending with the same ``marker_id`` after no reply or an
    error reply (as the desk's errors say to); the acknowledged sample."""
    answers = []
    for _ in range(attempts):
        answer = mark(session, {"label": label, "marker_id": marker_id})
        if answer.replies:
            (reply,) = answer.replies
            return int(json.loads(reply[1])["sample_index"])
        answers.append(answer.errors or "no reply within the query's timeout")
    raise AssertionError(f"{label!r} not acknowledged in {attempts} attempts: {answers}")


def cli(*argv: str, port: int) -> list[str]:
    return [*argv, "--connect", f"tcp/127.0.0.1:{port}", "--mode", "client", "--timeout", "5"]


def test_mark_and_condition_are_acknowledged_and_recorded(daemon, tmp_path, free_port, capsys):
    desk = daemon.desk
    assert desk is not None
    before = desk.next_sample()
    assert main(cli("mark", "trial 3 start", "--id", "t3", port=free_port)) == 0
    after = desk.next_sample()
    out = capsys.readouterr().out
    acked = int(out.split(" at sample ")[1].split()[0])
    assert before <= acked <= after  # the next sample when the daemon took it
    assert main(cli("mark", "trial 3 start again", "--id", "t3", port=free_port)) == 0
    assert "already recorded" in capsys.readouterr().out
    assert main(cli("condition", "fatigue", "--robot", "testbot", port=free_port)) == 0
    changed = int(capsys.readouterr().out.split(" from sample ")[1].split()[0])
    assert changed >= acked
    wire_at = desk.next_sample() - 100
    daemon.acquisition.markers.put(WireMarker(wire_at, "wire trial\x07"))
    counters = desk.counters
    deadline = time.monotonic() + 10
    while counters()["markers_by_source"]["wire"] < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    daemon.request_stop()
    for runner in [t for t in threading.enumerate() if t.name == "test-daemon"]:
        runner.join(30)  # the file is finished when the daemon's run returns

    path = only_recording(tmp_path)
    assert path.name.startswith("S01_2_testbot-ankle_")
    got = read_session(path)
    assert [(m["sample_index"], m["label"], m["source"]) for m in got.markers] == sorted(
        [
            (acked, "trial 3 start", "zenoh"),  # the resent id is recorded once
            (wire_at, "wire trial?", "wire"),  # at its own sample, control character cleaned
        ]
    )
    assert [(s["sample_index"], s["condition"]) for s in got.sessions][-1] == (changed, "fatigue")
    assert got.sessions[0]["condition"] == "baseline"
    grid = read_recording(path).samples
    assert grid.first_index <= acked < grid.end_index  # the marked sample is in the recording
    status = counters()
    assert status["markers"] == 2 and status["duplicates"] == 1
    assert status["condition_changes"] == 1 and status["condition"] == "fatigue"


def test_hostile_labels_are_refused_and_puts_are_counted(daemon, free_port, wait_for):
    desk = daemon.desk
    assert desk is not None
    with client(free_port) as session:
        for label in ("x" * 10_000, "a\x1b[2Jb", ""):
            answer = mark(session, {"label": label})
            assert not answer.replies and len(answer.errors) == 1
            assert "NOT recorded" in answer.errors[0]
        assert mark(session, b"\xff\xfe").errors  # not UTF-8
        html = '<script>alert("x")</script>'
        answer = mark(session, {"label": html})
        assert json.loads(answer.replies[0][1])["label"] == html  # text, recorded as sent
        session.put("rtsid/testbot/ankle/mark/in", "put trial")
        session.put("rtsid/testbot/ankle/mark/in", "y" * 10_000)
        wait_for(lambda: desk.counters()["markers"] >= 2 and desk.counters()["refused"] >= 5, 10)
        latest = query(session, "rtsid/testbot/ankle/session", timeout_s=5.0)
    counters = desk.counters()
    assert counters["markers_by_source"]["zenoh"] == 2  # the HTML label and the put
    assert counters["refused_by_reason"] == {"bad_label": 4, "bad_request": 1}
    (reply,) = latest.replies
    assert json.loads(reply[1])["subject"] == "S01"  # a late joiner sees the session


def test_a_daemon_that_does_not_record_refuses_to_acknowledge(tmp_path, free_port, capsys):
    config = DaemonConfig.load(write_config(tmp_path, free_port))
    d = Daemon(dataclasses.replace(config, mcap=McapConfig(enabled=False)))
    runner = threading.Thread(target=d.run, kwargs={"duration_s": 30.0}, name="test-daemon")
    runner.start()
    try:
        deadline = time.monotonic() + 20
        while not (d.desk is not None and d.desk.running) and time.monotonic() < deadline:
            time.sleep(0.01)
        code = main(cli("mark", "trial 1", port=free_port))
        counters = d.desk.counters() if d.desk is not None else {}
    finally:
        d.request_stop()
        runner.join(30)
    assert not runner.is_alive()
    err = capsys.readouterr().err
    assert code == 1 and "the marker was NOT recorded" in err and "did not write it" in err
    assert counters["refused_by_reason"] == {"not_written": 1} and counters["markers"] == 0


def test_mark_with_no_daemon_fails_with_one_line(free_port, capsys):
    code = main(["mark", "trial 1", "--connect", f"tcp/127.0.0.1:{free_port}", "--timeout", "1"])
    err = capsys.readouterr().err.strip()
    assert code != 0
    assert len(err.splitlines()) == 1 and "the marker was NOT recorded" in err


def test_acknowledged_marks_survive_kill_9_once_each(tmp_path, free_port):
    # 100 marks: each is its own chunk, written and flushed before its acknowledgement, over
    # more than one flush interval; 1000 took the same path ten times more (and 20 s of CI),
    # far below REMEMBERED_IDS (4096), the one bound a count of marks could reach
    marks = 100
    proc = start_daemon(write_config(tmp_path, free_port, SESSION))
    acked: dict[str, int] = {}
    try:
        deadline = time.monotonic() + 30
        while True:  # the daemon's listener may not be up yet
            try:
                session = client(free_port)
                break
            except zenoh.ZError:
                assert time.monotonic() < deadline, "daemon never listened"
                time.sleep(0.1)
        with session:
            while not query(session, "rtsid/testbot/ankle/session", timeout_s=2.0).replies:
                assert time.monotonic() < deadline, "daemon never answered"
            for k in range(marks):
                marker_id = uuid.uuid4().hex
                acked[marker_id] = acknowledged(session, f"trial {k}", marker_id)
    finally:
        stop_process(proc, signal.SIGKILL)
    fixed = tmp_path / "fixed.mcap"
    recover(only_recording(tmp_path), fixed)
    got = read_session(fixed)
    assert got.subject == "S01" and got.metadata[0]["condition"] == "baseline"  # recovered too
    recorded = {m["marker_id"]: m["sample_index"] for m in got.markers}
    assert recorded == acked  # none lost, none twice, each on its acknowledged sample
    assert len(acked) == marks and sorted(acked.values()) == list(acked.values())


def test_a_marker_resent_after_a_write_timeout_is_acknowledged_with_its_first_write(
    daemon, tmp_path, free_port, monkeypatch
):
    """The MCAP writer held past the desk's wait (a stalled disk, say): the mark gets an error
    reply; resent with its id once the writer goes on, it is acknowledged with the sample of
    the first write, and the recording holds it once, on that sample."""
    import rtsid.runtime.session as desk_module

    desk = daemon.desk
    assert desk is not None
    writer = desk._mcap
    held, released = threading.Event(), threading.Event()
    turn = writer.wait_turn

    def held_turn() -> None:
        held.set()
        released.wait(20)  # bounded: the test releases it
        turn()

    monkeypatch.setattr(desk_module, "WRITE_TIMEOUT_S", 0.3)
    marker_id = uuid.uuid4().hex
    with client(free_port) as session:
        writer.wait_turn = held_turn
        try:
            before = desk.next_sample()
            first = mark(session, {"label": "held", "marker_id": marker_id})
            assert held.is_set()
        finally:
            writer.wait_turn = turn
            released.set()
        assert not first.replies and "did not confirm" in first.errors[0]
        again = mark(session, {"label": "held", "marker_id": marker_id})
    (reply,) = again.replies
    ack = json.loads(reply[1])
    assert ack["sample_index"] < desk.next_sample() and ack["sample_index"] >= before
    counters = desk.counters()
    assert counters["refused_by_reason"] == {"write_timeout": 1} and counters["markers"] == 1
    daemon.request_stop()
    for runner in [t for t in threading.enumerate() if t.name == "test-daemon"]:
        runner.join(30)
    got = read_session(only_recording(tmp_path))
    assert [(m["marker_id"], m["sample_index"]) for m in got.markers] == [
        (marker_id, ack["sample_index"])
    ]


def test_watch_and_query_show_the_session_and_markers(daemon, free_port, capsys):
    import io

    from rtsid.io.watch import watch

    assert main(cli("query", "--session", port=free_port)) == 0
    (line,) = capsys.readouterr().out.splitlines()
    shown = json.loads(line)
    assert (shown["subject"], shown["session"], shown["condition"]) == ("S01", "2", "baseline")
    out = io.StringIO()
    connect = (f"tcp/127.0.0.1:{free_port}",)
    with client(free_port) as session:
        sender = threading.Timer(1.0, lambda: mark(session, {"label": "trial 10"}))
        sender.start()
        try:
            code = watch("rtsid/*/*", connect, mode="client", count=250, timeout_s=30, out=out)
        finally:
            sender.join(10)
    assert code == 0
    lines = out.getvalue().splitlines()
    assert "testbot/ankle subject S01  session 2  condition baseline (from t=" in lines[0]
    assert any("marker 'trial 10' at t=" in ln and "zenoh)" in ln for ln in lines)


def test_run_flags_name_the_recording_and_fill_its_metadata(tmp_path, free_port, capsys):
    config = write_config(tmp_path, free_port, SESSION)
    argv = ["run", "--config", str(config), "--subject", "S 01", "--condition", "walk"]
    assert main([*argv, "--duration", "1", "--quiet"]) == 0
    assert "subject S 01, session 2, condition walk" in capsys.readouterr().out
    path = only_recording(tmp_path)
    assert path.name.startswith("S_01_2_testbot-ankle_") and path.name.endswith("Z.mcap")
    got = read_session(path)
    assert (got.subject, got.session, got.metadata[0]["condition"]) == ("S 01", "2", "walk")
    assert got.sessions[0]["condition"] == "walk" and got.markers == []


def test_a_flood_of_puts_is_recorded_or_counted_never_lost(daemon, free_port, wait_for):
    desk = daemon.desk
    assert desk is not None
    sent = 2000
    with client(free_port) as session:
        publisher = session.declare_publisher(
            "rtsid/testbot/ankle/mark/in", congestion_control=zenoh.CongestionControl.BLOCK
        )
        for k in range(sent):
            publisher.put(f"flood {k}")
        publisher.undeclare()

        def settled() -> bool:
            c = desk.counters()
            return c["markers"] + c["refused"] == sent

        wait_for(settled, 60, "every put recorded or counted")
    counters = desk.counters()
    assert counters["refused"] == counters["refused_by_reason"].get("inbox_full", 0)
    assert counters["markers"] >= 256  # at least a full inbox was recorded
