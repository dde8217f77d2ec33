"""What a deadline miss coincided with: garbage collections and the daemon's own steps.

A window over budget is rare (about one a minute at a 4 ms hop) and its cause is not in the
window: the worker was kept from running. :class:`StallJournal` keeps the recent spans of
what can keep it — every garbage collection (``gc.callbacks``, with its generation and the
thread that ran it) and the housekeeping tick's steps (estimates to MCAP, samples forwarded,
history deflate, status) — in bounded rings, and for each missed window the spans that
overlapped it. The daemon logs one line per miss (``deadline miss: window ending 12345,
compute 5.2 ms; during it: gc gen 2 3.1 ms (rtsid-worker), …``) and counts misses by what
they coincided with (:meth:`StallJournal.causes`), so a cause is measured, not guessed.

Each miss is also split by where its wall time went (:meth:`Miss.dominant_wait`): the worker's
own CPU (``thread_time``), waiting for a CPU (runnable, not running: the kernel's run-queue
delay of the worker thread, ``/proc/thread-self/schedstat``, :class:`RunQueueClock`) and the
rest, asleep while runnable work waited — the GIL held by another thread. A miss that
overlapped nothing is counted under the largest of the three (``nothing seen: waiting for a
CPU`` is the machine's other work, not the daemon's), and every miss under ``miss_waits``.

A miss line also carries the worker thread's counters over the window (user and system CPU,
page faults, context switches: :class:`~rtsid.runtime.stages.Usage`, read by the stage log)
and the host's since the housekeeping tick before it (:class:`HostCounters`: steal time,
interrupts, and ``/proc/vmstat``'s compaction stalls, huge-page faults and major faults), so
a window whose CPU ran long says whether its kernel, its neighbours or the host took it.

Garbage collections are timed in wall and in the collecting thread's CPU time; the longest
since the daemon began running windows (:meth:`StallJournal.running`) is kept with its
generation (:attr:`StallJournal.longest_gc`), apart from the start-up's. Spans are kept as
plain tuples of a string and two floats, which the collector stops tracking at their first
collection: the kept spans (thousands) are not walked by every later full collection.

Times are ``time.perf_counter()`` s. The journal's own cost: two ``perf_counter`` calls and
a deque append per collection and per housekeeping step; the worker reads its run-queue
clock once per window (a ``pread`` of a proc file, ≈ 5 µs), before the window's clock starts.
"""

from __future__ import annotations

import collections
import contextlib
import gc
import math
import os
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, NamedTuple

from rtsid.runtime.stages import WindowStages

__all__ = [
    "WAITS",
    "GcPause",
    "HostCounters",
    "HostReading",
    "Miss",
    "RunQueueClock",
    "Span",
    "StallJournal",
]

#: Spans kept (collections and housekeeping steps): minutes of a daemon's life at a 4 ms hop.
SPANS_KEPT = 8192
#: A span is appended as it ends, so the kept spans are in the order they ended but for a
#: thread switched out between its clock read and its append: up to this long, s.
SPAN_ORDER_SLACK_S = 1.0
#: Missed windows kept for the log.
MISSES_KEPT = 256
#: Miss lines logged one by one per minute; beyond them one line a minute counts the rest
#: (a loaded machine misses hundreds a minute: the log stays readable, the status counts all).
#: Misses of the window's own CPU (rare, and what the stage split is for) have a quota of
#: their own: those waiting for a CPU on a loaded machine do not crowd them out.
MISS_LINES_PER_MINUTE = 20
#: Where a missed window's wall time went, by :meth:`Miss.dominant_wait` (the last one where
#: the run-queue delay is not known).
WAITS = (
    "the window's own CPU",
    "waiting for a CPU",
    "waiting for the GIL",
    "waiting for a CPU or the GIL",
)


class RunQueueClock:
    """The calling thread's time spent runnable but not running (Linux ``schedstat``'s
    run-queue delay), ns: what the kernel and the hypervisor kept it waiting for a CPU.

    The proc file is opened by the first :meth:`read_ns` and names the thread that opened it,
    so read it from one thread only (the worker's). Elsewhere (no such file) every read is
    None and misses are split by CPU time alone.
    """

    PATH = "/proc/thread-self/schedstat"

    def __init__(self) -> None:
        self._fd: int | None = None
        self._unavailable = False

    def read_ns(self) -> int | None:
        """The thread's run-queue delay since it started, ns (None: not available)."""
        if self._fd is None:
            if self._unavailable:
                return None
            try:
                self._fd = os.open(self.PATH, os.O_RDONLY)
            except OSError:
                self._unavailable = True
                return None
        try:
            return int(os.pread(self._fd, 128, 0).split()[1])
        except (OSError, ValueError, IndexError):
            return None

    def close(self) -> None:
        """Close the proc file (a later read opens it again, on the reading thread)."""
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)


class HostReading(NamedTuple):
    """The machine's counters at one time (:meth:`HostCounters.read`), or their change over a
    span (:meth:`since`): ``at_s`` (``perf_counter``; over a span, its length), the
    hypervisor's steal time (all CPUs, ms; ``/proc/stat``, 10 ms ticks), interrupts served
    (all CPUs) and ``/proc/vmstat``'s direct compaction stalls, transparent huge pages
    allocated at a fault, and major faults."""

    at_s: float
    steal_ms: float
    interrupts: int
    compact_stall: int
    thp_fault_alloc: int
    pgmajfault: int

    def since(self, earlier: HostReading) -> HostReading:
        """The change from ``earlier`` to this reading."""
        return HostReading(
            self.at_s - earlier.at_s,
            self.steal_ms - earlier.steal_ms,
            self.interrupts - earlier.interrupts,
            self.compact_stall - earlier.compact_stall,
            self.thp_fault_alloc - earlier.thp_fault_alloc,
            self.pgmajfault - earlier.pgmajfault,
        )

    def describe(self) -> str:
        """``host over 0.06 s: steal 0 ms, 312 interrupts, compact_stall 0, …``"""
        return (
            f"host over {self.at_s:.2f} s: steal {self.steal_ms:.0f} ms, {self.interrupts} "
            f"interrupts, compact_stall {self.compact_stall}, thp_fault_alloc "
            f"{self.thp_fault_alloc}, pgmajfault {self.pgmajfault}"
        )


class HostCounters:
    """Reads the machine's :class:`HostReading` from ``/proc/stat`` and ``/proc/vmstat`` (one
    ``read`` of each and a few ``bytes.find``: ≈ 20 µs, the kernel's formatting of the files
    most of it; a tick's and a missed window's, not every window's). None where either file
    is missing or unreadable."""

    STAT, VMSTAT = "/proc/stat", "/proc/vmstat"
    VMSTAT_FIELDS = (b"compact_stall", b"thp_fault_alloc", b"pgmajfault")

    def __init__(self) -> None:
        self._tick_ms = 1e3 / os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 10.0

    @staticmethod
    def _contents(path: str) -> bytes:
        fd = os.open(path, os.O_RDONLY)
        try:
            return b"\n" + os.read(fd, 1 << 16)  # a line break before the first line too
        finally:
            os.close(fd)

    @staticmethod
    def _number_after(text: bytes, key: bytes) -> int:
        """The number after ``key`` at the start of a line of ``text`` (0: no such line)."""
        at = text.find(b"\n" + key + b" ")
        if at < 0:
            return 0
        at += len(key) + 2
        end = text.find(b"\n", at)
        return int(text[at : end if end >= 0 else len(text)].split(b" ", 1)[0])

    def read(self) -> HostReading | None:
        """The counters now (None: not available)."""
        at = time.perf_counter()
        try:
            stat, vmstat = self._contents(self.STAT), self._contents(self.VMSTAT)
            cpu = stat[1 : stat.index(b"\n", 1)].split()  # cpu user nice system … steal
            steal = int(cpu[8]) if len(cpu) > 8 else 0
            interrupts = self._number_after(stat, b"intr")
            counts = [self._number_after(vmstat, name) for name in self.VMSTAT_FIELDS]
        except (OSError, ValueError):
            return None
        return HostReading(at, steal * self._tick_ms, interrupts, *counts)


class GcPause(NamedTuple):
    """One garbage collection: its generation, wall time and the collecting thread's CPU
    time, ms."""

    generation: int
    ms: float
    cpu_ms: float

    def describe(self) -> str:
        """``gen 2, 3.10 ms (CPU 2.95 ms)``"""
        return f"gen {self.generation}, {self.ms:.2f} ms (CPU {self.cpu_ms:.2f} ms)"


#: Objects :func:`freeze_survivors` moved out of the collector's view in this process.
_frozen = 0


def freeze_survivors() -> None:
    """``gc.freeze()`` right after a full collection, counting what it freezes: the objects
    the collector still tracks (the survivors, and what came since), listed in time
    proportional to them alone. ``gc.get_freeze_count`` walks all that was ever frozen
    instead (9 ms at the daemon's 90 000 objects, the GIL held: reading it in every status
    made the status step miss 4 ms windows)."""
    global _frozen
    _frozen += len(gc.get_objects())
    gc.freeze()


def frozen_count() -> int:
    """Objects :func:`freeze_survivors` froze in this process so far."""
    return _frozen


@dataclass(frozen=True)
class Span:
    """Something that ran in the daemon: ``name`` from ``start_s`` to ``end_s``."""

    name: str
    start_s: float
    end_s: float

    @property
    def ms(self) -> float:
        """Length, ms."""
        return 1e3 * (self.end_s - self.start_s)


@dataclass(frozen=True)
class Miss:
    """A window over budget: its last sample, compute span and what overlapped it."""

    window_end_index: int
    start_s: float
    end_s: float
    overlapped: tuple[Span, ...]
    cpu_ms: float | None = None  # the worker thread's CPU time over the compute span
    cpu_wait_ms: float | None = None  # of the span, runnable but not running (run queue)
    stages: WindowStages | None = None  # the worker's CPU by stage, and its counters
    host: HostReading | None = None  # the host's counters since the tick before the window

    @property
    def wall_ms(self) -> float:
        """The window's compute span, ms."""
        return 1e3 * (self.end_s - self.start_s)

    def dominant_wait(self) -> str | None:
        """Where most of the span went (one of :data:`WAITS`): the worker's own CPU, waiting
        for a CPU, or the rest (asleep though it had work: the GIL). None without CPU time;
        without the run-queue delay the two waits are one."""
        if self.cpu_ms is None:
            return None
        if self.cpu_wait_ms is None:  # no run-queue clock: the waits are not told apart
            return WAITS[0] if self.cpu_ms >= self.wall_ms - self.cpu_ms else WAITS[3]
        queued = self.cpu_wait_ms
        shares = (self.cpu_ms, queued, self.wall_ms - self.cpu_ms - queued)
        return WAITS[shares.index(max(shares))]

    def describe(self) -> str:
        """One line: ``deadline miss: window ending N, compute X ms; during it: …``."""
        during = ", ".join(f"{s.name} {s.ms:.2f} ms" for s in self.overlapped) or "nothing seen"
        cpu = "" if self.cpu_ms is None else f" (of it on CPU {self.cpu_ms:.2f} ms"
        if cpu and self.cpu_wait_ms is not None:
            cpu += f", waiting for a CPU {self.cpu_wait_ms:.2f} ms"
        cpu += ")" if cpu else ""
        stages = "" if self.stages is None else f"; {self.stages.describe()}"
        host = "" if self.host is None else f"; {self.host.describe()}"
        return (
            f"deadline miss: window ending {self.window_end_index}, compute "
            f"{1e3 * (self.end_s - self.start_s):.2f} ms{cpu}; during it: {during}{stages}{host}"
        )


class StallJournal:
    """Recent garbage collections and housekeeping steps, set against missed windows.

    Use as a context manager: it adds a ``gc.callbacks`` entry on entry and removes it on
    exit. :meth:`step` times a housekeeping step, :meth:`miss` records a missed window (from
    the worker thread), :meth:`drain_misses` hands the new ones to the logger.
    """

    def __init__(self) -> None:
        # (name, start s, end s): plain tuples, untracked by the collector once it saw them
        self._spans: collections.deque[tuple[str, float, float]] = collections.deque(
            maxlen=SPANS_KEPT
        )
        self._misses: collections.deque[Miss] = collections.deque(maxlen=MISSES_KEPT)
        self._gc_started: dict[int, float] = {}  # thread id -> collection start
        self._gc_cpu_started: dict[int, int] = {}  # thread id -> its CPU clock then, ns
        self._running_windows = False  # the daemon runs windows (after its start-up)
        #: the longest collection since :meth:`running`, and the longest before it
        self.longest_gc: GcPause | None = None
        self.longest_startup_gc: GcPause | None = None
        self._host = HostCounters()
        self._host_tick: HostReading | None = None  # the latest :meth:`note_host`
        self._running: dict[object, tuple[str, float]] = {}  # steps begun: name, start
        self.collections = [0, 0, 0]  # by generation
        self.gc_ms = [0.0, 0.0, 0.0]  # time in collections, by generation
        self.miss_causes: collections.Counter[str] = collections.Counter()
        #: every miss by where most of its time went (:meth:`Miss.dominant_wait`)
        self.miss_waits: collections.Counter[str] = collections.Counter()
        self._minute_start_s = -math.inf  # the minute of miss_lines' rate limit
        self._logged = 0
        self._logged_own = 0  # lines of misses of the window's own CPU, this minute
        self._unlogged = 0

    def __enter__(self) -> StallJournal:
        gc.callbacks.append(self._on_gc)
        return self

    def __exit__(self, *exc: object) -> None:
        with contextlib.suppress(ValueError):
            gc.callbacks.remove(self._on_gc)

    # ------------------------------------------------------------------ recording
    def running(self) -> None:
        """The daemon's start-up is over: collections from now on are the running daemon's
        (:attr:`longest_gc`)."""
        self._running_windows = True

    def _on_gc(self, phase: str, info: dict[str, Any]) -> None:
        now = time.perf_counter()
        cpu_now = time.thread_time_ns()
        thread = threading.get_ident()
        if phase == "start":
            self._gc_started[thread] = now
            self._gc_cpu_started[thread] = cpu_now
            return
        started = self._gc_started.pop(thread, now)
        cpu_ms = 1e-6 * (cpu_now - self._gc_cpu_started.pop(thread, cpu_now))
        generation = int(info.get("generation", 0))
        self.collections[generation] += 1
        self.gc_ms[generation] += 1e3 * (now - started)
        pause = GcPause(generation, 1e3 * (now - started), cpu_ms)
        if self._running_windows:
            if self.longest_gc is None or pause.ms > self.longest_gc.ms:
                self.longest_gc = pause
        elif self.longest_startup_gc is None or pause.ms > self.longest_startup_gc.ms:
            self.longest_startup_gc = pause
        name = f"gc gen {generation} ({threading.current_thread().name})"
        self._spans.append((name, started, now))

    def note_host(self) -> None:
        """Read the host's counters (the housekeeping tick): a miss's are taken since."""
        self._host_tick = self._host.read()

    def host_since_tick(self) -> HostReading | None:
        """The host's counters since the latest :meth:`note_host` (None: not read)."""
        before = self._host_tick
        if before is None:
            return None
        now = self._host.read()
        return None if now is None else now.since(before)

    @contextlib.contextmanager
    def step(self, name: str) -> Iterator[None]:
        """Time a step of the daemon (e.g. ``"housekeeping: history deflate"``)."""
        started = time.perf_counter()
        key = object()
        self._running[key] = (name, started)
        try:
            yield
        finally:
            del self._running[key]
            self._spans.append((name, started, time.perf_counter()))

    def miss(
        self,
        window_end_index: int,
        start_s: float,
        end_s: float,
        cpu_ms: float | None = None,
        cpu_wait_ms: float | None = None,
        stages: WindowStages | None = None,
        host: HostReading | None = None,
    ) -> None:
        """A window whose compute ran from ``start_s`` to ``end_s`` (``cpu_ms`` of it on the
        worker's CPU, ``cpu_wait_ms`` waiting for one, its CPU by stage and counters, and the
        host's counters since the tick before it, when known) missed its deadline."""
        running = [Span(f"{name} (still running)", t0, end_s) for name, t0 in self._running_now()]
        overlapped = (*self._spans_overlapping(start_s, end_s), *running)
        miss = Miss(window_end_index, start_s, end_s, overlapped, cpu_ms, cpu_wait_ms, stages, host)
        self._misses.append(miss)
        wait = miss.dominant_wait()
        unseen = "nothing seen" if wait is None else f"nothing seen: {wait}"
        for cause in {s.name.split(" (")[0] for s in overlapped} or {unseen}:
            self.miss_causes[cause] += 1
        if wait is not None:
            self.miss_waits[wait] += 1

    def _spans_overlapping(self, start_s: float, end_s: float) -> list[Span]:
        """The kept spans overlapping ``start_s .. end_s``, oldest first. Spans are kept in
        the order they ended (to within a thread switch), so the search walks back from the
        newest and stops at the first that ended :data:`SPAN_ORDER_SLACK_S` before the
        window began: on the worker's thread, right after its missed window, it reads the
        few recent spans rather than all :data:`SPANS_KEPT` (1–2 ms of Python that delayed
        the next window)."""
        found = []
        oldest_end = start_s - SPAN_ORDER_SLACK_S
        for name, began, ended in reversed(list(self._spans)):  # a copy: others append
            if ended < oldest_end:
                break
            if ended >= start_s and began <= end_s:
                found.append(Span(name, began, ended))
        found.reverse()
        return found

    def _running_now(self) -> list[tuple[str, float]]:
        """Steps and collections begun and not yet ended (another thread's, e.g.)."""
        steps = list(self._running.values())
        collections_ = [("gc", t0) for t0 in list(self._gc_started.values())]
        return steps + collections_

    # ------------------------------------------------------------------ reading
    def spans(self) -> list[Span]:
        """The kept spans, in the order they ended (to within a thread switch)."""
        return [Span(*span) for span in list(self._spans)]

    def drain_misses(self) -> list[Miss]:
        """Misses recorded since the last call, oldest first."""
        out = []
        while self._misses:
            out.append(self._misses.popleft())
        return out

    def miss_lines(self, now_s: float) -> list[str]:
        """The log lines for the misses since the last call (:meth:`drain_misses`): each
        miss's own line, at most :data:`MISS_LINES_PER_MINUTE` a minute, and once the minute
        is over, one line counting those not logged."""
        lines: list[str] = []
        if now_s - self._minute_start_s >= 60.0:
            if self._unlogged:
                lines.append(
                    f"{self._unlogged} more deadline misses in the last minute, not logged one "
                    "by one (the status message's worker.miss_causes counts every miss)"
                )
            self._minute_start_s, self._logged, self._unlogged = now_s, 0, 0
            self._logged_own = 0
        for miss in self.drain_misses():
            if miss.dominant_wait() == WAITS[0] and self._logged_own < MISS_LINES_PER_MINUTE:
                lines.append(miss.describe())
                self._logged_own += 1
            elif self._logged < MISS_LINES_PER_MINUTE:
                lines.append(miss.describe())
                self._logged += 1
            else:
                self._unlogged += 1
        return lines

    def causes(self) -> dict[str, int]:
        """Misses by what overlapped them (a miss counts once per kind of span)."""
        return dict(self.miss_causes)

    def gc_counters(self) -> dict[str, Any]:
        """The collections for the status: by generation (count, wall ms), the longest since
        the daemon ran windows and at its start-up (``[generation, ms, CPU ms]``, None: none
        yet), and the objects frozen out of the collector's view (``gc.freeze``)."""

        def plain(pause: GcPause | None) -> list[float] | None:
            return None if pause is None else [pause[0], round(pause[1], 3), round(pause[2], 3)]

        return {
            "gc_collections": list(self.collections),
            "gc_ms": [round(ms, 3) for ms in self.gc_ms],
            "gc_longest": plain(self.longest_gc),
            "gc_longest_startup": plain(self.longest_startup_gc),
            "gc_frozen": frozen_count(),
        }
