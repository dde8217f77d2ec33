"""ZenohPublisher: keys, liveliness, queryables, never raising when zenoh is unavailable,
and publishing across processes (spawn) while a subscriber comes and goes."""

from __future__ import annotations

import json
import multiprocessing as mp
import time
from typing import Any

import pytest
import zenoh

from rtsid.errors import ConfigError
from rtsid.io.schemas import ESTIMATE_FIELDS
from rtsid.io.zenoh_link import (
    ZenohConfig,
    ZenohPublisher,
    key_expressions,
    subscriber_config,
    zenoh_config,
)


def estimate(seq: int) -> dict[str, Any]:
    est: dict[str, Any] = dict.fromkeys(ESTIMATE_FIELDS, 1.0)
    est.update(
        robot="rig",
        joint="ankle",
        seq=seq,
        window_start_index=seq,
        window_end_index=seq + 749,
        ok=True,
        reason=None,
        flags=[],
        host_time_ns=time.time_ns(),
    )
    return est


def config(port: int, **kw: Any) -> ZenohConfig:
    return ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",), robot="rig", joint="ankle", **kw)


def test_config_validation_names_key_and_accepted_values() -> None:
    with pytest.raises(ConfigError, match=r"zenoh\.mode.*'peer', 'client'"):
        ZenohConfig.from_mapping({"mode": "router"})
    with pytest.raises(ConfigError, match=r"zenoh\.robot"):
        ZenohConfig.from_mapping({"robot": "a/b"})
    with pytest.raises(ConfigError, match=r"zenoh\.listen"):
        ZenohConfig.from_mapping({"listen": ["127.0.0.1:7447"]})
    with pytest.raises(ConfigError, match=r"zenoh\.connect.*client mode"):
        ZenohConfig.from_mapping({"mode": "client"})
    with pytest.raises(ConfigError, match=r"zenoh\.listen.*config_file"):
        ZenohConfig.from_mapping({"config_file": "lab.json5", "listen": ["tcp/127.0.0.1:1"]})
    cfg = ZenohConfig.from_mapping({"connect": ["tcp/127.0.0.1:7448"], "key_prefix": "lab/rtsid"})
    assert cfg.connect == ("tcp/127.0.0.1:7448",)
    assert key_expressions(cfg)["estimate"] == "lab/rtsid/robot/ankle/estimate"


def test_default_zenoh_config_is_loopback_without_scouting() -> None:
    conf = zenoh_config(ZenohConfig())
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(conf.get_json("connect/endpoints")) == []
    assert json.loads(conf.get_json("mode")) == "peer"
    for key in ("scouting/multicast/enabled", "scouting/gossip/enabled"):
        assert json.loads(conf.get_json(key)) is False


def test_config_file_replaces_the_session_settings(tmp_path: Any, free_port: int) -> None:
    port = free_port
    lab = tmp_path / "lab.json5"
    lab.write_text(
        '{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:' + str(port) + '"] },\n'
        "  scouting: { multicast: { enabled: false }, gossip: { enabled: false } } }"
    )
    conf = zenoh_config(ZenohConfig(config_file=str(lab)))
    assert f"127.0.0.1:{port}" in conf.get_json("listen/endpoints")
    with pytest.raises(ConfigError, match="no such file"):
        zenoh_config(ZenohConfig(config_file=str(tmp_path / "missing.json5")))
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    with pytest.raises(ConfigError, match="not a valid zenoh config"):
        zenoh_config(ZenohConfig(config_file=str(bad)))


def test_publish_liveliness_and_queryables_in_process(free_port: int, wait_for: Any) -> None:
    port = free_port
    cfg = config(port)
    keys = key_expressions(cfg)
    with (
        ZenohPublisher(cfg, run_config={"worker": {"hop_s": 0.02}}) as pub,
        zenoh.open(subscriber_config((f"tcp/127.0.0.1:{port}",), mode="client")) as sub_session,
    ):
        assert pub.stats()["state"] == "up"
        sub = sub_session.declare_subscriber(keys["estimate"], zenoh.handlers.FifoChannel(64))
        received: list[dict[str, Any]] = []
        for seq in range(1000):  # bounded: until the subscription has propagated
            assert pub.publish_estimate(estimate(seq))
            sample = sub.try_recv()
            if sample is not None:
                received.append(json.loads(sample.payload.to_bytes()))
                break
            time.sleep(0.01)
        assert received and received[0]["robot"] == "rig"
        assert str(sample.encoding).startswith("application/json")
        alive = [str(r.ok.key_expr) for r in sub_session.liveliness().get("rtsid/**", timeout=5)]
        assert alive == [keys["alive"]]
        config_replies = list(sub_session.get(keys["config"], timeout=5))
        assert json.loads(config_replies[0].ok.payload.to_bytes()) == {"worker": {"hop_s": 0.02}}
        pub.publish_status({"robot": "rig", "joint": "ankle", "host_time_ns": 1, "uptime_s": 3.0})
        status_replies = list(sub_session.get(keys["status"], timeout=5))
        assert json.loads(status_replies[0].ok.payload.to_bytes())["uptime_s"] == 3.0
        wait_for(lambda: pub.stats()["queries"] == 2, 5.0, "both queries counted")
        assert pub.stats()["errors"] == 0
        assert not pub.publish_samples(0, [0.0], [0.0], [True], [0], fs_hz=2500.0)  # off by default
    assert pub.stats()["state"] == "closed"


def test_taken_port_is_reported_then_recovered_without_raising(
    free_port: int, wait_for: Any
) -> None:
    port = free_port
    blocker = zenoh.open(zenoh_config(config(port)))
    try:
        with ZenohPublisher(config(port, retry_interval_s=0.05)) as pub:
            stats = pub.stats()
            assert stats["state"] == "down" and stats["errors"] >= 1  # the retry may add one
            assert f"127.0.0.1:{port}" in stats["last_error"]
            assert "Address already in use" in stats["last_error"]
            assert "zenoh.listen" in stats["last_error"]
            assert not pub.publish_estimate(estimate(0))
            assert not pub.publish_status(
                {"robot": "r", "joint": "j", "host_time_ns": 1, "uptime_s": 0}
            )
            assert pub.stats()["not_published"] == 2
            blocker.close()
            wait_for(lambda: pub.stats()["state"] == "up")
            assert pub.publish_estimate(estimate(1))
            assert pub.stats()["open_attempts"] >= 2
    finally:
        blocker.close()


def test_disabled_publisher_is_a_no_op() -> None:
    with ZenohPublisher(ZenohConfig(enabled=False)) as pub:
        assert not pub.publish_estimate(estimate(0))
    assert pub.stats()["state"] == "disabled"


def _subscribe_n(endpoint: str, key: str, n: int, out: Any) -> None:
    """Child process: receive n estimates, report their seq numbers, close and exit."""
    with zenoh.open(subscriber_config((endpoint,), mode="client")) as session:
        sub = session.declare_subscriber(key, zenoh.handlers.FifoChannel(256))
        seqs: list[int] = []
        deadline = time.monotonic() + 30.0
        while len(seqs) < n and time.monotonic() < deadline:
            sample = sub.try_recv()
            if sample is None:
                time.sleep(0.005)
                continue
            seqs.append(json.loads(sample.payload.to_bytes())["seq"])
        sub.undeclare()
    out.put(seqs)


def test_cross_process_subscriber_receives_and_its_departure_is_harmless(free_port: int) -> None:
    port = free_port
    cfg = config(port)
    ctx = mp.get_context("spawn")
    out = ctx.Queue()
    child = ctx.Process(
        target=_subscribe_n,
        args=(f"tcp/127.0.0.1:{port}", key_expressions(cfg)["estimate"], 5, out),
    )
    try:
        with ZenohPublisher(cfg) as pub:
            child.start()
            seqs = None
            for seq in range(3000):  # bounded: ≤ 30 s at 10 ms
                pub.publish_estimate(estimate(seq))
                if not out.empty():
                    seqs = out.get(timeout=5)
                    break
                time.sleep(0.01)
            child.join(timeout=20)
            assert seqs is not None and len(seqs) == 5
            assert seqs == sorted(seqs) and len(set(seqs)) == 5
            assert child.exitcode == 0
            # the subscriber is gone: publishing goes on without error
            assert all(pub.publish_estimate(estimate(10_000 + i)) for i in range(20))
            assert pub.stats()["errors"] == 0
    finally:
        if child.is_alive():
            child.kill()
        child.join(timeout=10)
        out.close()
        out.join_thread()


def test_samples_are_published_when_enabled(free_port: int) -> None:
    from rtsid.io.schemas import decode_samples

    port = free_port
    cfg = config(port, publish_samples=True)
    with (
        ZenohPublisher(cfg) as pub,
        zenoh.open(subscriber_config((f"tcp/127.0.0.1:{port}",), mode="client")) as session,
    ):
        sub = session.declare_subscriber(
            key_expressions(cfg)["samples"], zenoh.handlers.FifoChannel(64)
        )
        sample = None
        for k in range(1000):  # bounded: until the subscription has propagated
            assert pub.publish_samples(
                k * 3,
                [0.1, float("nan"), 0.3],
                [1.0, 2.0, 3.0],
                [True, False, True],
                [0, 1, 0],
                fs_hz=2500.0,
            )
            sample = sub.try_recv()
            if sample is not None:
                break
            time.sleep(0.01)
        assert sample is not None
        batch = decode_samples(sample.payload.to_bytes())
        assert batch.fs_hz == 2500.0 and batch.valid.tolist() == [True, False, True]
        assert batch.position_rad[0] == 0.1 and batch.torque_nm[2] == 3.0


# ---------------------------------------------------------------------- hostile selectors

from hypothesis import HealthCheck, example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from rtsid.io.zenoh_link import query  # noqa: E402

_VALUE = st.text(
    st.characters(blacklist_categories=("Cc", "Cs"), blacklist_characters=";=#?&"), max_size=24
)


@pytest.fixture
def history_daemon(free_port: int) -> Any:
    """A publisher holding a few estimates (the daemon's queryables) and a client session."""
    cfg = config(free_port)
    with (
        ZenohPublisher(cfg) as pub,
        zenoh.open(subscriber_config((f"tcp/127.0.0.1:{free_port}",), mode="client")) as session,
    ):
        for seq in range(3):
            pub.publish_estimate(estimate(seq))
        yield pub, session, key_expressions(cfg)["history"]


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])  # one daemon throughout
@given(params=st.dictionaries(st.sampled_from(["since", "from", "to", "kind", "x"]), _VALUE))
@example(params={"since": "1e308"})  # the daemon raised OverflowError and sent nothing
@example(params={"from": "9" * 5000})
def test_every_history_selector_gets_a_reply_or_an_error_reply(
    history_daemon: Any, params: dict[str, str]
) -> None:
    pub, session, key = history_daemon
    selector = key + ("?" + ";".join(f"{k}={v}" for k, v in params.items()) if params else "")
    try:
        answer = query(session, selector, timeout_s=10)
    except zenoh.ZError:
        return  # zenoh's own parser refused the selector before it left
    assert answer.replies or answer.errors, selector  # never silence
    assert pub.stats()["errors"] == 0  # no failure in the daemon's callback
