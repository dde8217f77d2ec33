"""The recent-history ring a daemon answers zenoh queries from (late joiners, ``rtsid query``).

Every message the daemon publishes on a history channel (estimates, status, and any other
channel but raw samples) is kept, as the bytes that went out, in a bounded ring per channel
holding at least the last ``history_s`` (default 10 min). Queries are served from a copy of
the ring taken without any lock: the ring has one writer (the thread that publishes that
channel) and appends with two stores and a counter bump; a reader copies the slots it wants
and then re-reads the counter, dropping any slot the writer may have reused meanwhile
(a seqlock without the lock). The writer never waits for a reader, so a flood of queries
cannot delay the window worker; the replies are built on zenoh's callback thread.

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
import json
import math
import re
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass

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


class MessageRing:
    """A fixed number of (publication time ns, payload) slots; one writer, any readers.

    The payloads are copied into one byte arena reserved, and touched, when the first
    message arrives (``capacity`` × its size × :attr:`ARENA_SLACK`), so that a daemon's
    memory reaches its ceiling at once instead of creeping up while the history fills; the
    arena grows (a rare re-layout) only when later messages turn out larger on average.
    Each payload is contiguous in the arena: one that does not fit before the end starts
    again at the beginning.

    Parameters
    ----------
    capacity : int
        Slots (the oldest message is replaced once they are all used).
    """

    #: Arena bytes per slot, as a multiple of the first message's size.
    ARENA_SLACK = 1.5
    #: Message counts at which the arena is checked against the mean size so far (and grown
    #: while it holds little), so that a small first message does not force a growth later.
    _SIZE_CHECKS = frozenset((16, 64, 256, 1024))
    _PAGE = 4096

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError(f"MessageRing capacity {capacity}; expected >= 1")
        self.capacity = int(capacity)
        self._times = [0] * self.capacity
        # (arena, start byte, length per slot): replaced as one on growth, never mutated after.
        self._layout: tuple[bytearray, list[int], list[int]] = (
            bytearray(),
            [0] * self.capacity,
            [0] * self.capacity,
        )
        self._reserved = 0  # byte position (absolute) the writer may be writing up to
        self._generation = 0  # bumped when a growth renumbers the byte positions
        self._written = 0  # messages appended so far; bumped last (the commit)

    def __len__(self) -> int:
        return min(self._written, self.capacity)

    @property
    def written(self) -> int:
        """Messages appended since the start."""
        return self._written

    @property
    def reserved_bytes(self) -> int:
        """Bytes of the arena (0 until the first message)."""
        return len(self._layout[0])

    def append(self, time_ns: int, payload: bytes) -> None:
        """Add one message (writer thread only; O(len(payload)), no lock, no allocation but
        the arena's own, once, or on a rare growth)."""
        slot = self._written % self.capacity
        if self._written in self._SIZE_CHECKS:
            self._fit_mean_size()
        position = self._place(len(payload))
        arena, starts, lengths = self._layout
        offset = position % len(arena)
        arena[offset : offset + len(payload)] = payload
        starts[slot], lengths[slot] = position, len(payload)
        self._times[slot] = time_ns
        self._written += 1

    def _place(self, n: int) -> int:
        """Where the next payload of ``n`` bytes goes (absolute), reserved before it is written."""
        arena, starts, _ = self._layout
        size = len(arena)
        if size == 0:
            self._grow(n)
            return self._place(n)
        position = self._reserved
        if position % size + n > size:  # does not fit before the end: start over at 0
            position += size - position % size
        oldest_kept = self._written - self.capacity + 2  # held after this append
        if n > size or (
            oldest_kept >= 0 and position + n - size > starts[oldest_kept % self.capacity]
        ):
            self._grow(n)
            return self._place(n)
        self._reserved = position + n
        return position

    def _fit_mean_size(self) -> None:
        _, _, lengths = self._layout
        held = min(self._written, self.capacity)
        mean = sum(lengths[:held]) / held if self._written <= self.capacity else 0.0
        if mean * self.capacity * 1.25 > self.reserved_bytes:
            self._grow(round(mean * 1.25))

    def _grow(self, n: int) -> None:
        """A larger arena holding the messages held now, renumbered from byte 0."""
        old, old_starts, old_lengths = self._layout
        wanted = max(2 * len(old), int(self.capacity * max(n, 64) * self.ARENA_SLACK))
        size = -(-wanted // self._PAGE) * self._PAGE
        arena = bytearray(size)
        arena[:: self._PAGE] = bytes(len(range(0, size, self._PAGE)))  # touch every page now
        starts, lengths = [0] * self.capacity, [0] * self.capacity
        position = 0
        for index in range(max(0, self._written - self.capacity + 1), self._written):
            slot = index % self.capacity
            begin, length = old_starts[slot] % len(old), old_lengths[slot]
            arena[position : position + length] = old[begin : begin + length]
            starts[slot], lengths[slot] = position, length
            position += length
        self._generation += 1
        self._layout = (arena, starts, lengths)
        self._reserved = position

    def _time_at(self, index: int) -> int:
        return self._times[index % self.capacity]

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
        for _ in range(8):  # a growth renumbers the bytes meanwhile: copy again (rare)
            generation = self._generation
            copied = self._copy(from_ns, to_ns)
            if self._generation == generation:
                return copied
        return [], None, None

    def newest(self) -> bytes | None:
        """The newest message (None: none yet), without copying the rest."""
        end = self._written
        if end == 0:
            return None
        time_ns = self._time_at(end - 1)
        messages, _, _ = self.snapshot(time_ns, 2**63 - 1)
        return messages[-1] if messages else None

    def _copy(self, from_ns: int, to_ns: int) -> tuple[list[bytes], int | None, int | None]:
        arena, starts, lengths = self._layout
        end = self._written
        start = max(0, end - self.capacity + 1)  # the slot after `end` may be mid-write
        if end <= start or not arena:
            return [], None, None
        size = len(arena)
        indices = range(start, end)
        lo = start + bisect.bisect_left(indices, from_ns, key=self._time_at)
        hi = start + bisect.bisect_right(indices, to_ns, key=self._time_at)
        times, positions, messages = [], [], []
        for i in range(lo, hi):
            slot = i % self.capacity
            times.append(self._times[slot])
            position, length = starts[slot], lengths[slot]
            positions.append(position)
            messages.append(bytes(arena[position % size : position % size + length]))
        held_from = self._time_at(start)
        # Seqlock check: drop what the writer reused (slot or bytes) while we copied.
        reused = self._written - self.capacity + 1 - lo
        overwritten = bisect.bisect_left(positions, self._reserved - size)
        drop = max(reused, overwritten)
        if drop > 0:
            times, messages = times[drop:], messages[drop:]
            held_from = times[0] if times else self._time_at(self._written - 1)
        return messages, held_from, (times[0] if times else None)


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
