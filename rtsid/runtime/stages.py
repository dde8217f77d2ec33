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

What the CPU clock cannot say — whether a costly window's CPU went to page faults, the kernel,
a preemption or a slow vCPU — the thread's resource counters can (:class:`Usage`,
``getrusage(RUSAGE_THREAD)``: user and system CPU, minor and major faults, voluntary
context switches (the thread waited: for the GIL, mostly) and involuntary ones (its CPU was
taken), 0.8 µs a read). The log reads them as a window begins and ends
and around the compiled call, keeps each window's deltas beside its stages, and names the
cause of every costly and every missed window (:data:`CPU_CAUSES`,
:meth:`WindowStages.cause`): faults in the compiled call or elsewhere in the window (ours to
fix), kernel time without faults (interrupts served on the worker's CPU, which this kernel
charges to the thread), involuntary switches (another thread or the OS took the CPU), or none
of these with the compiled call's fixed work at a slow pace (the vCPU ran slow: the host).
"""

from __future__ import annotations

import dataclasses
import resource
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

__all__ = [
    "CPU_CAUSES",
    "STAGES",
    "WINDOWS_KEPT",
    "StageLog",
    "Usage",
    "UsualUsage",
    "WindowStages",
    "thread_usage",
]

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
#: The marks that open and close the compiled call (its usage is read at both).
_CALL_OPENS, _CALL_CLOSES = "held parameters", "compiled call"
#: Why a costly (or missed) window took its CPU, by :meth:`WindowStages.cause`, in the order
#: it is judged: its CPU no more than :data:`USUAL_FACTOR` times its usual (a missed window's
#: wall time went to waits: for a CPU, the GIL), page faults (the compiled call's, or the
#: window's elsewhere), kernel time without faults, waits for the GIL (voluntary switches: each
#: hand-over costs the waiter CPU too), involuntary context switches, a slow CPU (user time
#: inflated with none of those: the compiled call's fixed work slow too), or the stage's own
#: CPU: its work, or a stall of the vCPU that the host did not report as steal (this kernel
#: charges it to the thread that was running: a tracker stage took 4.5 ms live at a 4 ms
#: hop on 27 Nov, where no window of a like run's 49 515 took over 0.16 ms replayed, and a
#: fixed Python loop here shows such 1–6 ms stalls about once a minute). ``rtsid bench
#: service`` replays every missed window to tell the two apart.
CPU_CAUSES = (
    "CPU as usual (its time went to waits)",
    "page faults in the compiled call",
    "page faults",
    "kernel time without page faults",
    "GIL waits (voluntary switches)",
    "involuntary switches",
    "slow CPU, no faults or switches (the host)",
    "the stage's own CPU (its work, or a host stall charged to it)",
)
#: System CPU above its usual by at least this share of a window's excess CPU is the kernel's.
KERNEL_SHARE = 0.5
#: Voluntary switches above a window's usual that make its cause the GIL: at the daemon's
#: 0.1 ms switch interval, 2 ms of waiting for another thread of ours.
GIL_WAITS = 20
#: A window whose CPU is within this many times its usual (the sum of its stages' medians)
#: did not run long: a miss of such a window waited.
USUAL_FACTOR = 2.0


class Usage(NamedTuple):
    """The change of the worker thread's resource counters (``getrusage(RUSAGE_THREAD)``)
    over a span (:meth:`between` two readings). Faults and switches are exact counts; the
    user/system split of CPU time is the kernel's tick-sampled one, scaled to the exact total
    and kept monotonic by moving time between the two (a millisecond span's split can be off
    by a tick or more)."""

    user_us: int
    system_us: int
    minor_faults: int
    major_faults: int
    voluntary_switches: int
    involuntary_switches: int

    @property
    def faults(self) -> int:
        """Minor and major page faults."""
        return self.minor_faults + self.major_faults

    @classmethod
    def between(cls, earlier: Any, later: Any) -> Usage:
        """The change from one ``getrusage`` reading to a later one (``struct_rusage``s)."""
        return cls(
            round((later.ru_utime - earlier.ru_utime) * 1e6),
            round((later.ru_stime - earlier.ru_stime) * 1e6),
            later.ru_minflt - earlier.ru_minflt,
            later.ru_majflt - earlier.ru_majflt,
            later.ru_nvcsw - earlier.ru_nvcsw,
            later.ru_nivcsw - earlier.ru_nivcsw,
        )

    def describe(self) -> str:
        """``user 0.61 / system 0.05 ms, 0 page faults, 1 voluntary / 0 involuntary switches``"""
        major = f" ({self.major_faults} major)" if self.major_faults else ""
        return (
            f"user {1e-3 * self.user_us:.2f} / system {1e-3 * self.system_us:.2f} ms, "
            f"{self.faults} page faults{major}, {self.voluntary_switches} voluntary / "
            f"{self.involuntary_switches} involuntary switches"
        )


#: ``getrusage``'s per-thread counters (Linux; None elsewhere).
_RUSAGE_THREAD: int | None = getattr(resource, "RUSAGE_THREAD", None)


def thread_usage() -> Any:
    """The calling thread's ``getrusage`` reading (a ``resource.struct_rusage``; 0.8 µs), or
    None where the platform does not count per thread. Two readings make a :class:`Usage`
    (:meth:`Usage.between`)."""
    if _RUSAGE_THREAD is None:
        return None
    return resource.getrusage(_RUSAGE_THREAD)


class UsualUsage(NamedTuple):
    """A window's usual page faults, system CPU (µs) and context switches: their medians over
    the kept windows."""

    faults: int
    system_us: int
    voluntary_switches: int
    involuntary_switches: int


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
    usual_ns : tuple of int, optional
        Each stage's median CPU over the kept windows, ns (None: not computed).
    usage : Usage, optional
        The thread's counters over the window, begin to end (None: not read).
    call_usage : Usage, optional
        Over the compiled call alone (None: no compiled call, or not read).
    usual_usage : UsualUsage, optional
        The counters' medians over the kept windows that :meth:`cause` compares with (None:
        not computed).
    """

    window_end_index: int
    cpu_ns: tuple[int, ...]
    new_reflex_model: bool = False
    usual_ns: tuple[int, ...] | None = None
    usage: Usage | None = None
    call_usage: Usage | None = None
    usual_usage: UsualUsage | None = None

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
        line = f"stages, CPU ms: {parts} (largest: {self.largest}{usual}{model})"
        if self.usage is not None:
            line += f"; the window: {self.usage.describe()}"
        if self.call_usage is not None:
            line += f"; the compiled call: {self.call_usage.describe()}"
        cause = self.cause()
        return line + ("" if cause is None else f"; cause: {cause}")

    def cause(self) -> str | None:
        """Why the window took its CPU (one of :data:`CPU_CAUSES`), judged in that order from
        its counters against their medians over the kept windows; None without medians.

        A window whose CPU stayed within :data:`USUAL_FACTOR` of its usual did not run long.
        Faults above the usual are the cause whatever else is seen (each is kernel time on
        the worker's CPU: a fresh page zeroed, a huge page, a compaction); then system CPU
        above its usual by :data:`KERNEL_SHARE` of the excess (interrupts served meanwhile,
        charged to the thread here); then :data:`GIL_WAITS` voluntary switches above the
        usual (the GIL held by another thread of ours: each hand-over costs the waiter CPU);
        then involuntary switches above the usual (the CPU taken away mid-window: its caches
        cold after); then the compiled call's fixed work at :data:`SLOW_PACE` or more
        (everything slow with no kernel work: the vCPU ran slow); else the stage's own work."""
        if self.usual_ns is None:
            return None
        usual_ns = sum(self.usual_ns)
        excess_us = 1e-3 * (sum(self.cpu_ns) - usual_ns)
        if 1e3 * excess_us <= (USUAL_FACTOR - 1.0) * usual_ns:
            return CPU_CAUSES[0]
        usage, usual = self.usage, self.usual_usage
        if usage is not None and usual is not None:
            call = self.call_usage
            if call is not None and call.faults > 0:
                return CPU_CAUSES[1]
            if usage.faults > usual.faults:
                return CPU_CAUSES[2]
            if usage.system_us - usual.system_us >= KERNEL_SHARE * excess_us:
                return CPU_CAUSES[3]
            if usage.voluntary_switches - usual.voluntary_switches >= GIL_WAITS:
                return CPU_CAUSES[4]
            if usage.involuntary_switches > usual.involuntary_switches:
                return CPU_CAUSES[5]
        pace = self.fixed_work_pace
        if pace is not None and pace >= SLOW_PACE:
            return CPU_CAUSES[6]
        return CPU_CAUSES[7]

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
    usage : callable, optional
        The thread's ``getrusage`` reading (default :func:`thread_usage`; None from it or
        here: not read). Four a window (its begin and end, around the compiled call), kept
        as read: a :class:`Usage` is made of two only for a costly or missed window.
    """

    def __init__(
        self,
        clock: Callable[[], int] = time.thread_time_ns,
        usage: Callable[[], Any] | None = thread_usage,
    ) -> None:
        self._clock = clock
        self._read_usage = usage
        self._rows = [[0] * len(STAGES) for _ in range(WINDOWS_KEPT)]
        self._ends = [-1] * WINDOWS_KEPT
        self._new_model = [False] * WINDOWS_KEPT
        # getrusage readings of each kept window: as it began and ended, and as its compiled
        # call began and ended (None: not read)
        self._began: list[Any] = [None] * WINDOWS_KEPT
        self._ended: list[Any] = [None] * WINDOWS_KEPT
        self._call_began: list[Any] = [None] * WINDOWS_KEPT
        self._call_ended: list[Any] = [None] * WINDOWS_KEPT
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
        #: missed windows, and costly ones missed or not, by :meth:`WindowStages.cause`
        self.miss_cpu_causes: Counter[str] = Counter()
        self.costly_causes: Counter[str] = Counter()
        #: windows that took page faults, costly or not, and their faults (the window path
        #: touching memory it had not: a fresh allocation, memory glibc gave back)
        self.faulted_windows = 0
        self.window_faults = 0
        #: ... of them, compiled calls that took page faults, and their faults
        self.faulted_calls = 0
        self.call_faults = 0
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
        self._ended[slot] = self._call_began[slot] = self._call_ended[slot] = None
        read_usage = self._read_usage
        self._began[slot] = None if read_usage is None else read_usage()
        now = self._clock()
        if self._last_ns is not None:
            row[0] = now - self._last_ns
        self._last_ns = self._start_ns = now
        self.windows += 1

    def mark(self, stage: str) -> None:
        """The named stage of the current window ends now (the compiled call's counters are
        read outside its CPU: before its opening mark's clock, after its closing one's)."""
        read_usage = self._read_usage
        if stage == _CALL_OPENS and read_usage is not None:
            self._call_began[(self._next - 1) % WINDOWS_KEPT] = read_usage()
        now = self._clock()
        self._row[_INDEX[stage]] += now - (now if self._last_ns is None else self._last_ns)
        self._last_ns = now
        if stage == _CALL_CLOSES and read_usage is not None:
            slot = (self._next - 1) % WINDOWS_KEPT
            ended = self._call_ended[slot] = read_usage()
            began = self._call_began[slot]
            if began is not None and ended is not None:
                faults = ended.ru_minflt - began.ru_minflt + ended.ru_majflt - began.ru_majflt
                if faults:
                    self.faulted_calls += 1
                    self.call_faults += faults

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
        self._window_usage_so_far()
        self._count_faults()
        mean = self._mean_ns
        if self.windows > WINDOWS_KEPT and cpu > COSTLY_FACTOR * mean:
            self._count_costly()
        else:  # a mean over about the last 32 usual windows
            self._mean_ns = mean + (cpu - mean) / 32.0 if mean else float(cpu)
        self.mark("window end")

    def _window_usage_so_far(self) -> None:
        """Read the current window's counters as of now (its end, or its miss)."""
        if self._read_usage is not None:
            self._ended[(self._next - 1) % WINDOWS_KEPT] = self._read_usage()

    def _count_faults(self) -> None:
        """Count the current window's page faults, if it took any."""
        slot = (self._next - 1) % WINDOWS_KEPT
        began, ended = self._began[slot], self._ended[slot]
        if began is None or ended is None:
            return
        faults = ended.ru_minflt - began.ru_minflt + ended.ru_majflt - began.ru_majflt
        if faults:
            self.faulted_windows += 1
            self.window_faults += faults

    def _count_costly(self) -> None:
        stages = self.with_usual()
        above = stages.most_above_usual if stages is not None else None
        if stages is None or above is None:
            return
        pace = stages.fixed_work_pace
        slow = pace is not None and pace >= SLOW_PACE
        self.costly_stages[f"{above[0]}, {'slow CPU' if slow else 'CPU at its pace'}"] += 1
        cause = stages.cause()
        if cause is not None:
            self.costly_causes[cause] += 1

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
        self._window_usage_so_far()
        stages = self.with_usual()
        if stages is None:
            return None
        above = stages.most_above_usual
        assert above is not None
        self.miss_stages[above[0]] += 1
        cause = stages.cause()
        if cause is not None:
            self.miss_cpu_causes[cause] += 1
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
        return dataclasses.replace(stages, usual_ns=usual, usual_usage=self._usual_usage(kept))

    def _usual_usage(self, kept: int) -> UsualUsage | None:
        """The medians :meth:`WindowStages.cause` compares with, over the ``kept`` windows
        whose counters were read (three columns of plain integers: on the worker's thread
        right after a miss, 64 ``Usage`` objects cost twice the stages' medians)."""
        read = [
            (began, ended)
            for began, ended in zip(self._began[:kept], self._ended[:kept], strict=True)
            if began is not None and ended is not None
        ]
        if not read:
            return None
        middle = len(read) // 2
        faults = sorted(e.ru_minflt + e.ru_majflt - b.ru_minflt - b.ru_majflt for b, e in read)
        system = sorted(e.ru_stime - b.ru_stime for b, e in read)
        waits = sorted(e.ru_nvcsw - b.ru_nvcsw for b, e in read)
        switches = sorted(e.ru_nivcsw - b.ru_nivcsw for b, e in read)
        return UsualUsage(
            faults[middle], round(system[middle] * 1e6), waits[middle], switches[middle]
        )

    def _stages_of(self, slot: int) -> WindowStages:
        began, ended = self._began[slot], self._ended[slot]
        call_began, call_ended = self._call_began[slot], self._call_ended[slot]
        return WindowStages(
            self._ends[slot],
            tuple(self._rows[slot]),
            self._new_model[slot],
            usage=None if began is None or ended is None else Usage.between(began, ended),
            call_usage=(
                None
                if call_began is None or call_ended is None
                else Usage.between(call_began, call_ended)
            ),
        )
