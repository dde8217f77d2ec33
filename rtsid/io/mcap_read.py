"""Read rtsid MCAP recordings — complete ones and ones that lost their footer.

A recorder killed with SIGKILL (or a full disk) leaves a file without summary and footer,
possibly ending in the middle of a record. ``mcap.reader.make_reader(...).iter_messages()``
refuses such a file; everything here reads records in order with the stream reader and stops
cleanly at the first incomplete or damaged record, so every message written before it is
returned. :func:`recover` rewrites such a file as a valid one.

Replay (issue 5) feeds :func:`iter_sample_batches` into the same window worker as the daemon.
"""

from __future__ import annotations

import io
import itertools
import json
import math
import os
import re
import struct
from collections.abc import Generator, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from rtsid import __version__
from rtsid.errors import InputDataError, RecordingError
from rtsid.ident.levinson import compiled_kernel
from rtsid.io.files import atomic_write
from rtsid.io.schemas import (
    SCHEMAS,
    SampleBatch,
    compact_sample_rows,
    decode_samples,
    decode_samples_into,
)

if TYPE_CHECKING:
    from rtsid.io.summary_table import SummaryTable, TableBuilder

# The summary table (rtsid.io.summary_table) is imported where it is written or read: a
# replay reads the messages and needs neither.

__all__ = [
    "ReadReport",
    "holds_no_record",
    "holds_topics",
    "iter_can_frames",
    "iter_estimates",
    "iter_messages",
    "iter_sample_batches",
    "iter_status",
    "read_json_topics",
    "read_metadata",
    "read_run_config",
    "read_summary_table",
    "recording_parts",
    "recover",
    "run_config_from_metadata",
    "sample_count",
    "summarize",
    "topic_counts",
]

#: Largest MCAP record or chunk (uncompressed) read, bytes: rtsid writes chunks of at most
#: ``[mcap] chunk_size`` (64 MiB) plus one message, so larger is damage, refused before it is
#: allocated.
MAX_RECORD_BYTES = 256 << 20

_STOPPED = (
    "the writer stopped before finishing the file: kill -9, a crash, a full disk or a torn copy"
)
TOPICS = {name: topic for name, (_schema, topic) in SCHEMAS.items()}


@dataclass
class ReadReport:
    """What a pass over a recording found.

    Attributes
    ----------
    path : Path
    messages : int
        Complete messages read.
    by_topic : dict[str, int]
        Messages per topic.
    complete : bool
        The footer was reached (the file was finished properly).
    bytes_read : int
        Bytes of the file up to the end of the last complete record read.
    error : str or None
        Why reading stopped early (truncated record, bad CRC, …); None when complete.
    """

    path: Path
    messages: int = 0
    by_topic: dict[str, int] = field(default_factory=dict)
    complete: bool = False
    error: str | None = None
    bytes_read: int = 0


def _damage_errors() -> tuple[type[BaseException], ...]:
    from mcap.exceptions import McapError

    errors: list[type[BaseException]] = [McapError, struct.error, ValueError, EOFError]
    try:
        import zstandard

        errors.append(zstandard.ZstdError)
    except ImportError:  # pragma: no cover - zstandard is a dependency
        pass
    return tuple(errors)


#: Reads larger than this are first clamped to what the file still holds.
_LARGE_READ = 1 << 20


class _FileBoundReader(io.BufferedReader):
    """A recording opened for reading whose large reads never ask for more than the file
    still holds: mcap's record parsers read a length field and then that many bytes, so one
    flipped bit in a chunk's inner length (fuzzed: 1 TB) was a MemoryError before the file
    could prove too short. Short data then fails as damage, and the read says so."""

    def read(self, size: int | None = -1) -> bytes:
        if size is not None and size > _LARGE_READ:
            size = min(size, max(0, os.fstat(self.fileno()).st_size - self.tell()))
        return super().read(size)


def _open(path: str | Path) -> IO[bytes]:
    p = Path(path)
    try:
        return _FileBoundReader(io.FileIO(p, "rb"))
    except FileNotFoundError:
        raise RecordingError(f"recording {str(p)!r} does not exist; check the path") from None
    except OSError as exc:
        raise RecordingError(f"cannot open recording {str(p)!r}: {exc.strerror}") from exc


def _iter_records(path: str | Path, report: ReadReport) -> Generator[Any, None, None]:
    """Every complete record in file order (chunks opened); stops at the first damaged one."""
    from mcap.exceptions import EndOfFile, InvalidMagic
    from mcap.records import Chunk, Footer
    from mcap.stream_reader import StreamReader

    damage = _damage_errors()
    with _open(path) as fh:
        reader = StreamReader(fh, emit_chunks=True, record_size_limit=MAX_RECORD_BYTES)
        records = reader.records
        first = True
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except InvalidMagic:
                raise RecordingError(
                    f"{str(path)!r} is not an MCAP file (bad magic bytes); pass an .mcap recording"
                ) from None
            except EndOfFile:
                if first:
                    raise RecordingError(
                        f"{str(path)!r} is empty or shorter than an MCAP header; nothing to read"
                    ) from None
                report.error = f"without its footer ({_STOPPED})"
                return
            except damage as exc:
                if first:
                    raise RecordingError(
                        f"{str(path)!r} is not an MCAP file (its header does not read: {exc}); "
                        "pass an .mcap recording"
                    ) from None
                report.error = (
                    f"without its footer (cut off inside a record: {_STOPPED})"
                    if not fh.read(1)
                    else f"damaged record after {report.messages} messages: {exc}"
                )
                return
            first = False
            if isinstance(record, Chunk):
                declared = max(record.uncompressed_size, _compressed_content_size(record))
                if declared > MAX_RECORD_BYTES:
                    report.error = (
                        f"damaged chunk after {report.messages} messages: it declares "
                        f"{declared} bytes, more than the "
                        f"{MAX_RECORD_BYTES >> 20} MiB a chunk may hold"
                    )
                    return
                try:
                    inner = _chunk_records(record)
                except damage as exc:
                    report.error = f"damaged chunk after {report.messages} messages: {exc}"
                    return
                report.bytes_read = fh.tell()
                yield from inner
            else:
                report.bytes_read = fh.tell()
                if isinstance(record, Footer):
                    report.complete = True
                yield record


#: The compiled CRC-32 (``zlib.crc32``'s value; None on the numpy path, where mcap checks
#: each chunk with ``zlib.crc32`` itself).
_CRC32 = getattr(compiled_kernel(), "crc32", None)


def _chunk_records(chunk: Any) -> list[Any]:
    """The records of ``chunk`` (mcap's ``breakup_chunk``), its CRC checked.

    A zstd chunk is decompressed here as mcap does it and its CRC checked by the compiled
    ``crc32`` (sixteen bytes at a time: ``zlib.crc32`` took a fifth of replay's reading),
    then split by mcap as an uncompressed chunk of the same bytes; any other chunk, and every
    chunk on the numpy path, by ``breakup_chunk(chunk, validate_crc=True)``, the reference.

    Raises
    ------
    CRCValidationError, ZstdError, McapError
        As ``breakup_chunk`` raises them for a damaged chunk.
    """
    from mcap.records import Chunk
    from mcap.stream_reader import CRCValidationError, breakup_chunk

    if _CRC32 is None or chunk.compression != "zstd":
        return breakup_chunk(chunk, validate_crc=True)
    import zstandard

    data = zstandard.decompress(chunk.data, chunk.uncompressed_size)
    expected = chunk.uncompressed_crc
    if expected != 0 and (actual := _CRC32(data)) != expected:
        raise CRCValidationError(expected=expected, actual=actual, record=chunk)
    plain = Chunk(
        compression="",
        data=data,
        message_end_time=chunk.message_end_time,
        message_start_time=chunk.message_start_time,
        uncompressed_crc=0,
        uncompressed_size=len(data),
    )
    return breakup_chunk(plain)


def _compressed_content_size(chunk: Any) -> int:
    """The size a chunk's compressed frame says it inflates to (0 when it does not say): the
    decompressors allocate that much whatever the chunk record declares, so a flipped bit in
    a frame header would otherwise be a multi-gigabyte allocation."""
    unreadable: tuple[type[BaseException], ...] = (*_damage_errors(), RuntimeError)
    try:
        if chunk.compression == "zstd":
            import zstandard

            return max(0, int(zstandard.frame_content_size(chunk.data)))
        if chunk.compression == "lz4":
            import lz4.frame

            return max(0, int(lz4.frame.get_frame_info(chunk.data).get("content_size") or 0))
    except ImportError:
        return 0
    except unreadable:  # a frame header that does not parse: breakup_chunk says how
        return 0
    return 0


def iter_messages(
    path: str | Path, report: ReadReport | None = None
) -> Iterator[tuple[str, Any, Any]]:
    """Yield ``(topic, channel, message)`` for every complete message, in file order.

    Parameters
    ----------
    path : str or Path
        An MCAP file, complete or not.
    report : ReadReport, optional
        Filled in as reading proceeds (counts, whether the footer was reached, why it stopped).

    Raises
    ------
    RecordingError
        The file is missing, empty or not MCAP. Damage after the header is not an error: reading
        stops there and ``report.error`` says why.
    """
    from mcap.records import Channel, Message

    report = report if report is not None else ReadReport(Path(path))
    channels: dict[int, Any] = {}
    for record in _iter_records(path, report):
        if isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            channel = channels.get(record.channel_id)
            if channel is None:
                continue  # its channel record was lost with a damaged chunk
            report.messages += 1
            report.by_topic[channel.topic] = report.by_topic.get(channel.topic, 0) + 1
            yield channel.topic, channel, record


def _iter_topic(path: str | Path, name: str, report: ReadReport | None) -> Iterator[Any]:
    topic = TOPICS[name]
    for t, _channel, message in iter_messages(path, report):
        if t == topic:
            yield message


def iter_sample_batches(
    path: str | Path, report: ReadReport | None = None, *, block_rows: int = 0
) -> Iterator[SampleBatch]:
    """Raw sample batches of one file in recording order, as numpy arrays (``report`` as in
    :func:`iter_messages`). To read a recording as samples, use :mod:`rtsid.io.recording`.

    Parameters
    ----------
    path : str or Path
    report : ReadReport, optional
    block_rows : int
        0: one batch per ``/samples`` message, as logged. Else consecutive messages that
        continue each other (same rate, each starting where the previous ended) are decoded
        straight into blocks of up to this many rows, one batch per block (replay's reading:
        no per-message arrays, copies or steps after it); the same rows either way.

    Yields
    ------
    SampleBatch
        ``first_index``, ``fs_hz``, ``position_rad``/``torque_nm`` (float64, NaN for lost
        rows), ``valid`` (bool), ``status`` (int64), ``log_time_ns`` (a block's: its first
        message's). Consecutive batches are contiguous unless samples were dropped by the
        logger (then ``first_index`` jumps: a gap, never bridged).
    """
    messages = _iter_topic(path, "samples", report)
    if block_rows > 0:
        yield from _sample_blocks(messages, path, block_rows)
        return
    for message in messages:
        yield _sample_batch(message, path)


class _SampleBlock:
    """Preallocated columns that consecutive ``/samples`` payloads are decoded into (the
    compact layout in place, :func:`~rtsid.io.schemas.decode_samples_into`; any other, and
    every payload on the numpy path, by the reference and copied), handed on as one batch of
    views."""

    def __init__(self, rows: int) -> None:
        self.position = np.empty(rows)
        self.torque = np.empty(rows)
        self.valid = np.empty(rows, dtype=bool)
        self.status = np.empty(rows, dtype=np.int64)
        self.rows = 0
        self.first_index = 0
        self.fs_hz = 0.0
        self.log_time_ns = 0

    def add(self, message: Any, path: str | Path) -> bool:
        """Decode ``message`` after the rows held; False (nothing added) when it does not fit
        or does not continue them (another rate, a gap, an overlap), or is refused (the
        caller reads it again, alone, and says why)."""
        done = decode_samples_into(
            message.data, self.position, self.torque, self.valid, self.status, self.rows
        )
        if done is None:  # another layout, or the numpy path: the reference, then a copy
            done = self._copied(message, path)
            if done is None:
                return False
        first_index, fs_hz, rows = done
        if self.rows == 0:
            if not (math.isfinite(fs_hz) and fs_hz > 0 and 0 <= first_index < 2**62):
                return False  # the reference reads it again, and refuses it
            self.first_index, self.fs_hz, self.log_time_ns = first_index, fs_hz, message.log_time
        elif first_index != self.first_index + self.rows or fs_hz != self.fs_hz:
            return False
        self.rows += rows
        return True

    def _copied(self, message: Any, path: str | Path) -> tuple[int, float, int] | None:
        """``message`` read by the reference into the rows after those held (None: refused,
        or more rows than the block has left)."""
        try:
            batch = _sample_batch(message, path)
        except RecordingError:
            return None
        at, n = self.rows, len(batch)
        if at + n > self.position.size:
            return None
        self.position[at : at + n] = batch.position_rad
        self.torque[at : at + n] = batch.torque_nm
        self.valid[at : at + n] = batch.valid
        self.status[at : at + n] = batch.status
        return batch.first_index, batch.fs_hz, n

    def batch(self) -> SampleBatch:
        """The rows held, as views."""
        n = self.rows
        return SampleBatch(
            self.first_index,
            self.fs_hz,
            self.position[:n],
            self.torque[:n],
            self.valid[:n],
            self.status[:n],
            self.log_time_ns,
        )


def _sample_blocks(messages: Iterable[Any], path: str | Path, rows: int) -> Iterator[SampleBatch]:
    """:func:`iter_sample_batches` in blocks of up to ``rows`` rows: a message that does not
    continue the block starts the next one; one no block can take (more rows than a block,
    damage) is read alone, after the block is yielded (a damaged one raises after every
    sample before it)."""
    block = _SampleBlock(rows)
    for message in messages:
        if block.add(message, path):
            continue
        if block.rows:
            yield block.batch()
            block = _SampleBlock(rows)
            if block.add(message, path):
                continue
        yield _sample_batch(message, path)
    if block.rows:
        yield block.batch()


def _sample_batch(message: Any, path: str | Path) -> SampleBatch:
    """One ``/samples`` message decoded (a RecordingError naming ``path`` when it does not)."""
    try:
        batch = decode_samples(message.data, message.log_time)
    except (InputDataError, OverflowError, RecursionError) as exc:
        reason = str(exc)[:200] or type(exc).__name__
        raise RecordingError(f"{path}: a /samples message does not read: {reason}") from None
    if not (math.isfinite(batch.fs_hz) and batch.fs_hz > 0 and 0 <= batch.first_index < 2**62):
        raise RecordingError(
            f"{path}: a /samples message says fs_hz = {batch.fs_hz!r}, first_index = "
            f"{batch.first_index}; the file is damaged or not rtsid's"
        )
    return batch


def iter_estimates(path: str | Path, report: ReadReport | None = None) -> Iterator[dict[str, Any]]:
    """Estimate messages of one file (dicts following ESTIMATE_SCHEMA; null numbers → None)."""
    for message in _iter_topic(path, "estimate", report):
        yield _json_object(message.data, path, "an estimate")


def iter_status(path: str | Path) -> Iterator[dict[str, Any]]:
    """Status messages (dicts following STATUS_SCHEMA)."""
    for message in _iter_topic(path, "status", None):
        yield _json_object(message.data, path, "a status message")


def iter_can_frames(path: str | Path) -> Iterator[Any]:
    """Raw CAN frames (``can.Message``) from the optional ``/can_frames`` channel."""
    import can

    for message in _iter_topic(path, "can_frames", None):
        for f in json.loads(message.data)["frames"]:
            yield can.Message(
                timestamp=f["timestamp_s"],
                arbitration_id=f["arbitration_id"],
                is_extended_id=f["is_extended_id"],
                is_error_frame=f["is_error_frame"],
                data=bytes.fromhex(f["data_hex"]),
            )


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """Metadata records by name (``rtsid``: software version, robot, joint, fs_hz, …;
    ``config``: the run configuration as JSON under key ``json``; ``rtsid.session``: subject,
    session, condition, robot, joint, started_utc, rtsid_version)."""
    from mcap.records import Metadata

    damage: tuple[type[BaseException], ...] = (*_damage_errors(), OverflowError, StopIteration)
    with _open(path) as fh:
        try:
            summary = _summary_records(fh)
            indexed = None if summary is None else _indexed_metadata(fh, summary)
        except damage:
            indexed = None
    if indexed:  # a finished file: its metadata index, no chunk read (none indexed: scan)
        return indexed
    out: dict[str, dict[str, str]] = {}
    for record in _iter_records(path, ReadReport(Path(path))):
        if isinstance(record, Metadata):
            out[record.name] = dict(record.metadata)
    return out


def topic_counts(path: str | Path) -> dict[str, int] | None:
    """Messages per topic by a finished file's Statistics record, without reading a message
    (None when the file has no summary to say: no footer, damaged, or not indexed)."""
    damage: tuple[type[BaseException], ...] = (*_damage_errors(), OverflowError, StopIteration)
    with _open(path) as fh:
        try:
            summary = _summary_records(fh)
        except damage:
            return None
    return None if summary is None else _channel_counts(summary)


def holds_topics(path: str | Path, topics: Iterable[str]) -> bool:
    """Whether the file may hold messages of ``topics``: False only when its Statistics record
    says it holds none (a pass over the file for them would decompress every chunk for
    nothing: a converted recording has samples alone)."""
    counts = topic_counts(path)
    return counts is None or any(counts.get(t, 0) for t in topics)


def read_run_config(path: str | Path) -> dict[str, Any]:
    """The daemon configuration stored in the recording (``{}`` when none was stored)."""
    return run_config_from_metadata(read_metadata(path))


def run_config_from_metadata(metadata: dict[str, dict[str, str]]) -> dict[str, Any]:
    """The daemon configuration in :func:`read_metadata`'s result (``{}`` when none)."""
    meta = metadata.get("config", {})
    return (
        _json_object(meta["json"], "the recording", "its config metadata") if "json" in meta else {}
    )


def _json_object(data: bytes | str, path: str | Path, what: str) -> dict[str, Any]:
    """``data`` parsed as a JSON object; anything else is a RecordingError naming ``what``."""
    try:
        value = json.loads(data)
    except (ValueError, RecursionError) as exc:
        reason = type(exc).__name__ if isinstance(exc, RecursionError) else str(exc)[:100]
        raise RecordingError(
            f"{path}: {what} is not valid JSON ({reason}); the file is damaged or not rtsid's"
        ) from None
    if not isinstance(value, dict):
        raise RecordingError(
            f"{path}: {what} is {type(value).__name__}, not a JSON object; the file is "
            "damaged or not rtsid's"
        )
    return value


_PART = re.compile(r"^(?P<session>.*\d{8}T\d{6}Z.*?)(?:-(?P<part>\d{3,}))?(?:-recovered)?\.mcap$")


def recording_parts(path: str | Path) -> list[Path]:
    """Every part of the recording session ``path`` belongs to, in order.

    A daemon's session is ``rtsid-<robot>-<joint>-<UTC>.mcap`` (or the ``[session]``
    ``recording_pattern``'s name, which always holds the UTC start) followed by ``-001``,
    ``-002``, … after rotation (or after a write error). Given any part, returns the existing
    parts in the same directory sorted by part number (a file not named that way is returned
    alone, and so is a ``…-recovered.mcap`` written by ``rtsid recover``).
    """
    p = Path(path)
    match = _PART.match(p.name)
    if match is None or p.name.endswith("-recovered.mcap"):
        return [p]  # a recovered file is read as itself, never as its session's damaged part
    session = match["session"]
    parts = []
    for candidate in p.parent.glob(f"{session}*.mcap"):
        m = _PART.match(candidate.name)
        if (
            m is not None
            and m["session"] == session
            and not candidate.name.endswith("-recovered.mcap")
        ):
            parts.append((int(m["part"] or 0), candidate))
    return [c for _n, c in sorted(parts)] or [p]


def holds_no_record(path: str | Path) -> bool:
    """Whether ``path`` is empty or ends inside the MCAP magic and header (a part created when
    the disk was already full), so that it holds nothing to read."""
    from mcap.exceptions import EndOfFile, McapError
    from mcap.stream_reader import StreamReader

    with _open(path) as fh:
        try:
            next(StreamReader(fh, record_size_limit=MAX_RECORD_BYTES).records)
        except EndOfFile:
            return True
        except (McapError, StopIteration, ValueError, struct.error):
            return False
    return False


def sample_count(path: str | Path) -> int:
    """Rows of samples in a recording (valid or not).

    A batch in the logger's compact layout (:func:`~rtsid.io.schemas.encode_samples`) is
    counted by the items of its last column (``status``: integers, one a row), without
    reading its numbers — replay's progress bar counts a recording before replaying it, and
    decoding every number for that doubled what it spent reading; any other payload is
    decoded (and refused as :func:`iter_sample_batches` refuses it).
    """
    rows = 0
    for message in _iter_topic(path, "samples", None):
        counted = compact_sample_rows(message.data)
        rows += len(_sample_batch(message, path)) if counted is None else counted
    return rows


def recover(
    src: str | Path, dst: str | Path, *, overwrite: bool = False, chunk_size: int = 1 << 20
) -> ReadReport:
    """Rewrite a recording (typically one that lost its footer) as a valid, indexed MCAP file.

    Parameters
    ----------
    src : str or Path
        The damaged (or complete) recording; never modified.
    dst : str or Path
        Output path (must differ from ``src``).
    overwrite : bool
        Replace ``dst`` if it exists.
    chunk_size : int
        Chunk size of the output, bytes.

    Returns
    -------
    ReadReport
        Messages saved (total and by topic), whether ``src`` was complete, and why it ended.

    Raises
    ------
    RecordingError
        ``src`` missing, empty or not MCAP (checked before ``dst`` is touched), ``dst`` equal
        to ``src`` or existing (without ``overwrite``), or ``dst`` not writable.
    """
    from mcap.writer import CompressionType, Writer

    from rtsid.io.summary_table import TableBuilder, attach_table

    src_p, dst_p = Path(src), Path(dst)
    if src_p.resolve() == dst_p.resolve():
        raise RecordingError(f"recover would overwrite its input {str(src_p)!r}; pick another -o")
    report = ReadReport(src_p)
    records = _iter_records(src_p, report)
    header = next(records, None)  # a missing, empty or non-MCAP input fails here, not as output
    if dst_p.exists() and not overwrite:
        records.close()
        raise RecordingError(f"{str(dst_p)!r} exists; remove it or pass --overwrite")
    with atomic_write(dst_p, "wb", what="the recovered recording") as out:
        writer = Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        writer.start(profile="", library=f"rtsid {__version__} (recover)")
        table = TableBuilder()
        _copy_records(
            itertools.chain([] if header is None else [header], records), writer, report, table
        )
        writer.add_metadata(
            "recovery",
            {
                "source": str(src_p),
                "source_complete": str(report.complete).lower(),
                "messages": str(report.messages),
                "stopped_because": report.error or "",
            },
        )
        attach_table(writer, table)  # as the logger does: rtsid summary reads it
        writer.finish()
    return report


def _copy_records(
    records: Iterable[Any], writer: Any, report: ReadReport, table: TableBuilder
) -> None:
    """Schemas, channels, messages and metadata into ``writer`` (ids renumbered); the
    messages of the summary table's channels into ``table``."""
    from mcap.records import Channel, Message, Metadata, Schema

    from rtsid.io.summary_table import KINDS

    table_kinds = {TOPICS[kind]: kind for kind in KINDS}  # the table's channels: kind by topic
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    topic_of: dict[int, str] = {}
    for record in records:
        if isinstance(record, Schema):
            schema_ids[record.id] = writer.register_schema(
                record.name, record.encoding, record.data
            )
        elif isinstance(record, Channel):
            channel_ids[record.id] = writer.register_channel(
                record.topic,
                record.message_encoding,
                schema_ids.get(record.schema_id, 0),
                dict(record.metadata),
            )
            report.by_topic.setdefault(record.topic, 0)
            topic_of[channel_ids[record.id]] = record.topic
        elif isinstance(record, Message) and record.channel_id in channel_ids:
            new_id = channel_ids[record.channel_id]
            writer.add_message(
                new_id, record.log_time, record.data, record.publish_time, record.sequence
            )
            report.messages += 1
            topic = topic_of[new_id]
            report.by_topic[topic] = report.by_topic.get(topic, 0) + 1
            if topic in table_kinds:
                table.add_payload(table_kinds[topic], record.data)
        elif isinstance(record, Metadata):
            writer.add_metadata(record.name, dict(record.metadata))


def summarize(path: str | Path) -> ReadReport:
    """Count messages per topic (reading the whole file); says whether it was complete."""
    report = ReadReport(Path(path))
    for _ in iter_messages(path, report):
        pass
    return report


def read_json_topics(
    path: str | Path, topics: Iterable[str], report: ReadReport | None = None
) -> tuple[dict[str, list[dict[str, Any]]], dict[str, dict[str, str]]]:
    """One pass over a file: the JSON messages of ``topics`` and every metadata record.

    What ``rtsid summary`` needs of a recording (estimates, reflex fits, status, session and
    markers) without a second pass for the metadata; other topics (the samples) are skipped
    undecoded.

    Parameters
    ----------
    path : str or Path
        An MCAP file, complete or not.
    topics : iterable of str
        Topics to decode, e.g. ``"/estimate"``; each is a key of the result, possibly empty.
    report : ReadReport, optional
        As in :func:`iter_messages`.

    Returns
    -------
    messages : dict[str, list[dict]]
        The messages of each topic in file order, as JSON objects.
    metadata : dict[str, dict[str, str]]
        Metadata records by name (as :func:`read_metadata`).

    Raises
    ------
    RecordingError
        As :func:`iter_messages`, or a message that is not a JSON object.
    """
    from mcap.records import Channel, Message, Metadata

    report = report if report is not None else ReadReport(Path(path))
    messages: dict[str, list[dict[str, Any]]] = {t: [] for t in topics}
    metadata: dict[str, dict[str, str]] = {}
    channels: dict[int, str] = {}
    for record in _iter_records(path, report):
        if isinstance(record, Channel):
            channels[record.id] = record.topic
        elif isinstance(record, Message):
            topic = channels.get(record.channel_id)
            if topic is None:
                continue  # its channel record was lost with a damaged chunk
            report.messages += 1
            report.by_topic[topic] = report.by_topic.get(topic, 0) + 1
            if topic in messages:
                messages[topic].append(_json_object(record.data, path, f"a {topic} message"))
        elif isinstance(record, Metadata):
            metadata[record.name] = dict(record.metadata)
    return messages, metadata


def read_summary_table(
    path: str | Path,
) -> tuple[SummaryTable, dict[str, dict[str, str]]] | None:
    """A part's summary table (:mod:`rtsid.io.summary_table`) and its metadata records, read
    through the file's summary section (a few seeks, no message decoded).

    Returns
    -------
    (SummaryTable, dict) or None
        The table and the metadata records by name (as :func:`read_metadata`); None when the
        file has no footer or summary section, no table attachment, a table this version does
        not read (another version, damaged, hostile), or one whose message counts differ from
        the file's Statistics record (a stale table): the caller reads the messages instead.

    Raises
    ------
    RecordingError
        The file is missing or unreadable.
    """
    from mcap.records import Attachment

    from rtsid.io.summary_table import ATTACHMENT_NAME, KINDS, SummaryTable, TableError

    damage: tuple[type[BaseException], ...] = (
        *_damage_errors(),
        TableError,
        OverflowError,
        MemoryError,
        StopIteration,
    )
    with _open(path) as fh:
        try:
            summary = _summary_records(fh)
            if summary is None:
                return None
            indexes = [a for a in summary["attachment_indexes"] if a.name == ATTACHMENT_NAME]
            if len(indexes) != 1 or indexes[0].data_size > MAX_RECORD_BYTES:
                return None
            attachment = _record_at(fh, indexes[0].offset)
            metadata = _indexed_metadata(fh, summary)
            if not isinstance(attachment, Attachment) or metadata is None:
                return None
            table = SummaryTable.from_npz(bytes(attachment.data))
        except damage:
            return None
    counts = _channel_counts(summary)
    if any(table.counts[kind] != counts.get(TOPICS[kind], 0) for kind in KINDS):
        return None  # stale: the file holds other messages than the table was made from
    return table, metadata


def _indexed_metadata(
    fh: IO[bytes], summary: dict[str, list[Any]]
) -> dict[str, dict[str, str]] | None:
    """The metadata records by name, read at the offsets of the summary's metadata index
    (as :func:`read_metadata` gives them); None when an offset holds no Metadata record."""
    from mcap.records import Metadata

    out: dict[str, dict[str, str]] = {}
    for index in summary["metadata_indexes"]:
        record = _record_at(fh, index.offset)
        if not isinstance(record, Metadata):
            return None
        out[record.name] = dict(record.metadata)
    return out


def _record_at(fh: IO[bytes], offset: int) -> Any:
    """The one record that starts at byte ``offset``."""
    from mcap.stream_reader import StreamReader

    fh.seek(offset)
    return next(StreamReader(fh, skip_magic=True, record_size_limit=MAX_RECORD_BYTES).records)


def _summary_records(fh: IO[bytes]) -> dict[str, list[Any]] | None:
    """The channels, statistics, attachment and metadata indexes of a finished file, read
    through its Summary Offset records (the chunk indexes, a thousand per 30 MiB, are
    skipped); None when the footer points to no summary offsets. Raises mcap's errors when
    there is no footer."""
    from mcap.opcode import Opcode
    from mcap.records import (
        AttachmentIndex,
        Channel,
        Footer,
        MetadataIndex,
        Statistics,
        SummaryOffset,
    )
    from mcap.stream_reader import MAGIC_SIZE, StreamReader

    wanted: dict[int, tuple[str, type]] = {
        Opcode.CHANNEL: ("channels", Channel),
        Opcode.STATISTICS: ("statistics", Statistics),
        Opcode.ATTACHMENT_INDEX: ("attachment_indexes", AttachmentIndex),
        Opcode.METADATA_INDEX: ("metadata_indexes", MetadataIndex),
    }
    if fh.seek(0, 2) < 2 * MAGIC_SIZE + _FOOTER_BYTES:
        return None  # too short to hold a footer: the message reader says what the file is
    fh.seek(-(_FOOTER_BYTES + MAGIC_SIZE), 2)
    footer = next(StreamReader(fh, skip_magic=True, record_size_limit=1024).records)
    if not isinstance(footer, Footer) or footer.summary_offset_start == 0:
        return None
    fh.seek(footer.summary_offset_start)
    offsets = list(StreamReader(fh, skip_magic=True, record_size_limit=1024).records)
    out: dict[str, list[Any]] = {key: [] for key, _cls in wanted.values()}
    for offset in offsets:
        if not isinstance(offset, SummaryOffset) or offset.group_opcode not in wanted:
            continue
        key, cls = wanted[offset.group_opcode]
        if offset.group_length > MAX_RECORD_BYTES:
            return None  # an empty group (no attachment, say) is read as none below
        fh.seek(offset.group_start)
        group = io.BytesIO(fh.read(offset.group_length))
        records = StreamReader(group, skip_magic=True, record_size_limit=MAX_RECORD_BYTES).records
        while group.tell() < offset.group_length:
            record = next(records)
            if not isinstance(record, cls):
                return None
            out[key].append(record)
    return out if len(out["statistics"]) == 1 else None


#: Bytes of an MCAP Footer record (opcode, length, three uint64 and a uint32).
_FOOTER_BYTES = 1 + 8 + 8 + 8 + 4


def _channel_counts(summary: dict[str, list[Any]]) -> dict[str, int]:
    """Messages per topic by the Statistics record."""
    topics = {c.id: c.topic for c in summary["channels"]}
    counts: dict[str, int] = {}
    for channel_id, n in summary["statistics"][0].channel_message_counts.items():
        if channel_id in topics:
            counts[topics[channel_id]] = counts.get(topics[channel_id], 0) + int(n)
    return counts
