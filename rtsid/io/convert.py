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

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid import __version__
from rtsid.errors import InputDataError, RecordingError
from rtsid.io.files import atomic_write
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
    """Growing columns of decoded samples (offline: lists, converted once at the end)."""

    def __init__(self) -> None:
        self.position: list[float] = []
        self.torque: list[float] = []
        self.valid: list[bool] = []
        self.status: list[int] = []

    def gap(self, n: int) -> None:
        self.position.extend([math.nan] * n)
        self.torque.extend([math.nan] * n)
        self.valid.extend([False] * n)
        self.status.extend([0] * n)

    def add(self, position_raw: int, torque_raw: int, status: int) -> None:
        self.position.append(position_raw * POSITION_SCALE_RAD)
        self.torque.append(torque_raw * TORQUE_SCALE_NM)
        self.valid.append(True)
        self.status.append(status)


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
        Unreadable file, or no AnkleState frame in it.
    """
    import can

    p = Path(path)
    if not p.is_file():
        raise InputDataError(f"{p}: no such file")
    if not fs_hz > 0:
        raise InputDataError(f"--fs {fs_hz!r}: the state-frame rate must be > 0 Hz")
    counters = ImportCounters()
    rows = _Rows()
    first = last = -1
    last_time = 0.0
    first_time = 0.0
    sequence: Sequencer[tuple[int, int, int, float]] = Sequencer(reach=reorder_window)
    try:
        with can.LogReader(p) as reader:
            for msg in reader:
                state = _classify(msg, counters)
                if state is None:
                    continue
                position, torque, counter, status = state
                stamp = float(msg.timestamp or 0.0)
                if last < 0:
                    first = last = sequence.last = counter
                    first_time = last_time = stamp
                    rows.add(position, torque, status)
                    counters.samples += 1
                    continue
                elapsed = stamp - last_time if stamp > 0 and stamp >= last_time else 0.0
                index = unwrap_counter(counter, last, elapsed, fs_hz, reorder_window)
                if index <= last:
                    _count_late(counters, rows, index - first)
                    continue
                for row_index, row in sequence.offer(index, (position, torque, status, stamp)):
                    if row_index > last + 1:
                        counters.gaps += 1
                        counters.lost_samples += row_index - last - 1
                        rows.gap(row_index - last - 1)
                    rows.add(*row[:3])
                    counters.samples += 1
                    last, last_time = row_index, row[3]
    except (OSError, ValueError, EOFError) as exc:
        raise InputDataError(f"{p}: cannot read it as a CAN log ({exc})") from None
    if first < 0:
        raise InputDataError(
            f"{p}: no AnkleState frames (id 0x{STATE_ID:X}) among {counters.frames} frames; "
            "is it a capture of the ankle robot's bus?"
        )
    counters.strays, counters.unjudged = sequence.strays, sequence.held
    counters.duplicates += sequence.duplicates
    start_ns = round(first_time * 1e9) if first_time > _EPOCH_2000_S else 0
    return ImportedSamples(
        first_index=first,
        fs_hz=float(fs_hz),
        position_rad=np.asarray(rows.position, dtype=np.float64),
        torque_nm=np.asarray(rows.torque, dtype=np.float64),
        valid=np.asarray(rows.valid, dtype=bool),
        status=np.asarray(rows.status, dtype=np.int64),
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
    import can

    times: list[float] = []
    counters: list[int] = []
    ignored = ImportCounters()
    with can.LogReader(path) as reader:
        for msg in reader:
            state = _classify(msg, ignored)
            if state is not None and msg.timestamp:
                times.append(float(msg.timestamp))
                counters.append(state[2])
    return np.asarray(times, dtype=np.float64), np.asarray(counters, dtype=np.int64)


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
        raise InputDataError(
            f"{p}: {exc}; pass the robot's state-frame rate with --fs HZ"
        ) from None
    except (OSError, ValueError, EOFError) as exc:
        raise InputDataError(f"{p}: cannot read it as a CAN log ({exc})") from None
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
    if 0 <= row < len(rows.valid) and rows.valid[row]:
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
