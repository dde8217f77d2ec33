"""The acquisition thread: frames (or datagrams) in, one ring-buffer row per sample out.

:class:`Acquisition` owns a thread named "rtsid-acquisition" that loops
``bus.recv(receive_timeout_s)`` (so :meth:`Acquisition.stop` returns within about that
time), asks the link's protocol object to turn each frame into samples and writes the ring
buffer. The protocol is a CAN mapping (:mod:`rtsid.link.mapping`: any DBC; the built-in
ankle protocol, the default, keeps its fast integer decoder) or a UDP datagram layout
(:mod:`rtsid.link.udp`, read from a :class:`~rtsid.link.udp.UdpReceiver`); everything below
is done here, once, for all of them.

Sample bookkeeping, in one place:

* the counter (12-bit for the built-in protocol; its width is the protocol's) is unwrapped
  into a monotonic ``sample_index``; after a silence of one or more whole wraps (1.64 s at
  2500 Hz with 12 bits) the number of wraps comes from the frames' bus timestamps (host
  clock when the interface gives none), rounded towards fewer wraps;
* without a counter the index comes from the frames' timestamps (:func:`index_from_time`:
  a jump of more than 1.5 periods is a gap);
* a forward jump of ``d`` writes ``d - 1`` invalid rows (a *gap*; ``lost_samples`` += d - 1)
  once the frames after it confirm it; frames the next in-sequence frames refute are
  *strays*, dropped (:mod:`rtsid.link.sequence`: a run of up to ``MAX_STRAY_RUN``
  consecutive strays is classified like one; for UDP, runs are counted in datagrams);
* a frame whose counter is at most ``reorder_window`` behind the newest is late: a
  *duplicate* if its row is valid already, otherwise *out of order*; both are dropped (rows
  already published are never rewritten);
* a state frame of the wrong length, a failing checksum, a remote frame, a datagram of the
  wrong length → *malformed*, never decoded; a frame of a two-frame sample whose partner
  never comes → *unpaired*; other identifiers → *unknown_id*; error frames →
  *error_frames* (bus-off also reopens the bus);
* a marker signal's change puts a :class:`~rtsid.link.markers.WireMarker` in
  :attr:`Acquisition.markers`, stamped with its sample's index;
* the rate is measured from the data (indices per second of sender time over >= 2 s) and
  compared with ``fs_hz`` (``rate_mismatch``: two measurements in a row off on the same
  side, so that a sender catching up after a stall — slow, then fast — is not a wrong rate);
* ``bus.recv`` raising → *bus_errors*, the bus is closed and reopened from the factory with
  exponential back-off (*reconnects* counts successes);
* no state frame for ``stale_after_s`` → ``stale`` (and optionally reopen the bus after
  ``reconnect_after_stale_s``).

Sample time is ``anchor_host_time_s + (sample_index - anchor_index) / fs_hz``, anchored to
``time.monotonic()`` at the first sample (:meth:`Acquisition.sample_time_s`).
"""

from __future__ import annotations

import binascii
import math
import struct
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import can
import numpy as np

from rtsid.errors import LinkError, LinkHandshakeError
from rtsid.ident.levinson import compiled_kernel
from rtsid.lifecycle import ThreadOwner
from rtsid.link.counters import LINK_STATES, LinkCounters
from rtsid.link.mapping import (
    FRAME_COMMAND,
    FRAME_DIAGNOSTICS,
    AnkleDecoder,
    MappedProtocol,
    builtin_protocol,
)
from rtsid.link.markers import MarkerInbox, WireMarker
from rtsid.link.protocol import (
    COUNTER_MODULO,
    POSITION_SCALE_RAD,
    STATE_ID,
    TORQUE_SCALE_NM,
    Command,
)
from rtsid.link.ring import RingBuffer
from rtsid.link.sequence import CONTRADICTIONS, MAX_STRAY_RUN, Sequencer
from rtsid.link.socketcand import Record, parse_records, record_message
from rtsid.link.udp import Datagram, UdpLayout

__all__ = ["LINK_STATES", "Acquisition", "LinkCounters", "explain_link_state", "unwrap_counter"]

#: Opens a bus: a python-can bus, or a :class:`~rtsid.link.udp.UdpReceiver` (``recv``,
#: ``shutdown``, ``send``): the only part that differs between sources.
BusFactory = Callable[[], Any]
CAN_ERR_BUSOFF = 0x40
_CPU_EVERY = 512  # frames between thread CPU readings
_WRAP_TOLERANCE = 0.1  # of a wrap period: how much earlier than expected a frame may arrive
_HOST_SLACK_WRAPS = 0.3  # of a wrap period: how much longer than the host saw a silence may be
_MAX_REJECTS_IN_ROW = 256  # rejected state frames in a row: a broken link, fatal to the thread
_STATE_BYTES = 8  # the built-in state frame's length
_MAX_BLOCK_ROWS = 2048  # frames one socketcand read may hold (64 KiB of 48-byte records)
_EXTENDED = 1 << 31  # frame key bit of a 29-bit identifier (rtsid.link.mapping.frame_key)
RATE_WINDOW_S = 2.0  # sender-clock span over which the sample rate is measured

# position rad, torque N·m, status, host s, bus s, marker label (None: no marker)
_Sample = tuple[float, float, int, float, float, str | None]


def _usable_time(stamp: Any) -> bool:
    """Whether a frame's bus timestamp is a finite, non-negative number (0: not stamped)."""
    return isinstance(stamp, int | float) and not isinstance(stamp, bool) and 0 <= stamp < math.inf


def unwrap_counter(
    counter: int,
    last: int,
    elapsed_s: float,
    fs_hz: float,
    reorder_window: int = 64,
    modulo: int = COUNTER_MODULO,
) -> int:
    """Unwrapped sample index of a frame ``counter`` given the newest index ``last``.

    Whole wraps hidden in a silence are counted from the elapsed time, rounded towards
    fewer wraps: frames arrive late (a stalled sender catching up) far more often than
    early, so an elapsed time up to 0.9 of a wrap period longer than the counter says is
    taken as delay, not as 4096 lost samples. Used live by :class:`Acquisition` and offline
    by the CAN-log import, so both number samples alike.

    Parameters
    ----------
    counter : int
        The frame's counter, ``0 .. COUNTER_MODULO - 1``.
    last : int
        Unwrapped index of the newest sample so far.
    elapsed_s : float
        Time since the newest sample's frame, s (0 when unknown).
    fs_hz : float
        Sample rate, Hz.
    reorder_window : int
        Counter distance behind the newest treated as a late frame rather than a wrap.
    modulo : int
        ``2**bits`` of the counter (4096 for the built-in 12-bit counter).

    Returns
    -------
    int
        The index: ``last + 1`` for the next sample, more after lost samples, ``<= last``
        for a late (duplicate or reordered) frame.
    """
    delta = (counter - last) % modulo
    wraps = math.floor((elapsed_s * fs_hz - delta) / modulo + _WRAP_TOLERANCE)
    if wraps >= 1:  # a silence of at least one whole wrap
        return last + delta + wraps * modulo
    if delta == 0:
        return last  # the newest sample again
    if delta > modulo - reorder_window:
        return last + delta - modulo  # behind the newest: late
    return last + delta


def _consecutive(first: int, n: int, modulo: int) -> list[int]:
    """``n`` counter values from ``first`` on, wrapping at ``modulo``."""
    if first + n <= modulo:
        return list(range(first, first + n))
    return [*range(first, modulo), *range(0, first + n - modulo)]


def index_from_time(t_s: float, last: int, last_t_s: float, fs_hz: float) -> int:
    """Sample index of a frame stamped ``t_s`` (no counter), given the newest sample's.

    ``last + ceil((t_s - last_t_s)·fs_hz - 0.5)``: a frame within half a period of the
    newest is the newest again (a duplicate), a timestamp jump of more than 1.5 periods
    skips at least one sample (a gap), and one further back is late. Counting from the
    newest sample, not from the first, keeps a sender clock a little off ``fs_hz`` from
    drifting into phantom gaps.
    """
    return last + math.ceil((t_s - last_t_s) * fs_hz - 0.5)


def explain_link_state(acquisition: Mapping[str, Any], where: str) -> str | None:
    """Why no samples come, in words, from a status message's ``acquisition`` object.

    Parameters
    ----------
    acquisition : Mapping
        :class:`LinkCounters` as a dict (the status message's ``acquisition``).
    where : str
        The link's far end as a user knows it, e.g. ``"127.0.0.1:29536"``.

    Returns
    -------
    str or None
        E.g. ``"connected to 127.0.0.1:29536 but socketcand has not greeted (bus errors
        4)"``, or that the measured rate is not ``fs_hz``; None while state frames stream
        at the configured rate (or from a status without ``link_state``).
    """
    state = acquisition.get("link_state", "streaming")
    errors = f"bus errors {acquisition.get('bus_errors', 0)}"
    if state == "opening":
        return f"opening the bus at {where} ({errors})"
    if state == "unreachable":
        return f"not connected to {where} ({errors}; last: {acquisition.get('last_error')})"
    if state == "no_greeting":
        return f"connected to {where} but socketcand has not greeted ({errors})"
    if state == "no_frames":
        return f"connected to {where}, no frames yet from the bus"
    if state == "no_state_frames":
        return (
            f"{acquisition.get('frames', 0)} frames from {where} but no state frame "
            f"({acquisition.get('unknown_id', 0)} unknown id, "
            f"{acquisition.get('malformed', 0)} malformed): check the robot's identifiers"
        )
    if state == "stopped":
        return "the acquisition has stopped"
    if state == "stale":
        age_s = float(acquisition.get("last_frame_age_s", 0.0))
        return f"stale: no state frame from {where} for {age_s:.1f} s"
    if acquisition.get("rate_mismatch"):
        rate = float(acquisition.get("measured_rate_hz", float("nan")))
        return (
            f"the data from {where} arrive at {rate:.1f} samples/s, not at link.fs_hz: set "
            "link.fs_hz to the sender's rate"
        )
    return None


class Acquisition(ThreadOwner):
    """Receive state frames on a thread and write one ring row per sample.

    A :class:`~rtsid.lifecycle.ThreadOwner`: ``start()``, ``stop(timeout_s)``, ``failure``.

    Parameters
    ----------
    bus : can.BusABC, UdpReceiver or callable
        A bus factory (called to open and to reopen; the buses it returns are owned and
        shut down here), or an open bus (not owned, never reopened). A UDP source is a
        :class:`~rtsid.link.udp.UdpReceiver` with the same ``recv``/``shutdown``.
    ring : RingBuffer
        Where samples go; this thread is its only writer.
    fs_hz : float
        The robot's sample rate, Hz.
    stale_after_s : float
        No state frame for this long: ``stale``.
    receive_timeout_s : float
        Longest single ``recv`` wait, s (bounds ``stop``).
    reconnect_after_stale_s : float
        Reopen the bus after this long without state frames (0: never).
    backoff_min_s, backoff_max_s : float
        Reconnection back-off, doubling from the minimum to the maximum.
    reorder_window : int
        Counter distance behind the newest sample treated as late rather than as a wrap.
    name : str
        Thread name.
    protocol : MappedProtocol or UdpLayout, optional
        What the bus speaks: a CAN mapping (:mod:`rtsid.link.mapping`; default the built-in
        ankle protocol) or a UDP datagram layout (:mod:`rtsid.link.udp`, with a bus whose
        ``recv`` gives :class:`~rtsid.link.udp.Datagram`). Either way the samples go through
        the same sequencing, gap counting and ring writes.
    rate_tolerance_percent : float
        Measured rate vs ``fs_hz`` beyond which ``rate_mismatch`` is reported.

    Examples
    --------
    >>> ring = RingBuffer(25_000)  # doctest: +SKIP
    >>> with Acquisition(lambda: can.Bus(interface="virtual", channel="x"), ring) as acq:
    ...     snap = ring.latest(750)
    """

    def __init__(
        self,
        bus: Any,
        ring: RingBuffer,
        *,
        fs_hz: float = 2500.0,
        stale_after_s: float = 0.1,
        receive_timeout_s: float = 0.05,
        reconnect_after_stale_s: float = 0.0,
        backoff_min_s: float = 0.1,
        backoff_max_s: float = 5.0,
        reorder_window: int = 64,
        name: str = "rtsid-acquisition",
        protocol: MappedProtocol | UdpLayout | None = None,
        rate_tolerance_percent: float = 2.0,
    ) -> None:
        super().__init__(name)
        self.protocol = builtin_protocol() if protocol is None else protocol
        self._decoder: Any = self.protocol.decoder()
        if hasattr(self._decoder, "set_rate"):
            self._decoder.set_rate(float(fs_hz))
        self._modulo = self.protocol.counter_modulo
        self._timestamps = self.protocol.uses_timestamps
        self._udp = isinstance(self.protocol, UdpLayout)
        # the built-in protocol's state frames from a batch-reading bus go in one block
        self._ankle = isinstance(self._decoder, AnkleDecoder)
        self._state_ident = f"{STATE_ID:03X}".encode("ascii")  # as socketcand prints it
        kernel = compiled_kernel() if self._ankle else None
        self._kernel = kernel if hasattr(kernel, "ankle_frames") else None
        rows = _MAX_BLOCK_ROWS
        # the compiled decoder's output: counter, position, torque, status, bus time
        self._scratch = (
            np.zeros(rows, np.int64),
            np.zeros(rows),
            np.zeros(rows),
            np.zeros(rows, np.uint8),
            np.zeros(rows),
        )
        self._kinds = {} if self._udp else dict(self.protocol.frame_kinds)  # type: ignore[union-attr]
        self._lengths = {} if self._udp else dict(self.protocol.state_lengths)  # type: ignore[union-attr]
        self.rate_tolerance = rate_tolerance_percent / 100.0
        if isinstance(bus, can.BusABC) or hasattr(bus, "recv"):  # an open bus or socket
            self._factory: BusFactory | None = None
            self._bus: Any = bus
        else:
            self._factory = bus
            self._bus = None
        self.ring = ring
        self.fs_hz = float(fs_hz)
        self.stale_after_s = stale_after_s
        self.receive_timeout_s = receive_timeout_s
        self.reconnect_after_stale_s = reconnect_after_stale_s
        self.backoff_min_s = backoff_min_s
        self.backoff_max_s = backoff_max_s
        self.reorder_window = reorder_window
        self.name = name
        self._require_bus = True
        self._send_lock = threading.Lock()
        self._c = dict.fromkeys(
            (
                "frames",
                "samples",
                "gaps",
                "lost_samples",
                "duplicates",
                "out_of_order",
                "malformed",
                "unknown_id",
                "error_frames",
                "bus_off",
                "bus_errors",
                "reconnects",
                "diagnostics",
                "commands_seen",
                "stale_events",
                "rejected",
            ),
            0,
        )
        self._stale = False
        self._cpu_s = 0.0
        self._started = time.monotonic()
        self._last_frame_host = self._started
        self._last_bus_time = 0.0
        self._last_index = -1
        self._open_failure = ""  # why the last opening of the bus failed ("" after success)
        # A datagram carries many samples: judge jumps in whole datagrams (a reordered
        # datagram must not read as a confirmed gap after 9 of the next one's samples).
        per_unit = self.protocol.samples_per_unit if self._udp else 1  # type: ignore[union-attr]
        self.reorder_window = max(reorder_window, 8 * per_unit)
        self._sequence: Sequencer[_Sample] = Sequencer(
            reach=self.reorder_window,
            max_stray_run=MAX_STRAY_RUN * per_unit,
            contradictions=CONTRADICTIONS * per_unit,
        )
        self._rejects_in_row = 0
        self._backoff = backoff_min_s
        self._last_reopen = self._started
        self._command_counter = 0
        self.anchor_index = -1
        self.anchor_host_time_s = float("nan")
        self.last_diagnostics: dict[str, Any] = {}
        self.last_error: str = ""
        self.markers = MarkerInbox()  # trial markers decoded from the wire, for the daemon
        self._rate_anchor = (-1, 0.0)  # (sample index, sender time s) the rate is measured from
        self._rate_due_s = 0.0  # sender time of the next rate measurement
        self._rate_hz = float("nan")
        self._rate_side = 0  # the last measurement's side of fs_hz beyond tolerance: -1, 0, 1
        self._rate_mismatch = False

    # ------------------------------------------------------------------ life cycle
    def start(self, *, require_bus: bool = True) -> Acquisition:
        """Open the bus (when given a factory) and start the thread.

        Parameters
        ----------
        require_bus : bool
            Open the bus here and raise :class:`~rtsid.errors.LinkError` if that fails.
            False: the thread opens it (so a server that never answers cannot block the
            caller, e.g. the daemon's main thread and its signal handling) and keeps
            retrying with back-off.
        """
        self._require_bus = require_bus
        return super().start()

    def _before_start(self) -> None:
        if self._bus is None and self._factory is not None and self._require_bus:
            try:
                self._bus = self._factory()
            except LinkError as exc:
                if self._udp:  # already says which address and what to fix
                    raise
                raise LinkError(
                    f"cannot open the CAN bus: {exc}; check [link] interface, channel, "
                    "host and port, and that the adapter or server is up"
                ) from exc
            except Exception as exc:
                raise LinkError(
                    f"cannot open the CAN bus: {exc}; check [link] interface, channel, "
                    "host and port, and that the adapter or server is up"
                ) from exc
        self._started = self._last_frame_host = self._last_reopen = time.monotonic()

    def _after_stop(self, ended: bool) -> None:
        """Close an owned bus once the thread is gone (``stop`` returns within about
        ``receive_timeout_s``)."""
        if ended:
            self._close_bus()

    # ------------------------------------------------------------------ public API
    def drain_markers(self) -> list[WireMarker]:
        """Trial markers decoded from the wire since the last call, oldest first."""
        return self.markers.drain()

    def counters(self) -> LinkCounters:
        """A consistent-enough snapshot of the counters (each value is read once)."""
        c = dict(self._c)
        c["strays"] = self._sequence.strays
        c["duplicates"] += self._sequence.duplicates
        age = time.monotonic() - self._last_frame_host
        connected = self._bus is not None
        return LinkCounters(
            **c,
            unpaired=self._decoder.unpaired,
            measured_rate_hz=self._rate_hz,
            rate_mismatch=self._rate_mismatch,
            ring_overwrites=self.ring.reader_overruns,
            stale=age > self.stale_after_s,
            last_frame_age_s=age,
            connected=connected,
            link_state=self._link_state(connected, c["frames"], age),
            last_error=self.last_error,
            thread_cpu_s=self._cpu_s,
            newest_index=self.ring.newest_index,
        )

    def _link_state(self, connected: bool, frames: int, age_s: float) -> str:
        """One of :data:`LINK_STATES`."""
        if self._stop.is_set():
            return "stopped"
        if not connected:
            return self._open_failure or "opening"
        if self._last_index < 0:
            return "no_state_frames" if frames else "no_frames"
        return "stale" if age_s > self.stale_after_s else "streaming"

    def sample_time_s(self, index: int) -> float:
        """Host-clock (``time.monotonic``) time of sample ``index``, from the counter."""
        return self.anchor_host_time_s + (index - self.anchor_index) / self.fs_hz

    def send(self, msg: can.Message, timeout: float = 0.1) -> None:
        """Send a frame on the acquisition's bus (thread-safe with the receiving thread).

        Raises
        ------
        LinkError
            No bus is open, or the interface refused the frame.
        """
        with self._send_lock:
            bus = self._bus
            if bus is None:
                raise LinkError("the CAN bus is not open (reconnecting); send again later")
            try:
                bus.send(msg, timeout=timeout)
            except (can.CanError, OSError) as exc:
                raise LinkError(f"could not send frame 0x{msg.arbitration_id:X}: {exc}") from exc

    def send_command(self, command: Command) -> None:
        """Send a PerturbationCommand (enable, kind, amplitude, bandwidth) to the robot.

        Raises
        ------
        LinkError
            The protocol maps no command message (or a UDP source), or the send failed.
        """
        protocol = self.protocol
        if self._udp or protocol.command_message is None:  # type: ignore[union-attr]
            raise LinkError(
                "this link carries no perturbation command (a UDP source, or no "
                "link.protocol.command message); drive the perturbation on the robot"
            )
        self._command_counter = (self._command_counter + 1) & 0xFF
        numbered = Command(**{**command.__dict__, "counter": self._command_counter})
        self.send(protocol.encode_command(numbered))  # type: ignore[union-attr]

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:
        stop = self._stop
        timeout = self.receive_timeout_s
        handle = self._on_datagram if self._udp else self._handle
        frames_since_cpu = 0
        if self._bus is None and self._factory is not None:
            self._open_bus()  # start(require_bus=False): the first try is at once, here
        while not stop.is_set():
            bus = self._bus
            if bus is None:
                self._reopen()
                continue
            read_chunk = getattr(bus, "recv_chunk", None)  # rtsid's socketcand client
            try:
                got = bus.recv(timeout) if read_chunk is None else read_chunk(timeout)
            except Exception as exc:  # any interface error: count, close, reopen
                self._on_bus_error(exc)
                continue
            now = time.monotonic()
            if got is None or (read_chunk is not None and not got):
                self._idle(now)
                continue
            if read_chunk is not None:
                frames_since_cpu += self._on_chunk(got, now)
            else:
                try:
                    handle(got, now)
                except Exception as exc:  # a frame must never end the thread; many do
                    self._reject(exc)
                frames_since_cpu += 1
            if frames_since_cpu >= _CPU_EVERY:
                frames_since_cpu = 0
                self._cpu_s = time.thread_time()
        self._cpu_s = time.thread_time()

    def _on_chunk(self, chunk: bytes, now: float) -> int:
        """The complete records of one socketcand read: written as one block when they are
        the built-in protocol's state frames continuing the newest sample (the common case;
        decoded by the compiled kernel when it is built, else by :meth:`_write_block`), else
        one by one through :meth:`_handle`, exactly as python-can's frames were. Returns the
        number of frames."""
        kernel, scratch = self._kernel, self._scratch
        if kernel is not None and self._last_index >= 0 and not self._sequence.held:
            n = kernel.ankle_frames(
                chunk, self._state_ident, POSITION_SCALE_RAD, TORQUE_SCALE_NM, *scratch
            )
            if n > 0 and self._write_decoded(n, now):
                return int(n)
        return self._on_records(parse_records(chunk)[0], now)

    def _write_decoded(self, n: int, now: float) -> bool:
        """Write the kernel's ``n`` decoded samples as one ring block if their first counter
        continues the newest sample (their counters follow one another: the kernel checked)."""
        counter, position, torque, status, bus_time = self._scratch
        last = self._last_index
        if self._unwrap(int(counter[0]), last, float(bus_time[0]), now) != last + 1:
            return False
        times = bus_time[:n]
        self._commit_block(position[:n], torque[:n], status[:n], times, float(times.max()), now)
        return True

    def _on_records(self, records: list[Record], now: float) -> int:
        """Parsed records (:func:`~rtsid.link.socketcand.parse_records`): one block when they
        are built-in state frames continuing the newest sample, else frame by frame.
        Returns the number of records."""
        if self._ankle and self._write_block(records, now):
            return len(records)
        channel = getattr(self._bus, "channel", None)
        for record in records:
            try:
                self._handle(record_message(record, channel), now)
            except Exception as exc:  # a frame must never end the thread; many in a row do
                self._reject(exc)
        return len(records)

    def _write_block(self, records: list[Record], now: float) -> bool:
        """Write a read's state frames as one ring block; False (nothing done) unless every
        record is a well-formed built-in state frame, the counters continue the newest
        sample one by one and no counter jump is held (then the per-frame path would write
        the same rows: same values, same counters)."""
        n = len(records)
        last = self._last_index
        if last < 0 or self._sequence.held:
            return False
        kinds, idents, stamps, payloads = zip(*records, strict=True)
        if kinds.count(b"frame") != n or idents.count(self._state_ident) != n:
            return False
        if set(map(len, payloads)) != {2 * _STATE_BYTES}:
            return False
        words = struct.unpack(f"<{n}Q", binascii.unhexlify(b"".join(payloads)))
        decoded = AnkleDecoder.decode_words(words)
        if decoded is None:
            return False
        counters, positions, torques, statuses = decoded
        first_counter = counters[0]
        if counters != _consecutive(first_counter, n, self._modulo):
            return False
        times = list(map(float, stamps))
        if self._unwrap(first_counter, last, times[0], now) != last + 1:
            return False
        self._commit_block(positions, torques, statuses, times, max(times), now)
        return True

    def _commit_block(
        self,
        positions: Any,
        torques: Any,
        statuses: Any,
        times: Any,
        latest_time: float,
        now: float,
    ) -> None:
        """Write samples ``newest + 1 …`` (lists or arrays) and do what :meth:`_write` does
        for each: the counters, the link's freshness and the rate measurement."""
        n = len(positions)
        last = self._last_index
        self._c["frames"] += n
        newest = self.ring.append_block(positions, torques, statuses, now, times)
        self._last_index = self._sequence.last = newest
        self._c["samples"] += n
        self._last_frame_host = now
        self._last_bus_time = float(times[-1])
        self._stale = False
        self._backoff = self.backoff_min_s
        self._rejects_in_row = 0
        if latest_time >= self._rate_due_s:  # every 2 s of sender time
            for k in range(n):
                t = float(times[k])
                if t >= self._rate_due_s:
                    self._measure_rate(last + 1 + k, t)

    def _handle(self, msg: can.Message, now: float) -> None:
        """Count and dispatch one CAN frame (the thread's hot path: keep it lean)."""
        c = self._c
        c["frames"] += 1
        if msg.is_error_frame:
            c["error_frames"] += 1
            if msg.arbitration_id & CAN_ERR_BUSOFF:
                c["bus_off"] += 1
                self._on_bus_error(LinkError("bus-off reported by the interface"))
            return
        key = msg.arbitration_id | _EXTENDED if msg.is_extended_id else msg.arbitration_id
        size = self._lengths.get(key)
        if size is not None:  # a state frame
            data = msg.data
            if msg.is_remote_frame or msg.dlc != size or len(data) != size:
                c["malformed"] += 1
                return
            self._on_state(key, data, msg.timestamp, now)
            return
        kind = self._kinds.get(key)
        if kind == FRAME_DIAGNOSTICS:
            c["diagnostics"] += 1
            decoded = self.protocol.decode_diagnostics(msg.data)  # type: ignore[union-attr]
            if decoded is None:
                c["malformed"] += 1
            else:
                self.last_diagnostics.update(decoded)
        elif kind == FRAME_COMMAND:
            c["commands_seen"] += 1
        else:
            c["unknown_id"] += 1

    def _on_state(self, key: int, data: bytearray, bus_time: Any, now: float) -> None:
        if not _usable_time(bus_time) or (self._timestamps and bus_time <= 0):
            self._reject(LinkError(f"state frame with bus timestamp {bus_time!r}"))
            return
        decoded = self._decoder.decode(key, data, bus_time)
        if decoded is None:
            self._c["malformed"] += 1
            return
        if decoded:  # () : the first frame of a pair, waiting for its partner
            stamp, position, torque, status, marker = decoded
            sample = (
                position,
                torque,
                status,
                now,
                stamp if self._timestamps else bus_time,
                marker,
            )
            if self._last_index < 0:
                self._on_sample(stamp, sample)
            else:
                self._place(stamp, sample)

    def _on_datagram(self, datagram: Datagram, now: float) -> None:
        c = self._c
        c["frames"] += 1
        samples = self._decoder.decode(datagram.data)
        if samples is None:
            c["malformed"] += 1
            return
        bus_time = datagram.timestamp
        for counter, position, torque, status, marker in samples:
            self._on_sample(counter, (position, torque, status, now, bus_time, marker))

    def _on_sample(self, stamp: float, sample: _Sample) -> None:
        """Place one decoded sample: ``stamp`` is its counter, or its time without one."""
        if self._last_index < 0:
            first = 0 if self._timestamps else int(stamp)
            self.ring.start_at(first)
            self.anchor_index, self.anchor_host_time_s = first, sample[3]
            self._last_index = first - 1
            self._write(first, sample)
            self._sequence.last = first
        else:
            self._place(stamp, sample)

    def _place(self, stamp: float, sample: _Sample) -> None:
        """Write the sample a frame carries, or hold it while it may be a stray.

        Late frames (at or behind the newest sample) are dropped and counted here; every
        other frame goes through the :class:`~rtsid.link.sequence.Sequencer`, which holds
        counter jumps until later frames confirm them (a gap) or refute them (strays:
        dropped, counted, inventing no lost samples and never shifting the index).
        """
        last = self._last_index
        if self._timestamps:
            index = index_from_time(stamp, last, self._last_bus_time, self.fs_hz)
        else:
            index = self._unwrap(int(stamp), last, sample[4], sample[3])
        if index <= last:
            self._late(index)
            return
        for row_index, row in self._sequence.offer(index, sample):
            self._write(row_index, row)

    def _write(self, index: int, sample: _Sample) -> None:
        """Write sample ``index`` after the newest one, the skipped indices as a gap."""
        position, torque, status, now, bus_time, marker = sample
        lost = index - self._last_index - 1
        if lost > 0:
            self._c["gaps"] += 1
            self._c["lost_samples"] += lost
            self.ring.append_gap(lost, now)
        self._last_index = self.ring.append(position, torque, status, now, bus_time)
        self._c["samples"] += 1
        self._last_frame_host = now
        self._last_bus_time = bus_time
        self._stale = False
        self._backoff = self.backoff_min_s
        self._rejects_in_row = 0
        if marker is not None:
            self.markers.put(WireMarker(index, marker))
        if bus_time >= self._rate_due_s:
            self._measure_rate(index, bus_time)

    def _measure_rate(self, index: int, t_s: float) -> None:
        """Sample indices per second of sender time since the anchor; flag a mismatch."""
        first, t0 = self._rate_anchor
        self._rate_anchor = (index, t_s)
        self._rate_due_s = t_s + RATE_WINDOW_S
        if first < 0 or t_s - t0 > 10 * RATE_WINDOW_S:  # the first, or after a long silence
            return
        rate = (index - first) / (t_s - t0)
        self._rate_hz = rate
        off = rate / self.fs_hz - 1.0
        side = 0 if abs(off) <= self.rate_tolerance else (1 if off > 0 else -1)
        mismatch = side != 0 and side == self._rate_side
        self._rate_side = side
        if mismatch and not self._rate_mismatch:
            self._note_error(
                LinkError(
                    f"the data arrive at {rate:.1f} samples/s but link.fs_hz = {self.fs_hz:g} "
                    f"(more than {100 * self.rate_tolerance:g} % apart); set link.fs_hz to "
                    "the sender's rate"
                )
            )
        self._rate_mismatch = mismatch

    def _reject(self, exc: BaseException) -> None:
        """Count a frame that could not be used; many in a row mean a fault, not a frame."""
        self._c["rejected"] += 1
        self._note_error(exc)
        self._rejects_in_row += 1
        if self._rejects_in_row >= _MAX_REJECTS_IN_ROW:
            raise LinkError(
                f"{self._rejects_in_row} state frames in a row were rejected (last: "
                f"{self.last_error}); the link or this code is broken, not one frame"
            ) from exc

    def _unwrap(self, counter: int, last: int, bus_time: float, now: float) -> int:
        """Unwrapped index of ``counter`` given the newest index ``last``.

        The silence since the newest sample is measured on the bus clock when the interface
        stamps frames, but never taken longer than the host clock saw (plus a slack for
        queueing): a sender whose clock steps forward must not make whole counter wraps
        (4096 phantom lost samples each) out of nothing.
        """
        host_elapsed = now - self._last_frame_host
        elapsed = host_elapsed
        if bus_time > 0 and self._last_bus_time > 0 and bus_time >= self._last_bus_time:
            slack_s = _HOST_SLACK_WRAPS * self._modulo / self.fs_hz
            elapsed = min(bus_time - self._last_bus_time, host_elapsed + slack_s)
        return unwrap_counter(counter, last, elapsed, self.fs_hz, self.reorder_window, self._modulo)

    def _late(self, index: int) -> None:
        valid = self.ring.is_valid(index)
        if valid:
            self._c["duplicates"] += 1
        else:
            self._c["out_of_order"] += 1

    def _idle(self, now: float) -> None:
        self._cpu_s = time.thread_time()
        age = now - self._last_frame_host
        if age > self.stale_after_s and not self._stale:
            self._stale = True
            self._c["stale_events"] += 1
        if (
            self.reconnect_after_stale_s > 0
            and self._factory is not None
            and age > self.reconnect_after_stale_s
            and now - self._last_reopen > self.reconnect_after_stale_s
        ):
            self._close_bus()
            self._last_reopen = now

    def _on_bus_error(self, exc: BaseException) -> None:
        self._c["bus_errors"] += 1
        self._note_error(exc)
        if self._factory is not None:
            self._close_bus()
        else:
            self._stop.wait(self._next_backoff())

    def _reopen(self) -> None:
        if self._factory is None or self._stop.wait(self._next_backoff()):
            return
        self._open_bus(reconnect=True)

    def _open_bus(self, *, reconnect: bool = False) -> None:
        """Open a bus from the factory on this thread; count a failure (retried later)."""
        assert self._factory is not None
        try:
            bus = self._factory()
        except Exception as exc:
            self._c["bus_errors"] += 1
            self._note_error(exc)
            handshake = isinstance(exc, LinkHandshakeError)
            self._open_failure = "no_greeting" if handshake else "unreachable"
            return
        self._open_failure = ""
        with self._send_lock:
            self._bus = bus
        self._c["reconnects"] += reconnect
        self._last_reopen = time.monotonic()

    def _next_backoff(self) -> float:
        delay = self._backoff
        self._backoff = min(self._backoff * 2, self.backoff_max_s)
        return delay

    def _close_bus(self) -> None:
        with self._send_lock:
            bus, self._bus = self._bus, None
        if bus is not None and self._factory is not None:
            try:
                bus.shutdown()
            except Exception as exc:
                self._note_error(exc)

    def _note_error(self, exc: BaseException) -> None:
        self.last_error = f"{type(exc).__name__}: {exc}"
