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
    kinds = None
    if parameters.get("kind"):
        kinds = tuple(k.strip() for k in parameters["kind"].split(",") if k.strip())
    return HistoryQuery(kinds, from_ns, to_ns)


class MessageRing:
    """A fixed number of (publication time ns, payload bytes) slots; one writer, any readers.

    Parameters
    ----------
    capacity : int
        Slots (the oldest message is replaced once they are all used).
    """

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError(f"MessageRing capacity {capacity}; expected >= 1")
        self.capacity = int(capacity)
        self._times = [0] * self.capacity
        self._payloads: list[bytes] = [b""] * self.capacity
        self._written = 0  # messages appended so far; bumped last (the commit)

    def __len__(self) -> int:
        return min(self._written, self.capacity)

    @property
    def written(self) -> int:
        """Messages appended since the start."""
        return self._written

    def append(self, time_ns: int, payload: bytes) -> None:
        """Add one message (writer thread only; O(1), no lock, no allocation but the slot)."""
        slot = self._written % self.capacity
        self._times[slot] = time_ns
        self._payloads[slot] = payload
        self._written += 1

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
        end = self._written
        start = max(0, end - self.capacity + 1)  # the slot after `end` may be mid-write
        if end <= start:
            return [], None, None
        indices = range(start, end)
        lo = start + bisect.bisect_left(indices, from_ns, key=self._time_at)
        hi = start + bisect.bisect_right(indices, to_ns, key=self._time_at)
        times = [self._time_at(i) for i in range(lo, hi)]
        messages = [self._payloads[i % self.capacity] for i in range(lo, hi)]
        held_from = self._time_at(start)
        # Seqlock check: drop what the writer reused while we copied.
        reused = self._written - self.capacity + 1 - lo
        if reused > 0:
            times, messages = times[reused:], messages[reused:]
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
        if ring is None or ring.written == 0:
            return None
        messages, _, _ = ring.snapshot(0, 2**63 - 1)
        return messages[-1] if messages else None

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
