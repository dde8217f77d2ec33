"""MCAP recordings under hostile input: arbitrary bytes, truncations and bit flips of a real
recording, records and chunks declaring huge sizes, and well-formed files whose messages are
garbage. Only rtsid's own errors escape the one recording reader (warnings say how much of a
damaged file was read), nothing is allocated beyond the documented caps. Issue 20."""

from __future__ import annotations

import io
import json
import struct
import warnings
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from mcap.writer import CompressionType, Writer

from rtsid.cli import main
from rtsid.errors import RecordingError, RtsidError, RtsidWarning
from rtsid.io.mcap_log import register_channels
from rtsid.io.mcap_read import MAX_RECORD_BYTES, ReadReport, iter_messages, read_run_config, recover
from rtsid.io.recording import read_estimates, read_recording

FUZZ = settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
REFERENCE = Path(__file__).resolve().parents[2] / "replay" / "reference" / "sim_3s.mcap"
MAGIC = b"\x89MCAP0\r\n"


def reads_or_refuses(path: Path, tmp_path: Path) -> None:
    """Every reader either reads ``path`` or raises rtsid's own error."""
    readers = [
        lambda: read_recording(path),
        lambda: read_estimates(path),
        lambda: read_run_config(path),
        lambda: recover(path, tmp_path / "recovered.mcap", overwrite=True),
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RtsidWarning)
        for read in readers:
            try:
                read()
            except RtsidError:
                pass


@FUZZ
@given(data=st.binary(max_size=600))
@example(data=MAGIC)
@example(data=MAGIC + b"\x01" + struct.pack("<Q", 2**62))
@example(data=MAGIC + b"\x01" + struct.pack("<Q", 4) + b"\xff\xff\xff\xff")
def test_fuzz_arbitrary_bytes(tmp_path: Path, data: bytes) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(data)
    reads_or_refuses(path, tmp_path)


@FUZZ
@given(draw=st.data())
def test_fuzz_mutated_real_recording(tmp_path: Path, draw: st.DataObject) -> None:
    original = REFERENCE.read_bytes()
    out = bytearray(original[: draw.draw(st.integers(0, len(original)), label="cut")])
    for _ in range(draw.draw(st.integers(0, 6), label="flips")):
        if out:
            out[draw.draw(st.integers(0, len(out) - 1))] ^= 1 << draw.draw(st.integers(0, 7))
    path = tmp_path / "x.mcap"
    path.write_bytes(bytes(out))
    reads_or_refuses(path, tmp_path)


def _recording(messages: list[tuple[str, bytes]], metadata: dict[str, str] | None = None) -> bytes:
    """A well-formed MCAP file with rtsid's channels carrying ``messages`` as given."""
    out = io.BytesIO()
    writer = Writer(out, compression=CompressionType.ZSTD)
    writer.start(profile="", library="test")
    channels = register_channels(writer)
    if metadata is not None:
        writer.add_metadata("config", metadata)
    for t, (kind, payload) in enumerate(messages):
        writer.add_message(channels[kind], log_time=t, data=payload, publish_time=t)
    writer.finish()
    return out.getvalue()


_JSON = st.recursive(
    st.one_of(
        st.none(),
        st.booleans(),
        st.integers(),
        st.sampled_from([2**64, -1, 10**30]),
        st.floats(allow_nan=False, allow_infinity=False),
        st.text(max_size=5),
    ),
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=12), inner, max_size=4)
    ),
    max_leaves=12,
)
_SAMPLE_KEYS = ["first_index", "fs_hz", "position_rad", "torque_nm", "valid", "status"]


@st.composite
def samples_payloads(draw: st.DrawFn) -> bytes:
    """A /samples payload: rtsid's keys with hostile values, or any JSON, or any bytes."""
    kind = draw(st.sampled_from(["keys", "json", "bytes"]))
    if kind == "bytes":
        return draw(st.binary(max_size=60))
    if kind == "json":
        return json.dumps(draw(_JSON)).encode()
    n = draw(st.integers(0, 3))
    message: dict[str, Any] = {
        "first_index": draw(st.sampled_from([0, -5, 2**40, 10**30, 1.5, "0", None])),
        "fs_hz": draw(st.sampled_from([2500.0, 0.0, -1.0, 1e300, "x", None])),
        "position_rad": [0.0] * n,
        "torque_nm": [0.0] * n,
        "valid": [True] * n,
        "status": [0] * n,
    }
    for key in draw(st.lists(st.sampled_from(_SAMPLE_KEYS), max_size=2)):
        message[key] = draw(_JSON)
    return json.dumps(message).encode()


@FUZZ
@given(
    payloads=st.lists(samples_payloads(), min_size=1, max_size=3),
    estimate=_JSON,
    config=st.one_of(st.text(max_size=20), _JSON.map(json.dumps)),
)
@example(
    payloads=[
        b'{"first_index": 0, "fs_hz": 2500, "position_rad": [0], "torque_nm": [0], '
        b'"valid": [true], "status": [0]}',
        b'{"first_index": 1000000000000, "fs_hz": 2500, "position_rad": [0], "torque_nm": [0], '
        b'"valid": [true], "status": [0]}',
    ],
    estimate=[1],
    config="[",
)
@example(payloads=[b"[" * 100_000], estimate=None, config="{}")
@example(
    payloads=[
        b'{"first_index": 0, "fs_hz": 2500.0, "position_rad": [], "torque_nm": null, '
        b'"valid": [], "status": []}'
    ],
    estimate=None,
    config="",
)
def test_fuzz_well_formed_files_with_garbage_messages(
    tmp_path: Path, payloads: list[bytes], estimate: Any, config: str
) -> None:
    messages = [("samples", p) for p in payloads] + [("estimate", json.dumps(estimate).encode())]
    path = tmp_path / "x.mcap"
    path.write_bytes(_recording(messages, {"json": config}))
    reads_or_refuses(path, tmp_path)


def test_a_gap_beyond_the_row_cap_is_refused_before_allocating(tmp_path: Path) -> None:
    batch = '"position_rad": [0], "torque_nm": [0], "valid": [true], "status": [0]'
    messages = [
        ("samples", f'{{"first_index": 0, "fs_hz": 2500, {batch}}}'.encode()),
        ("samples", f'{{"first_index": 1000000000000, "fs_hz": 2500, {batch}}}'.encode()),
    ]
    path = tmp_path / "gap.mcap"
    path.write_bytes(_recording(messages))
    with pytest.raises(RecordingError, match=r"exceed the 20000000 rows one read holds"):
        read_recording(path)


def _chunk_declaring(uncompressed_size: int, data: bytes = b"") -> bytes:
    """A zstd chunk record whose header declares ``uncompressed_size`` bytes, holding ``data``."""
    body = struct.pack("<QQQI", 0, 0, uncompressed_size, 0)
    body += struct.pack("<I", 4) + b"zstd" + struct.pack("<Q", len(data)) + data
    return b"\x06" + struct.pack("<Q", len(body)) + body


def test_a_chunk_declaring_more_than_the_cap_stops_the_read_as_damage(tmp_path: Path) -> None:
    header = b"\x01" + struct.pack("<Q", 8) + struct.pack("<I", 0) + struct.pack("<I", 0)
    path = tmp_path / "bomb.mcap"
    path.write_bytes(MAGIC + header + _chunk_declaring(2**40))
    report = ReadReport(path)
    assert list(iter_messages(path, report)) == []
    assert not report.complete and "more than the 256 MiB a chunk may hold" in str(report.error)
    assert MAX_RECORD_BYTES == 256 << 20


def test_a_zstd_frame_declaring_more_than_the_cap_is_not_inflated(tmp_path: Path) -> None:
    """A bit flipped in a chunk's zstd frame header made the decompressor allocate what the
    frame declares (found by the replay fuzz test as an out-of-memory exit)."""
    import zstandard

    size = MAX_RECORD_BYTES + (1 << 20)
    squeeze = zstandard.ZstdCompressor().compressobj(size=size)
    zeros = bytes(1 << 20)
    frame = b"".join(squeeze.compress(zeros) for _ in range(size >> 20)) + squeeze.flush()
    assert zstandard.frame_content_size(frame) == size and len(frame) < 100_000
    header = b"\x01" + struct.pack("<Q", 8) + struct.pack("<I", 0) + struct.pack("<I", 0)
    path = tmp_path / "frame.mcap"
    path.write_bytes(MAGIC + header + _chunk_declaring(100, frame))
    report = ReadReport(path)
    assert list(iter_messages(path, report)) == []
    assert f"it declares {size} bytes, more than the 256 MiB" in str(report.error)


def test_a_record_declaring_a_huge_length_is_damage_not_an_allocation(tmp_path: Path) -> None:
    path = tmp_path / "huge.mcap"
    path.write_bytes(REFERENCE.read_bytes()[:2000] + b"\x05" + struct.pack("<Q", 2**62))
    report = ReadReport(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RtsidWarning)
        list(iter_messages(path, report))
    assert not report.complete and report.error


@pytest.mark.parametrize(
    ("content", "code", "message"),
    [
        (b"", 2, "is empty or shorter than an MCAP header"),
        (b"garbage" * 10, 2, "is not an MCAP file"),
        ("half", 3, "ends early"),
        ("config", 2, "its config metadata is not valid JSON"),
    ],
)
def test_replay_of_damaged_recordings_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: Any, code: int, message: str
) -> None:
    path = tmp_path / "x.mcap"
    if content == "half":
        data = REFERENCE.read_bytes()
        content = data[: len(data) // 2]
    elif content == "config":
        content = _recording([], {"json": "{not json"})
    path.write_bytes(content)
    assert main(["replay", str(path)]) == code
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert "Traceback" not in captured.err and len(lines) == 1, captured.err
    assert message in lines[0]


@settings(
    max_examples=max(5, settings().max_examples // 5),  # a replay each: a fifth of the profile
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(draw=st.data())
def test_fuzz_replay_of_a_mutated_recording_is_done_or_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], draw: st.DataObject
) -> None:
    """The whole command, not only the reader: exit 0, 2 or 3, at most one line per warning
    or error, never a traceback."""
    original = REFERENCE.read_bytes()
    out = bytearray(original[: draw.draw(st.integers(0, len(original)), label="cut")])
    for _ in range(draw.draw(st.integers(0, 4), label="flips")):
        if out:
            out[draw.draw(st.integers(0, len(out) - 1))] ^= 1 << draw.draw(st.integers(0, 7))
    path = tmp_path / "x.mcap"
    path.write_bytes(bytes(out))
    capsys.readouterr()
    code = main(["replay", str(path)])
    captured = capsys.readouterr()
    assert code in (0, 2, 3), captured.err
    assert "Traceback" not in captured.err and "internal error" not in captured.err
    assert all(line.startswith("rtsid replay: ") for line in captured.err.strip().splitlines())
