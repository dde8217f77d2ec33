"""What the acquisition reports: :class:`LinkCounters` (a snapshot of its counters, the
status message's ``acquisition``) and :data:`LINK_STATES`.

Apart from :mod:`rtsid.link.acquisition` so that the messages' schemas
(:mod:`rtsid.io.messages`), which every reader of recordings imports, do not import the
acquisition thread and python-can with it (asyncio, sqlite3, email: ≈ 0.3 G instructions of a
spawned replay process's start-up).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["LINK_STATES", "LinkCounters"]

#: Where the link stands (``link_state`` in the counters): why no samples come, or that they do.
LINK_STATES = {
    "opening": "the bus is being opened (at start, or again after an error)",
    "unreachable": "the last attempt to open the bus failed (no server, adapter or channel)",
    "no_greeting": "the server accepted the connection but never greeted (socketcand)",
    "no_frames": "the bus is open and no frame has arrived yet",
    "no_state_frames": "frames arrive but none is a usable state frame (identifiers, length, "
    "checksum)",
    "streaming": "state frames arrive",
    "stale": "no state frame for longer than stale_after_s",
    "stopped": "the acquisition was stopped",
}


@dataclass(frozen=True)
class LinkCounters:
    """A snapshot of the acquisition's counters (all cumulative since start).

    Attributes
    ----------
    frames : int
        Frames received (any identifier, error frames included).
    samples : int
        Valid samples written to the ring.
    gaps, lost_samples : int
        Counter jumps and the samples they skipped (written as invalid rows).
    duplicates, out_of_order : int
        Late state frames dropped (row already valid / row already written as lost).
    malformed : int
        State frames of the wrong length, failing checksum or RTR: counted, never decoded.
    unknown_id : int
        Frames with an identifier the protocol does not define.
    error_frames, bus_off : int
        Error frames reported by the interface; of those, bus-off.
    bus_errors : int
        Exceptions from the bus (receive or reopen).
    reconnects : int
        Successful reopenings of the bus.
    ring_overwrites : int
        Rows readers lost because the writer lapped them.
    diagnostics, commands_seen : int
        Diagnostics and PerturbationCommand frames seen.
    stale : bool
        No state frame for longer than ``stale_after_s``.
    stale_events : int
        Times the link became stale.
    rejected : int
        State frames that could not be used (a bus timestamp that is not a finite number,
        or any error handling the frame): counted and dropped, never fatal one by one.
    strays : int
        State frames whose counter jumped ahead and that the frames after them refuted
        (foreign frames with a valid checksum, alone or up to
        :data:`~rtsid.link.sequence.MAX_STRAY_RUN` in a row): dropped, so they invent no
        lost samples and never shift the sample index.
    last_frame_age_s : float
        Seconds since the last state frame (since start if none).
    connected : bool
        A bus is open.
    link_state : str
        One of :data:`LINK_STATES`: why no samples come, or ``streaming``.
    last_error : str
        The newest error seen (opening the bus, receiving, a rejected frame); empty if none.
    thread_cpu_s : float
        CPU time of the acquisition thread, s.
    newest_index : int
        Newest sample index in the ring (-1 if none).
    unpaired : int
        Frames of a two-frame sample whose partner never came (the sample is lost).
    measured_rate_hz : float
        Sample rate measured from the data: sample indices per second of the sender's
        clock (frame timestamps) over the last >= 2 s; NaN until measured.
    rate_mismatch : bool
        ``measured_rate_hz`` differs from ``fs_hz`` by more than ``rate_tolerance_percent``
        (``last_error`` says by how much and what to fix).
    """

    frames: int
    samples: int
    gaps: int
    lost_samples: int
    duplicates: int
    out_of_order: int
    malformed: int
    unknown_id: int
    error_frames: int
    bus_off: int
    bus_errors: int
    reconnects: int
    ring_overwrites: int
    diagnostics: int
    commands_seen: int
    stale: bool
    stale_events: int
    rejected: int
    strays: int
    last_frame_age_s: float
    connected: bool
    link_state: str
    last_error: str
    thread_cpu_s: float
    newest_index: int
    unpaired: int = 0
    measured_rate_hz: float = float("nan")
    rate_mismatch: bool = False
