"""The JSON payloads: valid against their own schemas, no NaN in JSON, clear errors."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rtsid.errors import InputDataError
from rtsid.ident.levinson import HAVE_COMPILED_KERNEL
from rtsid.io.schemas import (
    CAN_FRAMES_SCHEMA,
    ESTIMATE_FIELDS,
    ESTIMATE_SCHEMA,
    SAMPLES_SCHEMA,
    STATUS_SCHEMA,
    decode_samples,
    encode_can_frames,
    encode_estimate,
    encode_estimate_reference,
    encode_samples,
    encode_status,
    estimate_payload,
)
from rtsid.verdicts import Flag, Reason

jsonschema = pytest.importorskip("jsonschema")


def make_estimate(**overrides: object) -> dict[str, object]:
    est: dict[str, object] = {
        "robot": "r1",
        "joint": "ankle",
        "seq": 7,
        "window_start_index": 1000,
        "window_end_index": 1749,
        "t_start_s": 0.4,
        "t_end_s": 0.6996,
        "I": np.float64(0.012),
        "B": 0.9,
        "K": 120.0,
        "I_se": 0.001,
        "B_se": 0.05,
        "K_se": 2.0,
        "K_track": 121.0,
        "K_track_se": 1.0,
        "B_track": None,
        "B_track_se": None,
        "vaf": 95.5,
        "vaf_irf": 97.0,
        "vaf_fit": 98.0,
        "lost_samples": 0,
        "compute_ms": 3.2,
        "latency_ms": 4.1,
        "ok": True,
        "reason": None,
        "flags": [],
        "host_time_ns": 1_700_000_000_000_000_000,
    }
    est.update(overrides)
    return est


@pytest.mark.parametrize(
    "schema", [ESTIMATE_SCHEMA, SAMPLES_SCHEMA, STATUS_SCHEMA, CAN_FRAMES_SCHEMA]
)
def test_schemas_are_valid_draft_2020_12(schema: dict) -> None:
    jsonschema.Draft202012Validator.check_schema(schema)


def test_estimate_encodes_nan_as_null_and_validates() -> None:
    est = make_estimate(K=float("nan"), K_se=np.float64("inf"), ok=False, reason="numerical")
    data = encode_estimate(est)
    msg = json.loads(data)
    assert msg["K"] is None and msg["K_se"] is None
    assert list(msg) == list(ESTIMATE_FIELDS)
    assert msg["I"] == pytest.approx(0.012)
    jsonschema.validate(msg, ESTIMATE_SCHEMA)


def test_estimate_with_missing_or_unknown_key_names_them() -> None:
    est = make_estimate()
    del est["vaf"]
    est["stiffness"] = 1.0
    with pytest.raises(
        InputDataError, match=r"missing keys \['vaf'\].*unknown keys \['stiffness'\]"
    ):
        encode_estimate(est)


def test_estimate_schema_rejects_extra_keys() -> None:
    msg = json.loads(encode_estimate(make_estimate()))
    msg["extra"] = 1
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(msg, ESTIMATE_SCHEMA)


def test_samples_keep_lost_rows_as_null_and_round_trip() -> None:
    pos = np.array([0.1, 0.2, np.nan, 0.4, 1e-17])
    tq = np.array([1.0, 2.0, 3.0, np.inf, -5.5])
    valid = np.array([True, False, True, True, True])
    status = np.array([0, 4, 0, 1, 0])
    data = encode_samples(2500, 2500.0, pos, tq, valid, status)
    msg = json.loads(data)
    jsonschema.validate(msg, SAMPLES_SCHEMA)
    assert msg["position_rad"] == [0.1, None, None, 0.4, 1e-17]
    assert msg["torque_nm"] == [1.0, None, 3.0, None, -5.5]
    assert msg["t_first_s"] == 1.0
    batch = decode_samples(data, log_time_ns=5)
    assert batch.first_index == 2500 and batch.end_index == 2505 and batch.fs_hz == 2500.0
    assert batch.valid.tolist() == valid.tolist()
    assert batch.status.tolist() == status.tolist()
    assert math.isnan(batch.position_rad[1]) and math.isnan(batch.torque_nm[3])
    # valid finite values come back bit-exact (replay must reproduce the live numbers)
    assert batch.position_rad[4] == 1e-17 and batch.torque_nm[4] == -5.5


def test_samples_float_values_round_trip_exactly(rng: np.random.Generator) -> None:
    pos = rng.normal(size=1000) * 0.05
    tq = rng.normal(size=1000) * 20
    n = pos.size
    batch = decode_samples(encode_samples(0, 2500.0, pos, tq, np.ones(n, bool), np.zeros(n)))
    np.testing.assert_array_equal(batch.position_rad, pos)
    np.testing.assert_array_equal(batch.torque_nm, tq)


def test_samples_of_different_lengths_are_rejected() -> None:
    with pytest.raises(InputDataError, match="differ in length"):
        encode_samples(0, 2500.0, [1.0, 2.0], [1.0], [True, True], [0, 0])
    with pytest.raises(InputDataError, match="rate > 0"):
        encode_samples(0, 0.0, [1.0], [1.0], [True], [0])


def test_decode_rejects_garbage() -> None:
    with pytest.raises(InputDataError, match="not an rtsid samples message"):
        decode_samples(b'{"K": 1}')


def test_status_requires_identity_keys_and_validates() -> None:
    status = {
        "robot": "r1",
        "joint": "ankle",
        "host_time_ns": 1,
        "uptime_s": 2.5,
        "cpu_percent": float("nan"),
        "rss_mb": 80.0,
        "acquisition": {"frames": 10, "gaps": 0},
        "worker": {"estimates": 3, "withheld": {"gap": 1}, "overruns": 0, "deadline_misses": 0},
        "mcap": {"state": "recording", "file": "x.mcap", "bytes": 10, "dropped": 0},
        "zenoh": {"state": "up", "published": 3, "errors": 0, "last_error": None},
    }
    msg = json.loads(encode_status(status))
    assert msg["cpu_percent"] is None
    jsonschema.validate(msg, STATUS_SCHEMA)
    with pytest.raises(InputDataError, match="uptime_s"):
        encode_status({"robot": "r", "joint": "j", "host_time_ns": 1})


def test_can_frames_encode_python_can_messages() -> None:
    can = pytest.importorskip("can")
    frames = [
        can.Message(timestamp=1.5, arbitration_id=0x123, data=b"\x01\xff", is_extended_id=False)
    ]
    msg = json.loads(encode_can_frames(frames))
    jsonschema.validate(msg, CAN_FRAMES_SCHEMA)
    assert msg["frames"][0]["data_hex"] == "01ff" and msg["frames"][0]["arbitration_id"] == 0x123


def test_process_meter_reports_busy_cpu_and_memory() -> None:
    import os
    import time

    from rtsid.io.procstats import ProcessMeter

    meter = ProcessMeter()
    cpu0 = sum(os.times()[:2])
    deadline = time.monotonic() + 5.0
    x = 0.0
    while sum(os.times()[:2]) - cpu0 < 0.05 and time.monotonic() < deadline:  # bounded busy work
        x += sum(range(1000)) * 1e-9
    stats = meter.sample()
    assert stats["cpu_percent"] > 0 and stats["rss_mb"] > 10 and stats["uptime_s"] > 0
    assert x > 0


def test_a_live_daemons_status_validates_and_declares_every_acquisition_counter(
    tmp_path, free_port
) -> None:
    from rtsid.runtime.daemon import Daemon, DaemonConfig

    statuses = []
    config = DaemonConfig.from_mapping(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port}"]},
            "mcap": {"directory": str(tmp_path)},
        }
    )
    Daemon(config, on_status=lambda status, _estimate: statuses.append(status)).run(duration_s=1.0)
    assert statuses
    for status in statuses:
        msg = json.loads(encode_status(status))
        jsonschema.validate(msg, STATUS_SCHEMA)
        declared = set(STATUS_SCHEMA["properties"]["acquisition"]["properties"])
        assert set(msg["acquisition"]) <= declared


def _in_schema_order(message: dict[str, object]) -> dict[str, object]:
    """``message`` with every estimate key, in schema order (as the window worker builds it)."""
    return {k: message.get(k) for k in ESTIMATE_FIELDS}


@pytest.mark.parametrize(
    "overrides,plain",
    [
        ({"I": 0.012}, True),  # plain values: the fast path
        ({"I": 0.012, "ok": False, "reason": Reason.GAP, "K": None}, True),
        ({"I": 0.012, "flags": [Flag.REFLEX_STALE, "low_vaf"], "reflex_seq": 3}, True),
        ({"I": 0.012, "flags": (Flag.REFLEX_STALE,)}, True),
        ({"I": np.float64(0.012)}, True),  # a float subclass: written as the float
        ({"K": math.nan}, False),  # → null: the reference
        ({"K": -math.inf, "B": math.inf}, False),
        ({"I": np.float64("nan")}, False),
        ({"lost_samples": np.int64(3)}, False),  # numpy: the reference converts it
        ({"ok": np.bool_(True)}, False),
        # a text the numpy path's check cannot tell apart (the compiled encoder writes it)
        ({"robot": "NaN-robot", "I": 0.012}, HAVE_COMPILED_KERNEL),
        ({"robot": "r{1}", "I": 0.012}, HAVE_COMPILED_KERNEL),
        ({"robot": 'a "quoted" ünïcode\trobot', "I": 0.012}, True),  # escaped texts
        ({"robot": "\ud800\U0001f600\x7f\\", "reason": "\x00"}, True),  # lone surrogate, astral
        ({"flags": [{True: 1}], "I": 0.012}, False),  # json_safe makes the key "True"
        ({"flags": [np.float32(0.5)], "I": 0.012}, False),
    ],
)
def test_estimate_payload_is_the_reference_byte_for_byte(overrides, plain) -> None:
    message = _in_schema_order(make_estimate(**overrides))
    payload, was_plain = estimate_payload(message)
    assert payload == encode_estimate_reference(message) == encode_estimate(message)
    assert was_plain is plain
    if plain:  # what the summary table may take instead of decoding the payload
        as_json = {k: list(v) if isinstance(v, tuple) else v for k, v in message.items()}
        assert json.loads(payload) == as_json


def test_estimates_in_another_order_or_without_optional_keys_encode_as_the_reference() -> None:
    message = make_estimate()  # not in schema order, optional keys missing
    assert estimate_payload(message) == (encode_estimate_reference(message), False)
    shuffled = dict(reversed(list(_in_schema_order(make_estimate(I=0.01)).items())))
    assert estimate_payload(shuffled) == (encode_estimate_reference(shuffled), False)
    assert list(json.loads(encode_estimate(shuffled))) == list(ESTIMATE_FIELDS)


def test_a_bad_reason_is_refused_on_the_fast_path_too() -> None:
    message = _in_schema_order(make_estimate(I=0.01, reason=3))
    with pytest.raises(InputDataError, match="'reason' = 3"):
        encode_estimate(message)


def test_replayed_estimates_encode_as_the_reference(tmp_path) -> None:
    from pathlib import Path

    from rtsid.replay import replay_file

    reference = Path(__file__).resolve().parents[2] / "replay" / "reference" / "sim_3s.mcap"
    messages = replay_file(reference).messages
    assert len(messages) > 100
    for message in messages:
        payload, plain = estimate_payload(message)
        assert payload == encode_estimate_reference(message)
        assert plain is (json.loads(payload) == message)


_TEXTS = st.text(max_size=10)  # escapes, non-ASCII, "NaN", braces
_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-(2**70), 2**70), st.floats(), _TEXTS)


@given(
    st.lists(_VALUES, min_size=len(ESTIMATE_FIELDS), max_size=len(ESTIMATE_FIELDS)),
    st.lists(_TEXTS, max_size=3),
    st.one_of(st.none(), _TEXTS),
)
def test_any_plain_values_encode_as_the_reference_byte_for_byte(values, flags, reason) -> None:
    """The compiled encoder writes what it writes as json.dumps does (floats by their repr,
    huge integers, texts needing no escape) and leaves the rest to the reference."""
    message = dict(zip(ESTIMATE_FIELDS, values, strict=True))
    message.update(flags=flags, reason=reason)
    payload, plain = estimate_payload(message)
    assert payload == encode_estimate_reference(message)
    finite = all(not isinstance(v, float) or math.isfinite(v) for v in message.values())
    if HAVE_COMPILED_KERNEL:  # the compiled path tells every plain message from the rest
        assert plain is finite
    if plain:
        assert json.loads(payload) == message


def test_a_worker_message_takes_the_compiled_encoder() -> None:
    from rtsid.io import schemas

    message = _in_schema_order(make_estimate(I=0.0125, flags=[Flag.REFLEX_STALE], reason=None))
    compiled = schemas._ESTIMATE_JSON
    assert (compiled is not None) is HAVE_COMPILED_KERNEL
    if compiled is not None:
        assert compiled(message, ESTIMATE_FIELDS, schemas._ESTIMATE_PREFIXES) == (
            encode_estimate_reference(message)
        )
        shuffled = dict(reversed(list(message.items())))
        assert compiled(shuffled, ESTIMATE_FIELDS, schemas._ESTIMATE_PREFIXES) is None
