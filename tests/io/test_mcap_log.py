"""McapLogger: never blocks or raises into the caller, bounded loss on SIGKILL, rotation,
full-disk handling, metadata; files read back with the mcap library's own reader."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any

import numpy as np
import pytest
from mcap.reader import make_reader

from rtsid.errors import ConfigError, IncompleteRecordingWarning, InputDataError
from rtsid.io import mcap_read
from rtsid.io.mcap_log import McapConfig, McapLogger, recording_name
from rtsid.io.schemas import ESTIMATE_FIELDS

FS_HZ = 2500.0
HERE = Path(__file__).resolve().parent


def estimate(seq: int) -> dict[str, Any]:
    est: dict[str, Any] = dict.fromkeys(ESTIMATE_FIELDS, 0.0)
    est.update(
        robot="r1",
        joint="ankle",
        seq=seq,
        window_start_index=seq * 50,
        window_end_index=seq * 50 + 749,
        ok=True,
        reason=None,
        flags=[],
        host_time_ns=1_000_000_000 + seq,
        K=100.0 + seq,
    )
    return est


def log_batches(logger: McapLogger, n_batches: int, batch: int = 250, start: int = 0) -> None:
    for k in range(start, start + n_batches):
        idx = np.arange(k * batch, (k + 1) * batch)
        assert logger.log_samples(k * batch, idx * 1e-3, -idx * 1e-2)


def read_all_with_mcap_reader(path: Path) -> list[Any]:
    with path.open("rb") as fh:
        return list(make_reader(fh).iter_messages())


def test_config_errors_name_the_key() -> None:
    with pytest.raises(ConfigError, match=r"mcap\.queue_size"):
        McapConfig.from_mapping({"queue_size": 1})
    with pytest.raises(ConfigError, match=r"unknown config key mcap\.chunk"):
        McapConfig.from_mapping({"chunk": 1})
    assert (
        McapConfig.from_mapping({"directory": "x", "flush_interval_s": 1}).flush_interval_s == 1.0
    )


def test_recording_name_follows_the_scheme() -> None:
    from datetime import UTC, datetime

    start = datetime(2026, 1, 2, 3, 4, 5, tzinfo=UTC)
    assert (
        recording_name("rig 1", "ankle/left", start, 0)
        == "rtsid-rig_1-ankle_left-20260102T030405Z.mcap"
    )
    assert recording_name("r", "j", start, 12).endswith("Z-012.mcap")


def test_everything_logged_is_read_back_by_mcap_reader(tmp_path: Path) -> None:
    cfg = McapConfig(directory=str(tmp_path))
    with McapLogger(
        cfg,
        robot="r1",
        joint="ankle",
        fs_hz=FS_HZ,
        run_config={"worker": {"hop_s": 0.02}},
        metadata={"operator": "test"},
    ) as logger:
        log_batches(logger, 12)
        for seq in range(30):
            assert logger.log_estimate(estimate(seq))
        assert logger.log_status(
            {"robot": "r1", "joint": "ankle", "host_time_ns": 5, "uptime_s": 1.0}
        )
    stats = logger.stats()
    assert stats["state"] == "stopped" and stats["written"] == 43 and stats["dropped"] == 0
    (path,) = logger.files
    assert path.name.startswith("rtsid-r1-ankle-")
    messages = read_all_with_mcap_reader(path)
    topics = [channel.topic for _schema, channel, _msg in messages]
    assert topics.count("/samples") == 12 and topics.count("/estimate") == 30
    assert topics.count("/status") == 1
    for schema, channel, _msg in messages:
        assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
    batches = list(mcap_read.iter_sample_batches(path))
    pos = np.concatenate([b.position_rad for b in batches])
    np.testing.assert_array_equal(pos, np.arange(3000) * 1e-3)
    assert [e["seq"] for e in mcap_read.iter_estimates(path)] == list(range(30))
    meta = mcap_read.read_metadata(path)
    assert meta["rtsid"]["robot"] == "r1" and meta["rtsid"]["fs_hz"] == "2500.0"
    assert meta["rtsid"]["operator"] == "test" and meta["rtsid"]["version"]
    assert mcap_read.read_run_config(path) == {"worker": {"hop_s": 0.02}}


def test_bad_arrays_raise_at_the_call_not_on_the_thread(tmp_path: Path) -> None:
    with McapLogger(McapConfig(directory=str(tmp_path)), robot="r", joint="j", fs_hz=FS_HZ) as lg:
        with pytest.raises(InputDataError, match="1-D arrays of one length"):
            lg.log_samples(0, np.zeros(3), np.zeros(4))
        with pytest.raises(InputDataError, match="missing keys"):
            lg.log_estimate({"K": 1.0})


class BlockingFile:
    """A file whose writes wait for ``release`` (a stalled disk)."""

    def __init__(self, path: Path, release: threading.Event) -> None:
        self._fh = path.open("xb")
        self._release = release

    def write(self, data: bytes) -> int:
        self._release.wait(10.0)
        return self._fh.write(data)

    def tell(self) -> int:
        return self._fh.tell()

    def flush(self) -> None:
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()


def test_full_queue_drops_and_counts_without_blocking(tmp_path: Path) -> None:
    release = threading.Event()
    cfg = McapConfig(directory=str(tmp_path), queue_size=16)
    logger = McapLogger(
        cfg, robot="r", joint="j", fs_hz=FS_HZ, open_file=lambda p: BlockingFile(p, release)
    )  # type: ignore[arg-type,return-value]
    with logger:
        accepted = sum(logger.log_estimate(estimate(i)) for i in range(100))
        stats = logger.stats()
        assert stats["dropped"] == 100 - accepted >= 100 - 16 - 1
        assert stats["dropped_by_kind"]["estimate"] == stats["dropped"]
        release.set()
    stats = logger.stats()
    assert stats["written"] == accepted and stats["lost"] == 0
    assert len(list(mcap_read.iter_estimates(logger.files[0]))) == accepted


class FullDisk:
    """A file that raises ENOSPC once ``capacity`` bytes were written."""

    def __init__(self, path: Path, capacity: int) -> None:
        self._fh = path.open("xb")
        self._left = capacity

    def write(self, data: bytes) -> int:
        if len(data) > self._left:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._left -= len(data)
        return self._fh.write(data)

    def tell(self) -> int:
        return self._fh.tell()

    def flush(self) -> None:
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()


def test_full_disk_is_reported_while_the_caller_keeps_going(tmp_path: Path, wait_for: Any) -> None:
    opened: list[Path] = []

    def open_file(path: Path) -> IO[bytes]:
        opened.append(path)
        capacity = 20_000 if len(opened) == 1 else 10**9  # the disk "frees up" for file 2
        return FullDisk(path, capacity)  # type: ignore[return-value]

    cfg = McapConfig(directory=str(tmp_path), flush_interval_s=0.02, retry_interval_s=0.2)
    with McapLogger(cfg, robot="r", joint="j", fs_hz=FS_HZ, open_file=open_file) as logger:
        for k in range(400):  # bounded; every call returns at once
            logger.log_samples(k * 250, np.arange(250) * 1.0, np.arange(250) * 2.0)
            logger.log_estimate(estimate(k))
            if (
                logger.stats()["errors"]
                and len(opened) > 1
                and logger.stats()["state"] == "recording"
            ):
                break
            time.sleep(0.005)
        stats = logger.stats()
        assert stats["errors"] >= 1
        assert "No space left on device" in stats["last_error"]
        assert "mcap.directory" in stats["last_error"] and "still published" in stats["last_error"]
        wait_for(lambda: logger.stats()["state"] == "recording")
        log_batches(logger, 2, start=1000)
    stats = logger.stats()
    assert stats["lost"] >= 1 and len(opened) == 2
    # the file cut by the full disk is recoverable; the next one is complete
    first_report = mcap_read.summarize(opened[0])
    assert not first_report.complete and first_report.messages > 0
    assert read_all_with_mcap_reader(opened[1])


def test_unwritable_directory_is_an_error_in_stats_not_an_exception(
    tmp_path: Path, wait_for: Any
) -> None:
    not_a_dir = tmp_path / "file"
    not_a_dir.write_text("x")
    cfg = McapConfig(directory=str(not_a_dir / "recordings"), retry_interval_s=60.0)
    with McapLogger(cfg, robot="r", joint="j", fs_hz=FS_HZ) as logger:
        wait_for(lambda: logger.stats()["errors"] >= 1)
        log_batches(logger, 3)
        assert logger.log_estimate(estimate(0))
        wait_for(lambda: logger.stats()["lost"] >= 4)
    stats = logger.stats()
    assert stats["state"] == "error" and stats["file"] is None and stats["written"] == 0
    assert "recordings" in stats["last_error"] and "mcap.directory" in stats["last_error"]


def test_rotation_by_size_keeps_samples_contiguous(tmp_path: Path) -> None:
    cfg = McapConfig(
        directory=str(tmp_path), flush_interval_s=0.01, rotate_size_mb=0.02, chunk_size=4096
    )
    with McapLogger(cfg, robot="r", joint="j", fs_hz=FS_HZ) as logger:
        for k in range(200):  # bounded
            log_batches(logger, 1, start=k)
            time.sleep(0.003)
            if len(logger.files) >= 3:
                break
    files = logger.files
    assert len(files) >= 3
    assert files[1].name.endswith("-001.mcap") and files[2].name.endswith("-002.mcap")
    first_indices = []
    for path in files:
        # each part is a complete, valid file (the last one may be empty)
        assert read_all_with_mcap_reader(path) or path == files[-1]
        assert mcap_read.read_metadata(path)["rtsid"]["part"] == str(files.index(path))
        first_indices += [b.first_index for b in mcap_read.iter_sample_batches(path)]
    assert first_indices == [250 * k for k in range(len(first_indices))]


def test_rotation_by_time(tmp_path: Path) -> None:
    cfg = McapConfig(directory=str(tmp_path), flush_interval_s=0.01, rotate_interval_s=0.05)
    with McapLogger(cfg, robot="r", joint="j", fs_hz=FS_HZ) as logger:
        for k in range(500):  # bounded
            log_batches(logger, 1, start=k)
            time.sleep(0.005)
            if len(logger.files) >= 2:
                break
    assert len(logger.files) >= 2
    total = sum(mcap_read.summarize(p).by_topic.get("/samples", 0) for p in logger.files)
    assert total == logger.stats()["written"]


def test_disabled_logger_writes_nothing(tmp_path: Path) -> None:
    cfg = McapConfig(directory=str(tmp_path / "rec"), enabled=False)
    with McapLogger(cfg, robot="r", joint="j", fs_hz=FS_HZ) as logger:
        assert not logger.log_estimate(estimate(0))
    assert logger.stats()["state"] == "disabled" and not (tmp_path / "rec").exists()


@pytest.mark.slow  # a real-time daemon run of seconds
@pytest.mark.parametrize("flush_interval_s", [0.5])
def test_sigkill_loses_at_most_about_one_second(tmp_path: Path, flush_interval_s: float) -> None:
    proc = subprocess.Popen(
        [sys.executable, str(HERE / "mcap_child.py"), str(tmp_path), str(flush_interval_s)],
        stdout=subprocess.PIPE,
        text=True,
    )
    handed_over = 0
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # bounded: the child stops itself after 10 000 batches
            if line.startswith("end"):
                handed_over = int(line.split()[1])
                if handed_over >= 3 * FS_HZ:
                    break
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        for line in proc.stdout.read().splitlines():  # what it handed over before it died
            if line.startswith("end"):
                handed_over = max(handed_over, int(line.split()[1]))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        if proc.stdout is not None:
            proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    (path,) = tmp_path.glob("rtsid-kill-ankle-*.mcap")
    with path.open("rb") as fh, pytest.raises(Exception):  # noqa: B017 - any error: no footer
        list(make_reader(fh).iter_messages())
    report = mcap_read.summarize(path)
    assert not report.complete
    saved = mcap_read.sample_count(path)
    lost_s = (handed_over - saved) / FS_HZ
    assert 0 <= lost_s <= 1.0 + flush_interval_s * 0.2, f"lost {lost_s:.2f} s of samples"
    out = tmp_path / "recovered.mcap"
    rec = mcap_read.recover(path, out)
    assert rec.messages == report.messages and not rec.complete
    messages = read_all_with_mcap_reader(out)
    assert len(messages) == report.messages
    positions = np.concatenate([b.position_rad for b in mcap_read.iter_sample_batches(out)])
    np.testing.assert_array_equal(positions, np.sin(np.arange(saved) / 100.0))


def test_recording_parts_lists_a_rotated_session_in_order(tmp_path: Path) -> None:
    cfg = McapConfig(
        directory=str(tmp_path), flush_interval_s=0.01, rotate_size_mb=0.02, chunk_size=4096
    )
    with McapLogger(cfg, robot="r", joint="j", fs_hz=FS_HZ) as logger:
        for k in range(200):  # bounded
            log_batches(logger, 1, start=k)
            time.sleep(0.003)
            if len(logger.files) >= 3:
                break
    (tmp_path / "unrelated.mcap").write_bytes(b"")
    files = logger.files
    assert mcap_read.recording_parts(files[1]) == files
    assert mcap_read.recording_parts(tmp_path / "unrelated.mcap") == [tmp_path / "unrelated.mcap"]
    starts = [b.first_index for p in files for b in mcap_read.iter_sample_batches(p)]
    assert starts == sorted(starts) and starts[0] == 0


def test_a_disk_still_full_at_each_retry_leaves_no_empty_parts(
    tmp_path: Path, wait_for: Any
) -> None:
    """Issue 20: each retry while the disk was full left a zero-byte part, and replaying the
    session then failed with '…-001.mcap is empty'."""
    opened: list[Path] = []

    def open_file(path: Path) -> IO[bytes]:
        opened.append(path)
        capacities = {1: 20_000, 2: 0, 3: 0, 4: 0}  # files 2-4: not even the header fits
        return FullDisk(path, capacities.get(len(opened), 10**9))  # type: ignore[return-value]

    cfg = McapConfig(directory=str(tmp_path), flush_interval_s=0.02, retry_interval_s=0.05)
    with McapLogger(cfg, robot="r", joint="j", fs_hz=FS_HZ, open_file=open_file) as logger:
        for k in range(2000):  # bounded; until a file opens after the full disk
            logger.log_samples(k * 250, np.arange(250) * 1.0, np.arange(250) * 2.0)
            if len(opened) >= 5 and logger.stats()["state"] == "recording":
                break
            time.sleep(0.005)
        wait_for(lambda: logger.stats()["state"] == "recording")
        log_batches(logger, 2, start=5000)
    files = mcap_read.recording_parts(opened[0])
    assert set(files) == set(tmp_path.glob("*.mcap")) and files[0] == opened[0]
    assert len(opened) >= 5 and len(files) == 2, [(f.name, f.stat().st_size) for f in files]
    assert all(f.stat().st_size > 0 for f in files)
    from rtsid.io.recording import read_recording

    with pytest.warns(IncompleteRecordingWarning):  # the part cut by the full disk
        grid = read_recording(files[0]).samples
    assert grid.end_index == 5002 * 250 and grid.all_rows().valid[-500:].all()


def test_a_batch_of_estimates_records_what_one_by_one_does(tmp_path: Path) -> None:
    """The daemon hands a tick's estimates over as one batch (payload, time, message): the
    file's messages and its summary table equal those of logging them one by one."""
    from rtsid.io.schemas import encode_estimate

    messages = [estimate(seq) for seq in range(40)]
    for seq, message in enumerate(messages):  # values the table must carry over exactly
        message.update(K=100.0 + seq / 3, reason=None if seq % 3 else "gap", ok=bool(seq % 3))
        message.update(B_held=seq % 2 == 0, reflex_seq=seq if seq % 4 else None)
    tables, payloads = [], []
    for folder, batched in (("one", False), ("batch", True)):
        cfg = McapConfig(directory=str(tmp_path / folder))
        with McapLogger(cfg, robot="r1", joint="ankle", fs_hz=FS_HZ) as logger:
            encoded = [(encode_estimate(m), 1_000 + i, m) for i, m in enumerate(messages)]
            if batched:
                assert logger.log_estimates(encoded[:25]) and logger.log_estimates(encoded[25:])
            else:
                for payload, t_ns, _ in encoded:
                    assert logger.log_estimate(payload, log_time_ns=t_ns)
        assert logger.stats()["written"] == 40 and logger.stats()["dropped"] == 0
        (path,) = logger.files
        payloads.append([(msg.log_time, msg.data) for _, _, msg in read_all_with_mcap_reader(path)])
        found = mcap_read.read_summary_table(path)
        assert found is not None
        tables.append(found[0])
    assert payloads[0] == payloads[1] and len(payloads[0]) == 40
    one, batch = tables
    assert one.counts == batch.counts and one.columns.keys() == batch.columns.keys()
    for key, column in one.columns.items():
        np.testing.assert_array_equal(column, batch.columns[key], err_msg=key)
    assert one.text("reason") == batch.text("reason") and "gap" in batch.text("reason")


def test_a_full_queue_counts_every_estimate_of_a_dropped_batch(tmp_path: Path) -> None:
    from rtsid.io.schemas import encode_estimate

    release = threading.Event()
    cfg = McapConfig(directory=str(tmp_path), queue_size=16)
    logger = McapLogger(
        cfg, robot="r", joint="j", fs_hz=FS_HZ, open_file=lambda p: BlockingFile(p, release)
    )  # type: ignore[arg-type,return-value]
    batch = [(encode_estimate(estimate(i)), i, estimate(i)) for i in range(7)]
    with logger:
        accepted = sum(logger.log_estimates(batch) for _ in range(30))  # 30 items, queue of 16
        stats = logger.stats()
        assert 30 - accepted >= 30 - 16 - 1
        assert stats["dropped"] == stats["dropped_by_kind"]["estimate"] == 7 * (30 - accepted)
        release.set()
    assert logger.stats()["written"] == 7 * accepted
