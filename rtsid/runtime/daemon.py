"""The daemon: link → ring → window worker → zenoh + MCAP, with status and a bounded shutdown.

Threads: acquisition (link), window worker, MCAP writer, zenoh's own; the calling thread runs
the housekeeping loop — forwarding every sample from the ring to the MCAP log (and optionally to
zenoh) and publishing status — on absolute deadlines until asked to stop.

Shutdown order keeps every sample: worker, then acquisition, then a last forward of the ring,
then the MCAP file is finished, zenoh closed and the embedded plant stopped.

Every thread owner (:class:`rtsid.lifecycle.ThreadOwner`) is watched each housekeeping tick:
when the acquisition, the worker, the MCAP writer or the embedded plant dies, the daemon shuts
down and :attr:`RunSummary.failure` says which and why (``rtsid run`` then exits 1, so a
supervisor such as systemd's ``Restart=on-failure`` restarts it). A run whose recordings
folder cannot be written does not start (:class:`~rtsid.errors.RecordingError`).
"""

from __future__ import annotations

import collections
import dataclasses
import gc
import logging
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rtsid import __version__
from rtsid.ident.reflex_lane import ReflexModels, ReflexUpdate
from rtsid.io.calibration import calibration_record, robot_calibration
from rtsid.io.mcap_log import McapLogger
from rtsid.io.messages import StatusMessage
from rtsid.io.procstats import ProcessMeter
from rtsid.io.schemas import encode_estimate, encode_json, encode_status
from rtsid.io.zenoh_link import RequestInbox, ZenohPublisher
from rtsid.lifecycle import ThreadOwner
from rtsid.link.acquisition import Acquisition
from rtsid.link.open import open_link
from rtsid.link.ring import RingBuffer, Snapshot
from rtsid.runtime.clock import Deadlines
from rtsid.runtime.daemon_config import SECTIONS, DaemonConfig, DaemonSettings
from rtsid.runtime.gate import WindowGate
from rtsid.runtime.power import cpu_latency_request, set_realtime_priority
from rtsid.runtime.session import SessionDesk, session_message
from rtsid.runtime.slow_lane import SlowLane
from rtsid.runtime.stalls import StallJournal, freeze_survivors
from rtsid.runtime.worker import WindowEvaluator, WindowWorker
from rtsid.verdicts import plain_counts

# the configuration lives in rtsid.runtime.daemon_config (a replay reads it without importing
# the daemon); its names are the daemon's too
__all__ = ["SECTIONS", "Daemon", "DaemonConfig", "DaemonSettings", "RunSummary"]

log = logging.getLogger(__name__)

#: Estimates the worker leaves for the housekeeping thread to hand to the MCAP writer (a
#: full hold means housekeeping is stuck: the worker then hands them over itself).
ESTIMATES_HELD = 4096


def _no_wait() -> None:
    """No worker to wait for."""


def _collect_in_the_gap() -> int | None:
    """The collection CPython would have run by now, run here (automatic collection is off
    while the daemon runs: the housekeeping tick calls this right after the worker has gone
    to sleep, so no collection runs inside a window). CPython's rule: the oldest generation
    whose count is past its threshold.

    A full (generation 2) collection's survivors are then frozen (``gc.freeze``): they have
    lived through every generation, so the next full collection walks only what came after
    them, not all the daemon ever kept — a full collection stays as short as a young one
    however long the daemon runs. What is frozen is still freed by reference counting; only
    a reference cycle among frozen objects would outlive the run (``gc_frozen`` in the status
    shows whether the frozen set grows).

    Returns
    -------
    int or None
        The generation collected (None: none due).
    """
    counts, thresholds = gc.get_count(), gc.get_threshold()
    due = [g for g in range(3) if thresholds[g] and counts[g] > thresholds[g]]
    if not due:
        return None
    gc.collect(due[-1])
    if due[-1] == 2:
        freeze_survivors()
    return due[-1]


def _freeze_what_lives() -> None:
    """Collect everything, then move the survivors out of the collector's view (start-up:
    what is built by now lives for the whole run, and later full collections need not walk
    it)."""
    gc.collect()
    freeze_survivors()


@dataclass(frozen=True)
class RunSummary:
    """What a run did (printed by ``rtsid run`` at exit)."""

    estimates: int
    withheld: dict[str, int]
    deadline_misses: int
    overruns: int
    samples: int
    lost_samples: int
    mcap_files: list[str]
    mcap_dropped: int
    clean_shutdown: bool
    failure: str | None = None


class Daemon:
    """Wire and run everything for one joint.

    Parameters
    ----------
    config : DaemonConfig
        The whole configuration.
    on_status : callable, optional
        Called on the housekeeping thread with each status message and the newest estimate
        message (or None) — e.g. to print a line to the console.
    message_tap : callable, optional
        ``tap(kind, log_time_ns, payload)`` sees every recorded message on the MCAP writer's
        thread (``rtsid run --foxglove``; see :class:`~rtsid.io.mcap_log.McapLogger`).
    """

    def __init__(
        self,
        config: DaemonConfig,
        on_status: Callable[[dict[str, Any], dict[str, Any] | None], None] | None = None,
        message_tap: Callable[[str, int, bytes], None] | None = None,
    ) -> None:
        # scipy is imported where it is used (a replay's process starts without it). A live
        # run imports scipy.signal here, before any of its threads, although its window path
        # designs its filters in numpy or reads them from the design cache (rtsid.ident.
        # designs): the embedded plant filters with scipy.signal as it runs, and a design the
        # cache does not hold yet (a new rate) would pay the import, ≈ 1 s of CPU, inside a
        # window's deadline. A daemon starts once a session; its start-up is no deadline.
        import scipy.signal  # noqa: F401

        self.config = config
        self.on_status = on_status
        self.message_tap = message_tap
        self.last_estimate: dict[str, Any] | None = None
        self.stop_event = threading.Event()
        self.meter = ProcessMeter()
        self._cursor = -1
        self._overwritten = 0
        # (payload, log time ns, message) of estimates published but not yet handed to the
        # MCAP writer
        self._unlogged: collections.deque[tuple[bytes, int, dict[str, Any]]] = collections.deque()
        self.worker: WindowWorker | None = None
        self.acquisition: Acquisition | None = None
        self.slow_lane: SlowLane | None = None
        self.desk: SessionDesk | None = None
        self._components: list[ThreadOwner | None] = []
        self.failure: str | None = None
        #: garbage collections and housekeeping steps, set against every missed deadline
        self.stalls = StallJournal()

    def request_stop(self) -> None:
        """Ask :meth:`run` to shut down (safe from a signal handler)."""
        self.stop_event.set()

    def run(self, duration_s: float | None = None) -> RunSummary:
        """Run until :meth:`request_stop` (or for ``duration_s``); returns a summary."""
        # Hand the GIL over every 0.1 ms instead of CPython's 5 ms, so the worker is not
        # kept waiting behind the acquisition, plant or logger threads (latency tails).
        previous_interval = sys.getswitchinterval()
        sys.setswitchinterval(min(previous_interval, self.config.daemon.gil_switch_interval_s))
        collecting = gc.isenabled()
        try:
            with cpu_latency_request(self.config.daemon.cpu_latency_us), self.stalls:
                return self._run(duration_s)
        finally:
            sys.setswitchinterval(previous_interval)
            gc.unfreeze()
            if collecting:
                gc.enable()

    def _run(self, duration_s: float | None) -> RunSummary:
        cfg = self.config
        robot, joint = cfg.zenoh.robot, cfg.zenoh.joint
        run_config = self.config.as_dict()
        # Loaded once: the worker subtracts it, the recording carries it.
        calibration = robot_calibration(cfg.worker.calibration_file, cfg.link.fs_hz)
        # The modules imported by now (numpy, scipy, zenoh, rtsid: about 90 000 objects) out
        # of the collector's view before any thread of the run starts: the full collection
        # this takes (40–60 ms of CPU) holds the GIL while nothing else runs, where the one
        # below, with the acquisition running, walks only what the start-up built since.
        _freeze_what_lives()
        with open_link(cfg.link, cfg.plant, start_plant=False) as handle:
            ring = handle.make_ring()

            def next_sample() -> int:
                return max(ring.newest_index + 1, 0)

            mcap = McapLogger(
                cfg.mcap,
                robot=robot,
                joint=joint,
                fs_hz=cfg.link.fs_hz,
                run_config=run_config,
                metadata={"software": f"rtsid {__version__}"},
                records=calibration_record(calibration, cfg.worker.calibration_file),
                tap=self.message_tap,
                session=cfg.session,
                session_message=session_message(
                    cfg.session, robot, joint, cfg.link.fs_hz, next_sample()
                ),
            )
            mcap.timed = self.stalls.step  # the writer's steps, set against deadline misses
            mcap.start(require_file=True)  # a run that cannot be recorded must not start
            rates_hz = {"estimate": 1 / cfg.worker.hop_s, "status": 1 / cfg.daemon.status_period_s}
            inbox = RequestInbox()
            with (
                mcap,
                ZenohPublisher(
                    cfg.zenoh, run_config=run_config, rates_hz=rates_hz, requests=inbox
                ) as zenoh,
            ):
                acquisition = handle.make_acquisition(ring)
                self.acquisition = acquisition
                desk = SessionDesk(
                    cfg.session,
                    robot=robot,
                    joint=joint,
                    fs_hz=cfg.link.fs_hz,
                    next_sample=next_sample,
                    mcap=mcap,
                    zenoh=zenoh,
                    inbox=inbox,
                    wire_markers=acquisition.drain_markers,
                    wire_dropped=lambda: acquisition.markers.dropped,
                )
                self.desk = desk
                # The embedded plant's in-process bus opens at once, before the plant sends;
                # any other bus opens on the acquisition thread (retried with back-off), so
                # a server that never answers cannot block this thread and its signals.
                acquisition.start(require_bus=handle.plant is not None)
                # --duration counts from here: samples flow from now on, not from the end of
                # the start-up below (a slow lane's process takes seconds on a busy machine)
                end = None if duration_s is None else time.monotonic() + duration_s
                if handle.plant is not None:
                    handle.plant.start()
                models = (
                    ReflexModels(cfg.link.fs_hz, cfg.slow_lane) if cfg.slow_lane.enabled else None
                )
                evaluator = WindowEvaluator(
                    cfg.link.fs_hz,
                    cfg.worker,
                    cfg.estimator,
                    lambda msg: self._publish_estimate(msg, mcap, zenoh),
                    robot=robot,
                    joint=joint,
                    calibration=calibration,
                    reflex=models,
                    tracker=cfg.tracker,
                )
                worker = WindowWorker(ring, evaluator)
                worker.stalls = self.stalls
                self.worker = worker
                self._writer_in_the_gaps(mcap, worker.gate)
                slow_lane = self._slow_lane(ring, worker, models, mcap, zenoh)
                # Everything built so far lives for the whole run: move it out of the cyclic
                # collector's view so full collections stay short (no multi-ms pauses).
                _freeze_what_lives()
                # and from now on collect only in the worker's gaps (the housekeeping tick,
                # _collect_in_the_gap): an automatic collection runs in whichever thread
                # allocates, the worker's window included
                gc.disable()
                self.stalls.running()  # collections from here on are the running daemon's
                worker.start()
                if slow_lane is not None:
                    slow_lane.start()
                desk.start()
                self._components = [acquisition, worker, mcap, handle.plant, slow_lane, desk]
                clean = True
                try:
                    self._raise_priority(acquisition, worker)
                    self._housekeeping(ring, mcap, zenoh, end)
                finally:
                    timeout = cfg.daemon.shutdown_timeout_s
                    if slow_lane is not None:
                        clean &= slow_lane.stop(timeout)
                    clean &= worker.stop(timeout)
                    clean &= acquisition.stop(timeout)
                    clean &= desk.stop(timeout)  # after the link: its last wire markers too
                    self._log_estimates(mcap)
                    self._forward_samples(ring, mcap, zenoh)
                    self._publish_status(mcap, zenoh)
            clean &= mcap.stop(cfg.daemon.shutdown_timeout_s)
            clean &= not mcap.stats().get("errors", 0)
        self.failure = self.failure or self._first_failure()
        return self._summary(mcap, clean and self.failure is None)

    def _raise_priority(self, *owners: ThreadOwner) -> None:
        """Real-time scheduling for the threads on the estimate's path (``[daemon]
        realtime_priority``; 0: none)."""
        priority = self.config.daemon.realtime_priority
        for owner in owners:
            if owner.native_id is not None:
                set_realtime_priority(owner.native_id, priority, owner.thread_name)

    def _first_failure(self) -> str | None:
        """The first component (acquisition, worker, MCAP writer, plant) whose thread died."""
        for component in self._components:
            failure = component.failure if component is not None else None
            if failure is not None:
                return failure
        return None

    # ------------------------------------------------------------------ housekeeping
    def _housekeeping(
        self, ring: RingBuffer, mcap: McapLogger, zenoh: ZenohPublisher, end: float | None
    ) -> None:
        """Forward samples, estimates and status each tick until a stop, a failure or ``end``
        (``time.monotonic()``; None: no end)."""
        settings = self.config.daemon
        ticks = Deadlines(settings.sample_batch_s)
        status_every = max(1, round(settings.status_period_s / settings.sample_batch_s))
        tick = 0
        step = self.stalls.step
        after_window = self._after_a_window()
        while ticks.wait(self.stop_event):
            after_window()  # the tick runs as the worker goes to sleep, not across a window
            _collect_in_the_gap()
            self.stalls.note_host()  # a miss's host counters are taken since this tick
            with step("housekeeping: estimates to MCAP"):
                self._log_estimates(mcap)
            with step("housekeeping: samples forwarded"):
                self._forward_samples(ring, mcap, zenoh)
            if zenoh.history_compaction_due:
                # the history's sealed blocks (about one a second at a 4 ms hop), here, off
                # the worker, in a gap of their own: by now a window may have begun
                after_window()
                with step("housekeeping: history deflate"):
                    zenoh.compact_history()
            tick += 1
            if tick % status_every == 0:
                # the status's two halves (build; encode and publish) each after a window
                # of their own, so neither shares a window's time with the steps above
                after_window()
                with step("housekeeping: status"):
                    status = self._status(mcap, zenoh)
                after_window()
                with step("housekeeping: status"):
                    self._send_status(status, mcap, zenoh)
            for line in self.stalls.miss_lines(time.monotonic()):
                log.warning("%s", line)
            self.failure = self._first_failure()
            if self.failure is not None:
                log.error(
                    "%s; stopping (exit status 1, so a supervisor restarts rtsid)", self.failure
                )
                break
            if end is not None and time.monotonic() >= end:
                break

    def _after_a_window(self) -> Callable[[], object]:
        """A wait on the worker's :class:`~rtsid.runtime.gate.WindowGate` until the worker
        has published its window and gone to wait for the next one: work begun then has the
        rest of the hop to itself. Bounded by two hops (at most half a sample batch), so with
        no windows the tick runs late by that at most."""
        gate = self.worker.gate if self.worker is not None else None
        if gate is None:
            return _no_wait
        bound_s = self._gate_bound_s()
        return lambda: gate.after_next_window(bound_s)

    def _gate_bound_s(self) -> float:
        """The longest wait on the window gate: two hops, at most half a sample batch, s."""
        return min(2 * self.config.worker.hop_s, self.config.daemon.sample_batch_s / 2)

    def _writer_in_the_gaps(self, mcap: McapLogger, gate: WindowGate) -> None:
        """The MCAP writer thread writes in the worker's gaps: each burst begins as the worker
        goes to sleep and pauses while a window computes (each wait bounded like the tick's),
        so its serialising and chunk compression never share a window's time."""
        bound_s = self._gate_bound_s()
        mcap.busy = lambda: gate.computing
        mcap.wait_turn = lambda: gate.after_next_window(bound_s)

    def _forward_samples(self, ring: RingBuffer, mcap: McapLogger, zenoh: ZenohPublisher) -> None:
        while True:
            snap = ring.read_since(self._cursor, 4096)
            self._overwritten += snap.overwritten
            if len(snap) == 0:
                return
            first = int(snap.sample_index[0])
            mcap.log_samples(first, snap.position_rad, snap.torque_nm, snap.valid, snap.status)
            zenoh.publish_samples(
                first,
                snap.position_rad,
                snap.torque_nm,
                snap.valid,
                snap.status,
                fs_hz=self.config.link.fs_hz,
            )
            self._cursor = snap.next_index

    def _slow_lane(
        self,
        ring: RingBuffer,
        worker: WindowWorker,
        models: ReflexModels | None,
        mcap: McapLogger,
        zenoh: ZenohPublisher,
    ) -> SlowLane | None:
        """The reflex slow lane, publishing each fit on ``/reflex`` (None when it is off)."""
        if models is None:
            return None
        evaluator = worker.evaluator

        def publish(update: ReflexUpdate, fit_ms: float) -> None:
            message = evaluator.reflex_message(update, fit_ms)
            payload = encode_json(message)
            zenoh.publish_reflex(payload)
            mcap.log_reflex(payload, log_time_ns=message["host_time_ns"])

        def torque_of(snap: Snapshot) -> np.ndarray:
            return np.asarray(evaluator.model_torque(snap.position_rad, snap.torque_nm))

        lane = SlowLane(ring, models, torque_of, publish)
        self.slow_lane = lane
        return lane

    def _publish_estimate(
        self, message: dict[str, Any], mcap: McapLogger, zenoh: ZenohPublisher
    ) -> None:
        """On the worker thread: put the estimate on zenoh now and leave it for the
        housekeeping thread to hand to the MCAP writer with the samples of its tick.

        Handing each estimate to the writer's queue here woke the writer thread once per
        window, on the worker's time (py-spy of a running daemon: 10 % of the GIL-holding
        samples were the worker inside that queue's ``notify``); the file gets the estimate
        at most ``[daemon] sample_batch_s`` later, as it gets the samples.
        """
        payload = encode_estimate(message)  # once, for both sinks
        zenoh.publish_estimate(payload)
        log_time_ns = message["host_time_ns"]
        if len(self._unlogged) < ESTIMATES_HELD:
            self._unlogged.append((payload, log_time_ns, message))
        else:  # housekeeping is stuck: the writer's own bounded queue counts what it drops
            mcap.log_estimate(payload, log_time_ns=log_time_ns)
        self.last_estimate = message

    def _log_estimates(self, mcap: McapLogger) -> None:
        """Hand the estimates the worker left to the MCAP writer, oldest first, as one batch
        (one queue item and one writer wake-up per tick, not one per estimate)."""
        batch = []
        while self._unlogged:  # popleft: the worker may append meanwhile
            batch.append(self._unlogged.popleft())
        mcap.log_estimates(batch)

    def _status(self, mcap: McapLogger, zenoh: ZenohPublisher) -> dict[str, Any]:
        acq = dataclasses.asdict(self.acquisition.counters()) if self.acquisition else {}
        acq["logger_overwritten"] = self._overwritten
        worker = dataclasses.asdict(self.worker.counters()) if self.worker else {}
        return StatusMessage(
            robot=self.config.zenoh.robot,
            joint=self.config.zenoh.joint,
            host_time_ns=time.time_ns(),
            **self.meter.sample(),
            acquisition=acq,
            worker=worker,
            mcap=mcap.stats(),
            zenoh=zenoh.stats(),
            slow_lane=dataclasses.asdict(self.slow_lane.counters()) if self.slow_lane else None,
            session=self.desk.counters() if self.desk else None,
        ).as_dict()

    def _publish_status(self, mcap: McapLogger, zenoh: ZenohPublisher) -> None:
        self._send_status(self._status(mcap, zenoh), mcap, zenoh)

    def _send_status(self, status: dict[str, Any], mcap: McapLogger, zenoh: ZenohPublisher) -> None:
        """Encode a built status, put it on zenoh, hand it to the MCAP writer and the
        console."""
        payload = encode_status(status)
        zenoh.publish_status(payload)
        mcap.log_status(payload, log_time_ns=status["host_time_ns"])
        if self.on_status is not None:
            self.on_status(status, self.last_estimate)

    def _summary(self, mcap: McapLogger, clean: bool) -> RunSummary:
        worker = self.worker.counters() if self.worker else None
        acq = self.acquisition.counters() if self.acquisition else None
        stats = mcap.stats()
        return RunSummary(
            estimates=worker.estimates if worker else 0,
            withheld=plain_counts(worker.withheld) if worker else {},
            deadline_misses=worker.deadline_misses if worker else 0,
            overruns=worker.overruns if worker else 0,
            samples=acq.samples if acq else 0,
            lost_samples=acq.lost_samples if acq else 0,
            mcap_files=[str(p) for p in mcap.files],
            mcap_dropped=int(stats.get("dropped", 0)),
            clean_shutdown=clean,
            failure=self.failure,
        )
