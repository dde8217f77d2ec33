"""The lab: daemons as clients of a zenoh router (eclipse-zenoh's router mode), the watch view
through it, late joiners' queries, a router that is unreachable or restarts, malformed
queries, and a flood of queries that must not disturb the fast lane."""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from rtsid.cli import main
from rtsid.errors import ConfigError, ServiceError
from rtsid.io.messages import EstimateMessage
from rtsid.io.schemas import encode_json
from rtsid.io.watch import LabFeed, WatchState, render_view
from rtsid.io.zenoh_link import (
    RouterConfig,
    ZenohConfig,
    ZenohPublisher,
    query,
    router_config,
    subscriber_config,
    zenoh_config,
)
from rtsid.runtime.daemon import Daemon, DaemonConfig
from rtsid.runtime.router import load_router_config, run_router

HW = Path(__file__).resolve().parents[2] / "hw"


class Router:
    """``run_router`` on a thread (what ``rtsid router`` runs), stopped on exit."""

    def __init__(self, port: int) -> None:
        self.endpoint = f"tcp/127.0.0.1:{port}"
        self.stop = threading.Event()
        self.lines: list[str] = []
        self.thread = threading.Thread(
            target=run_router,
            args=(RouterConfig(listen=(self.endpoint,)), self.stop),
            kwargs={"on_event": self.lines.append},
            name="test-router",
        )

    def __enter__(self) -> Router:
        self.thread.start()
        deadline = time.monotonic() + 10
        while not any("listening" in line for line in self.lines):
            assert time.monotonic() < deadline, "the router did not start"
            time.sleep(0.01)
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(10)
        assert not self.thread.is_alive()


def client(endpoint: str, joint: str, **kw: Any) -> ZenohConfig:
    return ZenohConfig(mode="client", connect=(endpoint,), robot="rig", joint=joint, **kw)


def wait_until_routed(endpoint: str, selector: str, timeout_s: float = 10.0) -> None:
    """Return once ``selector`` is answered through the router at ``endpoint``.

    A client's queryables reach the router a moment after its session opens; a query sent
    before that finds nobody and ends with no reply, which would read as a wrong answer.
    """
    deadline = time.monotonic() + timeout_s
    with zenoh.open(subscriber_config((endpoint,), "client")) as session:
        while True:
            answer = query(session, selector, timeout_s=1.0)
            if answer.replies or answer.errors:
                return
            assert time.monotonic() < deadline, f"{selector} was never answered via {endpoint}"
            time.sleep(0.05)


def estimate(joint: str, seq: int, robot: str = "rig") -> bytes:
    """A well-formed estimate (the clients check every message against ESTIMATE_SCHEMA)."""
    return encode_json(
        EstimateMessage(
            robot=robot, joint=joint, seq=seq, window_start_index=seq, window_end_index=seq + 749,
            t_start_s=0.0, t_end_s=0.2996, I=0.01, B=0.8, K=100.0 + seq, I_se=0.001, B_se=0.01,
            K_se=1.0, K_track=100.0, K_track_se=0.5, B_track=0.8, B_track_se=0.005, vaf=90.0,
            vaf_irf=90.0, vaf_fit=90.0, lost_samples=0, compute_ms=1.0, latency_ms=1.0, ok=True,
            reason=None, flags=(), host_time_ns=time.time_ns(), I_held=False, B_held=False,
        ).as_dict()
    )  # fmt: skip


def pump(
    publishers: dict[str, ZenohPublisher],
    feed: LabFeed,
    state: WatchState,
    until: Callable[[], bool],
    timeout_s: float = 15.0,
) -> None:
    """Publish an estimate per joint every 10 ms and feed what arrives, until ``until()``."""
    deadline = time.monotonic() + timeout_s
    seq = 0
    while not until():
        assert time.monotonic() < deadline, f"condition not met; joints {sorted(state.joints)}"
        for joint, pub in publishers.items():
            pub.publish_estimate(estimate(joint, seq))
        seq += 1
        for event in feed.poll():
            if event.kind in ("alive", "gone"):
                state.set_alive(event.key, event.kind == "alive")
            else:
                state.update(event.key, event.payload, event.received_ns)
        time.sleep(0.01)


def test_router_config_from_toml_json5_and_the_command_line(tmp_path: Path) -> None:
    assert load_router_config(None).listen == ("tcp/127.0.0.1:7447",)
    assert load_router_config(None, ("tcp/127.0.0.1:9",)).listen == ("tcp/127.0.0.1:9",)
    shipped = load_router_config(HW / "router.toml")  # the json5 a zenohd would use
    conf = router_config(shipped)
    assert json.loads(conf.get_json("mode")) == "router"
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    bad = tmp_path / "bad.toml"
    bad.write_text("[zenoh]\nmode = 'client'\n")
    with pytest.raises(ConfigError, match=r"unknown config section \[zenoh\]"):
        load_router_config(bad)
    bad.write_text("[router]\nlisten = ['127.0.0.1:7447']\n")
    with pytest.raises(ConfigError, match=r"router\.listen.*tcp/127\.0\.0\.1:7447"):
        load_router_config(bad)
    peer = tmp_path / "peer.json5"
    peer.write_text('{ mode: "peer" }')
    with pytest.raises(ConfigError, match="not in router mode"):
        router_config(RouterConfig(config_file=str(peer)))
    # A client only connects: the default listen endpoint is not opened, another is refused.
    conf = zenoh_config(ZenohConfig(mode="client", connect=("tcp/127.0.0.1:7447",)))
    assert json.loads(conf.get_json("listen/endpoints")) == []
    with pytest.raises(ConfigError, match=r"zenoh\.listen.*client mode"):
        ZenohConfig.from_mapping(
            {"mode": "client", "connect": ["tcp/127.0.0.1:1"], "listen": ["tcp/127.0.0.1:2"]}
        )


def test_a_taken_router_endpoint_is_one_clear_error(free_port: int, capsys: Any) -> None:
    with Router(free_port):
        with pytest.raises(ServiceError, match=r"router on tcp/127.0.0.1:\d+ could not open"):
            run_router(RouterConfig(listen=(f"tcp/127.0.0.1:{free_port}",)), threading.Event())
        assert main(["router", "--listen", f"tcp/127.0.0.1:{free_port}"]) == 2
    assert "--listen" in capsys.readouterr().err


def test_watch_through_the_router_shows_every_joint_and_drops_one_that_leaves(
    free_port: int,
) -> None:
    with Router(free_port) as router:
        pubs = {j: ZenohPublisher(client(router.endpoint, j)).start() for j in ("j0", "j1")}
        try:
            assert all(p.is_up for p in pubs.values())
            state = WatchState()
            with LabFeed("rtsid/*/*", (router.endpoint,), "client") as feed:
                pump(pubs, feed, state, lambda: all(
                    (v := state.joints.get(f"rig/{j}")) is not None and v.estimates >= 5
                    for j in pubs))  # fmt: skip
                rows = render_view(state, title="t", now_s=0.0).splitlines()
                assert [r.split()[0] for r in rows if r.startswith("rig/")] == ["rig/j0", "rig/j1"]
                # A late joiner asks for the latest estimate of every joint.
                with zenoh.open(subscriber_config((router.endpoint,), "client")) as late:
                    answer = query(late, "rtsid/*/*/estimate")
                assert sorted(k for k, _ in answer.replies) == [
                    "rtsid/rig/j0/estimate",
                    "rtsid/rig/j1/estimate",
                ]
                # Any other channel a daemon publishes reaches the feed; raw samples do not.
                session = pubs["j0"]._entities.session  # type: ignore[union-attr]
                session.put("rtsid/rig/j0/samples", b"{}")  # first: it would arrive first
                session.put("rtsid/rig/j0/reflex", b'{"gain": 1}')
                deadline = time.monotonic() + 10
                kinds: set[str] = set()
                while "reflex" not in kinds:
                    assert time.monotonic() < deadline, kinds
                    kinds |= {e.kind for e in feed.poll()}
                    time.sleep(0.01)
                assert "samples" not in kinds
                pubs.pop("j1").stop()
                pump(pubs, feed, state, lambda: "rig/j1" not in state.joints)
                view = render_view(state, title="t", now_s=0.0)
                assert "rig/j1" not in [r.split()[0] for r in view.splitlines() if r]
                assert "note: rig/j1 left at" in view and "rig/j0" in view
                deadline = time.monotonic() + 10
                while not any("rig/j1 left" in line for line in router.lines):
                    assert time.monotonic() < deadline, router.lines
                    time.sleep(0.05)
        finally:
            for pub in pubs.values():
                pub.stop()
    assert any("rig/j0 joined" in line for line in router.lines)


def test_unreachable_router_is_said_once_retried_and_joined_when_it_comes(
    free_port: int, caplog: pytest.LogCaptureFixture
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port}"
    caplog.set_level(logging.WARNING, logger="rtsid.io.zenoh")
    with ZenohPublisher(client(endpoint, "j0", retry_interval_s=0.1)) as pub:
        deadline = time.monotonic() + 10
        while pub.stats()["open_attempts"] < 4:
            assert time.monotonic() < deadline
            pub.publish_estimate(estimate("j0", 0))
            time.sleep(0.02)
        warnings = [r.getMessage() for r in caplog.records]
        assert len(warnings) == 1 and "router at" in warnings[0] and "unreachable" in warnings[0]
        assert pub.stats()["state"] == "down" and pub.stats()["not_published"] > 0
        assert pub.history is not None and pub.history.latest("estimate") is not None
        with Router(free_port):
            deadline = time.monotonic() + 10
            while not pub.is_up:
                assert time.monotonic() < deadline, "the daemon did not join the router"
                time.sleep(0.05)
            wait_until_routed(endpoint, "rtsid/rig/j0/history?since=60s")
            with zenoh.open(subscriber_config((endpoint,), "client")) as late:
                answer = query(late, "rtsid/rig/j0/history?since=60s")
            (part,) = [json.loads(p) for _, p in answer.replies if b'"estimate"' in p[:60]]
            assert part["messages"], "what was kept while the router was away is answered"
        deadline = time.monotonic() + 10
        while pub.stats()["state"] != "router_lost":  # the router went away again
            assert time.monotonic() < deadline, pub.stats()
            time.sleep(0.05)
    assert any("router at" in r.getMessage() and "lost" in r.getMessage() for r in caplog.records)


def test_malformed_queries_get_an_error_reply(free_port: int) -> None:
    with Router(free_port) as router, ZenohPublisher(client(router.endpoint, "j0")) as pub:
        pub.publish_estimate(estimate("j0", 1))
        wait_until_routed(router.endpoint, "rtsid/rig/j0/history?since=60s")
        with zenoh.open(subscriber_config((router.endpoint,), "client")) as session:
            for params, match in [
                ("since=abc", "since='abc' is not a duration"),
                ("bogus=1", "unknown query parameter 'bogus'"),
                ("kind=nope", "kind='nope' is not held here"),
                ("from=9;to=5", "before the range's start"),
            ]:
                answer = query(session, f"rtsid/rig/j0/history?{params}", timeout_s=10)
                assert not answer.replies
                (error,) = answer.errors
                assert match in json.loads(error)["error"]
        assert pub.stats()["query_errors"] == 4


def test_rtsid_query_prints_latest_and_history_as_json_lines(
    free_port: int, capsys: pytest.CaptureFixture[str]
) -> None:
    with Router(free_port) as router, ZenohPublisher(client(router.endpoint, "j0")) as pub:
        for seq in range(3):
            pub.publish_estimate(estimate("j0", seq))
        wait_until_routed(router.endpoint, "rtsid/rig/j0/history?since=60s")
        connect = ["--connect", router.endpoint]
        assert main(["query", *connect]) == 0
        (line,) = capsys.readouterr().out.splitlines()
        assert json.loads(line)["seq"] == 2
        assert main(["query", "rtsid/rig/j0", *connect, "--since", "1h", "--kind", "estimate"]) == 0
        captured = capsys.readouterr()
        assert [json.loads(x)["seq"] for x in captured.out.splitlines()] == [0, 1, 2]
        assert "rig/j0 estimate: held from" in captured.err and "starts at" in captured.err
        assert main(["query", *connect, "--since", "soon"]) == 2
        assert "--since" in capsys.readouterr().err
        assert main(["query", "rtsid/nobody/here", *connect, "--timeout", "1"]) == 1
        assert "no daemon answered" in capsys.readouterr().err


# ---------------------------------------------------------------------- bad peers (issue 20)


def test_the_history_queryable_answers_out_of_range_selectors_with_an_error_reply(
    free_port: int,
) -> None:
    with Router(free_port) as router, ZenohPublisher(client(router.endpoint, "j0")) as pub:
        pub.publish_estimate(estimate("j0", 1))
        wait_until_routed(router.endpoint, "rtsid/rig/j0/history?since=60s")
        with zenoh.open(subscriber_config((router.endpoint,), "client")) as session:
            for params, match in [
                ("since=1e308", "longer than a year"),  # was an OverflowError and no reply
                ("since=-5", "is not a duration"),
                ("since=nan", "is not a duration"),
                ("from=99999999999999999999", "out of range"),
                ("from=" + "9" * 5000, "is not an integer"),
            ]:
                answer = query(session, f"rtsid/rig/j0/history?{params}", timeout_s=10)
                assert not answer.replies, params
                (error,) = answer.errors
                assert match in json.loads(error)["error"]
        assert pub.stats()["query_errors"] == 5 and pub.stats()["errors"] == 0


BAD_REPLIES = [
    b"\xff\xfe\x00",  # not UTF-8: `rtsid query` died with UnicodeDecodeError
    b'{"K": NaN}',
    b"[1, 2, 3]",
    b'{"robot": "evil", "joint": "ankle", "kind": "estimate", "part": 0}',  # KeyError
    json.dumps({"robot": "evil", "joint": "ankle", "kind": "estimate", "from_ns": 0, "to_ns": 1,
                "held_from_ns": None, "first_ns": None, "complete": True, "note": "\x1b[2J",
                "part": 0, "parts": 1, "messages": "no"}).encode(),  # TypeError
    json.dumps({"robot": "evil", "joint": "ankle", "kind": "estimate", "from_ns": 0, "to_ns": 1,
                "held_from_ns": None, "first_ns": None, "complete": True, "note": "", "part": 0,
                "parts": 1, "messages": [1, {"K": 99999}, json.loads(estimate("x", 1))]}).encode(),
]  # fmt: skip


class FakeResponder:
    """A zenoh client (not a daemon) answering ``rtsid/evil/ankle/{history,estimate}`` with
    every payload of :data:`BAD_REPLIES`."""

    def __init__(self, endpoint: str) -> None:
        self.session = zenoh.open(subscriber_config((endpoint,), "client"))
        self.queryables = [
            self.session.declare_queryable(f"rtsid/evil/ankle/{kind}", self._answer)
            for kind in ("history", "estimate")
        ]

    @staticmethod
    def _answer(q: Any) -> None:
        with q:
            for payload in BAD_REPLIES:
                q.reply(str(q.key_expr), payload)

    def close(self) -> None:
        for queryable in self.queryables:
            queryable.undeclare()
        self.session.close()


def test_fake_responders_and_bad_keys_cannot_crash_the_clients(
    free_port: int, capsys: pytest.CaptureFixture[str], wait_for: Callable[..., None]
) -> None:
    from rtsid.io.watch import watch
    from rtsid.io.web.server import WebView

    with Router(free_port) as router, ZenohPublisher(client(router.endpoint, "j0")) as pub:
        fake = FakeResponder(router.endpoint)
        try:
            pub.publish_estimate(estimate("j0", 7))
            wait_until_routed(router.endpoint, "rtsid/rig/j0/history?since=60s")
            wait_until_routed(router.endpoint, "rtsid/evil/ankle/history")
            connect = ["--connect", router.endpoint, "--timeout", "3"]
            assert main(["query", *connect]) == 0
            out, err = capsys.readouterr()
            assert [json.loads(x)["robot"] for x in out.splitlines()] == ["rig"]
            assert "rejected 6 malformed" in err and "\x1b" not in err
            assert main(["query", *connect, "--since", "60s"]) == 0
            out, err = capsys.readouterr()
            assert {json.loads(x)["robot"] for x in out.splitlines()} == {"rig"}
            assert "rejected" in err and "\x1b" not in err
            code = watch("rtsid/*/*", (router.endpoint,), mode="client", timeout_s=1.0,
                         since_s=60.0, live=False)  # fmt: skip
            out, err = capsys.readouterr()
            assert code == 0 and "rig/j0 seq=7" in out and "99999" not in out
            assert "history: rejected" in err
            with WebView("rtsid/*/*", (router.endpoint,), mode="client", port=0) as view:
                wait_for(
                    lambda: view.board.rejected >= 6, 10.0, "the history's bad replies counted"
                )
                assert view.failure is None  # it exited at start-up
                wait_for(lambda: view.board.snapshot()[1]["joints"], 10.0, "rig/j0 on the board")
                assert list(view.board.snapshot()[1]["joints"]) == ["rig/j0"]
        finally:
            fake.close()
    for bad in ("", "rtsid//x", "rtsid/a?b"):
        for command in (["query", bad], ["watch", bad, "--timeout", "1"]):
            assert main(command) == 2
            (line,) = capsys.readouterr().err.splitlines()
            assert "is not a zenoh key expression" in line and "rtsid/*/*" in line


# ---------------------------------------------------------------------- the fast lane


@pytest.fixture
def daemon_in_thread(tmp_path: Path, free_port: int) -> Iterator[tuple[Daemon, str]]:
    config = DaemonConfig.from_mapping(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port}"], "robot": "rig"},
            "mcap": {"directory": str(tmp_path / "rec")},
            "plant": {"perturbation": "filtered_noise", "bandwidth_hz": 30.0},
        }
    )
    daemon = Daemon(config)
    thread = threading.Thread(target=daemon.run, args=(120.0,), name="test-daemon")
    thread.start()
    try:
        yield daemon, f"tcp/127.0.0.1:{free_port}"
    finally:
        daemon.request_stop()
        thread.join(30)
        assert not thread.is_alive()


@pytest.mark.slow  # a real-time daemon run of seconds
def test_a_flood_of_queries_never_reaches_the_worker(
    daemon_in_thread: tuple[Daemon, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """History and latest queries back to back while the daemon runs on the simulated plant:
    each is answered, on zenoh's threads (never the worker's), and the worker keeps going.
    (Whether it keeps its deadlines is wall-clock time, measured by ``rtsid bench lab``: a
    start-up miss on a loaded 2-core CI machine failed this test once.)"""
    from rtsid.io.history import HistoryStore

    daemon, endpoint = daemon_in_thread
    answered_on: set[str] = set()
    original = HistoryStore.answer

    def recording_answer(self: HistoryStore, *args: Any, **kw: Any) -> Any:
        answered_on.add(threading.current_thread().name)
        return original(self, *args, **kw)

    monkeypatch.setattr(HistoryStore, "answer", recording_answer)
    with zenoh.open(subscriber_config((endpoint,), "peer")) as session:
        deadline = time.monotonic() + 30
        while daemon.worker is None or daemon.worker.counters().estimates < 50:
            assert time.monotonic() < deadline, "the daemon did not start estimating"
            time.sleep(0.05)
        while not query(session, "rtsid/rig/ankle/estimate", timeout_s=1.0).replies:
            assert time.monotonic() < deadline, "the peers did not connect"  # zenoh retries
            time.sleep(0.05)
        before = daemon.worker.counters()
        histories = latest = 0
        for _ in range(150):  # bounded flood: ≈ 3 s of back-to-back queries
            answer = query(session, "rtsid/rig/ankle/history?since=60s", timeout_s=10)
            assert not answer.errors and answer.replies
            histories += 1
            latest += len(query(session, "rtsid/*/*/estimate", timeout_s=10).replies)
        after = daemon.worker.counters()
    worker_thread = daemon.worker._thread
    assert worker_thread is not None
    assert answered_on and worker_thread.name not in answered_on
    assert histories == 150 and latest == 150
    assert after.estimates > before.estimates  # the worker kept going meanwhile


@pytest.mark.slow  # real processes for tens of seconds
def test_bench_lab_prints_its_tables(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["bench", "lab", "--joints", "2", "--duration", "1", "--late-trials", "2"]
    assert main([*argv, "--query-rate", "2", "--cpu-latency-us", "-1"]) == 0
    out = capsys.readouterr().out
    for title in ("### Lab: 2 daemons", "### Per joint", "### Late joiner", "### History queries"):
        assert title in out
    rows = [line for line in out.splitlines() if line.startswith("|")]
    for phase in ("router", "router + queries", "TLS router", "peer-to-peer"):
        assert any(line.split("|")[1].strip() == phase for line in rows), phase
    late = [r for r in rows if r.split("|")[1].strip() in ("router", "TLS router", "peer-to-peer")]
    assert any(r.split("|")[2].strip() == "2" for r in late)  # trials done in each topology


def test_published_counts_only_what_had_a_router_and_the_outage_is_counted_as_lost(
    free_port: int,
) -> None:
    # issue 20: during a router outage `published` kept rising and `not_published` stayed 0
    endpoint = f"tcp/127.0.0.1:{free_port}"

    def publish_until(pub: ZenohPublisher, done: Callable[[dict[str, Any]], bool]) -> None:
        deadline = time.monotonic() + 15
        while not done(pub.stats()):
            assert time.monotonic() < deadline, pub.stats()
            pub.publish_estimate(estimate("j0", 0))
            time.sleep(0.01)

    with ZenohPublisher(client(endpoint, "j0", retry_interval_s=0.1)) as pub:
        with Router(free_port):
            publish_until(pub, lambda s: s["published"] >= 5)
            assert pub.stats()["not_published"] == 0
        # the router is gone: once zenoh sees it, nothing more counts as published
        publish_until(pub, lambda s: s["not_published"] > 0)
        before = pub.stats()
        for _ in range(50):
            assert pub.publish_estimate(estimate("j0", 1)) is False
        after = pub.stats()
        assert after["published"] == before["published"]
        assert after["not_published"] == before["not_published"] + 50
        assert after["not_published_by_reason"]["no_router"] == after["not_published"]
        assert after["state"] == "router_lost"
        with Router(free_port), zenoh.open(subscriber_config((endpoint,), "client")) as s:
            received = s.declare_subscriber("rtsid/rig/j0/estimate", zenoh.handlers.FifoChannel(64))
            publish_until(pub, lambda _: received.try_recv() is not None)  # delivered again
            back = pub.stats()
            for _ in range(20):
                assert pub.publish_estimate(estimate("j0", 2)) is True
            assert pub.stats()["published"] == back["published"] + 20 > after["published"] + 20
            assert pub.stats()["not_published"] == back["not_published"]
            assert pub.stats()["state"] == "up"
            received.undeclare()
