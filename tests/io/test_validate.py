"""rtsid.io.validate: the one check of what peers send, against the generated schemas and the
documented bounds; it never accepts what the JSON schemas (checked by ``jsonschema``) refuse."""

from __future__ import annotations

import json
from typing import Any

import jsonschema
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rtsid.io.messages import (
    ESTIMATE_SCHEMA,
    REFLEX_SCHEMA,
    STATUS_SCHEMA,
    EstimateMessage,
    ReflexMessage,
)
from rtsid.io.validate import (
    MAX_MESSAGE_BYTES,
    MalformedMessage,
    check_message,
    decode_message,
    error_reply_text,
    printable,
)
from rtsid.verdicts import Flag

KEY = "rtsid/rig/ankle/estimate"


def message(**changes: Any) -> dict[str, Any]:
    base = EstimateMessage(
        robot="rig", joint="ankle", seq=3, window_start_index=0, window_end_index=749,
        t_start_s=0.0, t_end_s=0.2996, I=0.01, B=0.8, K=150.0, I_se=0.001, B_se=0.01, K_se=1.0,
        K_track=150.0, K_track_se=0.5, B_track=0.8, B_track_se=0.005, vaf=90.0, vaf_irf=90.0,
        vaf_fit=90.0, lost_samples=0, compute_ms=1.0, latency_ms=1.0, ok=True, reason=None,
        flags=(Flag.LOW_VAF,), host_time_ns=1_800_000_000_000_000_000, I_held=False, B_held=False,
    ).as_dict()  # fmt: skip
    return {**base, **changes}


def test_a_daemons_messages_pass() -> None:
    assert decode_message("estimate", json.dumps(message()).encode(), KEY)["K"] == 150.0
    status = {"robot": "rig", "joint": "ankle", "host_time_ns": 1, "uptime_s": 2.0,
              "acquisition": {"samples": 5}, "worker": {"withheld": {"gap": 1}},
              "zenoh": {"last_error": "router lost:\n\tconnection reset"}}  # fmt: skip
    check_message("status", status, "rtsid/rig/ankle/status")  # an error text may span lines
    jsonschema.validate(status, STATUS_SCHEMA)
    with pytest.raises(MalformedMessage, match=r"mcap.file holds control characters"):
        check_message("status", {**status, "mcap": {"file": "\x1b[2J"}}, "rtsid/rig/ankle/status")


def test_a_reflex_message_passes() -> None:
    reflex = ReflexMessage(
        robot="rig", joint="ankle", seq=2, start_index=0, end_index=50_000,
        applies_from_index=50_000, ok=True, applied=True, variant="rect", gain=12.0,
        delay_ms=40.0, corner_hz=5.0, damping_ratio=0.7, dynamics_vaf=80.0, irf_gain=1.0, rank=4,
        vaf_total=92.0, vaf_intrinsic_only=85.0, vaf_intrinsic_path=80.0, vaf_reflex_path=12.0,
        iterations=3, irf_fs_hz=100.0, irf=[0.1 * i for i in range(200)], fit_ms=None,
        window_vaf_gain=2.5, windows_improved=0.8,
        error=None, host_time_ns=1_800_000_000_000_000_000,
    ).as_dict()  # fmt: skip
    check_message("reflex", json.loads(json.dumps(reflex)), "rtsid/rig/ankle/reflex")
    jsonschema.validate(reflex, REFLEX_SCHEMA)


@pytest.mark.parametrize(
    "changes, why",
    [
        ({"K": float("inf")}, "not a finite number"),
        ({"K": 1e16}, "not a finite number within"),
        ({"host_time_ns": "1"}, "host_time_ns is string"),
        ({"host_time_ns": 2**64}, "outside int64"),
        ({"seq": -1}, "below 0"),
        ({"reason": "<b>"}, "not one of the known values"),
        ({"flags": ["x"] * 3}, "not one of the known values"),
        ({"robot": "a b"}, "not a name"),
        ({"robot": "other"}, "came on rtsid/rig/ankle/estimate"),
        ({"note": 1}, "unknown key 'note'"),
        ({"ok": 1}, "ok is integer; expected boolean"),
        ({"window_start_index": 1.5}, "expected integer"),
    ],
)
def test_each_offence_is_named(changes: dict[str, Any], why: str) -> None:
    with pytest.raises(MalformedMessage, match=why):
        check_message("estimate", message(**changes), KEY)


def test_sizes_depth_and_json_extensions_are_refused() -> None:
    for payload, why in [
        (b" " * (MAX_MESSAGE_BYTES + 1), "more than the"),
        (b'{"robot": "rig", "joint": "ankle", "x": ' + b"[" * 50 + b"]" * 50 + b"}", "nested more"),
        (b"[" * 100_000 + b"]" * 100_000, "nested too deep"),
        (b'{"K": NaN}', "NaN is not a JSON number"),
        (b"\xc3\x28", "not UTF-8"),
        (b"{", "not JSON"),
    ]:
        with pytest.raises(MalformedMessage, match=why):
            decode_message("markers", payload, "rtsid/rig/ankle/markers")  # any channel


def test_printable_text_has_no_control_characters() -> None:
    assert printable("a\x1b[2Jb\nc") == "a?[2Jb?c"
    assert len(printable("x" * 1000)) == 300
    assert error_reply_text('{"error": "bad\\u001b[31m"}') == "bad?[31m"
    assert error_reply_text("\x00plain") == "?plain"


@st.composite
def mutated(draw: Any) -> dict[str, Any]:
    values = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8)
    values = values | st.lists(values, max_size=3)
    out = message()
    for key in draw(st.lists(st.sampled_from(sorted(out)), max_size=4)):
        out[key] = draw(values)
    return out


@given(mutated())
def test_what_passes_here_passes_the_json_schema(candidate: dict[str, Any]) -> None:
    try:
        check_message("estimate", candidate, KEY)
    except MalformedMessage:
        return
    jsonschema.validate(candidate, ESTIMATE_SCHEMA)
