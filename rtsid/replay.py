"""Replay recordings through the same window worker as the live daemon.

The live worker estimates windows that end on a fixed grid of sample indices, so replaying a
recording's samples with the recording's own configuration gives the same windows and the
same numbers. Replay is a plain iterator (:func:`iter_windows` over sample batches);
pacing in real time is a separate wrapper (:func:`paced`). Gaps in a recording — lost samples
logged as invalid rows, or batches missing from a file cut short — are respected: windows
across them are withheld with reason ``"gap"``, never bridged.
"""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from rtsid import __version__
from rtsid.calibrate import robot_torque_offset, with_recorded_calibration
from rtsid.errors import RecordingError
from rtsid.io.mcap_read import (
    iter_sample_batches,
    read_metadata,
    run_config_from_metadata,
    sample_count,
)
from rtsid.io.schemas import ESTIMATE_FIELDS, SCHEMAS, SampleBatch, encode_estimate, encode_json
from rtsid.link.ring import Snapshot
from rtsid.runtime.daemon import DaemonConfig
from rtsid.runtime.worker import WindowWorker

__all__ = [
    "ReplayResult",
    "iter_windows",
    "paced",
    "recording_config",
    "replay_file",
    "write_estimates_csv",
    "write_estimates_mcap",
]


def recording_config(path: str | Path) -> DaemonConfig:
    """The configuration a recording was made with (defaults where it has none), with the
    robot calibration the recording carries (:func:`rtsid.calibrate.with_recorded_calibration`)."""
    metadata = read_metadata(path)
    document = run_config_from_metadata(metadata)
    if not document:
        return DaemonConfig()
    return DaemonConfig.from_mapping(
        with_recorded_calibration(document, metadata.get("calibration"))
    )


class _Tail:
    """The newest rows of a recording, grown per batch and trimmed to what windows need."""

    def __init__(self, keep: int) -> None:
        self.keep = keep
        self.first = -1
        self.position = np.empty(0)
        self.torque = np.empty(0)
        self.valid = np.empty(0, dtype=bool)
        self.status = np.empty(0, dtype=np.uint8)

    @property
    def end(self) -> int:
        """Index one past the newest row."""
        return self.first + self.position.size

    def add(self, batch: SampleBatch) -> None:
        if self.first < 0:
            self.first = batch.first_index
        skip = max(0, self.end - batch.first_index)  # rows already seen (overlap)
        missing = max(0, batch.first_index - self.end)  # rows no batch carried: a gap
        gap_nan = np.full(missing, np.nan)
        rows = slice(skip, None)
        self.position = np.concatenate((self.position, gap_nan, batch.position_rad[rows]))
        self.torque = np.concatenate((self.torque, gap_nan, batch.torque_nm[rows]))
        self.valid = np.concatenate((self.valid, np.zeros(missing, bool), batch.valid[rows]))
        status = np.asarray(batch.status[rows], dtype=np.uint8)
        self.status = np.concatenate((self.status, np.zeros(missing, np.uint8), status))

    def window(self, end_index: int, n: int) -> Snapshot:
        lo = end_index - n + 1 - self.first
        hi = lo + n
        return Snapshot(
            sample_index=np.arange(end_index - n + 1, end_index + 1, dtype=np.int64),
            position_rad=self.position[lo:hi],
            torque_nm=self.torque[lo:hi],
            valid=self.valid[lo:hi],
            status=self.status[lo:hi],
            host_time_s=np.zeros(n),
            bus_time_s=np.full(n, np.nan),
        )

    def trim(self, oldest_needed: int) -> None:
        drop = oldest_needed - self.first
        if drop > self.keep:  # trim in large steps: concatenation stays rare
            self.first += drop
            self.position = self.position[drop:]
            self.torque = self.torque[drop:]
            self.valid = self.valid[drop:]
            self.status = self.status[drop:]


def iter_windows(batches: Iterable[SampleBatch], worker: WindowWorker) -> Iterator[Snapshot]:
    """Every grid window the batches complete, oldest first (the live daemon's windows)."""
    n = worker.window_samples
    tail = _Tail(keep=8 * n)
    next_end: int | None = None
    for batch in batches:
        tail.add(batch)
        if next_end is None:
            next_end = worker.first_window_end(tail.first)
        while next_end < tail.end:
            yield tail.window(next_end, n)
            next_end += worker.hop_samples
        tail.trim(next_end - n + 1)


def paced(
    batches: Iterable[SampleBatch], rate: float, *, clock: Callable[[], float] = time.monotonic
) -> Iterator[SampleBatch]:
    """Yield each batch no earlier than its sample time divided by ``rate`` (absolute deadlines)."""
    start_s: float | None = None
    first_index = 0
    for batch in batches:
        if start_s is None:
            start_s, first_index = clock(), batch.first_index
        due = start_s + (batch.end_index - first_index) / batch.fs_hz / rate
        delay = due - clock()
        if delay > 0:
            time.sleep(delay)
        yield batch


@dataclass
class ReplayResult:
    """What a replay produced."""

    source: str
    messages: list[dict[str, Any]] = field(default_factory=list)
    samples: int = 0
    duration_s: float = 0.0
    elapsed_s: float = 0.0

    @property
    def estimates(self) -> int:
        return sum(1 for m in self.messages if m["ok"])

    @property
    def withheld(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for m in self.messages:
            if not m["ok"]:
                counts[m["reason"]] = counts.get(m["reason"], 0) + 1
        return counts

    @property
    def speed(self) -> float:
        """Recording seconds per wall-clock second."""
        return self.duration_s / self.elapsed_s if self.elapsed_s > 0 else math.inf


def replay_file(
    path: str | Path,
    config: DaemonConfig | None = None,
    *,
    rate: float | None = None,
    publish: Callable[[dict[str, Any]], object] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ReplayResult:
    """Run the window worker over a recording's samples.

    Parameters
    ----------
    path : str or Path
        An rtsid MCAP recording (footer-less or truncated ones too).
    config : DaemonConfig, optional
        Default: the recording's own configuration (so the estimates equal the logged ones).
    rate : float, optional
        Pace at ``rate`` × real time (1: as the robot did); None: as fast as possible.
    publish : callable, optional
        Also called with every message (e.g. a zenoh publisher).
    progress : callable, optional
        ``progress(samples_done, samples_total)`` after each batch.

    Returns
    -------
    ReplayResult
    """
    config = config or recording_config(path)
    result = ReplayResult(source=str(path))

    def sink(message: dict[str, Any]) -> None:
        result.messages.append(message)
        if publish is not None:
            publish(message)

    worker = WindowWorker(
        ring=None,  # replay hands windows to evaluate()
        fs_hz=config.link.fs_hz,
        config=config.worker,
        options=config.estimator,
        publish=sink,
        robot=config.zenoh.robot,
        joint=config.zenoh.joint,
        torque_offset=robot_torque_offset(config.worker.calibration_file, config.link.fs_hz),
    )
    total = sample_count(path) if progress is not None else 0
    batches: Iterable[SampleBatch] = _counted(iter_sample_batches(path), result, progress, total)
    if rate is not None:
        batches = paced(batches, rate)
    started = time.perf_counter()
    for snap in iter_windows(batches, worker):
        worker.evaluate(snap, replay=True)
    result.elapsed_s = time.perf_counter() - started
    result.duration_s = result.samples / config.link.fs_hz
    if result.samples == 0:
        raise RecordingError(f"{path}: no samples to replay (is it an rtsid recording?)")
    return result


def _counted(
    batches: Iterable[SampleBatch],
    result: ReplayResult,
    progress: Callable[[int, int], None] | None,
    total: int,
) -> Iterator[SampleBatch]:
    for batch in batches:
        result.samples += len(batch)
        yield batch
        if progress is not None:
            progress(result.samples, total)


def write_estimates_csv(messages: Iterable[dict[str, Any]], fh: IO[str]) -> int:
    """Estimate messages as CSV, one row each, columns in schema order; returns the row count."""
    columns = [k for k in ESTIMATE_FIELDS if k not in ("robot", "joint", "host_time_ns")]
    writer = csv.DictWriter(fh, fieldnames=columns, lineterminator="\n", extrasaction="ignore")
    writer.writeheader()
    count = 0
    for message in messages:
        row = {k: ("" if message[k] is None else message[k]) for k in columns}
        row["flags"] = ";".join(message["flags"])
        writer.writerow(row)
        count += 1
    return count


def write_estimates_mcap(
    messages: Iterable[dict[str, Any]], fh: IO[bytes], *, source: str, config: DaemonConfig
) -> int:
    """Estimate messages as an MCAP file with the daemon's ``/estimate`` layout."""
    from mcap.writer import CompressionType, Writer

    writer = Writer(fh, compression=CompressionType.ZSTD)
    writer.start(profile="", library=f"rtsid {__version__}")
    schema, topic = SCHEMAS["estimate"]
    schema_id = writer.register_schema(
        name=schema["title"], encoding="jsonschema", data=encode_json(schema)
    )
    channel = writer.register_channel(topic=topic, message_encoding="json", schema_id=schema_id)
    writer.add_metadata("rtsid", {"software": "rtsid", "version": __version__, "replay_of": source})
    writer.add_metadata("config", {"json": encode_json(config.as_dict()).decode()})
    count = 0
    for message in messages:
        t = int(message["t_end_s"] * 1e9)
        writer.add_message(
            channel,
            log_time=t,
            publish_time=t,
            data=encode_estimate(message),
            sequence=message["seq"],
        )
        count += 1
    writer.finish()
    return count
