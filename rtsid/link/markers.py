"""Trial markers that arrive on the wire (a marker frame, signal or datagram field).

The acquisition thread puts a :class:`WireMarker` for each marker it decodes, stamped with the
sample it arrived with; the daemon drains them from its own thread and records them with the
markers that come over zenoh (``rtsid mark``). The inbox is bounded: a marker source gone mad
cannot grow memory, and what it drops is counted (``dropped``), never silent.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass

__all__ = ["MAX_PENDING_MARKERS", "MarkerInbox", "WireMarker"]

#: Markers held between two drains at most (a daemon drains every hop, ≈ 20 ms).
MAX_PENDING_MARKERS = 4096


@dataclass(frozen=True)
class WireMarker:
    """One marker from the wire: the sample it marks and its label."""

    sample_index: int
    label: str


class MarkerInbox:
    """A thread-safe, bounded queue of :class:`WireMarker` (one writer, one reader)."""

    def __init__(self, capacity: int = MAX_PENDING_MARKERS) -> None:
        self._pending: deque[WireMarker] = deque()
        self._capacity = capacity
        self._lock = threading.Lock()
        self.dropped = 0

    def put(self, marker: WireMarker) -> None:
        """Queue ``marker``; count it as dropped when the inbox is full."""
        with self._lock:
            if len(self._pending) >= self._capacity:
                self.dropped += 1
                return
            self._pending.append(marker)

    def drain(self) -> list[WireMarker]:
        """Every queued marker, oldest first; the inbox is empty afterwards."""
        with self._lock:
            drained = list(self._pending)
            self._pending.clear()
        return drained
