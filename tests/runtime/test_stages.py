"""The worker's per-window stage log: which stage of a missed window took its CPU."""

from __future__ import annotations

import gc
import resource
from collections import deque

import pytest

from rtsid.runtime.stages import CPU_CAUSES, STAGES, WINDOWS_KEPT, StageLog
from rtsid.runtime.stalls import StallJournal
from tests.runtime.test_worker import filled_ring, make_worker


class FakeThreadClock:
    """A thread CPU clock that moves 1 µs per read, and as far as a test pushes it."""

    def __init__(self) -> None:
        self.ns = 0

    def __call__(self) -> int:
        self.ns += 1_000
        return self.ns

    def spend(self, ms: float) -> None:
        self.ns += round(ms * 1e6)


def test_each_mark_charges_the_cpu_since_the_previous_one_to_its_stage():
    clock = FakeThreadClock()
    log = StageLog(clock)
    log.begin(9)
    clock.spend(0.5)
    log.mark("ring read")
    clock.spend(2.0)
    log.mark("compiled call")
    clock.spend(0.25)
    log.mark("compiled call")  # a stage marked twice adds up
    log.end()
    clock.spend(1.0)  # the worker's loop, between this window and the next
    log.begin(19)
    first, second = log.recent()
    assert first.window_end_index == 9 and second.window_end_index == 19
    assert first.cpu_ms("ring read") == pytest.approx(0.501)
    assert first.cpu_ms("compiled call") == pytest.approx(2.252)
    assert first.cpu_ms("between windows") == 0.0  # nothing before the first window
    assert first.largest == "compiled call"
    assert second.cpu_ms("between windows") == pytest.approx(1.001)
    assert log.latest() == second


def test_the_log_keeps_the_newest_windows_in_a_ring():
    log = StageLog(FakeThreadClock())
    for end in range(WINDOWS_KEPT + 10):
        log.begin(end)
        log.end()
    kept = [w.window_end_index for w in log.recent()]
    assert kept == list(range(10, WINDOWS_KEPT + 10))
    assert log.windows == WINDOWS_KEPT + 10


def test_a_window_taking_up_a_new_reflex_model_is_marked():
    log = StageLog(FakeThreadClock())
    for end, seq in [(9, None), (19, 0), (29, 0), (39, 1)]:
        log.begin(end)
        log.reflex_used(seq)
        log.end()
    assert [w.new_reflex_model for w in log.recent()] == [False, True, False, True]
    assert "a new reflex model" in log.recent()[-1].describe()


class SlowCall:
    """The stream's compiled window call, which spends ``ms`` of (fake) CPU each time."""

    def __init__(self, call, clock, ms):
        self._call, self._clock, self._ms = call, clock, ms

    def __getattr__(self, name):
        return getattr(self._call, name)

    def __call__(self, *args):
        self._clock.spend(self._ms)
        return self._call(*args)

    def stream_window(self, *args):  # the call with the stream's bookkeeping (stream8)
        self._clock.spend(self._ms)
        return self._call.stream_window(*args)


@pytest.mark.parametrize("slowed", ["tracker", "publish", "compiled call", "ring read"])
def test_a_missed_window_names_the_stage_that_was_slowed(slowed, monkeypatch):
    clock = FakeThreadClock()
    published = []
    worker = make_worker(filled_ring(), published, budget_s=1e-6, max_sample_age_s=60.0)  # all miss
    worker.stages = StageLog(clock)
    worker.evaluator.log_stages(worker.stages)
    worker.stalls = StallJournal()
    worker.process_window(1399)  # plans the stream: later windows take the one compiled call
    worker.process_window(1449)
    stream = worker.evaluator.stream
    compiled = stream._call is not None  # RTSID_NUMPY_ONLY=1: the numpy reference, no call
    if slowed == "compiled call" and not compiled:
        pytest.skip("the numpy-only path has no compiled window call")
    if slowed == "tracker":
        track = stream.track
        monkeypatch.setattr(stream, "track", lambda *a: (clock.spend(3.0), track(*a))[1])
    elif slowed == "publish":
        worker.evaluator.publish = lambda m: (clock.spend(3.0), published.append(m))
    elif slowed == "compiled call":
        monkeypatch.setattr(stream, "_call", SlowCall(stream._call, clock, 3.0))
    else:
        read = worker.ring.read_since
        monkeypatch.setattr(worker.ring, "read_since", lambda *a: (clock.spend(3.0), read(*a))[1])
    before = worker.counters().miss_stages.get(slowed, 0)
    worker.process_window(1499)
    *_, second = worker.stalls.drain_misses()
    assert second.stages is not None and second.stages.window_end_index == 1499
    assert second.stages.largest == slowed
    assert second.stages.cpu_ms(slowed) == pytest.approx(3.0, abs=0.05)
    assert second.stages.most_above_usual is not None
    assert second.stages.most_above_usual[0] == slowed
    assert f"(largest: {slowed}; most above its usual: {slowed} +" in second.describe()
    assert "stages, CPU ms: between windows" in second.describe()
    # the compiled call's fixed work as the CPU's pace: slowed itself, or as usual
    pace = second.stages.fixed_work_pace
    if not compiled:  # no compiled call: no pace read, none claimed
        assert pace is None and "the compiled call (the same" not in second.describe()
        return
    assert pace is not None and (pace > 100.0 if slowed == "compiled call" else pace == 1.0)
    assert f"the compiled call (the same work every window) at {pace:.1f}× its usual" in (
        second.describe()
    )
    assert worker.counters().miss_stages[slowed] == before + 1
    assert published[-1]["ok"]  # the numbers are not the log's business


def test_every_stage_of_a_planned_window_is_named_in_its_miss_line():
    worker = make_worker(filled_ring(), [], budget_s=1e-6, max_sample_age_s=60.0)
    worker.stalls = StallJournal()
    for end in (1399, 1449, 1499):
        worker.process_window(end)
    *_, miss = worker.stalls.drain_misses()
    line = miss.describe()
    assert all(f"{name} " in line for name in STAGES)
    assert miss.stages is not None and min(miss.stages.cpu_ns[:-1]) >= 0
    if worker.evaluator.stream._call is not None:  # the one-call path marks its parts
        assert miss.stages.cpu_ms("compiled call") > 0.0
    else:  # RTSID_NUMPY_ONLY=1: the whole estimate is "assembly"
        assert miss.stages.cpu_ms("compiled call") == 0.0 < miss.stages.cpu_ms("assembly")
    assert sum(worker.counters().miss_stages.values()) == 3


def test_costly_windows_are_counted_by_stage_and_by_the_cpus_pace():
    clock = FakeThreadClock()
    log = StageLog(clock)

    def window(end, call_ms=0.3, tracker_ms=0.05):
        log.begin(end)
        clock.spend(call_ms)
        log.mark("compiled call")
        clock.spend(tracker_ms)
        log.mark("tracker")
        log.end()

    for end in range(WINDOWS_KEPT + 5):  # usual windows: nothing costly
        window(end)
    assert log.costly_stages == {}
    window(1000, tracker_ms=3.0)  # the tracker's own work, the CPU at its pace
    window(1001, call_ms=1.2, tracker_ms=0.6)  # everything four times slower: a slow CPU
    window(1002)
    assert log.costly_stages == {
        "tracker, CPU at its pace": 1,
        "compiled call, slow CPU": 1,
    }


class FakeUsage:
    """The thread's resource counters, moved by the test (and its user time by the clock)."""

    def __init__(self, clock: FakeThreadClock) -> None:
        self.clock = clock
        self.system_us = self.faults = self.involuntary = self.voluntary = 0

    def __call__(self) -> resource.struct_rusage:
        user_s = 1e-9 * self.clock.ns - 1e-6 * self.system_us
        fields = [0.0] * 16  # getrusage's order: utime, stime, …, minflt (6), …, nivcsw (15)
        fields[0], fields[1], fields[6], fields[14], fields[15] = (
            user_s,
            1e-6 * self.system_us,
            self.faults,
            self.voluntary,
            self.involuntary,
        )
        return resource.struct_rusage(fields)


@pytest.mark.parametrize(
    ("what", "cause"),
    [
        ("faults in the call", CPU_CAUSES[1]),
        ("faults elsewhere", CPU_CAUSES[2]),
        ("kernel", CPU_CAUSES[3]),
        ("GIL", CPU_CAUSES[4]),
        ("preempted", CPU_CAUSES[5]),
        ("slow CPU", CPU_CAUSES[6]),
        ("tracker", CPU_CAUSES[7]),
    ],
)
def test_a_costly_window_is_counted_by_why_its_cpu_ran_long(what, cause):
    clock = FakeThreadClock()
    usage = FakeUsage(clock)
    log = StageLog(clock, usage)

    def window(end, slowed=None):
        log.begin(end)
        clock.spend(0.05)
        log.mark("held parameters")
        if slowed == "faults in the call":  # 600 pages zeroed: kernel time in the call
            usage.faults += 600
            usage.system_us += 1500
            clock.spend(1.5)
        elif slowed == "kernel":  # interrupts served on the worker's CPU, no faults
            usage.system_us += 1500
            clock.spend(1.5)
        clock.spend(0.3 * (4.0 if slowed == "slow CPU" else 1.0))
        log.mark("compiled call")
        if slowed == "faults elsewhere":
            usage.faults += 600
            usage.system_us += 1500
            clock.spend(1.5)
        elif slowed == "preempted":
            usage.involuntary += 1
            clock.spend(1.5)  # its caches cold after
        elif slowed == "GIL":  # another thread held the GIL: 130 hand-overs, each some CPU
            usage.voluntary += 130
            clock.spend(1.0)
        clock.spend(3.0 if slowed == "tracker" else 0.6 if slowed == "slow CPU" else 0.05)
        log.mark("tracker")
        log.end()

    for end in range(WINDOWS_KEPT + 5):
        window(end)
    assert log.faulted_windows == log.window_faults == 0
    window(1000, what)
    assert log.costly_causes == {cause: 1}
    faulted = what.startswith("faults")
    assert (log.faulted_windows, log.window_faults) == ((1, 600) if faulted else (0, 0))
    in_call = what == "faults in the call"
    assert (log.faulted_calls, log.call_faults) == ((1, 600) if in_call else (0, 0))
    stages = log.latest()
    assert stages is not None and stages.usage is not None and stages.call_usage is not None
    inside = what in ("faults in the call", "kernel")
    assert stages.call_usage.faults == (600 if what == "faults in the call" else 0)
    assert stages.call_usage.system_us == (1500 if inside else 0)
    assert stages.usage.faults == (600 if what.startswith("faults") else 0)
    usual = log.with_usual()
    assert usual is not None and usual.cause() == cause
    line = usual.describe()
    assert f"; cause: {cause}" in line and "; the window: user " in line
    assert "; the compiled call: user " in line


def test_a_missed_window_is_counted_by_its_cause_and_its_counters_read_so_far():
    clock = FakeThreadClock()
    usage = FakeUsage(clock)
    log = StageLog(clock, usage)
    for end in range(WINDOWS_KEPT):
        log.begin(end)
        log.end()
    log.begin(5000)
    usage.faults += 3
    clock.spend(2.0)
    log.mark("compiled call")
    missed = log.missed()  # before the window ends: its counters up to now
    assert missed is not None and missed.usage is not None and missed.usage.faults == 3
    assert log.miss_cpu_causes == {CPU_CAUSES[2]: 1}
    log.end()
    log.begin(5010)  # missed with its CPU as usual: its wall time went to waits
    usage.faults += 3
    log.mark("compiled call")
    assert log.missed() is not None
    assert log.miss_cpu_causes == {CPU_CAUSES[2]: 1, CPU_CAUSES[0]: 1}


def test_without_usage_counters_the_cause_falls_back_on_the_pace():
    clock = FakeThreadClock()
    log = StageLog(clock, usage=None)
    for end in range(WINDOWS_KEPT + 1):
        log.begin(end)
        clock.spend(0.3)
        log.mark("compiled call")
        log.end()
    log.begin(99)
    clock.spend(1.5)
    log.mark("compiled call")
    log.end()
    stages = log.latest()
    assert stages is not None and stages.usage is None
    assert "; the window:" not in stages.describe()
    assert log.costly_causes == {CPU_CAUSES[6]: 1}


def test_the_worker_keeps_no_more_tracked_objects_however_many_windows_it_runs():
    """Windows missed and logged leave nothing the collector must walk later: the stage log's
    rows and counters are preallocated or plain tuples, the journal's spans and misses bounded."""
    published: deque[dict] = deque(maxlen=1)  # the newest message only
    worker = make_worker(filled_ring(), published, budget_s=1e-6, max_sample_age_s=60.0)
    worker.stalls = StallJournal()
    ends = [749 + 50 * k for k in range(16)]  # every grid window the ring holds

    def run_windows(rounds: int) -> None:
        for _ in range(rounds):
            for end in ends:
                worker.process_window(end)
            worker.stalls.drain_misses()

    run_windows(8)  # warm: plan, held parameters, the rings filled
    gc.collect()
    tracked = len(gc.get_objects())
    run_windows(40)  # 640 more missed windows, each logged with its stages and counters
    gc.collect(0)
    assert len(gc.get_objects()) - tracked < 50
    assert worker.stages.windows == 48 * len(ends)
