"""The recent-history ring a daemon answers zenoh queries from (late joiners, ``rtsid query``).

Every message the daemon publishes on a history channel (estimates, status, and any other
channel but raw samples) is kept, as the bytes that went out, in a bounded ring per channel
holding at least the last ``history_s`` (default 10 min). The publishing thread appends the
payload it already holds (two list appends, no copy); every 256 messages it seals a block, and
the daemon's housekeeping tick compresses sealed blocks (zstd level 1,
:meth:`HistoryStore.compact`) in a gap of the window worker's of their own, so 10 minutes of
estimates at 250 Hz (a 4 ms hop) take ≈ 16 MiB instead of ≈ 95 MiB. Queries are
served from the blocks a reader takes under a short lock (references only); decompression and
the reply are built on zenoh's callback thread, so a flood of queries cannot delay the window
worker.

Key expression ``<prefix>/<robot>/<joint>/history``; parameters (zenoh selector syntax,
``;``-separated, all optional):

=============== ================================================================================
``kind``        channels to return, comma-separated (default: every channel held)
``since``       the last duration: ``60s``, ``5m``, ``1.5h``, ``250ms`` or plain seconds
``from``, ``to``  UNIX time bounds, ns (inclusive, 0 … 2**63 − 1); ``since`` and ``from`` exclude
                each other
=============== ================================================================================

``since`` is at most :data:`MAX_SINCE_S` (a year: far beyond any ring); anything else
(``1e308``, negative, NaN, not a number) gets an error reply naming the parameter.

Each channel is answered by one or more replies (parts of at most :data:`PART_MESSAGES`
messages), each a JSON object::

    {"robot", "joint", "kind", "from_ns", "to_ns", "held_from_ns", "first_ns", "complete",
     "note", "part", "parts", "messages": [ ...the messages, oldest first... ]}

``held_from_ns`` is the publication time of the oldest message the daemon still holds on that
channel (null: none yet); ``complete`` is false when the range starts before it, and ``note``
then says where the returned history starts (:data:`HISTORY_PART_SCHEMA`). A malformed query
gets an error reply (JSON ``{"error": ...}``) naming the parameter and what is accepted. A
client must ask with consolidation off (``zenoh.ConsolidationMode.NONE``) to receive every part.
"""

from __future__ import annotations

import bisect
import itertools
import json
import math
import re
import threading
import time
from array import array
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass

import zstandard

__all__ = [
    "HISTORY_PART_SCHEMA",
    "MAX_SINCE_S",
    "PART_MESSAGES",
    "HistoryQuery",
    "HistoryStore",
    "MessageRing",
    "QueryError",
    "parse_duration_s",
    "parse_history_query",
]

#: Messages per reply: bounds the bytes assembled in one go (≈ 0.4 MB of estimates).
PART_MESSAGES = 500
_DURATION = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(ms|s|m|min|h)?\s*$")
_UNIT_S = {"ms": 1e-3, "s": 1.0, "m": 60.0, "min": 60.0, "h": 3600.0, None: 1.0}
_PARAMETERS = ("kind", "since", "from", "to")
#: Longest ``since`` accepted, s (one year).
MAX_SINCE_S = 366 * 86400.0
_MAX_NS = 2**63 - 1
_NS_OR_NULL = {"type": ["integer", "null"], "minimum": 0}

#: One reply of the ``history`` queryable (what clients check each reply against; the
#: messages inside are checked against their channel's schema).
HISTORY_PART_SCHEMA = {
    "type": "object",
    "properties": {
        "robot": {"type": "string"},
        "joint": {"type": "string"},
        "kind": {"type": "string"},
        "from_ns": {"type": "integer", "minimum": 0},
        "to_ns": {"type": "integer", "minimum": 0},
        "held_from_ns": _NS_OR_NULL,
        "first_ns": _NS_OR_NULL,
        "complete": {"type": "boolean"},
        "note": {"type": "string"},
        "part": {"type": "integer", "minimum": 0},
        "parts": {"type": "integer", "minimum": 1},
        "messages": {"type": "array", "maxItems": PART_MESSAGES, "items": {"type": "object"}},
    },
    "required": [
        "robot", "joint", "kind", "from_ns", "to_ns", "held_from_ns", "first_ns", "complete",
        "note", "part", "parts", "messages",
    ],
    "additionalProperties": False,
}  # fmt: skip


class QueryError(ValueError):
    """A malformed history query (answered with an error reply, never raised to zenoh)."""


def parse_duration_s(text: str, name: str = "since") -> float:
    """``"60s"``, ``"5m"``, ``"1.5h"``, ``"250ms"`` or ``"90"`` (s) → seconds.

    Raises
    ------
    QueryError
        Not a positive finite duration of at most :data:`MAX_SINCE_S`.
    """
    match = _DURATION.match(text)
    value = float(match.group(1)) * _UNIT_S[match.group(2)] if match else math.nan
    if not (math.isfinite(value) and value > 0):
        raise QueryError(
            f"{name}={text[:40]!r} is not a duration; expected e.g. 60s, 5m, 1.5h, 250ms or seconds"
        )
    if value > MAX_SINCE_S:
        raise QueryError(
            f"{name}={text[:40]!r} is longer than a year ({MAX_SINCE_S:g} s); ask for less"
        )
    return value


@dataclass(frozen=True)
class HistoryQuery:
    """A parsed history query: which channels and the UNIX time range, ns (inclusive)."""

    kinds: tuple[str, ...] | None
    from_ns: int
    to_ns: int


def _parse_ns(name: str, text: str) -> int:
    try:
        value = int(text) if text.strip().isdigit() or text.strip().startswith("-") else None
    except ValueError:  # more digits than Python converts
        value = None
    if value is None:
        raise QueryError(f"{name}={text[:40]!r} is not an integer; expected UNIX time in ns")
    if value < 0:
        raise QueryError(f"{name}={text[:40]!r} is negative; expected UNIX time in ns")
    if value > _MAX_NS:
        raise QueryError(
            f"{name}={text[:40]!r} is out of range; expected UNIX time in ns, 0 … 2**63-1"
        )
    return value


def parse_history_query(
    parameters: Mapping[str, str], *, now_ns: int | None = None
) -> HistoryQuery:
    """Validate a history query's parameters (see the module docstring).

    Raises
    ------
    QueryError
        An unknown parameter, a malformed value, ``since`` together with ``from``, or a range
        that ends before it starts.
    """
    unknown = sorted(set(parameters) - set(_PARAMETERS))
    if unknown:
        raise QueryError(
            f"unknown query parameter {unknown[0][:40]!r}; accepted: " + ", ".join(_PARAMETERS)
        )
    now = time.time_ns() if now_ns is None else now_ns
    if "since" in parameters and "from" in parameters:
        raise QueryError("give either since= or from=, not both")
    from_ns = 0
    if "since" in parameters:
        from_ns = max(0, now - int(parse_duration_s(parameters["since"]) * 1e9))
    elif "from" in parameters:
        from_ns = _parse_ns("from", parameters["from"])
    to_ns = _parse_ns("to", parameters["to"]) if "to" in parameters else 2**63 - 1
    if to_ns < from_ns:
        raise QueryError(f"to={to_ns} is before the range's start {from_ns}; swap them")
    # ``kind=`` naming no channel (empty, blanks, commas) means every channel, as if left out:
    # an empty tuple would ask for nothing and the query would get no reply at all.
    names = tuple(k.strip() for k in parameters.get("kind", "").split(",") if k.strip())
    return HistoryQuery(names or None, from_ns, to_ns)


class _RawBlock:
    """Consecutive messages as published (the payload bytes objects themselves, no copy)."""

    __slots__ = ("first", "payloads", "times")

    def __init__(self, first: int, times: Sequence[int], payloads: Sequence[bytes]) -> None:
        self.first = first  # index (in appends since the start) of its first message
        self.times = times  # publication times, ns, oldest first
        self.payloads = payloads

    @property
    def count(self) -> int:
        return len(self.times)

    @property
    def stored_bytes(self) -> int:
        return sum(len(p) for p in self.payloads)

    def messages(self) -> Sequence[bytes]:
        return self.payloads


class _PackedBlock:
    """Consecutive messages compressed as one: their payloads joined and zstd-compressed, with
    each one's end offset in the joined bytes (a JSON estimate shrinks ≈ 5.8×)."""

    __slots__ = ("data", "ends", "first", "times")

    #: zstd level: level 1 compresses a block of 256 of the daemon's estimates (≈ 160 kB)
    #: 5.8× in 0.61 ms of CPU with the GIL released; zlib level 1 (this block's format before
    #: issue 22) 4.2× in 1.95 ms (the same 25 blocks back to back, on a loaded machine). The
    #: join and the offsets around it hold the GIL ≈ 0.05 ms.
    LEVEL = 1

    def __init__(self, block: _RawBlock, compressor: zstandard.ZstdCompressor) -> None:
        self.first = block.first
        self.times = array("q", block.times)
        self.ends = array("q", itertools.accumulate(map(len, block.payloads)))
        self.data = _exact_copy(compressor.compress(b"".join(block.payloads)))

    @property
    def count(self) -> int:
        return len(self.times)

    @property
    def stored_bytes(self) -> int:
        return len(self.data) + 8 * (len(self.times) + len(self.ends))

    def messages(self) -> Sequence[bytes]:
        joined = zstandard.decompress(self.data)
        starts = itertools.chain((0,), self.ends)
        return [joined[a:b] for a, b in zip(starts, self.ends, strict=False)]


_Block = _RawBlock | _PackedBlock


def _exact_copy(compressed: bytes) -> bytes:
    """``compressed`` in an allocation of its own length.

    python-zstandard's ``ZstdCompressor.compress`` allocates its result at the input's
    compression bound (about the input's size) and only shortens the object's length: a
    packed block of 256 estimates (≈ 145 kB in, ≈ 28 kB out) kept the whole 145 kB, so the
    history of a daemon at a 4 ms hop grew by ≈ 8.7 MiB a minute instead of ≈ 1.6 (its
    ``held_bytes`` counted the length, not the allocation). The copy costs microseconds.
    """
    return bytes(memoryview(compressed))


class MessageRing:
    """The last ``capacity - 1`` (publication time ns, payload) messages of one channel; one
    writer, any readers, one compactor.

    The newest messages sit in an open block: the payload bytes the publisher already holds,
    appended to a list (no copy, no lock). Every :attr:`block_messages` messages the writer
    seals the block (a lock held for a tuple swap). :meth:`compact`, called from another
    thread (the daemon's housekeeping tick), deflates sealed blocks into one compressed bytes
    object each (:class:`_PackedBlock`): a 10-minute history of JSON estimates at 250 Hz
    holds ≈ 16 MiB instead of ≈ 95 MiB raw. Without :meth:`compact` the sealed blocks stay
    raw, still bounded by ``capacity``. The oldest block is dropped once every message in it
    is older than the newest ``capacity - 1``; memory grows while the history fills, up to
    that bound.

    Readers take the blocks under the same lock (reference copies only; decompression happens
    after, on the reader's thread): a copy is always a run of consecutive messages.

    Parameters
    ----------
    capacity : int
        Messages held, plus one (the oldest is dropped once ``capacity - 1`` newer are held).
    block_messages : int, optional
        Messages per block (default :data:`BLOCK_MESSAGES`, fewer for a small ring).
    """

    #: Messages per block at most (256 estimates ≈ 160 kB raw, ≈ 40 kB deflated).
    BLOCK_MESSAGES = 256

    def __init__(self, capacity: int, block_messages: int | None = None) -> None:
        if capacity < 1:
            raise ValueError(f"MessageRing capacity {capacity}; expected >= 1")
        self.capacity = int(capacity)
        default = max(1, min(self.BLOCK_MESSAGES, self.capacity // 8))
        self.block_messages = int(block_messages or default)
        self._lock = threading.Lock()  # block swaps (writer, compactor) and reader copies
        self._compacting = threading.Lock()  # one compactor at a time
        self._compressor = zstandard.ZstdCompressor(level=_PackedBlock.LEVEL)  # compactor's
        self._seals = 0  # blocks sealed so far (writer)
        self._seals_compacted = 0  # of them, those a compaction has taken (compactor)
        self._blocks: tuple[_Block, ...] = ()  # sealed, oldest first (replaced, never mutated)
        self._open_first = 0  # index of the open block's first message
        self._open_times: list[int] = []
        self._open_payloads: list[bytes] = []
        self._written = 0  # messages appended so far

    def __len__(self) -> int:
        return min(self._written, self.capacity - 1)

    @property
    def written(self) -> int:
        """Messages appended since the start."""
        return self._written

    @property
    def held_bytes(self) -> int:
        """Bytes the ring keeps for its messages (payloads, compressed or not, and their
        times and offsets)."""
        with self._lock:
            blocks, payloads = self._blocks, list(self._open_payloads)
        return sum(b.stored_bytes for b in blocks) + sum(len(p) for p in payloads)

    def append(self, time_ns: int, payload: bytes) -> None:
        """Add one message (writer thread only): two list appends; every
        :attr:`block_messages` messages a seal (a short lock, no copy, no compression)."""
        self._open_times.append(time_ns)
        self._open_payloads.append(payload)
        self._written += 1
        if len(self._open_times) >= self.block_messages:
            self._seal()

    def _seal(self) -> None:
        block = _RawBlock(self._open_first, self._open_times, self._open_payloads)
        with self._lock:
            oldest_kept = self._written - self.capacity + 1
            blocks = (*self._blocks, block)
            drop = 0
            while drop < len(blocks) and blocks[drop].first + blocks[drop].count <= oldest_kept:
                drop += 1
            self._blocks = blocks[drop:]
            self._open_first = self._written
            self._open_times, self._open_payloads = [], []
            self._seals += 1

    def compact(self) -> int:
        """Deflate the sealed blocks still raw (any thread but the writer's; the compression
        runs outside the lock and releases the GIL). Returns how many blocks it packed."""
        if not self._compacting.acquire(blocking=False):
            return 0
        try:
            with self._lock:
                raw = [b for b in self._blocks if isinstance(b, _RawBlock)]
                self._seals_compacted = self._seals
            if not raw:
                return 0
            packed = {b.first: _PackedBlock(b, self._compressor) for b in raw}
            with self._lock:  # blocks dropped meanwhile are simply not found
                self._blocks = tuple(packed.get(b.first, b) for b in self._blocks)
            return len(packed)
        finally:
            self._compacting.release()

    @property
    def compaction_due(self) -> bool:
        """A block was sealed since the last :meth:`compact` began (a counter compare: the
        caller may wait for a quiet moment only when there is work)."""
        return self._seals != self._seals_compacted

    def _held(self) -> tuple[tuple[_Block, ...], int]:
        """The blocks holding the newest messages (the open one last) and the index of the
        oldest message held."""
        with self._lock:
            blocks = self._blocks
            first = self._open_first
            times, payloads = list(self._open_times), list(self._open_payloads)
        n = min(len(times), len(payloads))  # the writer may be between its two appends
        end = first + n
        return (*blocks, _RawBlock(first, times[:n], payloads[:n])), max(0, end - self.capacity + 1)

    def snapshot(self, from_ns: int, to_ns: int) -> tuple[list[bytes], int | None, int | None]:
        """The messages published in ``[from_ns, to_ns]``, oldest first.

        Returns
        -------
        messages : list of bytes
        held_from_ns : int or None
            Publication time of the oldest message still held (None: empty).
        first_ns : int or None
            Publication time of the first message returned (None: none returned).
        """
        blocks, oldest = self._held()
        held_from: int | None = None
        first: int | None = None
        messages: list[bytes] = []
        for block in blocks:
            skip = max(0, oldest - block.first)  # older than the newest capacity - 1
            if skip >= block.count:
                continue
            times = block.times
            if held_from is None:
                held_from = times[skip]
            if times[-1] < from_ns or times[skip] > to_ns:
                continue
            lo = max(skip, bisect.bisect_left(times, from_ns))
            hi = bisect.bisect_right(times, to_ns)
            if lo >= hi:
                continue
            if first is None:
                first = times[lo]
            messages.extend(block.messages()[lo:hi])
        return messages, held_from, first

    def newest(self) -> bytes | None:
        """The newest message (None: none yet)."""
        blocks, oldest = self._held()
        for block in reversed(blocks):
            if block.count and block.first + block.count > oldest:
                return block.messages()[-1]
        return None


class HistoryStore:
    """One :class:`MessageRing` per channel, each holding at least ``horizon_s``.

    Parameters
    ----------
    horizon_s : float
        History to keep, s.
    rates_hz : Mapping[str, float]
        Expected message rate per channel, Hz (sizes the rings with 25 % to spare); a
        channel not named gets :data:`DEFAULT_RATE_HZ`.
    """

    DEFAULT_RATE_HZ = 2.0

    def __init__(self, horizon_s: float, rates_hz: Mapping[str, float] | None = None) -> None:
        self.horizon_s = float(horizon_s)
        self._rates = dict(rates_hz or {})
        self._rings: dict[str, MessageRing] = {
            kind: self._ring(kind) for kind in ("estimate", "status", *self._rates)
        }

    def _ring(self, kind: str) -> MessageRing:
        rate = self._rates.get(kind, self.DEFAULT_RATE_HZ)
        return MessageRing(int(self.horizon_s * rate * 1.25) + 16)

    @property
    def kinds(self) -> tuple[str, ...]:
        """Channels held."""
        return tuple(self._rings)

    def compact(self) -> int:
        """Compress every channel's sealed blocks (the daemon's housekeeping tick; never the
        publishing threads). Returns the blocks packed."""
        return sum(ring.compact() for ring in list(self._rings.values()))

    @property
    def compaction_due(self) -> bool:
        """Some channel sealed a block since its last compaction (:meth:`compact` has work)."""
        return any(ring.compaction_due for ring in list(self._rings.values()))

    @property
    def held_bytes(self) -> int:
        """Bytes held for every channel's messages."""
        return sum(ring.held_bytes for ring in list(self._rings.values()))

    def append(self, kind: str, payload: bytes, time_ns: int | None = None) -> None:
        """Keep one published message (on the thread that publishes ``kind``)."""
        ring = self._rings.get(kind)
        if ring is None:  # a channel first seen now; a dict insert is atomic under the GIL
            ring = self._rings[kind] = self._ring(kind)
        ring.append(time.time_ns() if time_ns is None else time_ns, payload)

    def latest(self, kind: str) -> bytes | None:
        """The newest message of ``kind`` (None: none yet)."""
        ring = self._rings.get(kind)
        return None if ring is None else ring.newest()

    def answer(
        self, query: HistoryQuery, *, robot: str, joint: str, now_ns: int | None = None
    ) -> Iterator[bytes]:
        """The reply payloads for ``query`` (see the module docstring), part by part.

        Raises
        ------
        QueryError
            A channel in ``query.kinds`` that this daemon does not hold.
        """
        kinds = self.kinds if query.kinds is None else query.kinds
        for kind in kinds:
            if kind not in self._rings:
                raise QueryError(
                    f"kind={kind[:40]!r} is not held here; held: " + ", ".join(self.kinds)
                )
        now = time.time_ns() if now_ns is None else now_ns
        horizon_from = now - int(self.horizon_s * 1e9)
        for kind in kinds:
            from_ns = max(query.from_ns, horizon_from)
            messages, held_from, first = self._rings[kind].snapshot(from_ns, query.to_ns)
            if held_from is not None:  # older slots may linger, but only the horizon is held
                held_from = max(held_from, horizon_from)
            yield from _parts(
                kind, messages, robot, joint, query.from_ns, query.to_ns, held_from, first
            )


def _parts(
    kind: str,
    messages: list[bytes],
    robot: str,
    joint: str,
    from_ns: int,
    to_ns: int,
    held_from_ns: int | None,
    first_ns: int | None,
) -> Iterable[bytes]:
    complete = held_from_ns is not None and held_from_ns <= from_ns
    if held_from_ns is None:
        note = f"no {kind} messages held yet"
    elif complete:
        note = ""
    else:
        ago_s = (time.time_ns() - held_from_ns) / 1e9
        note = (
            f"history of {kind} starts at {held_from_ns} ns ({ago_s:.1f} s ago): earlier "
            "messages are no longer held (or were never published)"
        )
    parts = max(1, math.ceil(len(messages) / PART_MESSAGES))
    for part in range(parts):
        chunk = messages[part * PART_MESSAGES : (part + 1) * PART_MESSAGES]
        head = {
            "robot": robot,
            "joint": joint,
            "kind": kind,
            "from_ns": from_ns,
            "to_ns": to_ns,
            "held_from_ns": held_from_ns,
            "first_ns": first_ns,
            "complete": complete,
            "note": note,
            "part": part,
            "parts": parts,
        }
        yield json.dumps(head)[:-1].encode() + b', "messages": [' + b",".join(chunk) + b"]}"
