"""The history ring: parameters, ranges, parts, what is no longer held, and lock-free copies
that stay consistent while the writer keeps appending."""

from __future__ import annotations

import json
import threading
import tracemalloc

import pytest

from rtsid.io.history import (
    PART_MESSAGES,
    HistoryQuery,
    HistoryStore,
    MessageRing,
    QueryError,
    parse_duration_s,
    parse_history_query,
)

S = 1_000_000_000  # ns per s
NOW = 1_800_000_000 * S


@pytest.mark.parametrize(
    ("text", "seconds"),
    [("60s", 60.0), ("5m", 300.0), ("1.5h", 5400.0), ("250ms", 0.25), ("90", 90)],
)
def test_durations(text: str, seconds: float) -> None:
    assert parse_duration_s(text) == pytest.approx(seconds)


@pytest.mark.parametrize("text", ["", "abc", "-5s", "0", "5 parsecs", "nan", "inf"])
def test_bad_durations_name_the_parameter_and_the_forms(text: str) -> None:
    with pytest.raises(QueryError, match=r"since=.*60s, 5m"):
        parse_duration_s(text)


def test_query_parameters() -> None:
    q = parse_history_query({"since": "60s", "kind": "estimate, status"}, now_ns=NOW)
    assert q == HistoryQuery(("estimate", "status"), NOW - 60 * S, 2**63 - 1)
    assert parse_history_query({"from": "5", "to": "9"}) == HistoryQuery(None, 5, 9)
    assert parse_history_query({}).from_ns == 0
    # kind= naming no channel means every channel (an empty tuple asked for nothing and the
    # query got no reply at all: hypothesis found `kind= `)
    for blank in ("", " ", ",", " , "):
        assert parse_history_query({"kind": blank}).kinds is None
    for params, match in [
        ({"sincе": "1s"}, "unknown query parameter"),
        ({"since": "1s", "from": "1"}, "either since= or from="),
        ({"from": "x"}, "from='x' is not an integer"),
        ({"to": "-1"}, "negative"),
        ({"from": "9", "to": "5"}, "before the range's start"),
    ]:
        with pytest.raises(QueryError, match=match):
            parse_history_query(params)


def test_ring_returns_a_time_range_and_what_it_still_holds() -> None:
    ring = MessageRing(10)
    for i in range(25):  # wraps twice: the last 9 are held (one slot is kept for the writer)
        ring.append(NOW + i * S, b"%d" % i)
    messages, held_from, first = ring.snapshot(0, 2**63 - 1)
    assert messages == [b"%d" % i for i in range(16, 25)]
    assert held_from == first == NOW + 16 * S
    messages, _, first = ring.snapshot(NOW + 18 * S, NOW + 20 * S)
    assert messages == [b"18", b"19", b"20"] and first == NOW + 18 * S
    assert ring.snapshot(NOW + 30 * S, NOW + 40 * S)[0] == []
    assert MessageRing(3).snapshot(0, 1) == ([], None, None)


def estimate(i: int, t_ns: int) -> bytes:
    return json.dumps({"seq": i, "host_time_ns": t_ns}).encode()


def test_answer_in_parts_and_a_range_no_longer_held_says_where_it_starts() -> None:
    store = HistoryStore(60.0, {"estimate": 50.0})
    n = PART_MESSAGES + 10
    for i in range(n):
        store.append("estimate", estimate(i, NOW - 5 * S + i), NOW - 5 * S + i)
    store.append("status", b'{"uptime_s": 1}', NOW - 1 * S)
    parts = [
        json.loads(p)
        for p in store.answer(
            HistoryQuery(None, NOW - 10 * S, NOW), robot="rig", joint="ankle", now_ns=NOW
        )
    ]
    est = [p for p in parts if p["kind"] == "estimate"]
    assert [p["part"] for p in est] == [0, 1] and {p["parts"] for p in est} == {2}
    assert [m["seq"] for p in est for m in p["messages"]] == list(range(n))
    assert est[0]["held_from_ns"] == NOW - 5 * S and not est[0]["complete"]
    assert "starts at" in est[0]["note"] and est[0]["robot"] == "rig"
    status = [p for p in parts if p["kind"] == "status"]
    assert len(status) == 1 and status[0]["messages"] == [{"uptime_s": 1}]
    # The status started after the range did: not complete (it was never published).
    (inside,) = [
        json.loads(p)
        for p in store.answer(
            HistoryQuery(("status",), NOW - 2 * S, NOW), robot="rig", joint="ankle", now_ns=NOW
        )
    ]
    assert inside["messages"] == [{"uptime_s": 1}] and inside["held_from_ns"] == NOW - 1 * S
    assert not inside["complete"]
    (whole,) = [
        json.loads(p)
        for p in store.answer(
            HistoryQuery(("estimate",), NOW - 3 * S, NOW - 2 * S),
            robot="rig",
            joint="ankle",
            now_ns=NOW,
        )
    ]
    assert whole["complete"] and whole["note"] == "" and whole["messages"] == []  # held, empty
    with pytest.raises(QueryError, match="kind='reflexes' is not held here; held: estimate"):
        list(store.answer(HistoryQuery(("reflexes",), 0, NOW), robot="r", joint="j"))
    assert store.latest("estimate") == estimate(n - 1, NOW - 5 * S + n - 1)
    assert store.latest("nothing") is None


def test_messages_older_than_the_horizon_are_not_returned() -> None:
    store = HistoryStore(10.0, {"estimate": 1.0})
    for i in range(20):
        store.append("estimate", estimate(i, NOW - (20 - i) * S), NOW - (20 - i) * S)
    (part,) = [
        json.loads(p)
        for p in store.answer(HistoryQuery(("estimate",), 0, NOW), robot="r", joint="j", now_ns=NOW)
    ]
    assert [m["seq"] for m in part["messages"]] == list(range(10, 20))
    assert part["held_from_ns"] == NOW - 10 * S and not part["complete"]


def test_copies_stay_consistent_while_the_writer_appends() -> None:
    """One writer appending as fast as it can, readers copying the whole ring: every copy is
    a run of consecutive messages whose payload matches its time (no torn or reused slot)."""
    ring = MessageRing(64)
    stop = threading.Event()

    def write() -> None:
        i = 0
        while not stop.is_set() and i < 2_000_000:  # bounded
            ring.append(i, b"%d" % i)
            i += 1

    writer = threading.Thread(target=write)
    writer.start()
    try:
        copies = 0
        while copies < 3000:
            messages, held_from, first = ring.snapshot(0, 2**63 - 1)
            values = [int(m) for m in messages]
            if values:
                assert values == list(range(values[0], values[0] + len(values)))
                assert first == values[0] and held_from is not None and held_from <= first
                copies += 1
    finally:
        stop.set()
        writer.join(10)


def test_a_channel_first_seen_gets_its_own_ring() -> None:
    store = HistoryStore(60.0)
    store.append("reflex", b'{"gain": 1}', NOW - S)
    assert "reflex" in store.kinds
    parts = [json.loads(p) for p in store.answer(HistoryQuery(None, 0, NOW), robot="r", joint="j")]
    assert {p["kind"] for p in parts} == {"estimate", "status", "reflex"}
    assert next(p for p in parts if p["kind"] == "reflex")["messages"] == [{"gain": 1}]


# ---------------------------------------------------------------------- hostile selectors

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from rtsid.io.messages import EstimateMessage  # noqa: E402
from rtsid.io.schemas import encode_json  # noqa: E402
from rtsid.io.validate import check_replies  # noqa: E402


@pytest.mark.parametrize(
    "params",
    [
        {"since": "1e308"},  # raised OverflowError in the daemon: no reply at all
        {"since": "1e308s"},
        {"since": "1e20h"},
        {"since": "-5"},
        {"since": "nan"},
        {"since": "9" * 5000},
        {"from": "9" * 5000},
        {"from": "99999999999999999999"},
        {"to": "-1_0"},
        {"from": "1_000"},
    ],
)
def test_out_of_range_selectors_are_query_errors(params: dict[str, str]) -> None:
    with pytest.raises(QueryError) as caught:
        parse_history_query(params, now_ns=NOW)
    assert len(str(caught.value)) < 200  # one line, the value cut short


def daemon_estimate(seq: int, t_ns: int) -> bytes:
    return encode_json(
        EstimateMessage(
            robot="rig", joint="ankle", seq=seq, window_start_index=seq, window_end_index=seq + 749,
            t_start_s=0.0, t_end_s=0.3, I=0.01, B=0.8, K=150.0, I_se=None, B_se=None, K_se=1.0,
            K_track=150.0, K_track_se=0.5, B_track=None, B_track_se=None, vaf=90.0, vaf_irf=90.0,
            vaf_fit=90.0, lost_samples=0, compute_ms=1.0, latency_ms=1.0, ok=True, reason=None,
            flags=(), host_time_ns=t_ns, I_held=True, B_held=True,
        ).as_dict()
    )  # fmt: skip


@given(st.dictionaries(st.sampled_from(["since", "from", "to", "kind", "x"]), st.text(max_size=30)))
def test_any_selector_is_answered_or_refused_and_answers_pass_the_clients_checks(
    params: dict[str, str],
) -> None:
    store = HistoryStore(60.0)
    for i in range(3):
        store.append("estimate", daemon_estimate(i, NOW - (3 - i) * S), NOW - (3 - i) * S)
    try:
        query = parse_history_query(params, now_ns=NOW)
        parts = list(store.answer(query, robot="rig", joint="ankle", now_ns=NOW))
    except QueryError:
        return
    checked = check_replies([("rtsid/rig/ankle/history", part) for part in parts])
    assert not checked.rejected and len(checked.parts) == len(parts)


@given(
    key=st.sampled_from(["rtsid/rig/ankle/history", "rtsid/rig/ankle/estimate", "x", "a/b/c/d"]),
    payload=st.binary(max_size=100)
    | st.recursive(
        st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=10),
        lambda inner: (
            st.lists(inner, max_size=3)
            | st.dictionaries(
                st.sampled_from(["robot", "joint", "kind", "part", "parts", "messages", "note"]),
                inner,
                max_size=7,
            )
        ),
        max_leaves=15,
    ).map(lambda v: json.dumps(v).encode()),
)
def test_any_reply_is_checked_without_a_traceback(key: str, payload: bytes) -> None:
    checked = check_replies([(key, payload)])
    assert len(checked.rejected) + len(checked.parts) + len(checked.messages) >= 1


def estimate_like(i: int) -> bytes:
    """An estimate-sized JSON message whose numbers differ from message to message."""
    x = (i * 7919 % 10007) / 10007
    return json.dumps(
        {"robot": "rig", "joint": "ankle", "K": 100 + 50 * x, "K_se": x / 3, "B": 1 - x,
         "I": 0.01 * x, "vaf": 90 + x, "ok": True, "flags": [], "seq": i,
         "window_end_index": 749 + 10 * i, "host_time_ns": NOW + i * 4_000_000}
    ).encode()  # fmt: skip


def test_compacted_blocks_hold_a_fraction_and_give_back_the_same_messages() -> None:
    """A 10-minute history at a 4 ms hop must not take the daemon's memory: sealed blocks are
    deflated, and what comes back out is byte for byte what went in."""
    ring = MessageRing(2000, block_messages=100)
    payloads = [estimate_like(i) for i in range(3000)]
    for i, payload in enumerate(payloads):
        ring.append(NOW + i, payload)
    raw = ring.held_bytes
    assert ring.compact() > 0
    assert ring.held_bytes < raw / 3
    assert ring.compact() == 0  # nothing left raw
    messages, held_from, first = ring.snapshot(0, 2**63 - 1)
    assert messages == payloads[1001:] and held_from == first == NOW + 1001
    assert ring.newest() == payloads[-1]
    # a range across packed blocks and the open one
    messages, _, first = ring.snapshot(NOW + 2850, NOW + 2960)
    assert messages == payloads[2850:2961] and first == NOW + 2850


def test_packed_blocks_take_the_memory_they_count() -> None:
    """What a compacted ring holds in memory is what ``held_bytes`` counts: zstd's result was
    allocated at the input's size and only shortened, so each packed block kept its raw size
    (a 4 ms hop's history grew 5× faster than its ``held_bytes``)."""
    payloads = [estimate_like(i) for i in range(3000)]
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        ring = MessageRing(2000, block_messages=100)
        for i, payload in enumerate(payloads):
            ring.append(NOW + i, payload)
            if i % 100 == 99:  # the housekeeping tick compacts as blocks are sealed
                ring.compact()
        held, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    raw = sum(len(p) for p in payloads[-2000:])
    assert ring.held_bytes < raw / 3
    assert held - before < 1.5 * ring.held_bytes
    messages, _, _ = ring.snapshot(0, 2**63 - 1)
    assert messages == payloads[1001:]


def test_without_compaction_the_ring_stays_bounded() -> None:
    ring = MessageRing(100, block_messages=10)
    for i in range(1000):
        ring.append(i, b"x" * 50)
    assert len(ring) == 99
    assert ring.held_bytes <= (100 + 10) * 50
    messages, held_from, _ = ring.snapshot(0, 2**63 - 1)
    assert len(messages) == 99 and held_from == 901


def test_copies_stay_consistent_while_a_compactor_packs_the_blocks() -> None:
    """Writer, compactor and reader on three threads: every copy is still a run of
    consecutive messages whose payload matches its time."""
    ring = MessageRing(300, block_messages=16)
    stop = threading.Event()

    def write() -> None:
        i = 0
        while not stop.is_set() and i < 2_000_000:  # bounded
            ring.append(i, b"%d" % i)
            i += 1

    def compact() -> None:
        for _ in range(1_000_000):  # bounded
            if stop.is_set():
                return
            ring.compact()

    threads = [threading.Thread(target=write), threading.Thread(target=compact)]
    for thread in threads:
        thread.start()
    try:
        copies = 0
        while copies < 1000:
            messages, held_from, first = ring.snapshot(0, 2**63 - 1)
            values = [int(m) for m in messages]
            if values:
                assert values == list(range(values[0], values[0] + len(values)))
                assert first == values[0] and held_from is not None and held_from <= first
                assert len(values) <= 299
                copies += 1
    finally:
        stop.set()
        for thread in threads:
            thread.join(10)


def test_messages_of_any_size_come_back_as_they_went_in() -> None:
    ring = MessageRing(8, block_messages=3)
    payloads = [b"%d" % i for i in range(5)] + [b"x" * 10_000, b"y" * 3, b""]
    for i, payload in enumerate(payloads):
        ring.append(i, payload)
        if i % 2:
            ring.compact()
    messages, held_from, _ = ring.snapshot(0, 2**63 - 1)
    assert messages == payloads[1:] and held_from == 1
    assert ring.newest() == b""
    assert MessageRing(4).newest() is None


def test_the_store_compacts_every_channel() -> None:
    store = HistoryStore(60.0, {"estimate": 50.0})
    for i in range(2048):  # 8 whole blocks of estimates
        store.append("estimate", estimate_like(i), NOW + i)
        store.append("status", estimate_like(i), NOW + i)
    raw = store.held_bytes
    assert store.compact() > 0 and store.held_bytes < raw / 3
    (part,) = [
        json.loads(p)
        for p in store.answer(
            HistoryQuery(("status",), NOW + 2038, NOW + 2047), robot="r", joint="j", now_ns=NOW
        )
    ]
    assert [m["seq"] for m in part["messages"]] == list(range(2038, 2048))
