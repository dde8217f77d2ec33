"""``rtsid replay REC``: run the window worker over a recording (or a directory of them)."""

from __future__ import annotations

import argparse
import atexit
import collections
import concurrent.futures as cf
import contextlib
import json
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from rtsid.commands.common import add_output
from rtsid.errors import IncompleteRecordingWarning, InputDataError

if TYPE_CHECKING:
    from rtsid.replay import ReplayResult
    from rtsid.runtime.daemon_config import DaemonConfig

# The replay itself (numpy, the reader, the window path: ≈ 2 G instructions to import here,
# where every process compiles rtsid from source) is imported where it is used, so that a
# directory's children are spawned, and import it, while this process imports it too.


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", help="an rtsid .mcap recording, or a directory of them")
    parser.add_argument("--config", metavar="TOML", help="settings (default: the recording's own)")
    parser.add_argument(
        "--rate", default="max", help="1 = real time, N = N× real time, max = as fast as possible"
    )
    parser.add_argument("--publish", action="store_true", help="publish estimates over zenoh")
    add_output(
        parser,
        "the estimates: OUT.csv or OUT.mcap (a directory for a directory of recordings; "
        "default: a summary only)",
        old=("--out",),
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=0,
        help="processes for a directory, this one included (0: one a core)",
    )
    parser.add_argument(
        "--timing",
        metavar="JSON",
        help="also write when each process was ready and replayed each recording (to tune "
        "--jobs; see docs/workflow.md)",
    )


def _rate(text: str) -> float | None:
    if text == "max":
        return None
    try:
        rate = float(text)
    except ValueError:
        rate = -1.0
    if not rate > 0:
        raise InputDataError(f"--rate {text!r} is not accepted; use 1, a speed-up N > 0, or max")
    return rate


def _config(args: argparse.Namespace, path: Path) -> DaemonConfig:
    from rtsid.replay import recording_config
    from rtsid.runtime.daemon_config import DaemonConfig

    return DaemonConfig.load(args.config) if args.config else recording_config(path)


def _write(result: ReplayResult, out: Path, config: DaemonConfig) -> None:
    from rtsid.io.estimate_csv import open_output, write_estimates
    from rtsid.io.files import atomic_write
    from rtsid.replay import write_estimates_mcap

    if out.suffix == ".csv":
        with open_output(out) as fh:
            write_estimates(result.messages, fh)
    elif out.suffix == ".mcap":
        with atomic_write(out, "wb", what="estimates") as fh:
            write_estimates_mcap(
                result.messages,
                fh,
                source=result.source,
                config=config,
                reflex=result.reflex,
                markers=result.markers,
                sessions=result.sessions,
                session_metadata=result.session_metadata,
            )
    else:
        raise InputDataError(f"-o {out}: use a .csv or .mcap file name")


def _summary_row(result: ReplayResult) -> list[Any]:
    from rtsid.ident.stream import median
    from rtsid.verdicts import format_counts

    ok = [m for m in result.messages if m["ok"]]
    med = {k: median([m[k] for m in ok]) for k in ("K", "B", "I", "vaf")}
    withheld = format_counts(result.withheld)
    return [
        Path(result.source).name,
        result.duration_s,
        len(result.messages),
        len(ok),
        withheld,
        med["K"],
        med["B"],
        med["I"],
        med["vaf"],
        len(result.markers),
        result.speed,
    ]


def _progress(done: int, total: int) -> None:
    if total:
        width = 30
        filled = int(width * done / total)
        sys.stderr.write(f"\r[{'#' * filled}{'.' * (width - filled)}] {100 * done / total:5.1f} %")
        sys.stderr.flush()


class Replayed(NamedTuple):
    """One recording replayed, as the process that replayed it hands it back.

    Attributes
    ----------
    row : list
        The recording's summary row.
    incomplete : list of str
        Its incomplete-recording warnings (returned: a spawned child's warnings would not
        reach the parent's command line).
    pid : int
        The process that replayed it.
    started_s, ended_s : float
        When that process started and finished it, ``time.monotonic()`` s (one clock for
        every process of a machine: Linux's ``CLOCK_MONOTONIC``).
    cpu_s : float
        That process's CPU time when it finished it, its start-up included, s.
    """

    row: list[Any]
    incomplete: list[str]
    pid: int
    started_s: float
    ended_s: float
    cpu_s: float


class Ready(NamedTuple):
    """A process having imported the replay (:func:`_preload`).

    Attributes
    ----------
    pid : int
        The process.
    ready_s : float
        When, ``time.monotonic()`` s.
    cpu_s : float
        Its CPU time by then (the interpreter's start included), s: below the time since it
        was launched, it waited for a CPU.
    """

    pid: int
    ready_s: float
    cpu_s: float


def _replay_one(path: Path, args: argparse.Namespace, out: Path | None) -> Replayed:
    """Replay ``path`` (writing ``out``) in this process; its summary row and warnings."""
    started_s = time.monotonic()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", IncompleteRecordingWarning)
        row = _replay_and_write(path, args, out)
    for w in caught:
        if not issubclass(w.category, IncompleteRecordingWarning):
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    incomplete = [str(w.message) for w in caught if w.category is IncompleteRecordingWarning]
    return Replayed(row, incomplete, os.getpid(), started_s, time.monotonic(), time.process_time())


def _replay_and_write(path: Path, args: argparse.Namespace, out: Path | None) -> list[Any]:
    from rtsid.replay import replay_file

    config = _config(args, path)
    publish = None
    publisher = None
    if args.publish:
        from rtsid.io.zenoh_link import ZenohPublisher

        publisher = ZenohPublisher(config.zenoh, run_config=config.as_dict()).start()
        publish = publisher.publish_estimate
    try:
        show = _progress if args.progress and sys.stderr.isatty() else None
        # without --config, replay_file follows what the live run decided (the windows a late
        # worker skipped, the model each window used): passing the recording's own config
        # re-analysed every window on the schedule, and the output differed from live
        given = config if args.config else None
        result = replay_file(path, given, rate=_rate(args.rate), publish=publish, progress=show)
    finally:
        if publisher is not None:
            publisher.stop()
        if args.progress and sys.stderr.isatty():
            sys.stderr.write("\n")
    if out is not None:
        _write(result, out, config)
    return _summary_row(result)


def _replay_directory(folder: Path, args: argparse.Namespace) -> list[list[Any]]:
    """One job per recording: the parts of a rotated session replay together, as one."""
    files = sorted(folder.glob("*.mcap"))
    if not files:
        raise InputDataError(f"{folder}: no .mcap recordings in this directory")
    # this process replays too: a child more than there are other recordings would only
    # import rtsid and wait
    children = min(args.jobs or mp.cpu_count(), len(files)) - 1
    if children == 0:
        rows, write_timing = _replay_folder(files, args, None, [])
        write_timing({})
        return rows
    ctx = mp.get_context("spawn")
    with cf.ProcessPoolExecutor(children, ctx, initializer=_init_child) as pool:
        # the children start first, and import the replay while this process lists the
        # folder and imports it too
        ready = [pool.submit(_preload) for _ in range(children)]
        rows, write_timing = _replay_folder(files, args, pool, ready)
    # the pool has waited for every child's preload: one that was ready only after the last
    # recording ended (it replayed none) is in the timing too
    write_timing(
        {
            r.pid: r
            for f in ready
            if not f.cancelled() and f.exception() is None
            for r in [f.result()]
        }
    )
    return rows


def _replay_folder(
    files: list[Path],
    args: argparse.Namespace,
    pool: cf.ProcessPoolExecutor | None,
    ready: list[cf.Future[Ready]],
) -> tuple[list[list[Any]], Callable[[dict[int, Ready]], None]]:
    """The summary rows of the recordings among ``files``, replayed by this process and by
    the children of ``pool`` (None: this process alone), each child once its future in
    ``ready`` is done; and the writing of the run's timeline to ``args.timing`` (nothing
    without it), given when the children that replayed nothing were ready."""
    sessions = _sessions(files)
    out_dir = Path(args.output) if args.output else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    # Only plain options cross to the spawned children; they publish nothing and draw no bar.
    quiet = argparse.Namespace(config=args.config, rate=args.rate, publish=False, progress=False)
    folder_run = _FolderRun(_longest_first(sessions), quiet, out_dir)
    if pool is None:
        folder_run.replay_here()
    else:
        folder_run.replay_with(pool, ready)
    finished_s = time.monotonic()
    # the table keeps the recordings' order, whichever finished first
    done = folder_run.results(sessions)

    def write_timing(late_ready: dict[int, Ready]) -> None:
        if args.timing:
            _write_timing(Path(args.timing), late_ready | folder_run.ready, done, finished_s)

    return [_rewarn(d.row, d.incomplete) for d in done], write_timing


class _FolderRun:
    """The recordings of a folder handed out one at a time, longest first, to this process
    and to a pool's spawned processes: whichever process finishes a recording takes the next.

    This process is not spawned: it replays the largest recording at once (importing the
    replay as the children import theirs); a child is sent a recording when it is ready and
    the next when it finishes one (one at a time: a pool queues two per child, and a child
    kept one that this process could have replayed). A recording that fails is reported
    after the others have been replayed (their outputs are written).
    """

    def __init__(self, order: list[Path], args: argparse.Namespace, out_dir: Path | None):
        self._todo = collections.deque(order)
        self._args, self._out_dir = args, out_dir
        self._total = len(order)
        self._lock = threading.Lock()
        self._outcomes: dict[Path, Replayed | BaseException] = {}
        self._all_done = threading.Event()
        self._pool: cf.ProcessPoolExecutor | None = None
        #: when each process (by pid) had imported the replay
        self.ready: dict[int, Ready] = {}

    def replay_here(self) -> None:
        """Replay what is left in this process, one recording after another."""
        self._preload_here()
        while (path := self._take()) is not None:
            self._replay(path)

    def _replay(self, path: Path) -> None:
        try:
            outcome: Replayed | BaseException = _replay_one(path, self._args, self._output(path))
        except Exception as exc:  # reported once the others are done
            outcome = exc
        self._finished(path, outcome)

    def replay_with(self, pool: cf.ProcessPoolExecutor, ready: list[cf.Future[Ready]]) -> None:
        """Replay with the children of ``pool`` beside this process; each is sent its first
        recording when its future in ``ready`` is done."""
        try:
            with self._lock:  # the longest to this process, which starts at once
                first = self._todo.popleft()
                self._pool = pool
            for future in ready:
                future.add_done_callback(self._child_preloaded)
            self._preload_here()
            self._replay(first)
            # recordings a broken pool gave back are replayed here too
            while not self._all_done.is_set():
                self.replay_here()
                self._all_done.wait(0.2)
        finally:  # Ctrl-C: nothing more is sent; running recordings end (see _init_child)
            with self._lock:
                self._todo.clear()

    def results(self, order: list[Path]) -> list[Replayed]:
        """Each recording's summary row and incomplete-recording warnings, in ``order``;
        raises the failure of the first in ``order`` that failed (the others' outputs are
        written by then)."""
        done: list[Replayed] = []
        for path in order:
            outcome = self._outcomes[path]
            if isinstance(outcome, BaseException):
                raise outcome
            done.append(outcome)
        return done

    def _output(self, path: Path) -> Path | None:
        return self._out_dir / f"{path.stem}.csv" if self._out_dir else None

    def _take(self) -> Path | None:
        with self._lock:
            return self._todo.popleft() if self._todo else None

    def _send_next(self) -> None:
        """Send a child the next recording (with the lock held)."""
        if not self._todo or self._pool is None:
            return
        path = self._todo.popleft()
        try:
            future = self._pool.submit(_replay_in_child, path, self._args, self._output(path))
        except (RuntimeError, cf.BrokenExecutor):  # the pool is gone: this process takes it
            self._todo.appendleft(path)
            return
        future.add_done_callback(lambda done: self._child_done(path, done))

    def _child_done(self, path: Path, future: cf.Future[Replayed]) -> None:
        try:
            outcome: Replayed | BaseException = future.result()
        except BaseException as exc:  # a failed recording, or a child that died
            outcome = exc
        self._finished(path, outcome)
        if isinstance(outcome, KeyboardInterrupt):  # Ctrl-C reached the child: send no more
            with self._lock:
                self._todo.clear()
        self._child_ready(future)

    def _child_ready(self, _: cf.Future[Any]) -> None:
        with self._lock:
            self._send_next()

    def _child_preloaded(self, future: cf.Future[Ready]) -> None:
        if not future.cancelled() and future.exception() is None:
            ready = future.result()
            self.ready[ready.pid] = ready
        self._child_ready(future)

    def _preload_here(self) -> None:
        """Import the replay in this process (once), noting when it was done."""
        if os.getpid() not in self.ready:
            ready = _preload()
            self.ready[ready.pid] = ready

    def _finished(self, path: Path, outcome: Replayed | BaseException) -> None:
        with self._lock:
            self._outcomes[path] = outcome
            done = len(self._outcomes)
            if not isinstance(outcome, KeyboardInterrupt):  # no line once Ctrl-C was pressed
                _recordings_done(done, self._total, path.name)
            if done == self._total:
                self._all_done.set()


def _init_child() -> None:
    """Initializer of a replay child: Ctrl-C (the terminal sends it to the whole process
    group) ignored while it waits for a recording — a child interrupted in its queue read
    printed a traceback and broke the pool — and raised in the recording it replays; and
    the child's exit without the interpreter's teardown (:func:`_exit_at_once`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    atexit.register(_exit_at_once)


def _exit_at_once() -> None:
    """A replay child's last step once the pool has let it go (its non-daemon threads are
    joined and its multiprocessing finalizers run by then): flush its output and end the
    process, skipping the interpreter's teardown of its modules and arrays.

    The command waits for its children to exit before it does, and the teardown was on that
    path: 0.07-0.19 s from the last recording's result to the pool closed (2 cores under
    other engineers' load; 3-8 ms without it). The exit status reads 0 (a pool tells a
    child that died by its pipe, never by its status; an error in a recording comes back as
    that recording's exception). Exit handlers registered before the pool's initializer (a
    coverage tool's, say) do not run in a child."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(0)


def _preload() -> Ready:
    """A child's first task: import what a replay needs — rtsid's replay (compiled from
    source: this machine writes no bytecode) — while this process lists the folder and
    imports it too. Not scipy: the filters are designed in numpy or read from the design
    cache (:mod:`rtsid.ident.designs`; scipy.signal, 4.2 G instructions to import, is
    imported only by a design the cache does not hold yet). Returns when this process was
    ready (:class:`Ready`)."""
    import rtsid.replay  # noqa: F401

    return Ready(os.getpid(), time.monotonic(), time.process_time())


def _replay_in_child(path: Path, args: argparse.Namespace, out: Path | None) -> Replayed:
    """:func:`_replay_one` in a child, interruptible by Ctrl-C while it runs."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return _replay_one(path, args, out)
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _longest_first(sessions: list[Path]) -> list[Path]:
    """The recordings by size, largest first (the pool takes them in this order): a long
    recording started last would leave the other processes idle while it ends."""
    from rtsid.io.recording import session_parts

    return sorted(sessions, key=lambda f: -sum(p.stat().st_size for p in session_parts(f)))


def _recordings_done(done: int, total: int, name: str) -> None:
    """One progress line for a directory: redrawn in place on a terminal, else one line per
    finished recording (a log keeps them)."""
    text = f"replayed {done}/{total} recordings (last: {name})"
    if sys.stderr.isatty():
        sys.stderr.write(f"\r{text}" + ("\n" if done == total else ""))
    else:
        sys.stderr.write(text + "\n")
    sys.stderr.flush()


def _sessions(files: list[Path]) -> list[Path]:
    """The first part of each recording among ``files`` (other parts are read with it)."""
    from rtsid.io.recording import session_parts

    firsts: list[Path] = []
    for f in files:
        first = session_parts(f)[0]
        if first not in firsts:
            firsts.append(first)
    return firsts


def _write_timing(
    path: Path, ready: dict[int, Ready], done: list[Replayed], finished_s: float
) -> None:
    """``--timing JSON``: for each process (this one first), when it had imported the replay
    (``ready_s``) and its CPU time by then (``ready_cpu_s``, the interpreter's start
    included), when it started and ended each recording, how long it idled before the last
    recording ended (``idle_at_end_s``) and its CPU time by the end of its last recording
    (``cpu_s``, its start-up included); times are ``time.monotonic()`` s."""
    from rtsid.io.files import atomic_write

    # a process's readiness is known once its preload has come back; it always has before
    # the process is sent a recording, but the first start stands in, should it not
    first_s: dict[int, float] = {}
    for d in done:
        first_s[d.pid] = min(first_s.get(d.pid, d.started_s), d.started_s)
    ready_s = first_s | {pid: r.ready_s for pid, r in ready.items()}
    processes = []
    for pid in sorted(ready_s, key=lambda p: (p != os.getpid(), ready_s[p])):
        mine = sorted((d for d in done if d.pid == pid), key=lambda d: d.started_s)
        last_s = mine[-1].ended_s if mine else ready_s[pid]
        processes.append(
            {
                "pid": pid,
                "role": "command" if pid == os.getpid() else "child",
                "ready_s": ready_s[pid],
                "ready_cpu_s": ready[pid].cpu_s if pid in ready else None,
                "recordings": [
                    {"recording": d.row[0], "started_s": d.started_s, "ended_s": d.ended_s}
                    for d in mine
                ],
                "idle_at_end_s": max(0.0, finished_s - last_s),
                "cpu_s": max((d.cpu_s for d in mine), default=0.0),
            }
        )
    document = {
        "clock": "time.monotonic() s (Linux CLOCK_MONOTONIC: one clock for every process)",
        "finished_s": finished_s,
        "processes": processes,
    }
    with atomic_write(path, "w", what="timing") as fh:
        json.dump(document, fh, indent=1)
        fh.write("\n")


def _rewarn(row: list[Any], incomplete: list[str]) -> list[Any]:
    for message in incomplete:
        warnings.warn(IncompleteRecordingWarning(message), stacklevel=2)
    return row


def run(args: argparse.Namespace) -> int:
    # by the end every output is written and closed and the pool has let its children go:
    # the process may end without the interpreter's teardown (rtsid.cli.console); not after
    # publishing (zenoh's native threads are not Python's to count)
    args.skip_teardown = not args.publish
    path = Path(args.recording)
    if not path.exists():
        raise InputDataError(f"{path}: no such file or directory")
    if args.jobs < 0:
        raise InputDataError(
            f"--jobs {args.jobs}: use a number of processes ≥ 1, or 0 for one a core"
        )
    if path.is_dir():
        rows = _replay_directory(path, args)
    else:
        args.progress = True
        out = Path(args.output) if args.output else None
        ready = _preload()
        done = _replay_one(path, args, out)
        if args.timing:
            _write_timing(Path(args.timing), {ready.pid: ready}, [done], time.monotonic())
        rows = [_rewarn(done.row, done.incomplete)]
    from rtsid.benchmarks.table import print_table

    print_table(
        "Replay",
        [
            "recording",
            "seconds",
            "windows",
            "estimates",
            "withheld",
            "median K",
            "median B",
            "median I",
            "median VAF %",
            "markers",
            "× real time",
        ],
        rows,
    )
    return 0
