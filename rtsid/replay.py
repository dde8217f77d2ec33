"""Replay recordings through the same window worker as the live daemon.

The live worker estimates windows that end on a fixed grid of sample indices, so replaying a
recording's samples with the recording's own configuration gives the same windows and the
same numbers. Replay is a plain iterator (:func:`iter_windows` over sample batches);
pacing in real time is a separate wrapper (:func:`paced`). Gaps in a recording — lost samples
logged as invalid rows, or batches the logger dropped — are respected: windows across them
are withheld with reason ``"gap"``, never bridged. Recordings are read with the one recording
reader (:mod:`rtsid.io.recording`): the parts of a rotated session replay as one, and a file
cut short replays to its last complete message with a warning saying how much was read.
"""

from __future__ import annotations

import bisect
import math
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from rtsid import __version__
from rtsid.errors import RecordingError, RtsidWarning
from rtsid.ident.records import built
from rtsid.ident.reflex_lane import ReflexModels, SlowLaneSettings, fit_reflex_update
from rtsid.io.calibration import robot_calibration, with_recorded_calibration
from rtsid.io.mcap_read import (
    TOPICS,
    holds_topics,
    iter_estimates,
    read_metadata,
    run_config_from_metadata,
    sample_count,
)
from rtsid.io.recording import (
    BLOCK_ROWS,
    SESSION_TOPICS,
    GridColumns,
    RecordedMessages,
    SampleGrid,
    SessionRecord,
    iter_batches,
    read_messages,
    session_parts,
    session_record,
)
from rtsid.io.schemas import SCHEMAS, SampleBatch, encode_json, estimate_payload
from rtsid.runtime.daemon_config import DaemonConfig
from rtsid.runtime.worker import WindowEvaluator
from rtsid.verdicts import Reason

if TYPE_CHECKING:
    from rtsid.link.ring import Snapshot

__all__ = [
    "LiveDecisions",
    "ReplayResult",
    "WindowCutter",
    "is_announcement",
    "iter_windows",
    "paced",
    "recorded_evaluator",
    "recording_config",
    "replay_batches",
    "replay_file",
    "write_estimates_mcap",
]


def recording_config(path: str | Path) -> DaemonConfig:
    """The configuration a recording was made with (defaults where it has none; a recording
    whose configuration has no ``[slow_lane]`` ran without one), with the robot calibration
    the recording carries
    (:func:`rtsid.io.calibration.with_recorded_calibration`)."""
    metadata = read_metadata(path)
    document = run_config_from_metadata(metadata)
    if not document:
        return DaemonConfig(slow_lane=SlowLaneSettings(enabled=False))
    # a recording made before the slow lane existed (or was on by default) ran without it
    document.setdefault("slow_lane", {"enabled": False})
    # a replay reads samples, not frames: the wire protocol (whose DBC may not be on this
    # machine) does not matter to it
    link = document.get("link")
    if isinstance(link, dict):
        document["link"] = {k: v for k, v in link.items() if k != "protocol"}
    return DaemonConfig.from_mapping(
        with_recorded_calibration(document, metadata.get("calibration"))
    )


def is_announcement(message: Mapping[str, Any]) -> bool:
    """A live ``stale`` message that only announced a due window's samples had not come
    (no latency: nothing was evaluated), as opposed to the window's own evaluation."""
    return message.get("reason") == Reason.STALE and message.get("latency_ms") is None


@dataclass(frozen=True)
class LiveDecisions:
    """What the live run decided that its samples alone do not say, read from its estimates:
    which windows it estimated (a worker that fell behind skipped some, and the held I/B
    medians and the tracker only saw the rest) and which reflex model each one used (a late
    slow lane leaves a window on an older one). A replay that follows them reproduces the live
    numbers even then.
    """

    first_end: int
    last_end: int
    reflex: dict[int, tuple[int | None, bool, bool]]  # end -> (reflex_seq, absent, stale)
    stale: frozenset[int] = frozenset()  # windows evaluated live with samples too old

    def skipped(self, window_end: int) -> bool:
        """The live worker never evaluated this window: one before the live run's last
        estimate that it has no estimate of, those before its first included (a worker that
        starts late begins at the newest window, the earlier ones being history)."""
        return window_end <= self.last_end and window_end not in self.reflex

    def oldest_reflex_from(self, window_end: int) -> int | None:
        """The oldest reflex model (fit ``seq``) a live window ending at or after
        ``window_end`` used (None: none did). A live slow lane that fell behind left windows
        on a model many fits older than the schedule's: the replay keeps it until then."""
        ends, oldest = self._reflex_floor
        at = bisect.bisect_left(ends, window_end)
        return oldest[at] if at < len(ends) else None

    @cached_property
    def _reflex_floor(self) -> tuple[list[int], list[int]]:
        """The ends of the live windows that used a reflex model, in order, and the oldest
        model used at or after each."""
        used = sorted((end, seq) for end, (seq, _, _) in self.reflex.items() if seq is not None)
        oldest: list[int] = []
        for _, seq in reversed(used):
            oldest.append(min(seq, oldest[-1]) if oldest else seq)
        return [end for end, _ in used], oldest[::-1]

    @classmethod
    def of(cls, parts: Iterable[Path]) -> LiveDecisions | None:
        """From the recording's ``/estimate`` messages (None when it has none).

        A ``stale`` message without a latency only announced that the due window's samples
        had not come (``WindowEvaluator.publish_stale``): the window was evaluated later, or
        skipped when the worker caught up. One with a latency is the window's evaluation,
        withheld because its samples were too old when it ran."""
        estimates = (
            m
            for part in parts
            # a finished part without estimates (a converted recording) is not read
            if holds_topics(part, (TOPICS["estimate"],))
            for m in iter_estimates(part)
        )
        return cls.from_estimates(estimates)

    @classmethod
    def from_estimates(cls, messages: Iterable[Mapping[str, Any]]) -> LiveDecisions | None:
        """From ``/estimate`` messages already read, in file order (as :meth:`of`)."""
        reflex: dict[int, tuple[int | None, bool, bool]] = {}
        stale: set[int] = set()
        for m in messages:
            if is_announcement(m):
                continue
            end = int(m["window_end_index"])
            if m.get("reason") == Reason.STALE:
                stale.add(end)
            flags = set(m.get("flags") or ())
            absent, late = "reflex_absent" in flags, "reflex_stale" in flags
            reflex[end] = (m.get("reflex_seq"), absent, late)
        if not reflex:
            return None
        return cls(min(reflex), max(reflex), reflex, frozenset(stale))


def iter_windows(
    batches: Iterable[SampleBatch],
    evaluator: WindowEvaluator,
    slow_lane: ReplayedSlowLane | None = None,
    live: LiveDecisions | None = None,
) -> Iterator[Snapshot]:
    """Every grid window the batches complete, oldest first (the live daemon's windows), with
    the evaluator's history rows before each (never before the recording's first sample).

    Rows go onto a :class:`~rtsid.io.recording.SampleGrid` (gaps as invalid rows) that keeps
    only what the next windows (and the slow lane's next fit) need, so a long recording
    replays in bounded memory. A slow lane runs its fits in line, each when its first window
    is due: the same samples, so the same models, as live. With ``live``, the windows the live
    worker skipped are skipped here too.
    """
    cutter = WindowCutter(evaluator, slow_lane, live)
    for batch in batches:
        yield from cutter.add(batch)


class WindowCutter:
    """The grid windows of samples that arrive in batches: :func:`iter_windows` one batch at a
    time (for a caller that pushes samples as they come, :class:`rtsid.identifier.Identifier`).
    """

    def __init__(
        self,
        evaluator: WindowEvaluator,
        slow_lane: ReplayedSlowLane | None = None,
        live: LiveDecisions | None = None,
    ) -> None:
        self.evaluator = evaluator
        self.slow_lane = slow_lane
        self.live = live
        self.reach = evaluator.window_samples + evaluator.history_samples
        self.grid: SampleGrid | None = None
        self.first = self.next_end = 0
        self._times: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # rows -> host, bus times
        # sample indices from _index_first on (read-only): each window's are a view of them
        self._index = np.empty(0, dtype=np.int64)
        self._index_first = 0

    def add(self, batch: SampleBatch) -> Iterator[Snapshot]:
        """The windows ``batch`` completes (it follows the previous batch on the grid)."""
        snapshot = self._snapshot
        for columns, start, stop in self.spans(batch):
            yield snapshot(columns, start, stop)

    def spans(self, batch: SampleBatch) -> Iterator[tuple[GridColumns, int, int]]:
        """:meth:`add` without the snapshots: each window ``batch`` completes as the grid's
        ``columns`` (valid until the next batch) and its samples ``start .. stop − 1``
        (history included), what :meth:`WindowEvaluator.evaluate_rows` takes."""
        grid = self.grid
        if grid is None:
            grid = self.grid = SampleGrid(batch.first_index, batch.fs_hz, capacity=8 * self.reach)
            self.first = grid.first_index
            self.next_end = self.evaluator.first_window_end(self.first)
        grid.append(batch)
        # what every window of the batch shares, read once (the grid only grows after the
        # cutting: end_index holds while the windows are cut)
        end_index, hop, reach, first = (
            grid.end_index,
            self.evaluator.hop_samples,
            self.reach,
            self.first,
        )
        slow_lane, live = self.slow_lane, self.live
        columns = grid.buffers()  # the grid's columns, row 0 at sample columns[-1]
        ends = range(self.next_end, end_index, hop)
        # the one window end of the block at which the slow lane's next fit is due (a fit
        # every few seconds: no per-window call before it)
        fit_at = slow_lane.next_fit_end(first, ends) if slow_lane is not None else None
        for end in ends:
            if end == fit_at:
                assert slow_lane is not None
                slow_lane.catch_up(grid, first, end)
                fit_at = slow_lane.next_fit_end(first, range(end + hop, end_index, hop))
            if live is None or not live.skipped(end):
                yield columns, max(end - reach + 1, first), end + 1
            self.next_end = end + hop
        keep = self.next_end - self.reach + 1
        if self.slow_lane is not None:
            keep = min(keep, self.slow_lane.oldest_needed(self.first))
        grid.drop_before(keep)

    def _snapshot(self, columns: GridColumns, start: int, stop: int) -> Snapshot:
        """Rows ``start .. stop − 1`` of the grid's ``columns`` as the ring's snapshot (views):
        recorded samples have no host or bus times (zeros and NaN, read-only columns shared
        by every window of the same length)."""
        from rtsid.link.ring import Snapshot  # here: replay_file evaluates rows, no snapshot

        n = stop - start
        times = self._times.get(n)
        if times is None:
            times = self._times[n] = (_read_only(np.zeros(n)), _read_only(np.full(n, np.nan)))
        position, torque, valid, status, base = columns
        rows = slice(start - base, stop - base)
        return built(  # the constructor's record without its frozen __init__ (once a hop)
            Snapshot,
            sample_index=self._sample_index(start, stop),
            position_rad=position[rows],
            torque_nm=torque[rows],
            valid=valid[rows],
            status=status[rows],
            host_time_s=times[0],
            bus_time_s=times[1],
            overwritten=0,
        )

    def _sample_index(self, start: int, stop: int) -> np.ndarray:
        """``np.arange(start, stop)`` as a read-only view of one range laid out for the next
        windows too (a window's 19 k instructions of filling once per ~250 windows)."""
        lo = start - self._index_first
        if lo < 0 or stop - self._index_first > self._index.size:
            self._index_first, lo = start, 0
            self._index = _read_only(
                np.arange(start, start + 16 * max(self.reach, stop - start), dtype=np.int64)
            )
        return self._index[lo : lo + stop - start]


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


class ReplayedSlowLane:
    """The slow lane of a replay: its fits run in line, on the live schedule.

    Parameters
    ----------
    evaluator : WindowEvaluator
        The replay's evaluator (its reflex models are filled; its torque conversion is used).
    publish : callable
        Called with each fit's message (REFLEX_SCHEMA dict).
    live : LiveDecisions, optional
        The live run's decisions: every fit a live window used is kept until that window (a
        live slow lane that fell behind used fits the schedule has long replaced).
    """

    def __init__(
        self,
        evaluator: WindowEvaluator,
        publish: Callable[[dict[str, Any]], None],
        live: LiveDecisions | None = None,
    ) -> None:
        if evaluator.reflex is None:
            raise ValueError("the evaluator has no reflex models (slow lane off)")
        self.evaluator = evaluator
        self.models = evaluator.reflex
        self.publish = publish
        self.live = live
        self._next: int | None = None
        self.fit_cpu_s = 0.0  # CPU time of the fits so far, s

    def oldest_needed(self, first: int) -> int:
        """The first sample the next fit uses."""
        span = self.models.fit_span(self._next_seq(first), first)
        return span[0] if span is not None else first

    def _next_seq(self, first: int) -> int:
        if self._next is None:
            self._next = self.models.first_seq(first)
        return self._next

    def next_fit_end(self, first: int, ends: range) -> int | None:
        """The first of the window ``ends`` by which a fit is due that has not run (None:
        none; the schedule's due fit only grows with the window end, so a bisection finds
        it): :meth:`catch_up` does nothing at the ends before it."""
        seq, due_seq = self._next_seq(first), self.models.due_seq
        at = bisect.bisect_left(ends, True, key=lambda end: due_seq(end) >= seq)
        return ends[at] if at < len(ends) else None

    def catch_up(self, grid: SampleGrid, first: int, window_end: int) -> None:
        """Run every fit due by the window ending at ``window_end``."""
        due = self.models.due_seq(window_end)
        keep_from = self.live.oldest_reflex_from(window_end) if self.live is not None else None
        while (seq := self._next_seq(first)) <= due:
            span = self.models.fit_span(seq, first)
            assert span is not None  # first_seq leaves enough data
            started_cpu = time.thread_time()
            rows = grid.rows(*span)
            update = fit_reflex_update(
                seq,
                span[0],
                rows.position_rad,
                self.evaluator.model_torque(rows.position_rad, rows.torque_nm),
                None if rows.valid.all() else rows.valid,
                grid.fs_hz,
                self.models.settings,
            )
            self.models.add(update, keep_from)
            self.fit_cpu_s += time.thread_time() - started_cpu
            self.publish(self.evaluator.reflex_message(update, None))
            self._next = seq + 1


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
    parts: list[Path] = field(default_factory=list)
    messages: list[dict[str, Any]] = field(default_factory=list)
    reflex: list[dict[str, Any]] = field(default_factory=list)
    #: The recording's /marker messages (each marker_id once) and /session messages, carried
    #: through to the replay's MCAP output (:func:`rtsid.io.recording.read_session`).
    markers: list[dict[str, Any]] = field(default_factory=list)
    sessions: list[dict[str, Any]] = field(default_factory=list)
    #: The first part's ``rtsid.session`` metadata ({} for older recordings).
    session_metadata: dict[str, str] = field(default_factory=dict)
    samples: int = 0
    duration_s: float = 0.0
    elapsed_s: float = 0.0
    #: The evaluator's compute over every window, summed: wall time and CPU time, s.
    compute_s: float = 0.0
    compute_cpu_s: float = 0.0
    #: CPU time of the slow lane's fits (run in line), s.
    fit_cpu_s: float = 0.0

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
        An rtsid MCAP recording (footer-less or truncated ones too); given any part of a
        rotated session, every part is replayed, in order, as one recording.
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

    Warns
    -----
    IncompleteRecordingWarning
        A part ended early (see :mod:`rtsid.io.recording`); its complete messages are replayed.
    """
    parts = session_parts(path)
    # a re-analysis (config given) decides anew: it reads no live decisions
    recorded = _RecordedRun.read(parts, follow_live=config is None)
    live = recorded.live
    config = config or recording_config(parts[0])
    result = ReplayResult(source=str(path), parts=parts)
    total = sum(sample_count(p) for p in parts) if progress is not None else 0
    # as fast as possible: the samples in blocks (fewer steps); paced: as logged (its steps)
    blocks = BLOCK_ROWS if rate is None else 0
    batches: Iterable[SampleBatch] = _counted(
        iter_batches(parts, block_rows=blocks), result, progress, total
    )
    if rate is not None:
        batches = paced(batches, rate)
    replay_batches(batches, config, result, publish=publish, live=live)
    if result.samples == 0:
        raise RecordingError(f"{path}: no samples to replay (is it an rtsid recording?)")
    session, lost = recorded.session, recorded.lost
    if any(lost):
        warnings.warn(
            f"{path}: the live run's logger lost {lost[0]} samples, {lost[1]} sample batches "
            f"and {lost[2]} estimates (status acquisition.logger_overwritten, "
            "mcap.dropped_by_kind): the replay cannot follow live across them (windows "
            "without samples are gaps), and numbers after them can differ from the live ones",
            RtsidWarning,
            stacklevel=2,
        )
    result.markers, result.sessions = session.markers, session.sessions
    result.session_metadata = next((m for m in session.metadata if m), {})
    return result


@dataclass(frozen=True)
class _RecordedRun:
    """What a replay takes from a recording besides its samples, read in one pass per part
    (the live run's estimates, its last status, the session and markers) before the samples
    are: three passes each decompressing every chunk of the file, before."""

    live: LiveDecisions | None
    session: SessionRecord
    lost: tuple[int, int, int]  # (0, 0, 0) unless following the live run

    @classmethod
    def read(cls, parts: list[Path], *, follow_live: bool) -> _RecordedRun:
        """Read ``parts`` (a part ending early warns when its samples are read, not here)."""
        live_topics = (TOPICS["estimate"], TOPICS["status"]) if follow_live else ()
        topics = (*SESSION_TOPICS, *live_topics)
        with warnings.catch_warnings():  # said once, by the samples' pass
            warnings.simplefilter("ignore", RtsidWarning)
            each = [read_messages([part], topics) for part in parts]
        joined = RecordedMessages(
            parts,
            {t: [m for read in each for m in read.messages[t]] for t in topics},
            [read.metadata[0] for read in each],
            all(read.complete for read in each),
        )
        if not follow_live:
            return cls(None, session_record(joined), (0, 0, 0))
        live = LiveDecisions.from_estimates(joined.messages[TOPICS["estimate"]])
        statuses = each[-1].messages[TOPICS["status"]]
        return cls(live, session_record(joined), _what_the_logger_lost(statuses))


def _what_the_logger_lost(statuses: list[dict[str, Any]]) -> tuple[int, int, int]:
    """What the live run had that its recording lacks, by the last part's last status:
    samples the ring overwrote before the logger read them, and the sample batches and
    estimates the writer's queue dropped ((0, 0, 0) when the part has no status)."""
    last: Mapping[str, Any] = statuses[-1] if statuses else {}
    overwritten = (last.get("acquisition") or {}).get("logger_overwritten") or 0
    dropped = (last.get("mcap") or {}).get("dropped_by_kind") or {}
    return int(overwritten), int(dropped.get("samples") or 0), int(dropped.get("estimate") or 0)


def replay_batches(
    batches: Iterable[SampleBatch],
    config: DaemonConfig,
    result: ReplayResult,
    *,
    publish: Callable[[dict[str, Any]], object] | None = None,
    evaluated: Callable[[WindowEvaluator], None] | None = None,
    live: LiveDecisions | None = None,
) -> ReplayResult:
    """Run the live daemon's window worker (and slow lane) over batches of samples.

    Parameters
    ----------
    batches : iterable of SampleBatch
        Samples in order (from a recording, or arrays wrapped as one batch).
    config : DaemonConfig
        The settings, as the daemon takes them.
    result : ReplayResult
        Filled in: messages, reflex fits, samples, duration, elapsed time.
    publish : callable, optional
        Also called with every estimate message.
    evaluated : callable, optional
        Called with the evaluator after each window (e.g. to read ``last_reflex``).
    live : LiveDecisions, optional
        Follow the live run's skipped windows and reflex models.
    """

    def sink(message: dict[str, Any]) -> None:
        result.messages.append(message)
        if publish is not None:
            publish(message)

    # without a publisher, each message only goes into the result: no call in between
    evaluator = recorded_evaluator(config, sink if publish is not None else result.messages.append)
    slow_lane = (
        ReplayedSlowLane(evaluator, result.reflex.append, live) if evaluator.reflex else None
    )
    if live is not None:
        evaluator.recorded_reflex = live.reflex
        evaluator.recorded_stale = live.stale
    started = time.perf_counter()
    cutter, evaluate = WindowCutter(evaluator, slow_lane, live), evaluator.evaluate_rows
    for batch in batches:  # a block's windows in one loop, each rows of the grid's columns
        for columns, start, stop in cutter.spans(batch):
            evaluate(columns, start, stop)
            if evaluated is not None:
                evaluated(evaluator)
    result.elapsed_s = time.perf_counter() - started
    result.duration_s = result.samples / config.link.fs_hz
    result.compute_s, result.compute_cpu_s = evaluator.compute_s, evaluator.compute_cpu_s
    result.fit_cpu_s = slow_lane.fit_cpu_s if slow_lane is not None else 0.0
    return result


def recorded_evaluator(
    config: DaemonConfig, publish: Callable[[dict[str, Any]], None]
) -> WindowEvaluator:
    """The live daemon's window evaluator for recorded samples (never stale, no latency),
    with the slow lane's reflex models when it is enabled."""
    fs = config.link.fs_hz
    return WindowEvaluator(
        fs,
        config.worker,
        config.estimator,
        publish,
        robot=config.zenoh.robot,
        joint=config.zenoh.joint,
        calibration=robot_calibration(config.worker.calibration_file, fs),
        live=False,
        reflex=ReflexModels(fs, config.slow_lane) if config.slow_lane.enabled else None,
        tracker=config.tracker,
    )


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


def write_estimates_mcap(
    messages: Iterable[dict[str, Any]],
    fh: IO[bytes],
    *,
    source: str,
    config: DaemonConfig,
    reflex: Iterable[dict[str, Any]] = (),
    markers: Iterable[dict[str, Any]] = (),
    sessions: Iterable[dict[str, Any]] = (),
    session_metadata: Mapping[str, str] | None = None,
) -> int:
    """Estimate messages (and the slow lane's fits, on ``/reflex``) as an MCAP file with the
    daemon's layout; returns the number of estimates written. The source's markers
    (``/marker``), session changes (``/session``) and ``rtsid.session`` metadata are carried
    through, each at its sample time."""
    from mcap.writer import CompressionType, Writer

    from rtsid.io.summary_table import TableBuilder, attach_table  # here: only -o X.mcap

    writer = Writer(fh, compression=CompressionType.ZSTD)
    writer.start(profile="", library=f"rtsid {__version__}")
    channels = {}
    for kind in ("estimate", "reflex", "session", "marker"):
        schema, topic = SCHEMAS[kind]
        schema_id = writer.register_schema(
            name=schema["title"], encoding="jsonschema", data=encode_json(schema)
        )
        channels[kind] = writer.register_channel(
            topic=topic, message_encoding="json", schema_id=schema_id
        )
    writer.add_metadata("rtsid", {"software": "rtsid", "version": __version__, "replay_of": source})
    writer.add_metadata("config", {"json": encode_json(config.as_dict()).decode()})
    if session_metadata:
        writer.add_metadata("rtsid.session", dict(session_metadata))
    table = TableBuilder()  # rtsid summary reads it instead of the messages, as the logger's

    def put(kind: str, t_s: float, data: bytes, seq: int) -> None:
        _add_message(writer, channels[kind], t_s, data, seq)
        table.add_payload(kind, data)

    for kind, carried in (("session", sessions), ("marker", markers)):
        for k, message in enumerate(carried):
            put(kind, message["t_s"], encode_json(message), k)
    fs = config.link.fs_hz
    for fit in reflex:  # logged at the sample time from which it applies
        put("reflex", fit["applies_from_index"] / fs, encode_json(fit), fit["seq"])
    estimates, count = channels["estimate"], 0
    rows: list[Mapping[str, Any]] = []  # the summary table's, added together
    for message in messages:
        data, plain = estimate_payload(message)
        _add_message(writer, estimates, message["t_end_s"], data, message["seq"])
        count += 1
        if plain:  # the payload decodes to the message's values: no json.loads of it
            rows.append(message)
        else:  # the table reads it as written (rows before it first: the table keeps order)
            table.add_estimates(rows)
            rows.clear()
            table.add_payload("estimate", data)
    table.add_estimates(rows)
    attach_table(writer, table)
    writer.finish()
    return count


def _add_message(writer: Any, channel: int, t_s: float, data: bytes, seq: int) -> None:
    """One message logged and published at sample time ``t_s``."""
    t = int(t_s * 1e9)
    writer.add_message(channel, log_time=t, publish_time=t, data=data, sequence=seq)
