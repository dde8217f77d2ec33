"""The one recording reader: one grid, rotated parts as one, gaps as invalid rows, truncated
files read to the last complete message with a warning that says how much was read."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from rtsid.cli import main
from rtsid.errors import IncompleteRecordingWarning, RecordingError, RtsidWarning
from rtsid.io.mcap_log import McapConfig, McapLogger
from rtsid.io.recording import (
    SampleGrid,
    iter_batches,
    read_estimates,
    read_recording,
    session_parts,
)
from rtsid.io.schemas import SampleBatch

FS_HZ = 2500.0
REFERENCE = Path(__file__).resolve().parents[2] / "replay" / "reference" / "sim_3s.mcap"


def batch(first: int, n: int) -> SampleBatch:
    idx = np.arange(first, first + n)
    return SampleBatch(
        first, FS_HZ, idx * 1.0, idx * 2.0, np.ones(n, bool), np.full(n, 4, np.int64)
    )


def test_gaps_become_invalid_rows_and_overlaps_are_dropped():
    grid = SampleGrid(10, FS_HZ, capacity=4)
    for b in (batch(10, 5), batch(18, 4), batch(20, 5), batch(12, 3)):  # gap 15..17, overlaps
        grid.append(b)
    rows = grid.all_rows()
    assert (rows.first_index, rows.end_index) == (10, 25)
    assert np.flatnonzero(~rows.valid).tolist() == [5, 6, 7]
    assert np.isnan(rows.position_rad[5:8]).all() and (rows.status[5:8] == 0).all()
    ok = rows.valid
    np.testing.assert_array_equal(rows.position_rad[ok], np.arange(10, 25)[ok])
    np.testing.assert_array_equal(rows.torque_nm[ok], 2.0 * np.arange(10, 25)[ok])


def test_a_trimmed_grid_keeps_the_rows_and_reuses_its_buffer(rng):
    grid = SampleGrid(0, FS_HZ, capacity=1000)
    buffers = {id(grid._position)}
    end = 0
    for _ in range(2000):  # the replay pattern: append a batch, keep the last 750 rows
        n = int(rng.integers(1, 300))
        grid.append(batch(end, n))
        end += n
        np.testing.assert_array_equal(grid.rows(end - n, end).position_rad, np.arange(end - n, end))
        grid.drop_before(end - 750)
        buffers.add(id(grid._position))
    assert len(grid) <= 750 and grid.end_index == end
    assert len(buffers) <= 3  # grown geometrically to twice the need, then reused
    with pytest.raises(IndexError):
        grid.rows(end - 800, end)


def test_a_grids_columns_are_its_rows_views():
    grid = SampleGrid(10, FS_HZ, capacity=4)
    for b in (batch(10, 5), batch(18, 7)):  # a gap 15..17
        grid.append(b)
    grid.drop_before(12)
    for start, stop in ((12, 25), (14, 19), (20, 20)):
        rows = grid.rows(start, stop)
        columns = grid.columns(start, stop)
        for column, expected in zip(
            columns, (rows.position_rad, rows.torque_nm, rows.valid, rows.status), strict=True
        ):
            assert column.dtype == expected.dtype and column.base is not None  # a view
            np.testing.assert_array_equal(column, expected)
    for start, stop in ((11, 20), (20, 26), (15, 14)):
        with pytest.raises(IndexError):
            grid.columns(start, stop)


def rotated_session(folder: Path) -> list[Path]:
    cfg = McapConfig(
        directory=str(folder), flush_interval_s=0.01, rotate_size_mb=0.02, chunk_size=4096
    )
    with McapLogger(cfg, robot="r", joint="j", fs_hz=FS_HZ, run_config={"k": 1}) as logger:
        for k in range(200):  # bounded
            if k != 7:  # batch 7 never logged: a gap
                b = batch(250 * k, 250)
                logger.log_samples(b.first_index, b.position_rad, b.torque_nm, b.valid, b.status)
            time.sleep(0.003)
            if len(logger.files) >= 3:
                break
    return logger.files


def test_any_part_reads_the_whole_session_as_one_grid(tmp_path):
    parts = rotated_session(tmp_path)
    assert session_parts(parts[1]) == parts == session_parts(parts)
    recording = read_recording(parts[-1])
    rows = recording.samples.all_rows()
    assert recording.parts == parts and recording.config == {"k": 1}
    assert rows.first_index == 0 and rows.end_index % 250 == 0 and rows.end_index > 2000
    assert np.flatnonzero(~rows.valid).tolist() == list(range(1750, 2000))
    np.testing.assert_array_equal(rows.position_rad[rows.valid], np.flatnonzero(rows.valid))


def test_a_truncated_part_is_read_to_its_last_message_with_a_warning(tmp_path):
    parts = rotated_session(tmp_path)
    whole_end = read_recording(parts).samples.end_index
    data = parts[0].read_bytes()
    parts[0].write_bytes(data[: len(data) // 2])
    with pytest.warns(IncompleteRecordingWarning) as caught:
        first_part = list(iter_batches(parts[0]))
    (warning,) = caught
    rows, end_s = sum(len(b) for b in first_part), first_part[-1].end_index / FS_HZ
    assert rows > 0
    text = str(warning.message)
    assert text.startswith(f"{parts[0]} ends early, without its footer (")  # torn or not
    assert f"read {rows} samples, {rows / FS_HZ:.2f} s (t = 0.00–{end_s:.2f} s)" in text
    assert f"of {len(data) // 2 / 1024:.1f} KiB" in text and f"rtsid recover {parts[0]}" in text
    with pytest.warns(IncompleteRecordingWarning):
        grid = read_recording(parts).samples  # later parts are still read, after a gap
    assert grid.end_index == whole_end and not grid.all_rows().valid[rows:1750].any()


def test_a_recording_of_estimates_only_has_no_samples_to_read(tmp_path):
    from rtsid.replay import recording_config, replay_file, write_estimates_mcap

    estimates = tmp_path / "estimates.mcap"
    with estimates.open("wb") as fh:
        messages = replay_file(REFERENCE).messages
        write_estimates_mcap(messages, fh, source="x", config=recording_config(REFERENCE))
    with pytest.raises(RecordingError, match="no /samples messages"):
        read_recording(estimates)
    assert len(read_estimates(estimates)) == len(messages)


@pytest.mark.parametrize("command", ["replay", "plot"])
def test_replay_and_plot_of_a_file_cut_in_half_say_how_much_was_read(tmp_path, capsys, command):
    half = tmp_path / "half.mcap"
    data = REFERENCE.read_bytes()
    half.write_bytes(data[: len(data) // 2])
    argv = [command, str(half)] + (["-o", str(tmp_path / "k.png")] if command == "plot" else [])
    assert main(argv) == 3  # done, but on an incomplete recording
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"rtsid {command}: warning: {half} ends early")
    assert ("samples, " if command == "replay" else "estimates (up to t =") in (lines[0])
    assert main([command, str(REFERENCE), *argv[2:]]) == 0


def test_an_empty_part_left_by_a_full_disk_is_skipped_with_a_note(tmp_path, capsys):
    """Issue 20: a zero-byte part (an older logger's retry on a full disk) made the session
    fail with '…-001.mcap is empty'; it is skipped, with a note, and the rest is read."""
    parts = rotated_session(tmp_path)
    whole = read_recording(parts[0]).samples.end_index
    empty = parts[-1].with_name(parts[-1].name.replace(".mcap", "0.mcap"))  # -0020 sorts last
    empty.write_bytes(b"")
    with pytest.warns(RtsidWarning, match=r"skipped .*-0020\.mcap: it is empty"):
        recording = read_recording(parts[0])
    assert recording.parts == parts and recording.samples.end_index == whole
    defaults = tmp_path / "defaults.toml"  # the test session stores a config replay refuses
    defaults.write_text("")
    assert main(["replay", str(parts[0]), "--config", str(defaults)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rtsid replay: warning: skipped ")


def test_a_recovered_file_is_read_as_itself_not_as_its_damaged_original(tmp_path, capsys):
    """Issue 20: 'rtsid replay X-recovered.mcap' read the truncated X.mcap beside it."""
    parts = rotated_session(tmp_path)
    for extra in parts[1:]:
        extra.unlink()
    original = parts[0]
    whole = read_recording(original).samples.end_index
    with original.open("rb") as fh:  # the messages end where the summary table begins
        (table,) = make_reader(fh).get_summary().attachment_indexes
    original.write_bytes(original.read_bytes()[: table.offset // 2])
    assert main(["recover", str(original)]) == 0
    recovered = original.with_name(original.stem + "-recovered.mcap")
    assert session_parts(recovered) == [recovered]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a complete file: no incomplete-recording warning
        grid = read_recording(recovered).samples
    assert 0 < grid.end_index < whole
    capsys.readouterr()
    defaults = tmp_path / "defaults.toml"  # the test session stores a config replay refuses
    defaults.write_text("")
    assert main(["replay", str(recovered), "--config", str(defaults)]) == 0
    assert "ends early" not in capsys.readouterr().err


def grid_of(batches) -> SampleBatch:
    """Every row of ``batches`` on one grid (gaps invalid, overlaps dropped)."""
    grid: SampleGrid | None = None
    for b in batches:
        grid = grid or SampleGrid(b.first_index, b.fs_hz)
        grid.append(b)
    assert grid is not None
    return grid.all_rows()


def test_blocks_hold_the_rows_of_the_batches_as_logged(tmp_path):
    parts = rotated_session(tmp_path)  # batches of 250, batch 7 never logged: a gap
    logged = list(iter_batches(parts))
    blocks = list(iter_batches(parts, block_rows=1000))
    assert len(blocks) < len(logged)  # joined, four batches a block at most
    assert all(len(b) <= 1000 for b in blocks)
    # a block never spans the gap: it ends where the next batch as logged begins
    assert 1750 in [b.end_index for b in blocks] and 2000 in [b.first_index for b in blocks]
    a, b = grid_of(logged), grid_of(blocks)
    assert (a.first_index, a.end_index) == (b.first_index, b.end_index)
    for x, y in zip(
        (a.position_rad, a.torque_nm, a.valid, a.status),
        (b.position_rad, b.torque_nm, b.valid, b.status),
        strict=True,
    ):
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes()


def test_a_damaged_batch_in_a_block_is_refused_after_the_rows_before_it(tmp_path):
    from mcap.writer import Writer

    from rtsid.io.mcap_log import register_channels
    from rtsid.io.schemas import encode_samples

    path = tmp_path / "damaged.mcap"
    with path.open("wb") as fh:
        writer = Writer(fh)
        writer.start()
        channel = register_channels(writer)["samples"]
        for k in range(6):
            b = batch(250 * k, 250)
            data = encode_samples(k * 250, FS_HZ, b.position_rad, b.torque_nm, b.valid, b.status)
            if k == 4:
                data = data.replace(b",", b",,", 1)  # not JSON
            writer.add_message(channel, log_time=k, data=data, publish_time=k)
        writer.finish()
    read: list[SampleBatch] = []
    with pytest.raises(RecordingError, match="a /samples message does not read") as blocks:
        read.extend(iter_batches(path, block_rows=1 << 13))
    assert [(b.first_index, len(b)) for b in read] == [(0, 1000)]  # the four before it
    with pytest.raises(RecordingError) as logged:
        list(iter_batches(path))
    assert str(blocks.value) == str(logged.value)
