"""Import recordings made elsewhere as rtsid MCAP recordings (``rtsid convert``).

Sources:

* CAN captures from real rigs — candump ``.log``, Vector ``.asc``, ``.blf``, PEAK ``.trc`` —
  read with python-can's :func:`can.LogReader` and decoded with the project's DBC
  (:func:`rtsid.link.protocol.decode_state`). Samples are numbered exactly as the live link
  numbers them (:func:`rtsid.link.acquisition.unwrap_counter`): a jump of the sequence
  counter becomes invalid rows (a gap, later withheld, never bridged) once the frames after it
  confirm it, stray frames are dropped (:class:`rtsid.link.sequence.Sequencer`, as live),
  late frames (duplicates, reordered) are dropped, malformed frames are counted and never
  decoded.
* Sample files ``.npz``/``.csv`` (:func:`rtsid.io.sample_files.load_samples`); non-finite
  values become invalid rows.

The output has the live logger's layout (:func:`rtsid.io.mcap_log.register_channels`):
``/samples`` batches, ``rtsid`` metadata (with ``converted_from`` and the import counters)
and ``config`` metadata holding the configuration replay uses. It is written
synchronously and completely (nothing is dropped), atomically (:func:`rtsid.io.files.atomic_write`).
"""

from __future__ import annotations

import array
import logging
import math
import struct
import zlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid import __version__
from rtsid.errors import InputDataError, RecordingError
from rtsid.io.files import atomic_write, check_rows
from rtsid.io.mcap_log import register_channels
from rtsid.io.sample_files import load_samples
from rtsid.io.schemas import SampleBatch, encode_json, encode_samples
from rtsid.link import protocol
from rtsid.link.acquisition import unwrap_counter
from rtsid.link.protocol import (
    COMMAND_ID,
    DIAGNOSTICS_ID,
    POSITION_SCALE_RAD,
    STATE_ID,
    TORQUE_SCALE_NM,
    decode_state,
)
from rtsid.link.sequence import Sequencer

__all__ = [
    "CAN_LOG_SUFFIXES",
    "SAMPLE_FILE_SUFFIXES",
    "ImportCounters",
    "ImportedSamples",
    "check_estimable",
    "derive_rate",
    "rate_from_timestamps",
    "read_can_log",
    "read_sample_file",
    "read_source",
    "write_recording",
]

CAN_LOG_SUFFIXES = (".log", ".asc", ".blf", ".trc")
SAMPLE_FILE_SUFFIXES = (".npz", ".csv")
_EPOCH_2000_S = 946_684_800.0  # timestamps after this are wall-clock (UNIX) times
#: Highest state-frame rate a CAN capture is read at, Hz (as ``[link] fs_hz`` allows).
MAX_FS_HZ = 100_000.0


@dataclass
class ImportCounters:
    """What an import met (the live link's counter names where they mean the same)."""

    frames: int = 0
    samples: int = 0
    gaps: int = 0
    lost_samples: int = 0
    duplicates: int = 0
    out_of_order: int = 0
    malformed: int = 0
    unknown_id: int = 0
    error_frames: int = 0
    diagnostics: int = 0
    commands_seen: int = 0
    strays: int = 0  # jumped frames the frames after them refuted (dropped, as live)
    unjudged: int = 0  # frames after a jump at the very end, too few to judge (not written)

    def as_metadata(self) -> dict[str, str]:
        """As MCAP metadata strings, prefixed ``import_``."""
        return {f"import_{k}": str(v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class ImportedSamples:
    """Every row of an imported recording, gaps included (invalid, NaN).

    Attributes
    ----------
    first_index : int
        Sample index of row 0.
    fs_hz : float
        Sample rate, Hz.
    position_rad, torque_nm : numpy.ndarray, shape (n,)
        Values (NaN in invalid rows).
    valid : numpy.ndarray of bool, shape (n,)
    status : numpy.ndarray of int64, shape (n,)
        Status bits of each frame (0 for sample files).
    start_time_ns : int
        UNIX time of row 0, ns (0 when the source has no wall-clock time).
    source_format : str
        ``"candump"``, ``"asc"``, ``"blf"``, ``"trc"``, ``"npz"`` or ``"csv"``.
    counters : ImportCounters
    rate_note : str
        How ``fs_hz`` was derived when it was not given ("" when given).
    """

    first_index: int
    fs_hz: float
    position_rad: NDArray[np.float64]
    torque_nm: NDArray[np.float64]
    valid: NDArray[np.bool_]
    status: NDArray[np.int64]
    start_time_ns: int
    source_format: str
    counters: ImportCounters = field(default_factory=ImportCounters)
    rate_note: str = ""

    def __len__(self) -> int:
        return int(self.position_rad.size)

    def batches(self, batch_samples: int) -> Iterator[SampleBatch]:
        """Consecutive batches of ``batch_samples`` rows (the daemon's batching)."""
        step_ns = 1e9 / self.fs_hz
        # wall-clock time of the capture when known, else sample time since index 0
        base_ns = self.start_time_ns or round(self.first_index * step_ns)
        for lo in range(0, len(self), batch_samples):
            hi = min(lo + batch_samples, len(self))
            t_ns = base_ns + round(lo * step_ns)
            yield SampleBatch(
                first_index=self.first_index + lo,
                fs_hz=self.fs_hz,
                position_rad=self.position_rad[lo:hi],
                torque_nm=self.torque_nm[lo:hi],
                valid=self.valid[lo:hi],
                status=self.status[lo:hi],
                log_time_ns=t_ns,
            )


class _Rows:
    """Decoded samples, compactly (32 bytes each): gaps are not stored, only the row each
    sample goes to; :meth:`columns` lays them on the full grid once, gaps as invalid rows."""

    def __init__(self) -> None:
        self.row: array.array[int] = array.array("q")
        self.position: array.array[float] = array.array("d")
        self.torque: array.array[float] = array.array("d")
        self.status: array.array[int] = array.array("q")

    def add(self, row: int, position_raw: int, torque_raw: int, status: int) -> None:
        self.row.append(row)
        self.position.append(position_raw * POSITION_SCALE_RAD)
        self.torque.append(torque_raw * TORQUE_SCALE_NM)
        self.status.append(status)

    def holds(self, row: int) -> bool:
        """Whether a sample was stored at ``row`` (rows are stored in increasing order)."""
        rows = np.frombuffer(self.row, dtype=np.int64)
        at = int(np.searchsorted(rows, row))
        return at < rows.size and int(rows[at]) == row

    def columns(self, n_rows: int) -> tuple[Any, Any, Any, Any]:
        """``position, torque, valid, status`` over ``n_rows`` rows (NaN, False, 0 in gaps)."""
        rows = np.frombuffer(self.row, dtype=np.int64)
        position = np.full(n_rows, np.nan)
        torque = np.full(n_rows, np.nan)
        valid = np.zeros(n_rows, dtype=bool)
        status = np.zeros(n_rows, dtype=np.int64)
        position[rows] = np.frombuffer(self.position, dtype=np.float64)
        torque[rows] = np.frombuffer(self.torque, dtype=np.float64)
        valid[rows] = True
        status[rows] = np.frombuffer(self.status, dtype=np.int64)
        return position, torque, valid, status


#: What python-can's log readers raise on a damaged or foreign file (its BLF reader raises
#: its own BLFParseError, the text readers ValueError/IndexError on a malformed line, …).
def _reader_errors() -> tuple[type[BaseException], ...]:
    from can.io.blf import BLFParseError

    return (
        OSError,
        ValueError,
        EOFError,
        IndexError,
        KeyError,
        TypeError,
        struct.error,
        zlib.error,
        BLFParseError,
    )


class _CountParseFailures(logging.Filter):
    """Counts, and keeps off the console, the line-by-line "failed to parse" warnings of
    python-can's text readers (a damaged capture would print one per line)."""

    def __init__(self, counters: ImportCounters | None) -> None:
        super().__init__()
        self.counters = counters

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno <= logging.WARNING:
            if self.counters is not None:
                self.counters.malformed += 1
            return False
        return True


#: Longest line of a text capture (candump, asc, trc), characters: a frame is < 400.
MAX_CAPTURE_LINE_CHARS = 1 << 16


class _CappedLines:
    """A text file whose lines python-can iterates, each read with a length cap, so that a
    file without line breaks is refused, not held whole."""

    def __init__(self, fh: Any, path: Path) -> None:
        self._fh = fh
        self._path = path

    def __iter__(self) -> Iterator[str]:
        number = 0
        while line := self._fh.readline(MAX_CAPTURE_LINE_CHARS + 1):
            number += 1
            if len(line) > MAX_CAPTURE_LINE_CHARS:
                raise InputDataError(
                    f"line {number} is longer than {MAX_CAPTURE_LINE_CHARS} characters"
                )
            yield line

    def __getattr__(self, name: str) -> Any:
        return getattr(self._fh, name)


def _open_reader(path: Path) -> Any:
    """python-can's reader for ``path``'s suffix, on a file opened here (so that a reader that
    refuses the file in its constructor leaves no file open)."""
    from can.io.generic import BinaryIOMessageReader
    from can.io.player import MESSAGE_READERS

    reader_type: Any = MESSAGE_READERS[path.suffix.lower()]
    binary = issubclass(reader_type, BinaryIOMessageReader)
    fh = path.open("rb") if binary else path.open(encoding="utf-8", errors="replace")
    try:
        return reader_type(fh if binary else _CappedLines(fh, path))
    except BaseException:
        fh.close()
        raise


#: Largest BLF object (a container of frames) read, compressed or not, bytes: loggers write
#: containers of about 128 KiB; a larger size is damage or a decompression bomb, refused
#: before python-can's reader would allocate or inflate it.
MAX_BLF_OBJECT_BYTES = 64 << 20


def _check_blf_objects(path: Path) -> None:
    """Walk a BLF file's object headers (inflating each container in bounded steps) and refuse
    any header or object larger than :data:`MAX_BLF_OBJECT_BYTES` before python-can reads it.
    Other damage is left for python-can's reader to report."""
    from can.io import blf

    def too_large(what: str, n_bytes: int) -> InputDataError:
        return InputDataError(
            f"{path}: a BLF {what} of {n_bytes} bytes is larger than the "
            f"{MAX_BLF_OBJECT_BYTES >> 20} MiB rtsid reads; the file is damaged"
        )

    with path.open("rb") as fh:
        head = fh.read(blf.FILE_HEADER_STRUCT.size)
        if len(head) < blf.FILE_HEADER_STRUCT.size or head[:4] != b"LOGG":
            return
        header_size = blf.FILE_HEADER_STRUCT.unpack(head)[1]
        if header_size > MAX_BLF_OBJECT_BYTES:
            raise too_large("file header", header_size)
        fh.seek(max(header_size, blf.FILE_HEADER_STRUCT.size))
        base_size = blf.OBJ_HEADER_BASE_STRUCT.size
        while len(base := fh.read(base_size)) == base_size:
            signature, _hs, _hv, obj_size, obj_type = blf.OBJ_HEADER_BASE_STRUCT.unpack(base)
            if signature != b"LOBJ":
                return
            if not base_size <= obj_size <= MAX_BLF_OBJECT_BYTES:
                raise too_large("object", obj_size)
            body = fh.read(obj_size - base_size)
            fh.seek(obj_size % 4, 1)
            container = blf.LOG_CONTAINER_STRUCT.size
            if obj_type != blf.LOG_CONTAINER or len(body) < container:
                continue
            method, _declared = blf.LOG_CONTAINER_STRUCT.unpack_from(body)
            if method == blf.ZLIB_DEFLATE:
                inflated = zlib.decompressobj().decompress(body[container:], MAX_BLF_OBJECT_BYTES)
                if len(inflated) >= MAX_BLF_OBJECT_BYTES:
                    raise too_large("container, inflated,", len(inflated))


def _frames(path: Path, counters: ImportCounters | None = None) -> Iterator[Any]:
    """The frames of a CAN capture, in file order; a file python-can cannot read (garbage,
    another format, a damaged record) is an InputDataError naming it. Lines its text readers
    cannot parse are counted as ``malformed`` in ``counters``."""
    errors = _reader_errors()
    quiet = _CountParseFailures(counters)
    loggers = [logging.getLogger(f"can.io.{name}") for name in ("trc", "asc", "blf", "canutils")]
    for logger in loggers:
        logger.addFilter(quiet)
    try:
        if path.suffix.lower() == ".blf":
            _check_blf_objects(path)
        with _open_reader(path) as reader:
            yield from reader
    except errors as exc:
        reason = str(exc) or type(exc).__name__
        raise InputDataError(
            f"{path}: cannot read it as a {_log_format(path)} CAN capture ({reason[:200]}); "
            "is it complete and of the format its suffix says?"
        ) from None
    finally:
        for logger in loggers:
            logger.removeFilter(quiet)


def _finite_time(stamp: Any) -> float:
    """A frame's timestamp, s; 0 (unknown) when missing, non-finite or past year 2262."""
    value = float(stamp or 0.0)
    return value if math.isfinite(value) and 0 < value < 9.2e9 else 0.0


def _log_format(path: Path) -> str:
    suffix = path.suffix.lower()
    return "candump" if suffix == ".log" else suffix.lstrip(".")


def read_can_log(path: str | Path, fs_hz: float, *, reorder_window: int = 64) -> ImportedSamples:
    """Decode the AnkleState frames of a CAN capture into sample rows.

    Parameters
    ----------
    path : str or Path
        A ``.log`` (candump -L), ``.asc``, ``.blf`` or ``.trc`` file.
    fs_hz : float
        The robot's state-frame rate, Hz (frames carry a counter, not the rate).
    reorder_window : int
        Counter distance behind the newest sample treated as a late frame (as the link).

    Returns
    -------
    ImportedSamples

    Raises
    ------
    InputDataError
        Unreadable file, no AnkleState frame in it, a rate above :data:`MAX_FS_HZ`, or more
        rows (first to last sample, gaps included) than :data:`rtsid.io.files.MAX_ROWS`,
        refused before they are allocated.
    """
    p = Path(path)
    if not p.is_file():
        raise InputDataError(f"{p}: no such file")
    if not fs_hz > 0:
        raise InputDataError(f"--fs {fs_hz!r}: the state-frame rate must be > 0 Hz")
    if not fs_hz <= MAX_FS_HZ:
        raise InputDataError(
            f"--fs {fs_hz!r}: {p.name} would be read at more than {MAX_FS_HZ:g} Hz, the highest "
            "state-frame rate rtsid takes; pass the robot's rate (e.g. --fs 2500)"
        )
    counters = ImportCounters()
    rows = _Rows()
    first = last = -1
    last_time = 0.0
    first_time = 0.0
    sequence: Sequencer[tuple[int, int, int, float]] = Sequencer(reach=reorder_window)
    for msg in _frames(p, counters):
        state = _classify(msg, counters)
        if state is None:
            continue
        position, torque, counter, status = state
        stamp = _finite_time(msg.timestamp)
        if last < 0:
            first = last = sequence.last = counter
            first_time = last_time = stamp
            rows.add(0, position, torque, status)
            counters.samples += 1
            continue
        elapsed = stamp - last_time if stamp > 0 and stamp >= last_time else 0.0
        check_rows(p, last - first + elapsed * fs_hz, fs_hz)  # before unwrapping a silence
        index = unwrap_counter(counter, last, elapsed, fs_hz, reorder_window)
        if index <= last:
            _count_late(counters, rows, index - first)
            continue
        for row_index, row in sequence.offer(index, (position, torque, status, stamp)):
            check_rows(p, row_index - first + 1, fs_hz)
            if row_index > last + 1:
                counters.gaps += 1
                counters.lost_samples += row_index - last - 1
            rows.add(row_index - first, *row[:3])
            counters.samples += 1
            last, last_time = row_index, row[3]
    if first < 0:
        raise InputDataError(
            f"{p}: no AnkleState frames (id 0x{STATE_ID:X}) among {counters.frames} frames; "
            "is it a capture of the ankle robot's bus?"
        )
    counters.strays, counters.unjudged = sequence.strays, sequence.held
    counters.duplicates += sequence.duplicates
    start_ns = round(first_time * 1e9) if first_time > _EPOCH_2000_S else 0
    position_rad, torque_nm, valid, status = rows.columns(last - first + 1)
    return ImportedSamples(
        first_index=first,
        fs_hz=float(fs_hz),
        position_rad=position_rad,
        torque_nm=torque_nm,
        valid=valid,
        status=status,
        start_time_ns=start_ns,
        source_format=_log_format(p),
        counters=counters,
    )


RATE_BLOCK_FRAMES = 64


def rate_from_timestamps(times_s: NDArray[np.float64], counters: NDArray[np.int64]) -> float:
    """The state-frame rate, Hz, from the frames' timestamps and 12-bit counters.

    The frames are cut into blocks of :data:`RATE_BLOCK_FRAMES` consecutive frames; each block
    gives counter steps / elapsed time, and the rate is the median over blocks. A block
    averages out timestamp jitter and bursts (USB adapters deliver frames in bunches) and the
    microsecond quantisation of log files; the median ignores the few blocks a lost burst,
    a stray frame or a clock step spoils. Within 0.01 % of a whole number of Hz, that number
    is returned.

    Raises
    ------
    InputDataError
        Fewer than 16 timestamped frames, or no time passes between them.
    """
    modulo = protocol.COUNTER_MODULO
    steps = (np.diff(counters) + modulo // 2) % modulo - modulo // 2  # signed: late frames < 0
    elapsed = np.diff(times_s)
    if steps.size < 16 or not np.all(np.isfinite(elapsed)):
        raise InputDataError("too few timestamped state frames to derive the rate")
    blocks = max(1, steps.size // RATE_BLOCK_FRAMES)
    cut = blocks * (steps.size // blocks)
    step_sums = steps[:cut].reshape(blocks, -1).sum(axis=1)
    time_sums = elapsed[:cut].reshape(blocks, -1).sum(axis=1)
    usable = (time_sums > 0) & (step_sums > 0)
    if not usable.any():
        raise InputDataError("the state frames' timestamps do not advance")
    rate = float(np.median(step_sums[usable] / time_sums[usable]))
    return float(round(rate)) if abs(rate - round(rate)) <= 1e-4 * rate else rate


def _state_frame_times(path: Path) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Timestamps and counters of the decodable state frames, in file order."""
    times: array.array[float] = array.array("d")
    counters: array.array[int] = array.array("q")
    ignored = ImportCounters()
    for msg in _frames(path):
        state = _classify(msg, ignored)
        stamp = _finite_time(msg.timestamp)
        if state is not None and stamp:
            check_rows(path, len(times) + 1)
            times.append(stamp)
            counters.append(state[2])
    return np.frombuffer(times, dtype=np.float64), np.frombuffer(counters, dtype=np.int64)


def derive_rate(path: str | Path) -> tuple[float, str]:
    """The state-frame rate of a CAN capture from its timestamps, and a sentence saying so.

    Raises
    ------
    InputDataError
        Unreadable file, or timestamps that give no rate (the message asks for ``--fs``).
    """
    p = Path(path)
    try:
        times, counters = _state_frame_times(p)
        rate = rate_from_timestamps(times, counters)
    except InputDataError as exc:
        if str(exc).startswith(str(p)):
            raise
        raise InputDataError(
            f"{p}: {exc}; pass the robot's state-frame rate with --fs HZ"
        ) from None
    blocks = max(1, (times.size - 1) // RATE_BLOCK_FRAMES)
    note = (
        f"rate {rate:g} Hz derived from the frames' timestamps (median over {blocks} blocks of "
        f"{RATE_BLOCK_FRAMES} frames); pass --fs HZ if the robot's rate is another"
    )
    return rate, note


def _classify(msg: Any, counters: ImportCounters) -> tuple[int, int, int, int] | None:
    """Decoded state frame, or None after counting what else the frame was."""
    counters.frames += 1
    if msg.is_error_frame:
        counters.error_frames += 1
        return None
    if msg.is_extended_id:
        counters.unknown_id += 1
        return None
    if msg.arbitration_id == STATE_ID:
        data = msg.data
        if msg.is_remote_frame or msg.dlc != 8 or data is None or len(data) != 8:
            counters.malformed += 1
            return None
        decoded = decode_state(bytes(data))
        if decoded is None:
            counters.malformed += 1
        return decoded
    if msg.arbitration_id == DIAGNOSTICS_ID:
        counters.diagnostics += 1
    elif msg.arbitration_id == COMMAND_ID:
        counters.commands_seen += 1
    else:
        counters.unknown_id += 1
    return None


def _count_late(counters: ImportCounters, rows: _Rows, row: int) -> None:
    if row >= 0 and rows.holds(row):
        counters.duplicates += 1
    else:
        counters.out_of_order += 1


def read_sample_file(path: str | Path, fs_hz: float | None = None) -> ImportedSamples:
    """Rows of an ``.npz``/``.csv`` sample file (non-finite values become invalid rows)."""
    record = load_samples(path, fs_hz)
    valid = np.isfinite(record.position_rad) & np.isfinite(record.torque_nm)
    counters = ImportCounters(samples=int(np.count_nonzero(valid)))
    return ImportedSamples(
        first_index=0,
        fs_hz=record.fs_hz,
        position_rad=np.where(valid, record.position_rad, np.nan),
        torque_nm=np.where(valid, record.torque_nm, np.nan),
        valid=valid,
        status=np.zeros(valid.size, dtype=np.int64),
        start_time_ns=0,
        source_format=Path(path).suffix.lower().lstrip("."),
        counters=counters,
    )


def read_source(path: str | Path, fs_hz: float | None = None) -> ImportedSamples:
    """Any importable file, by suffix. Without ``fs_hz`` a CAN log's rate comes from its
    frames' timestamps (:func:`derive_rate`; ``rate_note`` of the result says so)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in CAN_LOG_SUFFIXES:
        note = ""
        if fs_hz is None:
            if not p.is_file():
                raise InputDataError(f"{p}: no such file")
            fs_hz, note = derive_rate(p)
        return replace(read_can_log(p, fs_hz), rate_note=note)
    if suffix in SAMPLE_FILE_SUFFIXES:
        return read_sample_file(p, fs_hz)
    accepted = ", ".join(CAN_LOG_SUFFIXES + SAMPLE_FILE_SUFFIXES)
    raise InputDataError(f"{p}: unknown file type {suffix!r}; rtsid convert reads {accepted}")


def check_estimable(samples: ImportedSamples, window_s: float, source: str) -> None:
    """Refuse rows that can never give an estimate: none valid, or fewer than one window.

    Raises
    ------
    InputDataError
        Names what is wrong with ``source`` and what to do.
    """
    rows, fs = len(samples), samples.fs_hz
    if not samples.valid.any():
        raise InputDataError(
            f"{source}: none of its {rows} rows has a finite position and torque (all NaN, inf "
            "or lost); check that the file holds the recording's values"
        )
    window = round(window_s * fs)
    if rows < window:
        raise InputDataError(
            f"{source}: {rows} rows at {fs:g} Hz ({rows / fs:.3g} s) are shorter than one "
            f"{window_s:g} s analysis window ({window} rows); convert a longer recording, or "
            "store a shorter [worker] window_s with --config"
        )


def write_recording(
    samples: ImportedSamples,
    out: str | Path,
    *,
    run_config: Mapping[str, Any],
    batch_samples: int,
    source: str,
    robot: str = "robot",
    joint: str = "ankle",
    overwrite: bool = False,
) -> Path:
    """Write every row as an rtsid MCAP recording (synchronously, nothing dropped).

    Parameters
    ----------
    samples : ImportedSamples
        The rows.
    out : str or Path
        Output ``.mcap`` (written atomically: :func:`rtsid.io.files.atomic_write`).
    run_config : Mapping
        The configuration stored as ``config`` metadata (what replay uses).
    batch_samples : int
        Rows per ``/samples`` message.
    source : str
        Where the rows came from (``rtsid`` metadata ``converted_from``).
    robot, joint : str
        Names for the ``rtsid`` metadata.
    overwrite : bool
        Replace ``out`` if it exists.

    Returns
    -------
    Path
        ``out``.
    """
    from mcap.writer import CompressionType, Writer

    dst = Path(out)
    if dst.suffix.lower() != ".mcap":
        raise InputDataError(f"-o {dst}: the output must be an .mcap file")
    if dst.exists() and not overwrite:
        raise RecordingError(f"{str(dst)!r} exists; remove it or pass --overwrite")
    if batch_samples < 1:
        raise InputDataError(f"batch_samples must be >= 1, got {batch_samples}")
    metadata = {
        "software": "rtsid",
        "version": __version__,
        "robot": robot,
        "joint": joint,
        "fs_hz": repr(samples.fs_hz),
        "converted_from": source,
        "source_format": samples.source_format,
        "schemas": "see docs/io.md",
        **samples.counters.as_metadata(),
    }
    with atomic_write(dst, "wb", what="recording", make_folder=True) as fh:
        writer = Writer(fh, chunk_size=1 << 20, compression=CompressionType.ZSTD)
        writer.start(profile="", library=f"rtsid {__version__} (convert)")
        channel = register_channels(writer)["samples"]
        writer.add_metadata("rtsid", metadata)
        writer.add_metadata("config", {"json": encode_json(dict(run_config)).decode()})
        for batch in samples.batches(batch_samples):
            payload = encode_samples(
                batch.first_index,
                batch.fs_hz,
                batch.position_rad,
                batch.torque_nm,
                batch.valid,
                batch.status,
            )
            t = batch.log_time_ns
            writer.add_message(channel, log_time=t, data=payload, publish_time=t)
        writer.finish()
    return dst
