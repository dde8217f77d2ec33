"""Where a window's CPU went, stage by stage: the worker's per-window stage log.

The miss journal (:mod:`rtsid.runtime.stalls`) tells a missed window's own CPU from its waits;
a miss of the window's own CPU (issue 22: 2.9–3.8 ms of the worker's CPU where 0.65 ms is
usual, nothing else running) needs the next split: which stage of the window took it.
:class:`StageLog` reads the worker thread's CPU clock (``time.thread_time_ns``:
``CLOCK_THREAD_CPUTIME_ID``; host steal is not in it on a kernel with paravirtual steal
accounting, interrupts served meanwhile are) at each stage boundary of a window and adds the
difference to that stage (:data:`STAGES`, in the order a window passes them). The last
:data:`WINDOWS_KEPT` windows are kept in a ring of preallocated rows; a missed window's row
goes into its miss line (``…; stages, CPU ms: ring read 0.01, …``) and the stage furthest
above its median over the kept windows is counted (``worker.miss_stages`` in the status), as
it is for every costly window, missed or not (``worker.costly_stages``), with the CPU's pace
read from the compiled call's fixed work (:attr:`WindowStages.fixed_work_pace`).

Its cost: one ``thread_time_ns`` call (a system call: the thread CPU clock has no vDSO path)
and a few dictionary and list operations per mark, a dozen marks a window: 40 k instructions
(callgrind) and about 8 µs of the worker's CPU per window (docs/service.md).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["STAGES", "WINDOWS_KEPT", "StageLog", "WindowStages"]

#: A window's stages, in the order the worker passes them. "between windows" is the worker's
#: CPU from the previous window's end to this window's start (its loop, its waits, a stale
#: message); "reflex model" the due slow-lane model looked up (a fit that arrived taken up);
#: "held parameters", "compiled call" and "assembly" the estimate's parts on the one-call
#: path (step by step, all of it is "assembly"); "publish" the zenoh put and the estimate
#: left for the MCAP writer; "window end" what follows until the window is closed (the
#: journal's bookkeeping).
STAGES = (
    "between windows",
    "ring read",
    "window check",
    "reflex model",
    "reflex prediction",
    "held parameters",
    "compiled call",
    "assembly",
    "tracker",
    "message",
    "publish",
    "window end",
)
#: Windows whose stages are kept (the newest ones).
WINDOWS_KEPT = 64
#: A window is costly when its CPU (start to publish) is above this many times the running
#: mean of the windows before (costly ones left out of the mean).
COSTLY_FACTOR = 3.0
#: A costly window whose compiled call ran at this many times its usual CPU or more ran on
#: a slow CPU (the call's work is the same every window).
SLOW_PACE = 1.5
_INDEX = {name: i for i, name in enumerate(STAGES)}


@dataclass(frozen=True)
class WindowStages:
    """One window's CPU by stage.

    Attributes
    ----------
    window_end_index : int
        The window's last sample.
    cpu_ns : tuple of int
        The worker thread's CPU in each of :data:`STAGES`, ns.
    new_reflex_model : bool
        The window took up a slow-lane model the window before had not used.
    """

    window_end_index: int
    cpu_ns: tuple[int, ...]
    new_reflex_model: bool = False
    usual_ns: tuple[int, ...] | None = None  # each stage's median over the kept windows

    @property
    def most_above_usual(self) -> tuple[str, float] | None:
        """The stage furthest above its median over the kept windows, and by how much, ms
        (None: no medians)."""
        if self.usual_ns is None:
            return None
        excess = [ns - usual for ns, usual in zip(self.cpu_ns, self.usual_ns, strict=True)]
        most = max(excess)
        return STAGES[excess.index(most)], 1e-6 * most

    @property
    def largest(self) -> str:
        """The stage that took the most CPU."""
        return STAGES[self.cpu_ns.index(max(self.cpu_ns))]

    def cpu_ms(self, stage: str) -> float:
        """CPU of one stage, ms."""
        return 1e-6 * self.cpu_ns[_INDEX[stage]]

    def describe(self) -> str:
        """``stages, CPU ms: between windows 0.02, ring read 0.01, …`` (window order; the
        largest stage and a new reflex model named at the end)."""
        parts = ", ".join(f"{n} {1e-6 * ns:.2f}" for n, ns in zip(STAGES, self.cpu_ns, strict=True))
        model = ", a new reflex model" if self.new_reflex_model else ""
        above = self.most_above_usual
        usual = "" if above is None else f"; most above its usual: {above[0]} +{above[1]:.2f} ms"
        pace = self.fixed_work_pace
        if pace is not None:
            usual += f"; the compiled call (the same work every window) at {pace:.1f}× its usual"
        return f"stages, CPU ms: {parts} (largest: {self.largest}{usual}{model})"

    @property
    def fixed_work_pace(self) -> float | None:
        """The compiled call's CPU over its median (None: unknown). The call does the same
        arithmetic in every planned window, so this is the CPU's pace: about 1 when a costly
        window's excess is some stage's own work, well above 1 when everything ran slow (the
        host or a sibling taking the core's time, which the thread's CPU clock still counts).
        """
        if self.usual_ns is None:
            return None
        i = _INDEX["compiled call"]
        usual = self.usual_ns[i]
        return self.cpu_ns[i] / usual if usual > 0 and self.cpu_ns[i] > 0 else None


class StageLog:
    """The worker's CPU per stage of its recent windows (a ring of preallocated rows).

    The worker calls :meth:`begin` as a window starts, :meth:`mark` at the end of each stage
    (the CPU since the previous mark goes to the named stage; a stage marked twice adds up)
    and :meth:`end` when the window is done. One thread only (the worker's).

    Parameters
    ----------
    clock : callable, optional
        Thread CPU time, ns (default ``time.thread_time_ns``; tests pass their own).
    """

    def __init__(self, clock: Callable[[], int] = time.thread_time_ns) -> None:
        self._clock = clock
        self._rows = [[0] * len(STAGES) for _ in range(WINDOWS_KEPT)]
        self._ends = [-1] * WINDOWS_KEPT
        self._new_model = [False] * WINDOWS_KEPT
        self._next = 0  # the row the next window takes
        self._row = self._rows[0]
        self._last_ns: int | None = None  # the clock at the latest mark (None: never read)
        self._reflex_seq: int | None = None  # the model the window before used
        self.windows = 0
        #: missed windows by the stage furthest above its usual CPU (its median over the
        #: kept windows)
        self.miss_stages: Counter[str] = Counter()
        #: costly windows (:data:`COSTLY_FACTOR`), missed or not, by that stage and whether
        #: the CPU ran at its usual pace (:meth:`WindowStages.fixed_work_pace`)
        self.costly_stages: Counter[str] = Counter()
        self._start_ns = 0  # the clock as the current window began
        self._mean_ns = 0.0  # running mean of a usual window's CPU (0: none yet)

    def begin(self, window_end_index: int) -> None:
        """A window starts: a fresh row; the CPU since the previous window went between."""
        slot = self._next
        self._next = (slot + 1) % WINDOWS_KEPT
        row = self._row = self._rows[slot]
        for i in range(len(row)):
            row[i] = 0
        self._ends[slot] = window_end_index
        self._new_model[slot] = False
        now = self._clock()
        if self._last_ns is not None:
            row[0] = now - self._last_ns
        self._last_ns = self._start_ns = now
        self.windows += 1

    def mark(self, stage: str) -> None:
        """The named stage of the current window ends now."""
        now = self._clock()
        self._row[_INDEX[stage]] += now - (now if self._last_ns is None else self._last_ns)
        self._last_ns = now

    def reflex_used(self, seq: int | None) -> None:
        """The slow-lane model the current window used (None: none)."""
        if seq is not None and seq != self._reflex_seq:
            self._new_model[(self._next - 1) % WINDOWS_KEPT] = True
        self._reflex_seq = seq

    def end(self) -> None:
        """The current window is done (its last stage, "window end", closes now); a costly
        one (its CPU from start to publish) is counted by its stage."""
        last = self._last_ns
        cpu = 0 if last is None else last - self._start_ns
        mean = self._mean_ns
        if self.windows > WINDOWS_KEPT and cpu > COSTLY_FACTOR * mean:
            self._count_costly()
        else:  # a mean over about the last 32 usual windows
            self._mean_ns = mean + (cpu - mean) / 32.0 if mean else float(cpu)
        self.mark("window end")

    def _count_costly(self) -> None:
        stages = self.with_usual()
        above = stages.most_above_usual if stages is not None else None
        if stages is None or above is None:
            return
        pace = stages.fixed_work_pace
        slow = pace is not None and pace >= SLOW_PACE
        self.costly_stages[f"{above[0]}, {'slow CPU' if slow else 'CPU at its pace'}"] += 1

    def latest(self) -> WindowStages | None:
        """The current (or latest) window's stages; None before the first window."""
        if not self.windows:
            return None
        return self._stages_of((self._next - 1) % WINDOWS_KEPT)

    def recent(self) -> list[WindowStages]:
        """The kept windows, oldest first."""
        kept = min(self.windows, WINDOWS_KEPT)
        first = (self._next - kept) % WINDOWS_KEPT
        return [self._stages_of((first + k) % WINDOWS_KEPT) for k in range(kept)]

    def missed(self) -> WindowStages | None:
        """The current window missed its deadline: its stages with each stage's median over
        the kept windows (for the miss line); the stage furthest above its median is counted.
        """
        stages = self.with_usual()
        if stages is None:
            return None
        above = stages.most_above_usual
        assert above is not None
        self.miss_stages[above[0]] += 1
        return stages

    def with_usual(self) -> WindowStages | None:
        """The current window's stages with each stage's median over the kept windows."""
        stages = self.latest()
        if stages is None:
            return None
        kept = min(self.windows, WINDOWS_KEPT)
        middle = kept // 2
        usual = tuple(
            sorted(row[i] for row in self._rows[:kept])[middle] for i in range(len(STAGES))
        )
        return WindowStages(stages.window_end_index, stages.cpu_ns, stages.new_reflex_model, usual)

    def _stages_of(self, slot: int) -> WindowStages:
        return WindowStages(self._ends[slot], tuple(self._rows[slot]), self._new_model[slot])
