"""MCAP logging on its own thread behind a bounded queue; the caller never blocks.

::

    caller threads ──log_samples / log_estimate / log_status / log_can_frames──►
        bounded queue (put_nowait; full → dropped, counted) ──► "rtsid-mcap" thread
        ──► mcap.Writer (zstd chunks) ──► recordings/rtsid-<robot>-<joint>-<UTC>[-NNN].mcap

- The writer thread keeps clear of the daemon's window worker: it writes in bursts that begin
  when the worker has just gone to sleep and pauses while a window computes (``wait_turn``,
  ``busy``), and it closes (compresses, writes) each full chunk itself in such a turn.
- Chunks are small (``chunk_size``) and the writer flushes every ``flush_interval_s``, so a
  process killed with SIGKILL loses at most about the flush interval plus one chunk; the file
  then lacks its footer and :func:`rtsid.io.mcap_read.recover` rewrites it as a valid one.
- Each file is self-contained (schemas, channels, ``rtsid`` and ``config`` metadata) and files
  rotate by size and by age.
- A write error (full disk, read-only or vanished directory) never reaches the caller: the file
  is closed, the error is counted and kept as ``last_error`` in :meth:`McapLogger.stats`,
  messages are counted as ``lost`` while there is no file, and a new file is tried every
  ``retry_interval_s``. A try that cannot write the new file's header (the disk is still full)
  removes the file it created, so a session never holds empty parts and replays whole.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import queue
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from contextlib import AbstractContextManager
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

import numpy as np

from rtsid import __version__
from rtsid.errors import InputDataError, RecordingError
from rtsid.io.mcap_config import McapConfig
from rtsid.io.schemas import (
    SCHEMAS,
    encode_can_frames,
    encode_estimate,
    encode_json,
    encode_samples,
    encode_status,
)
from rtsid.io.session import SessionConfig, recording_stem
from rtsid.io.summary_table import TableBuilder, attach_table
from rtsid.lifecycle import ThreadOwner

__all__ = ["McapConfig", "McapLogger", "channel_kinds", "recording_name", "register_channels"]

log = logging.getLogger("rtsid.io.mcap")

_KINDS = ("samples", "estimate", "status", "reflex", "can_frames", "session", "marker")
_STOP_POLL_S = 0.1
#: Bytes a message record adds to a chunk beyond its payload (opcode, length, channel id,
#: sequence, log and publish times): how the writer counts a chunk's size itself.
_RECORD_BYTES = 31
#: The mcap writer closes a chunk by itself only past this many times ``chunk_size``: the
#: logger closes it first, in a turn of its own (:meth:`McapLogger._close_full_chunk`).
_CHUNK_CEILING = 4


def _no_wait() -> None:
    """No one to wait for: write at once."""


def _never_busy() -> bool:
    """No window worker to keep clear of."""
    return False


def recording_name(
    robot: str,
    joint: str,
    start: datetime,
    part: int,
    session: SessionConfig | None = None,
) -> str:
    """File name of part ``part`` of a recording (part 0: no suffix).

    With a subject in ``session``: its ``recording_pattern`` filled in, e.g.
    ``S01_2_rig-ankle_20261126T184839Z[-NNN].mcap``; without:
    ``rtsid-<robot>-<joint>-<YYYYmmddTHHMMSSZ>[-NNN].mcap`` (see
    :func:`rtsid.io.session.recording_stem`).
    """
    suffix = f"-{part:03d}" if part else ""
    return f"{recording_stem(robot, joint, start, session)}{suffix}.mcap"


def channel_kinds(*, can_frames: bool = False) -> tuple[str, ...]:
    """The channels of an rtsid recording, by kind (keys of :data:`~rtsid.io.schemas.SCHEMAS`).

    Live views (``rtsid run --foxglove``) iterate over this list, so a channel added here
    appears in them too.
    """
    return tuple(k for k in _KINDS if can_frames or k != "can_frames")


def register_channels(writer: Any, *, can_frames: bool = False) -> dict[str, int]:
    """Register rtsid's schemas and channels on a started ``mcap.writer.Writer``.

    Every rtsid recording (the live logger's, and files written by ``rtsid convert``) has
    the same channels: ``/samples``, ``/estimate``, ``/status``, ``/reflex`` and optionally
    ``/can_frames``, JSON messages with JSON-schema schemas.

    Returns
    -------
    dict[str, int]
        Channel id by kind (``"samples"``, ``"estimate"``, ``"status"``, ``"reflex"``,
        ``"can_frames"``).
    """
    channels = {}
    for kind in channel_kinds(can_frames=can_frames):
        schema, topic = SCHEMAS[kind]
        schema_id = writer.register_schema(
            name=schema["title"], encoding="jsonschema", data=encode_json(schema)
        )
        channels[kind] = writer.register_channel(
            topic=topic, message_encoding="json", schema_id=schema_id
        )
    return channels


def _open_exclusive(path: Path) -> IO[bytes]:
    return open(path, "xb")


class _Counters:
    """Counters shared by caller threads and the writer thread (one lock, cheap)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.dropped = dict.fromkeys(_KINDS, 0)
        self.written = 0
        self.lost = 0
        self.errors = 0
        self.last_error: str | None = None
        self.files: list[str] = []
        self.file: str | None = None
        self.file_bytes = 0
        self.closed_bytes = 0
        self.state = "starting"


class McapLogger(ThreadOwner):
    """Write rtsid messages to MCAP from a dedicated thread (a context manager).

    A :class:`~rtsid.lifecycle.ThreadOwner`: ``start()``, ``stop(timeout_s)``, ``failure``.

    Parameters
    ----------
    config : McapConfig
        The ``[mcap]`` section.
    robot, joint : str
        Names for the file name and the ``rtsid`` metadata.
    fs_hz : float
        Sample rate of the logged samples, Hz.
    run_config : Mapping, optional
        The daemon's whole configuration, stored as JSON in the ``config`` metadata record.
    metadata : Mapping[str, str], optional
        Extra key/values for the ``rtsid`` metadata record.
    records : Mapping[str, Mapping[str, str]], optional
        Further metadata records written into every file (e.g. ``calibration``).
    open_file : callable, optional
        ``open_file(path) -> binary file``; tests inject failing files. Default: exclusive create.
    tap : callable, optional
        ``tap(kind, log_time_ns, payload_bytes)``, called on the writer thread with every
        message as it is written (a live view sees exactly the recording's messages, off the
        caller's thread). It must not block nor raise.
    session : SessionConfig, optional
        Subject, session and condition: they name the files (``recording_pattern``) and fill
        the ``rtsid.session`` metadata record of every part.
    session_message : Mapping, optional
        The first ``/session`` message (:class:`~rtsid.io.messages.SessionMessage` as a dict);
        every part starts with the newest one logged (:meth:`log_session`).

    Examples
    --------
    >>> with McapLogger(McapConfig(directory="rec"), robot="r1", joint="ankle", fs_hz=2500.0) as m:
    ...     m.log_samples(0, pos, tq)        # doctest: +SKIP
    ...     m.log_estimate(estimate_dict)    # doctest: +SKIP
    """

    def __init__(
        self,
        config: McapConfig,
        *,
        robot: str,
        joint: str,
        fs_hz: float,
        run_config: Mapping[str, Any] | None = None,
        metadata: Mapping[str, str] | None = None,
        records: Mapping[str, Mapping[str, str]] | None = None,
        open_file: Callable[[Path], IO[bytes]] = _open_exclusive,
        tap: Callable[[str, int, bytes], None] | None = None,
        session: SessionConfig | None = None,
        session_message: Mapping[str, Any] | None = None,
    ) -> None:
        if not fs_hz > 0:
            raise InputDataError(f"McapLogger fs_hz = {fs_hz!r}; expected the sample rate > 0 Hz")
        self.config = config
        self.robot = robot
        self.joint = joint
        self.fs_hz = float(fs_hz)
        self._run_config_json = encode_json(run_config or {}).decode()
        self._extra_metadata = {str(k): str(v) for k, v in (metadata or {}).items()}
        self._records = {name: dict(record) for name, record in (records or {}).items()}
        self._open_file = open_file
        self._tap = tap
        self.session = session or SessionConfig()
        # The newest /session message and its fields (writer thread after start()).
        self._session_now: tuple[bytes, dict[str, Any]] | None = None
        if session_message is not None:
            self._session_now = (encode_json(session_message), dict(session_message))
        super().__init__("rtsid-mcap")
        #: ``timed(name)`` wraps each write and flush of the writer thread (a context manager;
        #: the daemon sets its stall journal's ``step`` so that a deadline miss can be set
        #: against them; by default nothing is timed)
        self.timed: Callable[[str], AbstractContextManager[Any]] = contextlib.nullcontext
        #: ``wait_turn()`` waits, bounded, for a moment when the daemon's window worker has
        #: just gone to sleep, and ``busy()`` says a window is being computed (the daemon sets
        #: both from its :class:`~rtsid.runtime.gate.WindowGate`): the writer thread writes
        #: in bursts that begin in the worker's quiet part of the hop and pause while a window
        #: computes, so its serialising, compressing and writing never share the GIL or a core
        #: with a window it could make late. By default the writer never waits.
        self.wait_turn: Callable[[], object] = _no_wait
        self.busy: Callable[[], bool] = _never_busy
        self._chunk_bytes = 0  # bytes added to the open chunk (payloads and record heads)
        self._queue: queue.Queue[tuple[str, int, Any]] = queue.Queue(maxsize=config.queue_size)
        self._accepting = False
        self._require_file = False
        self._last_cause = ""
        self._c = _Counters()
        self._session_start = datetime.now(UTC)
        self._part = 0
        # Writer-thread state (touched only by the writer thread after start()).
        self._writer: Any = None
        self._stream: IO[bytes] | None = None
        self._channels: dict[str, int] = {}
        self._file_opened_at = 0.0
        self._retry_at = 0.0
        self._table: TableBuilder | None = None  # the current part's summary table
        if not config.enabled:
            self._c.state = "disabled"

    # ------------------------------------------------------------------ life cycle
    def start(self, *, require_file: bool = False) -> McapLogger:
        """Start the writer thread (idempotent).

        Parameters
        ----------
        require_file : bool
            Open the first file here and raise :class:`~rtsid.errors.RecordingError` if
            that fails (the daemon: a run that cannot be recorded must not start). False:
            the writer thread opens it, and failures are counted and retried.
        """
        if not self.config.enabled or self._thread is not None:
            return self
        self._require_file = require_file
        return super().start()

    def _before_start(self) -> None:
        if self._require_file:
            self._try_open()
            if self._writer is None:
                raise RecordingError(
                    f"cannot record: {self._last_cause}, or set mcap.enabled = false to run "
                    "without recording"
                )
        self._accepting = True

    def stop(self, timeout_s: float = 5.0) -> bool:
        """Stop accepting, write what is queued, finish the file (footer), join the thread.

        Parameters
        ----------
        timeout_s : float
            Upper bound on the wait, s.

        Returns
        -------
        bool
            True when the thread finished in time and cleanly (the file is then complete).
        """
        self._accepting = False
        return super().stop(timeout_s)

    def _after_stop(self, ended: bool) -> None:
        if not ended:
            log.error(
                "MCAP writer did not finish; the file may lack its footer "
                "(rtsid recover FILE rewrites it)"
            )

    # ------------------------------------------------------------------ caller side
    def log_samples(
        self,
        first_index: int,
        position_rad: Any,
        torque_nm: Any,
        valid: Any = None,
        status: Any = None,
        *,
        log_time_ns: int | None = None,
    ) -> bool:
        """Queue a batch of consecutive samples (copied; encoded on the writer thread).

        Parameters
        ----------
        first_index : int
            Sample index of row 0.
        position_rad, torque_nm : array_like, shape (n,)
            Values (rad, N·m); rows of lost samples may be NaN.
        valid : array_like of bool, shape (n,), optional
            False for lost/invalid rows (default: all valid).
        status : array_like of int, shape (n,), optional
            Per-sample status bits (default: zeros).
        log_time_ns : int, optional
            Host UNIX time for the MCAP log time (default: now).

        Returns
        -------
        bool
            True if queued; False if dropped (queue full, counted) or not recording.
        """
        pos = np.array(position_rad, dtype=np.float64)
        tq = np.array(torque_nm, dtype=np.float64)
        n = pos.shape[0] if pos.ndim == 1 else -1
        ok = np.ones(n, dtype=bool) if valid is None else np.array(valid, dtype=bool)
        st = np.zeros(n, dtype=np.int64) if status is None else np.array(status, dtype=np.int64)
        if pos.ndim != 1 or tq.shape != pos.shape or ok.shape != pos.shape or st.shape != pos.shape:
            raise InputDataError(
                f"log_samples needs 1-D arrays of one length; got position {pos.shape}, "
                f"torque {tq.shape}, valid {ok.shape}, status {st.shape}"
            )
        return self._put("samples", log_time_ns, (int(first_index), pos, tq, ok, st))

    def log_estimate(
        self, message: Mapping[str, Any] | bytes, *, log_time_ns: int | None = None
    ) -> bool:
        """Queue one estimate (a dict with :data:`~rtsid.io.schemas.ESTIMATE_FIELDS`, or the
        bytes of :func:`~rtsid.io.schemas.encode_estimate`). Log time defaults to its
        ``host_time_ns``."""
        if isinstance(message, bytes | bytearray):
            payload = bytes(message)
        else:
            payload = encode_estimate(message)
            if log_time_ns is None:
                log_time_ns = int(message["host_time_ns"])
        return self._put("estimate", log_time_ns, payload)

    def log_estimates(self, estimates: Sequence[tuple[bytes, int, Mapping[str, Any]]]) -> bool:
        """Queue encoded estimates as one item: one queue hand-over and one writer wake-up
        for a whole housekeeping tick's estimates (at a 4 ms hop, 25 every 0.1 s).

        Parameters
        ----------
        estimates : sequence of (bytes, int, Mapping)
            Each estimate's payload (:func:`~rtsid.io.schemas.encode_estimate`), log time
            (ns) and the message it encodes, which feeds the summary table instead of
            decoding the payload again (the same values: the payload is its encoding).

        Returns
        -------
        bool
            True if queued; False if dropped (queue full: every estimate counted) or not
            recording.
        """
        if not estimates:
            return True
        batch = list(estimates)
        return self._put("estimates", batch[0][1], batch, count=len(batch))

    def log_status(
        self, message: Mapping[str, Any] | bytes, *, log_time_ns: int | None = None
    ) -> bool:
        """Queue one status message (dict following STATUS_SCHEMA, or its encoded bytes)."""
        payload = message if isinstance(message, bytes) else encode_status(message)
        return self._put("status", log_time_ns, payload)

    def log_reflex(
        self, message: Mapping[str, Any] | bytes, *, log_time_ns: int | None = None
    ) -> bool:
        """Queue one slow-lane fit (dict following REFLEX_SCHEMA, or its JSON bytes)."""
        payload = message if isinstance(message, bytes) else encode_json(message)
        return self._put("reflex", log_time_ns, payload)

    def log_session(self, message: Mapping[str, Any], *, log_time_ns: int | None = None) -> bool:
        """Queue a ``/session`` message (a condition change); every later part starts with
        it, and its ``rtsid.session`` metadata names its condition."""
        fields = dict(message)
        return self._put("session", log_time_ns, (encode_json(fields), fields))

    def log_marker(
        self,
        message: Mapping[str, Any],
        *,
        log_time_ns: int | None = None,
        on_written: Callable[[bool], None] | None = None,
    ) -> bool:
        """Queue a ``/marker`` message.

        The writer thread writes it, closes the chunk and flushes the file at once (a marker
        written is in the file even if the process is killed right after: nothing of it waits
        for ``flush_interval_s``), then calls ``on_written(True)``; ``on_written(False)`` when
        there was no file to write it to. The daemon acknowledges ``rtsid mark`` from there.

        Returns
        -------
        bool
            True if queued (``on_written`` will be called, unless the writer thread dies);
            False if dropped (queue full, counted; or not recording): ``on_written`` is not
            called.
        """
        payload = encode_json(dict(message))
        if log_time_ns is None:
            log_time_ns = int(message["host_time_ns"])
        return self._put("marker", log_time_ns, (payload, on_written))

    def log_can_frames(self, frames: Iterable[Any], *, log_time_ns: int | None = None) -> bool:
        """Queue a batch of raw CAN frames (``can.Message``-like); ignored unless
        ``log_can_frames`` is on."""
        if not self.config.log_can_frames:
            return False
        return self._put("can_frames", log_time_ns, encode_can_frames(frames))

    def _put(self, kind: str, log_time_ns: int | None, payload: Any, count: int = 1) -> bool:
        if not self._accepting:
            return False
        t = time.time_ns() if log_time_ns is None else int(log_time_ns)
        try:
            self._queue.put_nowait((kind, t, payload))
        except queue.Full:
            with self._c.lock:
                self._c.dropped["estimate" if kind == "estimates" else kind] += count
            return False
        return True

    def stats(self) -> dict[str, Any]:
        """Counters for the status message (the ``mcap`` object of STATUS_SCHEMA).

        Returns
        -------
        dict
            ``state`` (disabled, starting, recording, error, stopped), ``file``, ``bytes`` (of
            the current file), ``total_bytes``, ``files``, ``written`` messages, ``dropped``
            (queue full, total) and ``dropped_by_kind``, ``lost`` (no file to write to),
            ``errors``, ``last_error``, ``queue_depth``.
        """
        c = self._c
        with c.lock:
            return {
                "state": c.state,
                "file": c.file,
                "bytes": c.file_bytes,
                "total_bytes": c.closed_bytes + c.file_bytes,
                "files": list(c.files),
                "written": c.written,
                "dropped": sum(c.dropped.values()),
                "dropped_by_kind": dict(c.dropped),
                "lost": c.lost,
                "errors": c.errors,
                "last_error": c.last_error,
                "queue_depth": self._queue.qsize(),
            }

    @property
    def channel_kinds(self) -> tuple[str, ...]:
        """The kinds of the channels this logger records (see :func:`channel_kinds`)."""
        return channel_kinds(can_frames=self.config.log_can_frames)

    @property
    def files(self) -> list[Path]:
        """Every file this logger has opened, oldest first."""
        with self._c.lock:
            return [Path(f) for f in self._c.files]

    # ------------------------------------------------------------------ writer thread
    def _run(self) -> None:
        try:
            self._loop()
        except BaseException:  # ThreadOwner keeps the error; leave no file open behind it
            stream, self._writer, self._stream = self._stream, None, None
            if stream is not None:
                try:
                    stream.close()  # without a footer: `rtsid recover` rewrites it
                except OSError:
                    pass
            raise

    def _loop(self) -> None:
        cfg = self.config
        if self._writer is None:  # not opened by start(require_file=True)
            self._try_open()
        next_flush = time.monotonic() + cfg.flush_interval_s
        while not self._stop.is_set():
            timeout = min(_STOP_POLL_S, max(0.0, next_flush - time.monotonic()))
            try:
                item = self._queue.get(timeout=timeout)
            except queue.Empty:
                item = None
            if item is not None:
                self.wait_turn()  # a burst begins as the worker goes to sleep
                self._write_burst(item, until_s=next_flush)
            now = time.monotonic()
            if now >= next_flush:
                self._take_turn_if_busy()
                with self.timed("mcap writer: flush"):
                    self._flush()
                next_flush += cfg.flush_interval_s
                if next_flush <= now:  # fell behind: next deadline from now, never a burst
                    next_flush = now + cfg.flush_interval_s
                self._maybe_rotate(now)
            if self._writer is None and now >= self._retry_at:
                self._try_open()
        self._drain()
        self._close_file(finish=True)
        with self._c.lock:
            self._c.state = "stopped" if self._c.state != "error" else "error"

    def _write_burst(self, item: tuple[str, int, Any], until_s: float) -> None:
        """Write ``item`` and then whatever else is queued, closing each chunk that is full;
        whenever a window has begun meanwhile, wait for the worker's next sleep before going
        on. The burst ends with the queue empty, at the flush deadline ``until_s``
        (``time.monotonic()``), on stop, or after a queue's worth of items: the loop comes
        back to its flush and its stop in bounded time however long the waits."""
        for _ in range(self.config.queue_size + 1):
            if item[0] == "estimates":
                self._write_estimates_pausing(item[2])
            else:
                with self.timed("mcap writer: write"):
                    self._write(item)
            if self._chunk_bytes >= self.config.chunk_size:
                self._take_turn_if_busy()
                self._close_full_chunk()
            if self._stop.is_set() or time.monotonic() >= until_s:
                return
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return
            self._take_turn_if_busy()

    def _write_estimates_pausing(self, batch: Sequence[tuple[bytes, int, Any]]) -> None:
        """Write a tick's estimates (25 at a 4 ms hop), stopping between two of them when a
        window has begun, until the worker sleeps again: a window never shares the GIL with
        the rest of the batch, and waits at most one estimate's write for it."""
        done = 0
        while done < len(batch):
            with self.timed("mcap writer: write"):
                for estimate, log_time_ns, message in batch[done:]:
                    self._write_payload("estimate", log_time_ns, estimate, message)
                    done += 1
                    if self.busy():
                        break
            if done < len(batch):
                self.wait_turn()

    def _take_turn_if_busy(self) -> None:
        """While a window is being computed, wait (bounded) for the worker to go to sleep."""
        if self.busy():
            self.wait_turn()

    def _close_full_chunk(self) -> None:
        """Compress and write the open chunk (and its index) now, in the writer's turn,
        rather than inside whichever ``add_message`` crosses the mcap writer's own limit."""
        with self.timed("mcap writer: chunk"):
            self._flush()

    def _drain(self) -> None:
        for _ in range(self.config.queue_size + 1):
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return
            self._write(item)

    def _write(self, item: tuple[str, int, Any]) -> None:
        kind, t_ns, payload = item
        on_written: Callable[[bool], None] | None = None
        if kind == "estimates":
            for estimate, log_time_ns, message in payload:
                self._write_payload("estimate", log_time_ns, estimate, message)
            return
        if kind == "samples" and (self._writer is not None or self._tap is not None):
            first, pos, tq, ok, st = payload
            payload = encode_samples(first, self.fs_hz, pos, tq, ok, st)
        elif kind == "session":
            self._session_now = payload
            payload = payload[0]
        elif kind == "marker":
            payload, on_written = payload
        written = self._write_payload(kind, t_ns, payload)
        if kind == "marker" and written:
            self._flush()  # a marker is acknowledged only once it is in the file
            written = self._writer is not None
        if on_written is not None:
            on_written(written)

    def _write_payload(
        self, kind: str, t_ns: int, payload: bytes, message: Mapping[str, Any] | None = None
    ) -> bool:
        if self._tap is not None:
            self._tap(kind, t_ns, payload)
        if self._writer is None:
            with self._c.lock:
                self._c.lost += 1
            return False
        try:
            self._writer.add_message(
                channel_id=self._channels[kind], log_time=t_ns, data=payload, publish_time=t_ns
            )
            self._chunk_bytes += len(payload) + _RECORD_BYTES
        except OSError as exc:
            with self._c.lock:
                self._c.lost += 1
            self._fail(exc, "writing")
            return False
        if self._table is not None:
            if message is None:
                self._table.add_payload(kind, payload)
            else:
                self._table.add(kind, message)
        with self._c.lock:
            self._c.written += 1
        return True

    def _flush(self) -> None:
        if self._writer is None or self._stream is None:
            return
        try:
            self._writer.flush()  # closes the open chunk: compressed, written with its index
            self._chunk_bytes = 0
            size = self._stream.tell()
        except OSError as exc:
            self._fail(exc, "flushing")
            return
        with self._c.lock:
            self._c.file_bytes = size

    def _maybe_rotate(self, now: float) -> None:
        cfg = self.config
        if self._writer is None:
            return
        too_big = cfg.rotate_size_mb > 0 and self._c.file_bytes >= cfg.rotate_size_mb * 2**20
        too_old = cfg.rotate_interval_s > 0 and now - self._file_opened_at >= cfg.rotate_interval_s
        if too_big or too_old:
            self._close_file(finish=True)
            self._part += 1
            self._try_open()

    def _next_path(self) -> Path:
        directory = Path(self.config.directory)
        directory.mkdir(parents=True, exist_ok=True)
        return directory / recording_name(
            self.robot, self.joint, self._session_start, self._part, self.session
        )

    def _try_open(self) -> None:
        """Open the next file; on error count it and retry after ``retry_interval_s``."""
        from mcap.writer import CompressionType, Writer

        path: Path | None = None
        stream: IO[bytes] | None = None
        try:
            for _ in range(1000):
                path = self._next_path()
                try:
                    stream = self._open_file(path)
                    break
                except FileExistsError:
                    self._part += 1
            if stream is None or path is None:
                raise FileExistsError(errno.EEXIST, "too many recordings with this name", path)
            # the logger closes chunks at chunk_size itself (_close_full_chunk); the mcap
            # writer's own limit only bounds a chunk whose close never got a turn
            writer = Writer(
                stream,
                chunk_size=_CHUNK_CEILING * self.config.chunk_size,
                compression=CompressionType.ZSTD,
            )
            writer.start(profile="", library=f"rtsid {__version__}")
            self._channels = self._register(writer)
            writer.add_metadata("rtsid", self._rtsid_metadata())
            writer.add_metadata("config", {"json": self._run_config_json})
            for name, record in self._records.items():
                writer.add_metadata(name, record)
            writer.add_metadata("rtsid.session", self._session_metadata())
            table = TableBuilder()
            if self._session_now is not None:  # every part says who and what from its start
                t_ns = time.time_ns()
                writer.add_message(
                    channel_id=self._channels["session"],
                    log_time=t_ns,
                    data=self._session_now[0],
                    publish_time=t_ns,
                )
                table.add_payload("session", self._session_now[0])
            writer.flush()
            size = stream.tell()
        except OSError as exc:
            self._stream = stream
            self._fail(exc, "creating", path)
            if stream is not None and path is not None:
                self._remove_unstarted(path)
            return
        self._writer, self._stream = writer, stream
        self._chunk_bytes = 0  # the header's flush closed the first chunk
        self._table = table
        self._file_opened_at = time.monotonic()
        with self._c.lock:
            self._c.file = str(path)
            self._c.files.append(str(path))
            self._c.file_bytes = size
            self._c.state = "recording"
        log.info("recording to %s", path)

    @staticmethod
    def _remove_unstarted(path: Path) -> None:
        """Delete a file this logger created whose header could not be written (it holds no
        message, and the next try reuses its name)."""
        try:
            path.unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            log.warning("could not remove the unstarted recording %s: %s", path, exc.strerror)

    def _register(self, writer: Any) -> dict[str, int]:
        return register_channels(writer, can_frames=self.config.log_can_frames)

    def _rtsid_metadata(self) -> dict[str, str]:
        import mcap

        return {
            "software": "rtsid",
            "version": __version__,
            "mcap_library": getattr(mcap, "__version__", "unknown"),
            "robot": self.robot,
            "joint": self.joint,
            "fs_hz": repr(self.fs_hz),
            "session_start_utc": self._session_start.isoformat(),
            "file_start_utc": datetime.now(UTC).isoformat(),
            "part": str(self._part),
            "schemas": "see docs/io.md",
            **self._extra_metadata,
        }

    def _session_metadata(self) -> dict[str, str]:
        """The ``rtsid.session`` record: subject, session, condition (the newest), robot,
        joint, started_utc (the run's start, ISO 8601), rtsid_version."""
        condition = self.session.condition
        if self._session_now is not None:
            condition = str(self._session_now[1].get("condition", condition))
        return {
            "subject": self.session.subject,
            "session": self.session.session,
            "condition": condition,
            "robot": self.robot,
            "joint": self.joint,
            "started_utc": self._session_start.isoformat(),
            "rtsid_version": __version__,
        }

    def _close_file(self, *, finish: bool) -> None:
        writer, stream, table = self._writer, self._stream, self._table
        self._writer, self._stream, self._table = None, None, None
        size = 0
        try:
            if writer is not None and finish:
                attach_table(writer, table)  # rtsid summary reads this, not the messages
                writer.finish()
            if stream is not None:
                stream.flush()
                size = stream.tell()
        except OSError as exc:
            self._fail(exc, "finishing")
        finally:
            if stream is not None:
                try:
                    stream.close()
                except OSError:
                    pass
        with self._c.lock:
            if writer is not None:
                self._c.closed_bytes += size or self._c.file_bytes
                self._c.file_bytes = 0

    def _fail(self, exc: OSError, action: str, path: Path | None = None) -> None:
        target = path or (self._c.file and Path(self._c.file)) or Path(self.config.directory)
        self._last_cause = _describe_os_error(exc, action, target)
        message = (
            f"{self._last_cause}. Estimates are still published; messages are counted as lost "
            "until a new file opens"
        )
        first = self._c.state != "error"
        # Abandon the file without writing more into it (its footer is missing: recoverable).
        writer_had_file = self._writer is not None
        if writer_had_file:
            self._part += 1  # the next try is a new file beside the damaged one
        stream = self._stream
        self._writer, self._stream, self._table = None, None, None
        if stream is not None:
            try:
                stream.close()
            except OSError:
                pass
        self._retry_at = time.monotonic() + self.config.retry_interval_s
        with self._c.lock:
            self._c.errors += 1
            self._c.last_error = message
            self._c.state = "error"
            if writer_had_file:
                self._c.closed_bytes += self._c.file_bytes
                self._c.file_bytes = 0
            self._c.file = None
        if first:
            log.error("%s", message)


def _describe_os_error(exc: OSError, action: str, path: Path) -> str:
    code = errno.errorcode.get(exc.errno or 0, "") if exc.errno else ""
    reason = exc.strerror or str(exc)
    if exc.errno == errno.ENOSPC:
        fix = "free disk space or set mcap.directory to another disk"
    elif exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        fix = "make the directory writable or set mcap.directory to a writable one"
    elif exc.errno == errno.ENOTDIR:
        fix = "part of the path is a file; set mcap.directory to a directory"
    elif exc.errno == errno.ENOENT:
        fix = "the directory vanished; recreate it or set mcap.directory"
    else:
        fix = "check the disk and mcap.directory"
    return f"MCAP {action} {os.fspath(path)} failed: {reason}{f' ({code})' if code else ''}; {fix}"
