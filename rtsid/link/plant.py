"""The virtual CAN plant: a simulated (or replayed) ankle robot sending DBC frames.

:class:`VirtualPlant` owns one thread ("rtsid-plant") that generates blocks of samples
(:mod:`rtsid.link.signals`), quantises them to the DBC's scaling, injects the configured
faults and sends the frames — paced against absolute monotonic deadlines
(``t0 + k·tick``, several frames per tick to keep the CPU low) or as fast as the receiver
takes them. It listens for PerturbationCommand frames and applies them from the next block.

The frames go to a *sink*: a python-can bus (``virtual`` in-process, or any real
interface), or the :class:`~rtsid.link.socketcand.SocketcandServer` (anything with
``send_frames(frames)`` and ``poll_received()``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any, Protocol

import can
import numpy as np
from numpy.typing import NDArray

from rtsid.config import invalid
from rtsid.lifecycle import ThreadOwner
from rtsid.link.config import FaultConfig, PlantConfig
from rtsid.link.mapping import MappedProtocol, builtin_protocol
from rtsid.link.protocol import (
    DIAGNOSTICS_ID,
    STATUS_DISCONTINUITY,
    STATUS_PERTURBATION_ON,
    STATUS_POSITION_SATURATED,
    STATUS_TORQUE_SATURATED,
    database,
    encode_diagnostics,
)
from rtsid.link.signals import Block, PlantTruth, PlayerSource, SimSource, TorqueMultisineSource
from rtsid.link.udp import UdpLayout

__all__ = ["UNKNOWN_ID", "BusSink", "FrameSink", "PlantCounters", "VirtualPlant", "plant_fields"]

UNKNOWN_ID = 0x7F0
_MAX_LAG_S = 1.0  # further behind than this, the plant skips samples (as a robot would lose them)
_LOST_LOG = 1_000_000


class FrameSink(Protocol):
    """Where the plant's frames go."""

    def send_frames(self, frames: Sequence[can.Message]) -> int:
        """Send frames in order; return how many could not be sent (receiver full)."""
        ...

    def poll_received(self) -> list[can.Message]:
        """Frames others sent to the robot since the last call (non-blocking)."""
        ...


class BusSink:
    """A python-can bus as a frame sink.

    Parameters
    ----------
    bus : can.BusABC
        Open bus (not owned: the caller shuts it down).
    blocking : bool
        Wait (in 20 ms slices, until ``stop`` is set) when the receiver is full, instead of
        dropping and counting the frame.
    """

    def __init__(self, bus: can.BusABC, blocking: bool = False) -> None:
        self.bus = bus
        self.blocking = blocking
        self.stop = threading.Event()

    def send_frames(self, frames: Sequence[can.Message]) -> int:
        failed = 0
        for frame in frames:
            while True:
                try:
                    self.bus.send(frame, timeout=0.02 if self.blocking else 0.0)
                    break
                except can.CanOperationError:
                    if not self.blocking or self.stop.is_set():
                        failed += 1
                        break
        return failed

    def poll_received(self) -> list[can.Message]:
        received = []
        for _ in range(64):
            msg = self.bus.recv(0.0)
            if msg is None:
                break
            received.append(msg)
        return received


@dataclass(frozen=True)
class PlantCounters:
    """What the plant did (snapshot). Lost samples = ``dropped + corrupted + shortened +
    silenced + skipped + tx_overflows``; reordered frames arrive late and are put back in
    place by the acquisition (it holds a jump until a later frame confirms it).
    ``samples`` counts samples whose turn to be sent has come (sent or destroyed by a fault).
    Fault counts are samples: a fault on a two-frame sample, or on a UDP datagram, counts
    each sample it hit (a dropped datagram of 10 samples adds 10 to ``dropped``)."""

    samples: int
    frames_sent: int
    dropped: int
    corrupted: int
    shortened: int
    silenced: int
    duplicated: int
    reordered: int
    error_frames: int
    unknown_frames: int
    saturated: int
    tx_overflows: int
    skipped: int
    late_ticks: int
    max_lag_s: float
    commands: int
    diagnostics: int

    @property
    def lost_by_plant(self) -> int:
        """Samples the plant never delivered intact (excluding reordering)."""
        return (
            self.dropped
            + self.corrupted
            + self.shortened
            + self.silenced
            + self.skipped
            + self.tx_overflows
        )


class _FaultInjector:
    """Turns a block's payloads into the frames actually sent, recording every fault."""

    def __init__(self, cfg: FaultConfig, fs_hz: float) -> None:
        self.cfg = cfg
        self.fs_hz = fs_hz
        self.rng = np.random.default_rng(cfg.seed)
        self.counts = dict.fromkeys(
            (
                "dropped",
                "corrupted",
                "shortened",
                "silenced",
                "duplicated",
                "reordered",
                "error_frames",
                "unknown_frames",
            ),
            0,
        )
        self.lost_indices = np.empty(_LOST_LOG, dtype=np.int64)
        self.lost_count = 0

    def _record_lost(self, indices: NDArray[np.int64]) -> None:
        take = min(indices.size, _LOST_LOG - self.lost_count)
        self.lost_indices[self.lost_count : self.lost_count + take] = indices[:take]
        self.lost_count += take

    def _silenced(self, index: NDArray[np.int64]) -> NDArray[np.bool_]:
        if self.cfg.silence_every_s <= 0:
            return np.zeros(index.size, dtype=bool)
        every = round(self.cfg.silence_every_s * self.fs_hz)
        length = round(self.cfg.silence_s * self.fs_hz)
        return (index >= every) & (index % every < length)

    def frames(
        self, index: NDArray[np.int64], groups: list[list[Any]], per_unit: int = 1
    ) -> list[Any]:
        """The frames (or datagrams) actually sent for units of samples.

        Parameters
        ----------
        index : numpy.ndarray of int, shape (n,)
            First sample index of each unit (a sample, or a datagram's first sample).
        groups : list of list
            The frames of each unit (``can.Message``, or ``bytes`` for UDP).
        per_unit : int
            Samples per unit; >1 means UDP datagrams (no error or foreign CAN frames).
        """
        n = len(groups)
        cfg = self.cfg
        if not cfg.any:
            return [f for group in groups for f in group]
        r = self.rng.random((7, n))
        silenced = self._silenced(index)
        dropped = ~silenced & (r[0] < cfg.drop_rate)
        corrupt = ~silenced & ~dropped & (r[1] < cfg.corrupt_rate)
        short = ~silenced & ~dropped & ~corrupt & (r[2] < cfg.short_rate)
        intact = ~(silenced | dropped | corrupt | short)
        duplicate = intact & (r[3] < cfg.duplicate_rate)
        reorder = intact & ~duplicate & (r[4] < cfg.reorder_rate)
        reorder[-1] = False
        reorder[:-1] &= intact[1:] & ~duplicate[1:]  # the partner is sent intact, once
        reorder[1:] &= ~reorder[:-1]  # a frame is in one swap at most
        can_frames = per_unit == 1
        error_after = ~silenced & (r[5] < cfg.error_frame_rate) & can_frames
        unknown_after = ~silenced & (r[6] < cfg.unknown_id_rate) & can_frames
        self._count(
            per_unit,
            silenced,
            dropped,
            corrupt,
            short,
            duplicate,
            reorder,
            error_after,
            unknown_after,
        )
        lost = index[silenced | dropped | corrupt | short]
        self._record_lost((lost[:, None] + np.arange(per_unit)).ravel())
        out: list[Any] = []
        for k in range(n):
            if reorder[k]:  # unit k goes out after unit k + 1 (it arrives late)
                continue
            if intact[k]:
                out.extend(groups[k])
                if duplicate[k]:
                    out.extend(groups[k])
                if k > 0 and reorder[k - 1]:
                    out.extend(groups[k - 1])
            elif corrupt[k]:
                out.append(_flip_bit(groups[k][0], int(self.rng.integers(64))))
                out.extend(groups[k][1:])
            elif short[k]:
                out.append(_shorten(groups[k][0], int(self.rng.integers(0, 8))))
                out.extend(groups[k][1:])
            if error_after[k]:
                out.append(
                    can.Message(
                        arbitration_id=0x4,
                        is_error_frame=True,
                        data=b"\0" * 8,
                        is_extended_id=False,
                    )
                )
            if unknown_after[k]:
                out.append(
                    can.Message(arbitration_id=UNKNOWN_ID, data=b"\x55" * 8, is_extended_id=False)
                )
        return out

    def _count(self, per_unit: int, *masks: NDArray[np.bool_]) -> None:
        names = (
            "silenced",
            "dropped",
            "corrupted",
            "shortened",
            "duplicated",
            "reordered",
            "error_frames",
            "unknown_frames",
        )
        for name, mask in zip(names, masks, strict=True):
            self.counts[name] += int(np.count_nonzero(mask)) * per_unit


def _flip_bit(frame: Any, bit: int) -> Any:
    """A copy of a frame (or datagram) with one bit of its first 8 bytes flipped."""
    data = bytearray(frame if isinstance(frame, bytes) else frame.data)
    data[(bit // 8) % len(data)] ^= 1 << (bit % 8)
    return bytes(data) if isinstance(frame, bytes) else _with_data(frame, bytes(data))


def _shorten(frame: Any, length: int) -> Any:
    """A copy of a frame (or datagram) cut to ``length`` bytes (< its length)."""
    if isinstance(frame, bytes):
        return frame[: min(length, len(frame) - 1)]
    return _with_data(frame, bytes(frame.data[: min(length, len(frame.data) - 1)]))


def _with_data(frame: can.Message, data: bytes) -> can.Message:
    return can.Message(
        arbitration_id=frame.arbitration_id,
        data=data,
        is_extended_id=frame.is_extended_id,
        check=False,
        timestamp=frame.timestamp,
    )


class VirtualPlant(ThreadOwner):
    """A simulated ankle robot on a CAN bus (context manager owning the "rtsid-plant" thread).

    Parameters
    ----------
    cfg : PlantConfig
        What to simulate or replay, pacing and faults.
    bus : can.BusABC or FrameSink
        Where frames go (not owned: the caller closes it after stopping the plant).
    record_samples : int
        Keep the quantised values of the first ``record_samples`` samples (before faults)
        for tests: :meth:`recorded`.
    wire : MappedProtocol or UdpLayout, optional
        What the plant speaks: a CAN protocol mapping (default: the built-in ankle
        protocol; without a counter, frames are stamped with their sample's time, so a
        virtual bus must preserve timestamps) or a UDP datagram layout (``bus`` is then a
        :class:`~rtsid.link.udp.UdpSender`; blocks must hold whole datagrams).

    Examples
    --------
    >>> import can
    >>> from rtsid.link.config import PlantConfig
    >>> with can.Bus(interface="virtual", channel="doc") as bus:  # doctest: +SKIP
    ...     with VirtualPlant(PlantConfig(), bus) as plant:
    ...         pass
    """

    def __init__(
        self,
        cfg: PlantConfig,
        bus: Any,
        *,
        record_samples: int = 0,
        wire: MappedProtocol | UdpLayout | None = None,
    ) -> None:
        self.cfg = cfg
        self.wire = builtin_protocol() if wire is None else wire
        self._per_unit = self.wire.samples_per_unit if isinstance(self.wire, UdpLayout) else 1
        if cfg.block_samples % self._per_unit:
            raise invalid(
                "plant.block_s",
                cfg.block_s,
                f"a block of whole datagrams ({self._per_unit} samples each at {cfg.fs_hz:g} Hz)",
            )
        self._wall0_s = time.time()
        if hasattr(bus, "send_frames"):
            self._sink: Any = bus
        else:
            self._sink = BusSink(bus, blocking=not cfg.realtime)
        self._source: SimSource | PlayerSource | TorqueMultisineSource
        if cfg.mode == "sim":
            self._source = SimSource(cfg)
        elif cfg.mode == "torque_multisine":
            self._source = TorqueMultisineSource(cfg)
        else:
            self._source = PlayerSource(cfg)
        self._faults = _FaultInjector(cfg.faults, cfg.fs_hz)
        super().__init__("rtsid-plant", ends_by_itself=True)  # a player reaches its end
        self._c = dict.fromkeys(
            (
                "samples",
                "generated",
                "frames_sent",
                "tx_overflows",
                "skipped",
                "late_ticks",
                "commands",
                "diagnostics",
                "saturated",
            ),
            0,
        )
        self._max_lag_s = 0.0
        self._record = np.zeros((record_samples, 2), dtype=np.float64)  # raw codes
        diagnostics = getattr(self.wire, "builtin", False) and cfg.diagnostics_hz > 0
        self._diag_every = round(cfg.fs_hz / cfg.diagnostics_hz) if diagnostics else 0
        self._t_start = time.monotonic()
        self.done = threading.Event()
        database()  # parse the DBC now, not in the middle of the first block

    # ------------------------------------------------------------------ life cycle
    def _interrupt(self) -> None:
        if isinstance(self._sink, BusSink):
            self._sink.stop.set()

    # ------------------------------------------------------------------ accessors
    @property
    def truth(self) -> PlantTruth | None:
        """True I, B, K(t) of the simulated joint (None in player mode)."""
        return self._source.truth

    def counters(self) -> PlantCounters:
        """What the plant has done so far."""
        f = self._faults.counts
        return PlantCounters(
            samples=self._c["samples"],
            frames_sent=self._c["frames_sent"],
            dropped=f["dropped"],
            corrupted=f["corrupted"],
            shortened=f["shortened"],
            silenced=f["silenced"],
            duplicated=f["duplicated"],
            reordered=f["reordered"],
            error_frames=f["error_frames"],
            unknown_frames=f["unknown_frames"],
            saturated=self._c["saturated"],
            tx_overflows=self._c["tx_overflows"],
            skipped=self._c["skipped"],
            late_ticks=self._c["late_ticks"],
            max_lag_s=self._max_lag_s,
            commands=self._c["commands"],
            diagnostics=self._c["diagnostics"],
        )

    def lost_indices(self) -> NDArray[np.int64]:
        """Sample indices the faults destroyed (dropped, corrupt, short, silenced)."""
        return np.sort(self._faults.lost_indices[: self._faults.lost_count])

    def recorded(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Position (rad) and torque (N·m) of the first recorded samples, as encoded."""
        n = min(self._c["generated"], self._record.shape[0])
        return self.wire.to_si(self._record[:n, 0], self._record[:n, 1])

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:  # an error is kept in .error by ThreadOwner
        try:
            self._loop()
        finally:
            self.done.set()

    def _loop(self) -> None:
        cfg = self.cfg
        per_tick = cfg.frames_per_tick if cfg.realtime else cfg.block_samples
        tick_s = per_tick / cfg.fs_hz
        t0 = time.monotonic()
        self._wall0_s = time.time()
        tick = 0
        pending: list[list[can.Message]] = []  # frames of each remaining sample of the block
        cursor = 0
        skip = 0  # samples to leave out after the plant fell far behind its deadlines
        while not self._stop.is_set():
            if cursor >= len(pending):
                if self._exhausted():
                    break
                pending, cursor = self._next_frames(), 0
                if not pending:
                    break
            if skip:
                n_skip = min(skip, len(pending) - cursor)
                skip -= n_skip
                cursor += n_skip
                self._c["skipped"] += n_skip
                continue
            samples = pending[cursor : cursor + per_tick]
            batch = [f for sample in samples for f in sample]
            cursor += per_tick
            if cfg.realtime:
                t0, tick, skip = self._wait_for_tick(t0, tick, tick_s)
            self._send(batch)
            self._c["samples"] += len(samples)
            self._handle_commands()
        self.done.set()

    def _exhausted(self) -> bool:
        source = self._source
        if isinstance(source, PlayerSource) and source.finished:
            return True
        return bool(self.cfg.max_samples) and self._c["generated"] >= self.cfg.max_samples

    def _wait_for_tick(self, t0: float, tick: int, tick_s: float) -> tuple[float, int, int]:
        """Sleep until tick ``tick``'s absolute deadline; returns ``(t0, tick + 1, skip)``.

        Far behind (> 1 s, e.g. the process was suspended), the schedule moves on and the
        samples whose time has passed are skipped, as a robot's full transmit queue would
        lose them, so that counters keep matching time.
        """
        deadline = t0 + tick * tick_s
        lag = time.monotonic() - deadline
        if lag < 0:
            time.sleep(-lag)
        elif lag > tick_s:
            self._c["late_ticks"] += 1
            self._max_lag_s = max(self._max_lag_s, lag)
            if lag > _MAX_LAG_S:
                ticks = int(lag / tick_s)
                return t0, tick + 1 + ticks, ticks * self.cfg.frames_per_tick
        return t0, tick + 1, 0

    def _send(self, batch: list[can.Message]) -> None:
        failed = self._sink.send_frames(batch)
        self._c["tx_overflows"] += failed
        self._c["frames_sent"] += len(batch) - failed

    def _handle_commands(self) -> None:
        wire = self.wire
        if isinstance(wire, UdpLayout):
            return
        for msg in self._sink.poll_received():
            if not msg.is_error_frame:
                command = wire.decode_command(msg)
                if command is not None:
                    self._source.apply(command)
                    self._c["commands"] += 1

    def _next_frames(self) -> list[list[can.Message]]:
        """Frames of the next block, grouped per sample (diagnostics ride along)."""
        block = self._source.next_block()
        n = block.position_rad.size
        if n == 0:
            return []
        if self.cfg.max_samples:
            n = min(n, self.cfg.max_samples - self._c["generated"])
        n -= n % self._per_unit  # whole datagrams (only max_samples can cut one)
        if n <= 0:
            return []
        index = block.first_index + np.arange(n, dtype=np.int64)
        groups = self._encode(block, n, index)
        frames = self._faults.frames(index[:: self._per_unit], groups, self._per_unit)
        self._c["generated"] += n
        return self._group(frames, index)

    def _encode(self, block: Block, n: int, index: NDArray[np.int64]) -> list[list[Any]]:
        """Quantised, flagged and encoded samples: the frames (datagrams) of each unit."""
        torque = block.torque_nm[:n]
        limit = self.cfg.faults.saturate_torque_nm
        sensor_sat = np.zeros(n, dtype=bool)
        if limit > 0:
            sensor_sat = np.abs(torque) > limit
            torque = np.clip(torque, -limit, limit)
        pos_raw, pos_sat, trq_raw, trq_sat = self.wire.quantise(block.position_rad[:n], torque)
        trq_sat |= sensor_sat
        status = (
            np.where(pos_sat, STATUS_POSITION_SATURATED, 0)
            | np.where(trq_sat, STATUS_TORQUE_SATURATED, 0)
            | np.where(block.discontinuity[:n], STATUS_DISCONTINUITY, 0)
            | (STATUS_PERTURBATION_ON if block.perturbation_on else 0)
        )
        self._c["saturated"] += int(np.count_nonzero(pos_sat | trq_sat))
        self._keep_record(index, pos_raw, trq_raw)
        every = round(self.cfg.marker_every_s * self.cfg.fs_hz)
        marker = (index // every) % 256 if every else np.zeros(n, dtype=np.int64)
        return self.wire.encode_samples(
            index,
            pos_raw,
            trq_raw,
            status,
            marker=marker,
            wall0_s=self._wall0_s,
            fs_hz=self.cfg.fs_hz,
        )

    def _keep_record(self, index: NDArray[np.int64], pos: NDArray[Any], trq: NDArray[Any]) -> None:
        cap = self._record.shape[0]
        keep = index < cap
        if np.any(keep):
            self._record[index[keep], 0] = pos[keep]
            self._record[index[keep], 1] = trq[keep]

    def _group(
        self, frames: list[can.Message], index: NDArray[np.int64]
    ) -> list[list[can.Message]]:
        """Split the frame list into ``len(index)`` per-sample groups of roughly equal share."""
        n = index.size
        groups: list[list[can.Message]] = [[] for _ in range(n)]
        # faults change the frame count; spread frames over sample slots in order
        per = len(frames) / n
        for k, frame in enumerate(frames):
            groups[min(int(k / per), n - 1)].append(frame)
        if self._diag_every:
            for j in np.flatnonzero(index % self._diag_every == 0):
                groups[int(j)].append(self._diagnostics_frame(int(index[j])))
        return groups

    def _diagnostics_frame(self, index: int) -> can.Message:
        page = (index // self._diag_every) % 2
        if page == 0:
            data = encode_diagnostics(0, MotorTemperature=35.0, SupplyVoltage=48.0, FaultCode=0)
        else:
            data = encode_diagnostics(
                1,
                Uptime=int(time.monotonic() - self._t_start),
                TxOverflows=min(self._c["tx_overflows"], 0xFFFFFF),
            )
        self._c["diagnostics"] += 1
        return can.Message(arbitration_id=DIAGNOSTICS_ID, data=data, is_extended_id=False)


def plant_fields() -> tuple[str, ...]:
    """Names of :class:`PlantCounters` fields (for tables)."""
    return tuple(f.name for f in fields(PlantCounters))
