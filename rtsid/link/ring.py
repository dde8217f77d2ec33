"""Preallocated single-writer ring buffer of samples; readers never block the writer.

Every row stands for one sample index: indices are contiguous, and a sample that never
arrived is a row with ``valid = False`` (never interpolated). Slot of index ``i`` is
``i % capacity``.

Consistency without locks (a seqlock on the indices): the writer first *claims* the indices
it is about to write, fills their slots, then publishes the new ``newest``; a reader reads
``newest``, copies the rows it wants, then reads the claim. A row of index ``j`` can have
been (partly) overwritten during the copy only if ``j <= claimed_after - capacity``; the reader then
retries (or, in :meth:`RingBuffer.read_since`, skips those rows and counts them as
overwritten). The writer never waits for anybody. Readers serialise among themselves with a
lock only to update the shared overrun counter.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from rtsid.ident.records import built

__all__ = ["RingBuffer", "Snapshot"]

_MAX_READ_ATTEMPTS = 8
_SCALAR_ROWS = 16  # append_block writes up to this many rows element by element
_Row = TypeVar("_Row", bound=np.generic)  # a column's element type


@dataclass(frozen=True)
class Snapshot:
    """A consistent copy of consecutive rows of the ring (oldest first).

    Attributes
    ----------
    sample_index : numpy.ndarray of int64, shape (n,)
        Unwrapped sample indices, contiguous (``sample_index[k] = first + k``).
    position_rad : numpy.ndarray of float64, shape (n,)
        Joint angle, rad (0.0 where not valid).
    torque_nm : numpy.ndarray of float64, shape (n,)
        Torque, N·m (0.0 where not valid).
    valid : numpy.ndarray of bool, shape (n,)
        False for rows standing for lost samples.
    status : numpy.ndarray of uint8, shape (n,)
        Status bits of the frame (``rtsid.link.protocol.STATUS_*``).
    host_time_s : numpy.ndarray of float64, shape (n,)
        ``time.monotonic()`` when the frame was received (for lost rows: when the gap was
        detected).
    bus_time_s : numpy.ndarray of float64, shape (n,)
        The interface's timestamp of the frame, s (its own clock; NaN for lost rows).
    overwritten : int
        Rows between the requested cursor and ``sample_index[0]`` that the writer had
        already overwritten (only :meth:`RingBuffer.read_since` sets it).
    """

    sample_index: NDArray[np.int64]
    position_rad: NDArray[np.float64]
    torque_nm: NDArray[np.float64]
    valid: NDArray[np.bool_]
    status: NDArray[np.uint8]
    host_time_s: NDArray[np.float64]
    bus_time_s: NDArray[np.float64]
    overwritten: int = 0

    def __len__(self) -> int:
        return int(self.sample_index.size)

    @property
    def next_index(self) -> int:
        """Cursor to pass to the next :meth:`RingBuffer.read_since` call."""
        return int(self.sample_index[-1]) + 1 if self.sample_index.size else -1

    def tail(self, n: int) -> Snapshot:
        """The newest ``n`` rows (views, not copies); the whole snapshot when it is shorter."""
        if n >= len(self):
            return self
        cut = slice(len(self) - n, None)
        return built(  # the constructor's record without its frozen __init__ (every hop)
            Snapshot,
            sample_index=self.sample_index[cut],
            position_rad=self.position_rad[cut],
            torque_nm=self.torque_nm[cut],
            valid=self.valid[cut],
            status=self.status[cut],
            host_time_s=self.host_time_s[cut],
            bus_time_s=self.bus_time_s[cut],
            overwritten=0,
        )


class RingBuffer:
    """Fixed-capacity ring of samples with one writer and any number of readers.

    Parameters
    ----------
    capacity : int
        Rows kept (e.g. ``10 s × 2500 Hz``); allocated once.
    """

    def __init__(self, capacity: int) -> None:
        if capacity < 2:
            raise ValueError(f"ring capacity must be >= 2 rows, got {capacity}")
        self.capacity = int(capacity)
        self._index = np.full(capacity, -1, dtype=np.int64)
        self._position = np.zeros(capacity)
        self._torque = np.zeros(capacity)
        self._valid = np.zeros(capacity, dtype=bool)
        self._status = np.zeros(capacity, dtype=np.uint8)
        self._host_time = np.zeros(capacity)
        self._bus_time = np.full(capacity, np.nan)
        self._first = -1  # index of the first row ever written
        self._newest = -1  # index of the newest published row
        self._claimed = -1  # highest index whose slot the writer is writing or has written
        self._reader_lock = threading.Lock()
        self.reader_overruns = 0
        # (index, event): the writer sets event once row index is published (see wake_at)
        self._wake: tuple[int, threading.Event] | None = None

    # ------------------------------------------------------------------ writer side
    @property
    def newest_index(self) -> int:
        """Index of the newest published row (-1 before the first write)."""
        return self._newest

    @property
    def first_index(self) -> int:
        """Index of the first row ever written, held or not (-1 before the first write)."""
        return self._first if self._newest >= 0 else -1

    @property
    def oldest_index(self) -> int:
        """Index of the oldest row still held (-1 before the first write)."""
        if self._newest < 0:
            return -1
        return max(self._first, self._newest - self.capacity + 1)

    def start_at(self, index: int) -> None:
        """Set the index of the first row (writer only; before the first write)."""
        if self._newest >= 0:
            raise RuntimeError("start_at() after rows were written")
        self._first = index
        self._newest = index - 1
        self._claimed = index - 1

    def append(
        self,
        position_rad: float,
        torque_nm: float,
        status: int,
        host_time_s: float,
        bus_time_s: float,
    ) -> int:
        """Write one valid sample as index ``newest + 1`` and publish it; returns its index."""
        index = self._newest + 1
        if self._first < 0:
            self._first = index
        self._claimed = index
        slot = index % self.capacity
        self._index[slot] = index
        self._position[slot] = position_rad
        self._torque[slot] = torque_nm
        self._valid[slot] = True
        self._status[slot] = status
        self._host_time[slot] = host_time_s
        self._bus_time[slot] = bus_time_s
        self._newest = index
        wake = self._wake
        if wake is not None and index >= wake[0]:
            wake[1].set()
        return index

    def append_block(
        self,
        position_rad: Sequence[float],
        torque_nm: Sequence[float],
        status: Sequence[int],
        host_time_s: float,
        bus_time_s: Sequence[float],
    ) -> int:
        """Write consecutive valid samples as indices ``newest + 1 …`` and publish them at once.

        The same rows as one :meth:`append` per sample with the same ``host_time_s`` (the
        frames of one read arrive together), in one slice assignment per column (two when
        the rows wrap around the arrays' end).

        Parameters
        ----------
        position_rad, torque_nm : sequence of float, shape (n,)
            Joint angle (rad) and torque (N·m) of each sample.
        status : sequence of int, shape (n,)
            Status bits of each sample.
        host_time_s : float
            ``time.monotonic()`` when the samples arrived.
        bus_time_s : sequence of float, shape (n,)
            The interface's timestamp of each frame, s.

        Returns
        -------
        int
            Index of the newest row (the last sample).
        """
        n = len(position_rad)
        if n == 0:
            return self._newest
        if n >= self.capacity:  # only the newest rows would survive: write them one by one
            for k in range(n):
                self.append(position_rad[k], torque_nm[k], status[k], host_time_s, bus_time_s[k])
            return self._newest
        start = self._newest + 1
        if self._first < 0:
            self._first = start
        stop = start + n
        self._claimed = stop - 1
        if n <= _SCALAR_ROWS and isinstance(position_rad, list):
            self._write_rows(start, position_rad, torque_nm, status, host_time_s, bus_time_s)
        else:
            self._write_slices(start, position_rad, torque_nm, status, host_time_s, bus_time_s)
        self._newest = stop - 1
        wake = self._wake
        if wake is not None and self._newest >= wake[0]:
            wake[1].set()
        return self._newest

    def _write_rows(
        self,
        start: int,
        position_rad: Sequence[float],
        torque_nm: Sequence[float],
        status: Sequence[int],
        host_time_s: float,
        bus_time_s: Sequence[float],
    ) -> None:
        """A few rows element by element (cheaper than converting short lists to arrays)."""
        capacity = self.capacity
        index, position, torque = self._index, self._position, self._torque
        valid, status_col, host, bus = self._valid, self._status, self._host_time, self._bus_time
        for k in range(len(position_rad)):
            slot = (start + k) % capacity
            index[slot] = start + k
            position[slot] = position_rad[k]
            torque[slot] = torque_nm[k]
            valid[slot] = True
            status_col[slot] = status[k]
            host[slot] = host_time_s
            bus[slot] = bus_time_s[k]

    def _write_slices(
        self,
        start: int,
        position_rad: Sequence[float],
        torque_nm: Sequence[float],
        status: Sequence[int],
        host_time_s: float,
        bus_time_s: Sequence[float],
    ) -> None:
        """Many rows as one slice assignment per column (two when they wrap around)."""
        n = len(position_rad)
        slot = start % self.capacity
        first = min(n, self.capacity - slot)
        for lo, hi, at in ((0, first, slot), (first, n, 0)):
            if hi <= lo:
                continue
            rows = slice(at, at + hi - lo)
            self._index[rows] = np.arange(start + lo, start + hi)
            self._position[rows] = position_rad[lo:hi]
            self._torque[rows] = torque_nm[lo:hi]
            self._valid[rows] = True
            self._status[rows] = status[lo:hi]
            self._host_time[rows] = host_time_s
            self._bus_time[rows] = bus_time_s[lo:hi]

    def append_gap(self, count: int, host_time_s: float) -> None:
        """Write ``count`` invalid rows (lost samples) after ``newest`` and publish them.

        Only the last ``capacity`` rows of a long gap are written (the others would be
        overwritten at once); indices still advance by ``count``.
        """
        if count <= 0:
            return
        start = self._newest + 1
        if self._first < 0:
            self._first = start
        stop = start + count
        self._claimed = stop - 1
        self._write_invalid(max(start, stop - self.capacity), stop, host_time_s)
        self._newest = stop - 1
        wake = self._wake
        if wake is not None and self._newest >= wake[0]:
            wake[1].set()

    def wake_at(self, index: int, event: threading.Event) -> None:
        """Have the writer set ``event`` when row ``index`` is published (at once if it is).

        One waiter at a time (a new call replaces the previous one). Clear the event
        before calling: the writer sets it for every row at or past ``index``, so a reader
        woken by the sample clock needs no polling.
        """
        self._wake = (index, event)
        if self._newest >= index:
            event.set()

    def _write_invalid(self, lo: int, hi: int, host_time_s: float) -> None:
        slots_a = lo % self.capacity
        n = hi - lo
        first = min(n, self.capacity - slots_a)
        for begin, length, base in ((slots_a, first, lo), (0, n - first, lo + first)):
            if length <= 0:
                continue
            sl = slice(begin, begin + length)
            self._index[sl] = np.arange(base, base + length)
            self._position[sl] = 0.0
            self._torque[sl] = 0.0
            self._valid[sl] = False
            self._status[sl] = 0
            self._host_time[sl] = host_time_s
            self._bus_time[sl] = np.nan

    # ------------------------------------------------------------------ reader side
    def is_valid(self, index: int) -> bool | None:
        """Whether row ``index`` holds a received sample (None if it is not in the ring)."""
        if index > self._newest or index < self.oldest_index:
            return None
        slot = index % self.capacity
        valid = bool(self._valid[slot])
        return valid if self._index[slot] == index else None

    def latest(self, n: int) -> Snapshot | None:
        """A consistent copy of the newest ``n`` rows, or None if fewer have been written.

        Parameters
        ----------
        n : int
            Rows wanted, ``1 <= n < capacity``.
        """
        if not 1 <= n < self.capacity:
            raise ValueError(f"latest(n) needs 1 <= n < capacity={self.capacity}, got {n}")
        for _ in range(_MAX_READ_ATTEMPTS):
            newest = self._newest
            if newest < 0 or newest - self._first + 1 < n:
                return None
            snap = self._copy(newest - n + 1, newest + 1)
            if newest - n + 1 > self._claimed - self.capacity:
                return snap
        return None  # the writer lapped us repeatedly: the caller is far too slow

    def read_since(self, next_index: int, max_n: int) -> Snapshot:
        """Every row from cursor ``next_index`` on (at most ``max_n``), for loggers.

        Rows the writer overwrote before they were read are skipped and counted in
        ``Snapshot.overwritten`` (and in :attr:`reader_overruns`). A cursor below the first
        row ever written starts at that row without counting anything.

        Returns
        -------
        Snapshot
            Possibly empty; continue from ``snapshot.next_index`` (or the same cursor when
            it is empty).
        """
        if max_n < 1:
            raise ValueError(f"max_n must be >= 1, got {max_n}")
        max_n = min(max_n, self.capacity - 1)
        overwritten = 0
        cursor = max(next_index, self._first) if self._first >= 0 else next_index
        for _ in range(_MAX_READ_ATTEMPTS):
            newest = self._newest
            if newest < 0 or cursor > newest:
                return self._empty(overwritten)
            oldest_safe = max(newest, self._claimed) + 1 - self.capacity
            if cursor < oldest_safe:
                overwritten += oldest_safe - cursor
                cursor = oldest_safe
            stop = min(newest + 1, cursor + max_n)
            snap = self._copy(cursor, stop)
            lapped = self._claimed + 1 - self.capacity
            if cursor >= lapped:
                self._count_overruns(overwritten)
                return Snapshot(**{**snap.__dict__, "overwritten": overwritten})
        self._count_overruns(overwritten)
        return self._empty(overwritten)

    def _count_overruns(self, n: int) -> None:
        if n:
            with self._reader_lock:
                self.reader_overruns += n

    def _copy(self, lo: int, hi: int) -> Snapshot:
        """Copy rows ``lo .. hi - 1`` (``hi - lo < capacity``) in index order.

        One or two slice copies per column (two when the rows wrap around the end of the
        arrays), not a gather through an index array: a window with the slow lane's history
        (4025 rows, seven columns) took 0.11 ms that way, on the worker, every hop.
        """
        if hi <= lo:
            return self._empty(0)
        start = lo % self.capacity
        stop = start + (hi - lo)
        wrapped = stop - self.capacity  # rows taken from the arrays' start (<= 0: none)

        def rows(column: NDArray[_Row]) -> NDArray[_Row]:
            if wrapped <= 0:
                return column[start:stop].copy()
            return np.concatenate((column[start:], column[:wrapped]))

        return Snapshot(
            rows(self._index),
            rows(self._position),
            rows(self._torque),
            rows(self._valid),
            rows(self._status),
            rows(self._host_time),
            rows(self._bus_time),
        )

    @staticmethod
    def _empty(overwritten: int) -> Snapshot:
        return Snapshot(
            np.empty(0, np.int64),
            np.empty(0),
            np.empty(0),
            np.empty(0, bool),
            np.empty(0, np.uint8),
            np.empty(0),
            np.empty(0),
            overwritten,
        )
