"""Which state frames become ring rows: a counter jump is held until frames decide it.

A frame whose (unwrapped) index is the next one is written at once. A frame that jumps ahead
may be the first of a real gap's far side, or a *stray*: a foreign or corrupt frame whose
checksum happened to pass, sometimes several in a row with consecutive counters (+1000,
+1001, …). Neither can be told from the frame itself, only from the frames that follow:

* frames that continue from the newest written sample *contradict* every held jump; a run
  of held frames contradicted ``contradictions`` times is strays: dropped, counted in
  :attr:`Sequencer.strays`, inventing no lost samples and never shifting the index;
* frames that continue a held run *confirm* it once it holds more than ``max_stray_run``
  frames: the jump was real; its frames are written (the skipped indices become a gap) and
  held runs below it are strays;
* a frame landing just below a held run (reordering at the gap's edge) joins it; a run that
  becomes contiguous with the newest sample is written at once (reordered frames fill the
  gap, nothing is lost).

So up to ``max_stray_run`` consecutive strays are classified like one, and a real gap is
still a gap; its far side reaches the ring ``max_stray_run + 1`` frames late (3.6 ms at
2500 Hz with the default 8). A run of more than ``max_stray_run`` strays in a row is taken
for a real jump (documented limit). Pure bookkeeping: no threads, clock or ring; the caller
writes the rows it is given (and the gaps between them) and handles frames at or behind the
newest sample (late frames) itself.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Generic, TypeVar

__all__ = ["CONTRADICTIONS", "MAX_STRAY_RUN", "Sequencer"]

T = TypeVar("T")

#: Consecutive frames with jumping counters that may still be strays (more: a real jump).
MAX_STRAY_RUN = 8
#: Frames continuing from the newest sample that unmask a held run as strays.
CONTRADICTIONS = 3
_MAX_RUNS = 4  # held runs at once; beyond, the oldest is dropped as strays


@dataclass
class _Run(Generic[T]):
    """Held frames close to one another (a jump's far side, or strays)."""

    frames: dict[int, T] = field(default_factory=dict)
    contradicted: int = 0

    @property
    def start(self) -> int:
        return min(self.frames)

    @property
    def end(self) -> int:
        return max(self.frames)


class Sequencer(Generic[T]):
    """Order frames by sample index, holding jumps until later frames confirm or refute them.

    Parameters
    ----------
    last : int
        Index of the newest sample already written (``first_index - 1`` before any).
    max_stray_run : int
        Longest run of consecutive strays recognised as strays.
    contradictions : int
        Frames continuing from the newest sample that make a held run strays.
    reach : int
        Index distance within which a held frame belongs to a run (reordering, drops).

    Attributes
    ----------
    last : int
        Newest index handed out for writing.
    strays : int
        Held frames dropped as strays.
    duplicates : int
        Frames repeating a held frame's index (dropped).

    Examples
    --------
    >>> seq = Sequencer(last=9)
    >>> [i for i, _ in seq.offer(10, "a")]
    [10]
    >>> seq.offer(1010, "stray"), seq.offer(1011, "stray")
    ([], [])
    >>> [[i for i, _ in seq.offer(k, "b")] for k in (11, 12, 13)]
    [[11], [12], [13]]
    >>> seq.strays
    2
    """

    def __init__(
        self,
        last: int = -1,
        *,
        max_stray_run: int = MAX_STRAY_RUN,
        contradictions: int = CONTRADICTIONS,
        reach: int = 64,
    ) -> None:
        self.last = last
        self.max_stray_run = max_stray_run
        self.contradictions = contradictions
        self.reach = reach
        self.strays = 0
        self.duplicates = 0
        self._runs: list[_Run[T]] = []

    @property
    def held(self) -> int:
        """Frames held now (not yet written, not yet judged)."""
        return sum(len(run.frames) for run in self._runs)

    def offer(self, index: int, item: T) -> list[tuple[int, T]]:
        """The rows to write now, ascending, after a frame at ``index > last`` arrived.

        Indices missing between consecutive rows (and between :attr:`last` before the call
        and the first row) are lost samples: the caller writes them as a gap.
        """
        if index <= self.last:
            raise ValueError(f"index {index} is not after the newest sample {self.last}")
        if not self._runs and index == self.last + 1:  # the common case, kept cheap
            self.last = index
            return [(index, item)]
        if index == self.last + 1:
            self.last = index
            self._contradict()
            return [(index, item), *self._flush()]
        for run in self._runs:
            if index in run.frames:
                self.duplicates += 1
                return []
        run = self._run_near(index)
        run.frames[index] = item
        if len(run.frames) > self.max_stray_run:
            return self._confirm(run)
        return []

    def _run_near(self, index: int) -> _Run[T]:
        for near in self._runs:
            if near.start - self.reach <= index <= near.end + self.reach:
                return near
        run: _Run[T] = _Run()
        self._runs.append(run)
        if len(self._runs) > _MAX_RUNS:
            self._drop(self._runs[0])  # the oldest: the most frames have passed it by
        return run

    def _flush(self) -> list[tuple[int, T]]:
        """Held frames that now continue the newest sample without a gap."""
        out: list[tuple[int, T]] = []
        moved = True
        while moved:
            moved = False
            for run in self._runs:
                item = run.frames.pop(self.last + 1, None)
                if item is None:
                    continue
                self.last += 1
                out.append((self.last, item))
                moved = True
                if not run.frames:
                    self._runs.remove(run)
                break
        return out

    def _contradict(self) -> None:
        for run in list(self._runs):
            run.contradicted += 1
            if run.contradicted >= self.contradictions:
                self._drop(run)

    def _confirm(self, run: _Run[T]) -> list[tuple[int, T]]:
        """A run longer than any stray run: a real jump. Write its frames up to its first
        hole (a frame reordered into the hole still fills it; the rest stays held, judged
        afresh); held runs below it are strays."""
        self._runs.remove(run)
        out: list[tuple[int, T]] = []
        index = run.start
        while index in run.frames:
            out.append((index, run.frames.pop(index)))
            index += 1
        self.last = out[-1][0]
        for other in [r for r in self._runs if r.start <= self.last]:
            self._drop(other)
        if run.frames:
            run.contradicted = 0
            self._runs.append(run)
        return out + self._flush()

    def _drop(self, run: _Run[T]) -> None:
        self._runs.remove(run)
        self.strays += len(run.frames)
