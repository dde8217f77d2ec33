"""Reading recordings that lost their footer or end mid-record, and rewriting them."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from rtsid.errors import IncompleteRecordingWarning, RecordingError
from rtsid.io import mcap_read
from rtsid.io.mcap_log import McapConfig, McapLogger
from rtsid.io.recording import read_messages, read_recording

FS_HZ = 2500.0


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    """A complete recording of 40 batches × 250 samples with several chunks."""
    cfg = McapConfig(directory=str(tmp_path / "rec"), chunk_size=8192)
    with McapLogger(cfg, robot="r", joint="j", fs_hz=FS_HZ, run_config={"k": 1}) as logger:
        for k in range(40):
            idx = np.arange(k * 250, (k + 1) * 250)
            valid = (idx % 97) != 0
            pos = np.where(valid, idx * 1e-4, np.nan)
            logger.log_samples(k * 250, pos, idx * 1e-2, valid, (~valid).astype(int))
    (path,) = logger.files
    return path


def test_complete_file_reads_fully(recording: Path) -> None:
    report = mcap_read.summarize(recording)
    assert report.complete and report.error is None and report.by_topic == {"/samples": 40}
    batch = read_recording(recording).samples.all_rows()
    assert batch.first_index == 0 and len(batch) == 10_000
    assert np.isnan(batch.position_rad[~batch.valid]).all()
    np.testing.assert_array_equal(
        batch.position_rad[batch.valid], np.arange(10_000)[batch.valid] * 1e-4
    )
    assert (batch.status == (~batch.valid)).all()


@pytest.mark.parametrize("keep_fraction", [0.15, 0.4, 0.63, 0.9, 0.999])
def test_truncated_file_yields_a_contiguous_prefix_and_recovers(
    recording: Path, tmp_path: Path, keep_fraction: float
) -> None:
    data = recording.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * keep_fraction)])
    report = mcap_read.ReadReport(cut)
    batches = [m for t, _c, m in mcap_read.iter_messages(cut, report) if t == "/samples"]
    assert not report.complete and report.error
    starts = [b.first_index for b in mcap_read.iter_sample_batches(cut)]
    assert starts == [250 * k for k in range(len(starts))] and len(starts) == len(batches)
    assert mcap_read.read_run_config(cut) == {"k": 1}
    out = tmp_path / "fixed.mcap"
    rec = mcap_read.recover(cut, out)
    assert rec.messages == len(starts)
    with out.open("rb") as fh:
        reader = make_reader(fh)
        assert sum(1 for _ in reader.iter_messages()) == len(starts)
        summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    meta = mcap_read.read_metadata(out)
    assert meta["recovery"]["source_complete"] == "false" and meta["rtsid"]["robot"] == "r"


def test_corrupted_chunk_stops_reading_there(recording: Path, tmp_path: Path) -> None:
    data = bytearray(recording.read_bytes())
    with recording.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    chunk = chunks[len(chunks) // 2]  # the middle chunk, wherever the header's records end
    middle = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[middle : middle + 64] = bytes(64)  # zeroes inside a compressed chunk
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    report = mcap_read.summarize(bad)
    assert not report.complete and report.error
    assert 0 < report.messages < 40


def test_not_mcap_and_empty_files_are_clear_errors(tmp_path: Path) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"hello world, not an mcap file")
    with pytest.raises(RecordingError, match="not an MCAP file"):
        mcap_read.summarize(junk)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(RecordingError, match="empty"):
        mcap_read.summarize(empty)
    with pytest.raises(RecordingError, match="does not exist"):
        mcap_read.summarize(tmp_path / "missing.mcap")


def test_recover_refuses_to_overwrite(recording: Path, tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="overwrite its input"):
        mcap_read.recover(recording, recording)
    out = tmp_path / "out.mcap"
    out.write_bytes(b"x")
    with pytest.raises(RecordingError, match="exists"):
        mcap_read.recover(recording, out)
    report = mcap_read.recover(recording, out, overwrite=True)
    assert report.complete and report.messages == 40


def test_can_frames_channel_round_trip(tmp_path: Path) -> None:
    can = pytest.importorskip("can")
    cfg = McapConfig(directory=str(tmp_path), log_can_frames=True)
    frames = [
        can.Message(timestamp=0.1 * i, arbitration_id=0x100 + i, data=bytes([i, 2]))
        for i in range(3)
    ]
    with McapLogger(cfg, robot="r", joint="j", fs_hz=FS_HZ) as logger:
        assert logger.log_can_frames(frames)
    got = list(mcap_read.iter_can_frames(logger.files[0]))
    assert [f.arbitration_id for f in got] == [0x100, 0x101, 0x102]
    assert got[2].data == bytes([2, 2]) and got[1].timestamp == pytest.approx(0.1)


def test_recover_command(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from rtsid.cli import main

    data = recording.read_bytes()
    cut = tmp_path / "killed.mcap"
    cut.write_bytes(data[: len(data) // 2])
    assert main(["recover", str(cut)]) == 0
    out = capsys.readouterr().out
    assert "incomplete" in out and "messages saved" in out
    fixed = tmp_path / "killed-recovered.mcap"
    with fixed.open("rb") as fh:
        assert sum(1 for _ in make_reader(fh).iter_messages()) > 0
    assert main(["recover", str(cut)]) == 2  # exists: a one-line error, exit 2
    assert "exists" in capsys.readouterr().err


def test_files_open_in_the_typescript_mcap_reader(recording: Path, tmp_path: Path) -> None:
    """Independent reader (@mcap/core, what Foxglove builds on). Opt-in: set
    RTSID_MCAP_JS_NODE_PATH to a node_modules with @mcap/core and @foxglove/wasm-zstd
    (``npm install @mcap/core @foxglove/wasm-zstd``)."""
    import json
    import os
    import shutil
    import subprocess

    node_path = os.environ.get("RTSID_MCAP_JS_NODE_PATH")
    if not node_path or shutil.which("node") is None:
        pytest.skip("set RTSID_MCAP_JS_NODE_PATH (node_modules with @mcap/core) to run")
    data = recording.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    fixed = tmp_path / "fixed.mcap"
    saved = mcap_read.recover(cut, fixed).messages
    script = Path(__file__).with_name("mcap_check.js")
    for path, expected in ((recording, 40), (fixed, saved)):
        result = subprocess.run(
            ["node", str(script), str(path)],
            capture_output=True,
            text=True,
            timeout=60,
            env={**os.environ, "NODE_PATH": node_path},
        )
        assert result.returncode == 0, result.stderr
        report = json.loads(result.stdout)
        assert report["counts"] == {"/samples": expected}
        assert report["encodings"]["/samples"] == ["jsonschema", "json"]


def test_metadata_comes_from_the_index_of_a_finished_file_and_from_a_scan_of_a_cut_one(
    tmp_path, monkeypatch
):
    from mcap.writer import CompressionType, Writer

    path = tmp_path / "meta.mcap"
    with path.open("wb") as fh:
        writer = Writer(fh, compression=CompressionType.ZSTD)
        writer.start(profile="", library="test")
        writer.add_metadata("rtsid", {"robot": "rig"})
        channel = writer.register_channel(topic="/x", message_encoding="json", schema_id=0)
        for k in range(2000):
            writer.add_message(channel_id=channel, log_time=k, data=b"{}" * 50, publish_time=k)
        writer.add_metadata("config", {"json": "{}"})
        writer.finish()
    expected = {"rtsid": {"robot": "rig"}, "config": {"json": "{}"}}
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    scans = []
    scan = mcap_read._iter_records
    with monkeypatch.context() as m:  # a cut file has no index: it is scanned
        m.setattr(mcap_read, "_iter_records", lambda *a: scans.append(1) or scan(*a))
        assert mcap_read.read_metadata(cut)["rtsid"] == {"robot": "rig"} and scans
    with monkeypatch.context() as m:  # a finished file needs no scan
        m.setattr(mcap_read, "_iter_records", lambda *a: pytest.fail("scanned"))
        assert mcap_read.read_metadata(path) == expected


def test_a_chunk_claiming_a_terabyte_inside_its_record_is_damage_not_a_memory_error(tmp_path):
    # hypothesis flipped a byte of a chunk's inner records length to ≈ 1 TB: mcap's parser read
    # that many bytes at once and the reader died of MemoryError instead of reporting damage
    import struct

    from mcap.writer import CompressionType, Writer

    path = tmp_path / "big.mcap"
    with path.open("wb") as fh:
        writer = Writer(fh, compression=CompressionType.NONE)
        writer.start(profile="", library="test")
        channel = writer.register_channel(topic="/x", message_encoding="json", schema_id=0)
        for k in range(100):
            writer.add_message(channel_id=channel, log_time=k, data=b"{}", publish_time=k)
        writer.finish()
    data = bytearray(path.read_bytes())
    at = data.index(b"\x06", 8)  # the chunk's opcode, after the header
    length_at = at + 1 + 8 + 8 + 8 + 8 + 4 + 4  # opcode, length, times, size, crc, "" (none)
    assert struct.unpack_from("<Q", data, length_at)[0] < 10_000  # the records' length
    struct.pack_into("<Q", data, length_at, 1 << 40)
    path.write_bytes(bytes(data))
    report = mcap_read.ReadReport(path)
    records = list(mcap_read._iter_records(path, report))
    assert report.error and not report.complete and len(records) < 10


def test_a_finished_file_says_which_topics_it_holds_and_a_cut_one_may_hold_any(
    recording: Path, tmp_path: Path
) -> None:
    """A pass for estimates or markers skips a finished file whose statistics count none (a
    converted recording has samples alone); a file without its summary is read to find out,
    and reading its messages gives what the full pass gives."""
    assert mcap_read.topic_counts(recording) == {"/samples": 40}
    assert mcap_read.holds_topics(recording, ["/samples"])
    assert not mcap_read.holds_topics(recording, ["/estimate", "/marker"])
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recording.read_bytes()[: recording.stat().st_size // 2])
    assert mcap_read.topic_counts(cut) is None
    assert mcap_read.holds_topics(cut, ["/estimate"])
    for path in (recording, cut):
        with contextlib.ExitStack() as stack:
            if path == cut:
                stack.enter_context(pytest.warns(IncompleteRecordingWarning, match="ends early"))
            read = read_messages([path], ["/estimate", "/marker"])
        found, metadata = mcap_read.read_json_topics(path, ["/estimate", "/marker"])
        assert read.messages == found and read.metadata == [metadata]
        assert read.complete == (path == recording)


def test_sample_count_counts_each_layouts_rows_as_decoding_them_does(tmp_path: Path) -> None:
    # compact payloads are counted by their status column, any other layout decoded
    import json

    from mcap.writer import Writer

    from rtsid.io.schemas import encode_samples

    n = 7
    position = np.linspace(0.0, 0.1, n)
    valid = np.ones(n, bool)
    valid[3] = False
    compact = encode_samples(10, 2500.0, position, position, valid, np.arange(n))
    spaced = json.dumps(json.loads(compact)).encode()  # json's default separators: not compact
    empty = encode_samples(17, 2500.0, [], [], [], [])
    out = tmp_path / "layouts.mcap"
    with out.open("wb") as fh:
        writer = Writer(fh)
        writer.start()
        channel = writer.register_channel("/samples", "json", 0)
        for k, data in enumerate((compact, spaced, empty, compact)):
            writer.add_message(channel, k, data, k)
        writer.finish()
    rows = sum(len(b) for b in mcap_read.iter_sample_batches(out))
    assert mcap_read.sample_count(out) == rows == 3 * n


def test_sample_count_refuses_a_payload_that_is_not_compact_and_does_not_read(tmp_path: Path):
    from mcap.writer import Writer

    out = tmp_path / "bad.mcap"
    with out.open("wb") as fh:
        writer = Writer(fh)
        writer.start()
        channel = writer.register_channel("/samples", "json", 0)
        writer.add_message(channel, 0, b'{"first_index": 0, "status": [1, x]}', 0)
        writer.finish()
    with pytest.raises(RecordingError, match="a /samples message does not read"):
        mcap_read.sample_count(out)


@pytest.mark.skipif(mcap_read._CRC32 is None, reason="no compiled kernel")
def test_the_compiled_crc32_is_zlibs() -> None:
    import zlib

    rng = np.random.default_rng(11)
    for n in [*range(0, 200), 1000, 4099, 1 << 16, (1 << 20) + 3]:
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        for value in (0, 1, 0xFFFFFFFF):
            assert mcap_read._CRC32(data, value) == zlib.crc32(data, value)
    view = memoryview(bytes(range(256)) * 3)[5:700]  # any buffer, any alignment
    assert mcap_read._CRC32(view) == zlib.crc32(view)


@pytest.mark.parametrize("compiled", [True, False])
def test_a_chunk_whose_crc_does_not_match_stops_the_read_there(
    recording: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compiled: bool
) -> None:
    """The compiled check and mcap's own (the numpy path's) refuse the same chunk alike: the
    messages before it read, the report naming the CRC."""
    import struct

    if not compiled:
        monkeypatch.setattr(mcap_read, "_CRC32", None)
    whole = [m.data for t, _c, m in mcap_read.iter_messages(recording) if t == "/samples"]
    data = bytearray(recording.read_bytes())
    at = 8 + 1 + 8 + struct.unpack_from("<Q", data, 9)[0]  # the record after the header
    chunks = []  # the offsets of the chunk records (opcode 6), in file order
    while len(chunks) < 2:
        if data[at] == 0x06:
            chunks.append(at)
        at += 1 + 8 + struct.unpack_from("<Q", data, at + 1)[0]
    assert data[chunks[1] + 1 + 8 + 24 + 4 + 4 : chunks[1] + 1 + 8 + 24 + 4 + 4 + 4] == b"zstd"
    crc_at = chunks[1] + 1 + 8 + 8 + 8 + 8  # opcode, length, start and end times, size
    struct.pack_into("<I", data, crc_at, struct.unpack_from("<I", data, crc_at)[0] ^ 1)
    damaged = tmp_path / "crc.mcap"
    damaged.write_bytes(bytes(data))
    report = mcap_read.ReadReport(damaged)
    read = [m.data for t, _c, m in mcap_read.iter_messages(damaged, report) if t == "/samples"]
    assert 0 < len(read) < len(whole) and read == whole[: len(read)]
    assert not report.complete and report.error is not None
    assert report.error.startswith(f"damaged chunk after {report.messages} messages: crc")
