"""The one recording reader: an rtsid MCAP session as rows on one sample-index grid.

Every command that turns a recording into samples or estimates reads it here — replay
streams it (:func:`iter_batches` into a :class:`SampleGrid` it trims), calibrate and tv read it
whole (:func:`read_recording`), plot reads its estimates (:func:`read_estimates`). The rules
are therefore the same everywhere:

* **Parts.** A daemon rotates a session into ``…Z.mcap``, ``…Z-001.mcap``, …; given any part,
  :func:`session_parts` lists them all in order and they are read as one recording.
* **Gaps.** Rows no batch carried (the logger dropped them, or a part is missing) become
  invalid rows (NaN, ``valid`` False, status 0) on the grid — never bridged. Rows already
  seen (an overlap) are dropped.
* **Truncated files.** A file cut short (kill -9, full disk, a copy torn in half) is read to
  its last complete message; then an :class:`~rtsid.errors.IncompleteRecordingWarning` says
  how much was read (samples, seconds, bytes of the file) and how to rewrite the file.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rtsid.errors import IncompleteRecordingWarning, RecordingError, RtsidWarning
from rtsid.io.files import MAX_ROWS
from rtsid.io.mcap_read import (
    TOPICS,
    ReadReport,
    holds_no_record,
    holds_topics,
    iter_estimates,
    iter_sample_batches,
    read_json_topics,
    read_metadata,
    read_run_config,
    read_summary_table,
    recording_parts,
)
from rtsid.io.schemas import SampleBatch

if TYPE_CHECKING:
    from rtsid.io.summary_table import SummaryTable

__all__ = [
    "BLOCK_ROWS",
    "SESSION_TOPICS",
    "GridColumns",
    "RecordedMessages",
    "RecordedTable",
    "Recording",
    "SampleGrid",
    "SessionRecord",
    "iter_batches",
    "read_estimates",
    "read_messages",
    "read_recording",
    "read_session",
    "read_table",
    "session_parts",
    "session_record",
]

Paths = str | Path | Sequence[str | Path]


def session_parts(paths: Paths) -> list[Path]:
    """Every part of the sessions ``paths`` belong to, in order, each once.

    A file not named like a daemon's part (``rtsid-<robot>-<joint>-<UTC>[-NNN].mcap``)
    stands alone, and so does a ``…-recovered.mcap``. Parts that hold no record (created when
    the disk was full) are skipped with a :class:`~rtsid.errors.RtsidWarning` note.
    """
    given = [paths] if isinstance(paths, str | Path) else list(paths)
    parts: list[Path] = []
    for path in given:
        parts += [p for p in recording_parts(path) if p not in parts]
    return _without_empty_parts(parts)


def _without_empty_parts(parts: list[Path]) -> list[Path]:
    """``parts`` less those holding no record (created when the disk was full), each skipped
    with a note; a session of nothing but empty parts is left for the reader to refuse."""
    kept = [p for p in parts if not (p.is_file() and holds_no_record(p))]
    if not kept:
        return parts
    for part in parts:
        if part not in kept:
            warnings.warn(
                RtsidWarning(
                    f"skipped {part}: it is empty (created while the disk was full); the "
                    "session's other parts are read, its samples are a gap"
                ),
                stacklevel=3,
            )
    return kept


#: A :class:`SampleGrid`'s buffers (position, torque, valid, status) and the sample index of
#: their row 0 (:meth:`SampleGrid.buffers`).
GridColumns = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]


class SampleGrid:
    """Rows of a recording on one sample-index grid, appended in place.

    The columns are preallocated and grow geometrically; :meth:`drop_before` forgets old rows
    (replay keeps only what its windows still need), and their room is reused by moving the
    kept rows to the front when the buffer fills — no allocation per batch.

    Parameters
    ----------
    first_index : int
        Sample index of row 0.
    fs_hz : float
        Sample rate, Hz.
    capacity : int
        Rows to allocate at first.
    """

    def __init__(self, first_index: int, fs_hz: float, capacity: int = 4096) -> None:
        self.fs_hz = float(fs_hz)
        self._first = int(first_index)  # sample index of buffer row self._lo
        self._lo = 0  # buffer rows before this are forgotten
        self._hi = 0  # buffer rows from here are free
        self._position = np.empty(max(1, capacity))
        self._torque = np.empty_like(self._position)
        self._valid = np.zeros(self._position.size, dtype=bool)
        self._status = np.zeros(self._position.size, dtype=np.uint8)

    @property
    def first_index(self) -> int:
        """Sample index of the oldest row kept."""
        return self._first

    @property
    def end_index(self) -> int:
        """Sample index one past the newest row."""
        return self._first + self._hi - self._lo

    def __len__(self) -> int:
        return self._hi - self._lo

    def append(self, batch: SampleBatch) -> None:
        """Add ``batch``'s new rows; rows between the newest row and it become invalid."""
        missing = max(0, batch.first_index - self.end_index)
        skip = min(len(batch), max(0, self.end_index - batch.first_index))
        new = len(batch) - skip
        self._make_room(missing + new)
        gap = slice(self._hi, self._hi + missing)
        self._position[gap] = np.nan
        self._torque[gap] = np.nan
        self._valid[gap] = False
        self._status[gap] = 0
        rows = slice(self._hi + missing, self._hi + missing + new)
        self._position[rows] = batch.position_rad[skip:]
        self._torque[rows] = batch.torque_nm[skip:]
        self._valid[rows] = batch.valid[skip:]
        self._status[rows] = batch.status[skip:]
        self._hi += missing + new

    def drop_before(self, index: int) -> None:
        """Forget the rows before sample ``index``."""
        drop = min(max(0, index - self._first), len(self))
        self._lo += drop
        self._first += drop

    def rows(self, start_index: int, stop_index: int) -> SampleBatch:
        """Rows ``start_index .. stop_index − 1`` as views (valid until the next append).

        Raises
        ------
        IndexError
            Rows outside what the grid holds.
        """
        if not self.first_index <= start_index <= stop_index <= self.end_index:
            raise IndexError(
                f"rows {start_index}..{stop_index} are outside {self.first_index}..{self.end_index}"
            )
        sl = slice(self._lo + start_index - self._first, self._lo + stop_index - self._first)
        return SampleBatch(
            start_index,
            self.fs_hz,
            self._position[sl],
            self._torque[sl],
            self._valid[sl],
            self._status[sl],
        )

    def columns(
        self, start_index: int, stop_index: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, torque, valid and status of rows ``start_index .. stop_index − 1``: what
        :meth:`rows` holds, as views without the batch around them (replay cuts a window's
        columns every hop).

        Raises
        ------
        IndexError
            Rows outside what the grid holds.
        """
        if not self._first <= start_index <= stop_index <= self._first + self._hi - self._lo:
            raise IndexError(
                f"rows {start_index}..{stop_index} are outside {self.first_index}..{self.end_index}"
            )
        sl = slice(self._lo + start_index - self._first, self._lo + stop_index - self._first)
        return self._position[sl], self._torque[sl], self._valid[sl], self._status[sl]

    def buffers(self) -> GridColumns:
        """The whole position, torque, valid and status buffers (views, valid until the next
        append) and the sample index of their row 0: rows ``i − base`` are sample ``i``'s for
        the samples the grid holds (replay slices each window from them, :meth:`columns`
        without its call and its checks)."""
        return (
            self._position,
            self._torque,
            self._valid,
            self._status,
            self._first - self._lo,
        )

    def all_rows(self) -> SampleBatch:
        """Every row kept, as views."""
        return self.rows(self.first_index, self.end_index)

    def _make_room(self, extra: int) -> None:
        kept = len(self)
        if kept + extra > MAX_ROWS:
            raise RecordingError(
                f"{kept + extra} rows at {self.fs_hz:g} Hz (a gap up to sample "
                f"{self.end_index + extra}) exceed the {MAX_ROWS} rows one read holds; the "
                "recording is damaged, or read its parts one by one"
            )
        if self._hi + extra <= self._position.size:
            return
        size = self._position.size
        if kept + extra > size // 2:  # grow geometrically, or move the kept rows to the front
            size = max(2 * size, kept + extra)
        for name in ("_position", "_torque", "_valid", "_status"):
            old = getattr(self, name)
            new = old if size == old.size else np.empty(size, dtype=old.dtype)
            new[:kept] = old[self._lo : self._hi]  # overlapping move: numpy copies safely
            setattr(self, name, new)
        self._lo, self._hi = 0, kept


@dataclass
class _Tally:
    """What was read from one part, to say how much when it ends early."""

    path: Path
    report: ReadReport = field(init=False)
    rows: int = 0
    first_index: int | None = None
    end_index: int = 0
    fs_hz: float = 0.0
    estimates: int = 0
    last_t_s: float | None = None

    def __post_init__(self) -> None:
        self.report = ReadReport(self.path)

    def add_batch(self, batch: SampleBatch) -> None:
        self.rows += len(batch)
        self.first_index = batch.first_index if self.first_index is None else self.first_index
        self.end_index = max(self.end_index, batch.end_index)
        self.fs_hz = batch.fs_hz

    def add_estimate(self, message: dict[str, Any]) -> None:
        self.estimates += 1
        self.last_t_s = message.get("t_end_s", self.last_t_s)

    def what_was_read(self) -> str:
        if self.first_index is not None and self.fs_hz > 0:
            t0, t1 = self.first_index / self.fs_hz, self.end_index / self.fs_hz
            return f"{self.rows} samples, {self.rows / self.fs_hz:.2f} s (t = {t0:.2f}–{t1:.2f} s)"
        if self.estimates:
            return f"{self.estimates} estimates (up to t = {self.last_t_s} s)"
        return "no samples or estimates"

    def warn_if_incomplete(self) -> None:
        """Say how much of the part was read when it ended before its footer."""
        if self.report.complete:
            return
        size = self.path.stat().st_size if self.path.exists() else 0
        warnings.warn(
            IncompleteRecordingWarning(
                f"{self.path} ends early, {self.report.error}; read {self.what_was_read()} "
                f"from the first {_kib(self.report.bytes_read)} of {_kib(size)}, up to its last "
                f"complete message ('rtsid recover {self.path}' rewrites that part as a "
                "complete file)"
            ),
            stacklevel=3,
        )


def _kib(n: int) -> str:
    return f"{n / 1024:.1f} KiB"


#: Rows of the blocks a whole-recording read decodes its samples into (replay, read_recording):
#: about 3 s at 2500 Hz, a dozen logged batches each.
BLOCK_ROWS = 1 << 13


def iter_batches(paths: Paths, *, block_rows: int = 0) -> Iterator[SampleBatch]:
    """Every ``/samples`` batch of the recording, in file order, part after part.

    Parameters
    ----------
    paths : path or sequence of paths
        One file, or the parts of a session in order (see :func:`session_parts`).
    block_rows : int
        0: the batches as logged; else consecutive batches joined into blocks of up to this
        many rows (e.g. :data:`BLOCK_ROWS`), decoded in place
        (:func:`rtsid.io.mcap_read.iter_sample_batches`): the same rows, fewer steps.

    Yields
    ------
    SampleBatch
        As logged; a jump of ``first_index`` is a gap (:class:`SampleGrid` makes it invalid rows).

    Warns
    -----
    IncompleteRecordingWarning
        A part ended before its footer (after its last complete message was yielded).

    Raises
    ------
    RecordingError
        A part is missing, empty or not MCAP.
    """
    for part in _as_list(paths):
        tally = _Tally(part)
        for batch in iter_sample_batches(part, tally.report, block_rows=block_rows):
            tally.add_batch(batch)
            yield batch
        tally.warn_if_incomplete()


def read_estimates(paths: Paths) -> list[dict[str, Any]]:
    """The ``/estimate`` messages of every part, in file order (warns like :func:`iter_batches`)."""
    estimates: list[dict[str, Any]] = []
    for part in _as_list(paths):
        tally = _Tally(part)
        for estimate in iter_estimates(part, tally.report):
            tally.add_estimate(estimate)
            estimates.append(estimate)
        tally.warn_if_incomplete()
    return estimates


@dataclass(frozen=True)
class Recording:
    """A whole recording on one grid.

    Attributes
    ----------
    samples : SampleGrid
        Every row from the first to the last sample read, gaps as invalid rows.
    config : dict
        The run configuration stored in the first part (``{}`` when none).
    parts : list of Path
        The files read, in order.
    """

    samples: SampleGrid
    config: dict[str, Any]
    parts: list[Path]


def read_recording(paths: Paths) -> Recording:
    """Read every sample of a recording (all parts of its session) onto one grid.

    Parameters
    ----------
    paths : path or sequence of paths
        Any part of a session, or several files; :func:`session_parts` completes the list.

    Warns
    -----
    IncompleteRecordingWarning
        A part ended before its footer.

    Raises
    ------
    RecordingError
        Missing, empty or non-MCAP file, or no ``/samples`` messages at all.
    """
    parts = session_parts(paths)
    grid: SampleGrid | None = None
    for batch in iter_batches(parts, block_rows=BLOCK_ROWS):
        if grid is None:
            grid = SampleGrid(batch.first_index, batch.fs_hz, capacity=1 << 16)
        grid.append(batch)
    if grid is None:
        raise RecordingError(
            f"{str(parts[0])!r} has no /samples messages, so no samples to read; give a "
            "recording made by 'rtsid run' or 'rtsid convert'"
        )
    return Recording(grid, read_run_config(parts[0]), parts)


@dataclass(frozen=True)
class SessionRecord:
    """Who was measured, under which conditions, and the trial markers of a recording.

    Attributes
    ----------
    metadata : list of dict
        The ``rtsid.session`` metadata record of each part, in part order (string values:
        subject, session, condition — the one at the part's start —, robot, joint,
        started_utc, rtsid_version); ``{}`` for a part without one (older recordings).
    sessions : list of dict
        The ``/session`` messages (SESSION_SCHEMA: robot, joint, t_s, sample_index, subject,
        session, condition, host_time_ns), each state once (every part repeats the newest at
        its start), by sample index: the first is the run's start, each next one a change of
        condition.
    markers : list of dict
        The ``/marker`` messages (MARKER_SCHEMA: robot, joint, t_s, sample_index, label,
        source, marker_id, host_time_ns), each ``marker_id`` once (a resent marker is
        recorded again after a daemon restart), by sample index.
    parts : list of Path
        The files read, in order.
    """

    metadata: list[dict[str, str]]
    sessions: list[dict[str, Any]]
    markers: list[dict[str, Any]]
    parts: list[Path]

    @property
    def subject(self) -> str:
        """The subject (from the first part that names one; ``""`` when none)."""
        return next((m["subject"] for m in self.metadata if m.get("subject")), "")

    @property
    def session(self) -> str:
        """The session (from the first part that names one; ``""`` when none)."""
        return next((m["session"] for m in self.metadata if m.get("session")), "")

    def condition_at(self, sample_index: int) -> str:
        """The condition in force at ``sample_index`` (``""`` before any is known)."""
        condition = ""
        for message in self.sessions:
            if message["sample_index"] > sample_index:
                break
            condition = message["condition"]
        return condition


def read_session(paths: Paths) -> SessionRecord:
    """The session metadata, condition changes and markers of a recording (all parts of its
    session, like :func:`read_recording`; a truncated part warns the same way).

    Parameters
    ----------
    paths : path or sequence of paths
        Any part of a session, or several files.

    Returns
    -------
    SessionRecord

    Raises
    ------
    RecordingError
        Missing, empty or non-MCAP file.
    """
    return session_record(read_messages(session_parts(paths), SESSION_TOPICS))


#: The topics a :class:`SessionRecord` is made from.
SESSION_TOPICS = (TOPICS["session"], TOPICS["marker"])


def session_record(read: RecordedMessages) -> SessionRecord:
    """The :class:`SessionRecord` of messages already read (topics :data:`SESSION_TOPICS`
    among them): each session state once, each ``marker_id`` once, by sample index."""
    sessions: dict[tuple[Any, ...], dict[str, Any]] = {}
    for message in read.messages[TOPICS["session"]]:
        state = tuple(message.get(k) for k in ("sample_index", "subject", "session", "condition"))
        sessions.setdefault(state, message)
    markers: dict[str, dict[str, Any]] = {}
    for message in read.messages[TOPICS["marker"]]:
        markers.setdefault(str(message.get("marker_id")), message)
    return SessionRecord(
        metadata=[records.get("rtsid.session", {}) for records in read.metadata],
        sessions=sorted(sessions.values(), key=_by_sample),
        markers=sorted(markers.values(), key=_by_sample),
        parts=list(read.parts),
    )


def _by_sample(message: dict[str, Any]) -> tuple[int, int]:
    index, stamp = message.get("sample_index"), message.get("host_time_ns")
    return (
        int(index) if isinstance(index, int) else 0,
        int(stamp) if isinstance(stamp, int) else 0,
    )


def _as_list(paths: Paths) -> list[Path]:
    return [Path(paths)] if isinstance(paths, str | Path) else [Path(p) for p in paths]


@dataclass(frozen=True)
class RecordedMessages:
    """The JSON messages of chosen topics of a whole recording, with each part's metadata.

    Attributes
    ----------
    parts : list of Path
        The files read, in order.
    messages : dict[str, list[dict]]
        Each topic's messages, part after part in file order.
    metadata : list of dict
        Each part's metadata records by name (``rtsid``, ``config``, …), in the parts' order.
    complete : bool
        Every part was read to its footer.
    """

    parts: list[Path]
    messages: dict[str, list[dict[str, Any]]]
    metadata: list[dict[str, dict[str, str]]]
    complete: bool


def read_messages(paths: Paths, topics: Sequence[str]) -> RecordedMessages:
    """The messages of ``topics`` from every part of a recording, one pass per part (warns
    like :func:`iter_batches` for a part that ends early; ``rtsid summary`` reads this way).

    Raises
    ------
    RecordingError
        A part is missing, empty or not MCAP, or a message is not a JSON object.
    """
    parts = _as_list(paths)
    messages: dict[str, list[dict[str, Any]]] = {t: [] for t in topics}
    metadata: list[dict[str, dict[str, str]]] = []
    complete = True
    for part in parts:
        tally = _Tally(part)
        if holds_topics(part, topics):
            found, meta = read_json_topics(part, topics, tally.report)
        else:  # a finished part whose statistics say it holds none of them
            found, meta = {t: [] for t in topics}, read_metadata(part)
            tally.report.complete = True
        for message in found.get("/estimate", []):
            tally.add_estimate(message)
        for topic in topics:
            messages[topic] += found[topic]
        metadata.append(meta)
        complete = complete and tally.report.complete
        tally.warn_if_incomplete()
    return RecordedMessages(parts, messages, metadata, complete)


@dataclass(frozen=True)
class RecordedTable:
    """A recording's summary table (:mod:`rtsid.io.summary_table`) and what goes with it.

    Attributes
    ----------
    table : SummaryTable
        The parts' tables joined, rows in part order.
    read : RecordedMessages
        Its ``/session`` and ``/marker`` messages (those of the table), each part's metadata
        records, the parts and whether every one was complete (for :func:`session_record`).
    from_attachments : bool
        Every part carried a consistent table (read without decoding a message); False: the
        messages were read and the table made from them.
    """

    table: SummaryTable
    read: RecordedMessages
    from_attachments: bool


def read_table(paths: Paths, *, from_messages: bool = False) -> RecordedTable:
    """A recording's summary table: from its parts' table attachments when every part has a
    consistent one (:func:`rtsid.io.mcap_read.read_summary_table`), else from its messages
    (one pass per part, warning like :func:`read_messages` for a part that ends early) — the
    same table either way.

    Parameters
    ----------
    paths : path or sequence of paths
        The parts of one recording, in order.
    from_messages : bool
        Read the messages even when the attachments are there (the reference path).

    Raises
    ------
    RecordingError
        As :func:`read_messages`.
    """
    from rtsid.io.summary_table import KINDS, SummaryTable, TableBuilder  # rtsid summary's

    parts = _as_list(paths)
    found = [] if from_messages else [read_summary_table(p) for p in parts]
    topics = [TOPICS["session"], TOPICS["marker"]]
    if found and all(f is not None for f in found):
        tables = [f[0] for f in found if f is not None]
        table = SummaryTable.concatenate(tables)
        messages = {TOPICS["session"]: table.sessions, TOPICS["marker"]: table.markers}
        metadata = [f[1] for f in found if f is not None]
        return RecordedTable(table, RecordedMessages(parts, messages, metadata, True), True)
    read = read_messages(parts, [TOPICS[k] for k in KINDS])
    builder = TableBuilder()
    for kind in KINDS:
        for message in read.messages[TOPICS[kind]]:
            builder.add(kind, message)
        if TOPICS[kind] not in topics:
            read.messages[TOPICS[kind]].clear()  # a study holds millions of windows
    return RecordedTable(builder.table(), read, False)
