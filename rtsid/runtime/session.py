"""The session desk: trial markers and condition changes, live, stamped on the sample stream.

One thread (``rtsid-session``) takes what arrives and records it::

    rtsid mark "trial 3 start"  ──query──►  …/mark        ─┐
    any zenoh client            ──put────►  …/mark/in     ─┼─► RequestInbox (bounded) ─┐
    rtsid condition fatigue     ──query──►  …/condition   ─┘                           │
    marker frames on the wire   ──► Acquisition.drain_markers() ───────────────────────┤
                                                                                       ▼
        stamp (next sample) ─► McapLogger.log_marker / log_session ─► the file (flushed)
                             ─► zenoh …/marker, …/session ─► the query's reply (acknowledgement)

- **Stamp.** A marker from zenoh marks the *next* sample: the ring's newest index + 1 when the
  desk takes it (latency: the zenoh hop, ≤ :data:`POLL_S` when idle — the desk wakes on each
  request — and how far the newest sample in the ring lags the bus). A wire marker keeps the
  sample it arrived with.
- **Acknowledgement.** A ``mark`` query is answered only after the MCAP writer wrote the marker
  and flushed the file (:meth:`~rtsid.io.mcap_log.McapLogger.log_marker`): an acknowledged
  marker survives a ``kill -9`` of the daemon. No file, a full queue, a label refused: an
  error reply saying the marker was NOT recorded. A put on ``mark/in`` has nobody to tell:
  what is refused is counted (``refused_by_reason``).
- **Duplicates.** A marker resent with the same ``marker_id`` (the sender did not hear the
  acknowledgement) is acknowledged again with its first stamp and recorded once (the last
  :data:`REMEMBERED_IDS` ids; after a daemon restart, readers drop it by ``marker_id``). One
  resent after a write timeout waits for its first write again: acknowledged with that
  write's stamp, never written twice.
- **Labels.** Plain text of at most :data:`~rtsid.io.messages.MAX_LABEL_CHARS` characters:
  one from zenoh with control characters or too long is refused (its sender is told why);
  one from the wire is cleaned (control characters → ``?``, cut to length).
"""

from __future__ import annotations

import json
import logging
import re
import threading
import time
import uuid
import zlib
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from rtsid.errors import ConfigError
from rtsid.io.mcap_log import McapLogger
from rtsid.io.messages import (
    MAX_LABEL_CHARS,
    MAX_MARKER_ID_CHARS,
    MarkerMessage,
    SessionMessage,
)
from rtsid.io.schemas import encode_json
from rtsid.io.session import SessionConfig, check_session_name
from rtsid.io.validate import printable
from rtsid.io.zenoh_link import Request, RequestInbox, ZenohPublisher
from rtsid.lifecycle import ThreadOwner
from rtsid.link.markers import WireMarker

__all__ = [
    "POLL_S",
    "REMEMBERED_IDS",
    "SessionCounters",
    "SessionDesk",
    "parse_mark_request",
    "session_message",
]

log = logging.getLogger(__name__)

#: Longest wait of the desk for a request, s (wire markers are drained this often).
POLL_S = 0.02
#: Marker ids remembered for duplicate detection.
REMEMBERED_IDS = 4096
#: Longest wait for the MCAP writer to write a marker before the query is told it failed, s.
WRITE_TIMEOUT_S = 2.0

_MARKER_ID = re.compile(rf"^[A-Za-z0-9_.:\-]{{1,{MAX_MARKER_ID_CHARS}}}$")
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


_NOT_WRITTEN = (
    "the MCAP writer did not write it (recording off, queue full or a disk error: see the "
    "status's mcap counters)"
)


class _PendingWrite:
    """A marker handed to the MCAP writer, and the writer's word on it (set on the writer's
    thread by :meth:`written`)."""

    def __init__(self, message: dict[str, Any]) -> None:
        self.message = message
        self.done = threading.Event()
        self.outcome: list[bool] = []

    def written(self, ok: bool) -> None:
        """The writer's callback: True once the marker is in the file."""
        self.outcome.append(ok)
        self.done.set()


class RefusedRequest(ValueError):
    """A request that is not recorded; ``reason`` is counted, the message told to a sender."""

    def __init__(self, message: str, reason: str) -> None:
        super().__init__(message)
        self.reason = reason


def check_label(label: object) -> str:
    """``label`` if it is a marker label: text of 1 to MAX_LABEL_CHARS characters without
    control characters (HTML and the like is text: views never render it as markup).

    Raises
    ------
    RefusedRequest
    """
    if not isinstance(label, str) or not label.strip():
        raise RefusedRequest("the label must be non-empty text", "bad_label")
    if len(label) > MAX_LABEL_CHARS:
        raise RefusedRequest(
            f"the label has {len(label)} characters; at most {MAX_LABEL_CHARS}", "bad_label"
        )
    if _CONTROL.search(label):
        raise RefusedRequest("the label holds control characters; send plain text", "bad_label")
    return label


def parse_mark_request(payload: bytes, *, plain_text: bool) -> tuple[str, str | None]:
    """``(label, marker_id or None)`` of a mark request: a JSON object ``{"label": …,
    "marker_id": …}`` (marker_id optional) or, when ``plain_text`` (a put), the UTF-8 label.

    Raises
    ------
    RefusedRequest
        Not UTF-8, not the JSON expected, a label or id not accepted.
    """
    try:
        text = payload.decode("utf-8")
    except UnicodeDecodeError:
        raise RefusedRequest("the request is not UTF-8", "bad_request") from None
    try:
        body = json.loads(text) if text.lstrip().startswith("{") or not plain_text else None
    except (ValueError, RecursionError):
        raise RefusedRequest(
            'the request is not JSON; send {"label": "...", "marker_id": "..."}', "bad_request"
        ) from None
    if body is None:
        return check_label(text), None
    if not isinstance(body, dict):
        raise RefusedRequest('send a JSON object {"label": "..."}', "bad_request")
    marker_id = body.get("marker_id")
    if marker_id is not None and not (isinstance(marker_id, str) and _MARKER_ID.match(marker_id)):
        raise RefusedRequest(
            f"marker_id must be 1-{MAX_MARKER_ID_CHARS} letters, digits or _ . : -",
            "bad_request",
        )
    return check_label(body.get("label")), marker_id


def clean_wire_label(label: str) -> str:
    """A wire marker's label as recorded: control characters → ``?``, cut to length, never
    empty."""
    text = _CONTROL.sub("?", label)[:MAX_LABEL_CHARS]
    return text if text.strip() else "(wire marker)"


@dataclass
class SessionCounters:
    """The ``session`` object of the status message."""

    subject: str = ""
    session: str = ""
    condition: str = ""
    condition_changes: int = 0
    markers: int = 0
    markers_by_source: dict[str, int] = field(default_factory=lambda: {"zenoh": 0, "wire": 0})
    refused: int = 0
    refused_by_reason: dict[str, int] = field(default_factory=dict)
    duplicates: int = 0
    wire_dropped: int = 0


def session_message(
    session: SessionConfig,
    robot: str,
    joint: str,
    fs_hz: float,
    sample_index: int,
    condition: str | None = None,
) -> dict[str, Any]:
    """The ``/session`` message (SessionMessage as a dict) holding from ``sample_index``, with
    ``condition`` (default: the section's)."""
    return SessionMessage(
        robot=robot,
        joint=joint,
        t_s=sample_index / fs_hz,
        sample_index=sample_index,
        subject=session.subject,
        session=session.session,
        condition=session.condition if condition is None else condition,
        host_time_ns=time.time_ns(),
    ).as_dict()


class SessionDesk(ThreadOwner):
    """Record markers and condition changes (a :class:`~rtsid.lifecycle.ThreadOwner`).

    Parameters
    ----------
    session : SessionConfig
        Subject, session and the condition at the start.
    robot, joint : str
        Names in every message.
    fs_hz : float
        Sample rate, Hz (t_s = sample_index / fs_hz).
    next_sample : callable
        ``next_sample() -> int``: the index of the next sample (the ring's newest + 1).
    mcap : McapLogger
        The recording.
    zenoh : ZenohPublisher
        Publishes ``/marker`` and ``/session``.
    inbox : RequestInbox
        Requests from zenoh (the publisher's ``requests``).
    wire_markers : callable, optional
        ``wire_markers() -> list[WireMarker]`` (``Acquisition.drain_markers``).
    wire_dropped : callable, optional
        ``wire_dropped() -> int``: wire markers the acquisition's inbox dropped.
    """

    def __init__(
        self,
        session: SessionConfig,
        *,
        robot: str,
        joint: str,
        fs_hz: float,
        next_sample: Callable[[], int],
        mcap: McapLogger,
        zenoh: ZenohPublisher,
        inbox: RequestInbox,
        wire_markers: Callable[[], list[WireMarker]] | None = None,
        wire_dropped: Callable[[], int] | None = None,
    ) -> None:
        super().__init__("rtsid-session")
        self.config = session
        self.robot, self.joint, self.fs_hz = robot, joint, float(fs_hz)
        self._next_sample = next_sample
        self._mcap, self._zenoh, self._inbox = mcap, zenoh, inbox
        self._wire_markers = wire_markers or (lambda: [])
        self._wire_dropped = wire_dropped or (lambda: 0)
        self._lock = threading.Lock()
        self._c = SessionCounters(session.subject, session.session, session.condition)
        self._acks: OrderedDict[str, dict[str, Any]] = OrderedDict()
        # markers whose write was not confirmed in time, by marker_id (the desk's thread only)
        self._pending: OrderedDict[str, _PendingWrite] = OrderedDict()
        self._inbox_refused_seen = 0
        self.current = self.session_message(max(0, self._next_sample()), session.condition)

    def next_sample(self) -> int:
        """The index a marker taken now would mark (the ring's newest + 1)."""
        return self._next_sample()

    # ------------------------------------------------------------------ messages
    def session_message(self, sample_index: int, condition: str) -> dict[str, Any]:
        """The ``/session`` message holding from ``sample_index``."""
        return session_message(
            self.config, self.robot, self.joint, self.fs_hz, sample_index, condition
        )

    def counters(self) -> dict[str, Any]:
        """The status message's ``session`` object (a copy)."""
        with self._lock:
            c = self._c
            c.wire_dropped = self._wire_dropped()
            refused = c.refused + self._inbox.refused
            by_reason = dict(c.refused_by_reason)
            if self._inbox.refused:
                by_reason["inbox_full"] = self._inbox.refused
            return {
                **c.__dict__,
                "markers_by_source": dict(c.markers_by_source),
                "refused": refused,
                "refused_by_reason": by_reason,
            }

    # ------------------------------------------------------------------ thread
    def _before_start(self) -> None:
        self._zenoh.publish_session(self.current)

    def _interrupt(self) -> None:
        self._inbox.wake()

    def _run(self) -> None:
        while not self._stop.is_set():
            self._handle(self._inbox.take(POLL_S))
            self._record_wire()
        self._handle(self._inbox.take(0.0))  # what came before the stop is answered
        self._record_wire()

    def _handle(self, requests: list[Request]) -> None:
        for request in requests:
            try:
                if request.kind == "condition":
                    reply = self._change_condition(request)
                else:
                    reply = self._mark(request)
            except RefusedRequest as exc:
                self._count_refused(exc.reason)
                self._reply_error(request, str(exc))
                continue
            self._reply(request, reply)

    # ------------------------------------------------------------------ markers
    def _mark(self, request: Request) -> dict[str, Any]:
        label, marker_id = parse_mark_request(request.payload, plain_text=request.query is None)
        if marker_id is not None:
            with self._lock:
                first = self._acks.get(marker_id)
                if first is not None:
                    self._c.duplicates += 1
                    return {**first, "duplicate": True}
            pending = self._pending.get(marker_id)
            if pending is not None:  # resent after a write timeout: the first write's word
                return self._settle(pending)
        index = self._next_sample()
        message = MarkerMessage(
            robot=self.robot,
            joint=self.joint,
            t_s=index / self.fs_hz,
            sample_index=index,
            label=label,
            source="zenoh",
            marker_id=marker_id or uuid.uuid4().hex,
            host_time_ns=time.time_ns(),
        ).as_dict()
        pending = _PendingWrite(message)
        if not self._mcap.log_marker(message, on_written=pending.written):
            raise RefusedRequest(_NOT_WRITTEN, "not_written")
        return self._settle(pending)

    def _settle(self, pending: _PendingWrite) -> dict[str, Any]:
        """Wait up to :data:`WRITE_TIMEOUT_S` for the MCAP writer's word on ``pending``; once
        written and flushed, publish the marker and return its acknowledgement.

        A write still unconfirmed is remembered by its ``marker_id`` (the last
        :data:`REMEMBERED_IDS`): a resend with that id waits for the same write again and is
        acknowledged with its stamp, instead of writing a second copy on a later sample
        (readers keep a ``marker_id``'s first copy, so the acknowledged sample would not be
        the recorded one).

        Raises
        ------
        RefusedRequest
            ``write_timeout`` (still unconfirmed) or ``not_written``.
        """
        message = pending.message
        marker_id = message["marker_id"]
        if not pending.done.wait(WRITE_TIMEOUT_S):
            self._pending[marker_id] = pending
            self._pending.move_to_end(marker_id)
            while len(self._pending) > REMEMBERED_IDS:
                self._pending.popitem(last=False)
            raise RefusedRequest(
                f"the MCAP writer did not confirm it within {WRITE_TIMEOUT_S:g} s (it may still "
                "be written: resend with the same marker_id and readers keep it once)",
                "write_timeout",
            )
        self._pending.pop(marker_id, None)
        if pending.outcome != [True]:
            raise RefusedRequest(_NOT_WRITTEN, "not_written")
        self._zenoh.publish_marker(message)
        ack = {
            "ok": True,
            **{k: message[k] for k in ("robot", "joint", "sample_index", "t_s", "label")},
            "marker_id": marker_id,
            "duplicate": False,
        }
        with self._lock:
            self._c.markers += 1
            self._c.markers_by_source["zenoh"] += 1
            self._acks[marker_id] = ack
            while len(self._acks) > REMEMBERED_IDS:
                self._acks.popitem(last=False)
        return ack

    def _record_wire(self) -> None:
        for wire in self._wire_markers():
            label = clean_wire_label(wire.label)
            message = MarkerMessage(
                robot=self.robot,
                joint=self.joint,
                t_s=wire.sample_index / self.fs_hz,
                sample_index=wire.sample_index,
                label=label,
                source="wire",
                marker_id=f"wire-{wire.sample_index}-{zlib.crc32(label.encode()):08x}",
                host_time_ns=time.time_ns(),
            ).as_dict()
            if not self._mcap.log_marker(message):
                self._count_refused("not_written")
                continue
            self._zenoh.publish_marker(message)
            with self._lock:
                self._c.markers += 1
                self._c.markers_by_source["wire"] += 1

    # ------------------------------------------------------------------ conditions
    def _change_condition(self, request: Request) -> dict[str, Any]:
        try:
            body = json.loads(request.payload.decode("utf-8"))
            condition = check_session_name("condition", body["condition"])
        except (ValueError, KeyError, TypeError, RecursionError, ConfigError) as exc:
            detail = str(exc) if isinstance(exc, ConfigError) else 'send {"condition": "..."}'
            raise RefusedRequest(f"condition not changed: {detail}", "bad_request") from None
        index = self._next_sample()
        message = self.session_message(index, condition)
        if not self._mcap.log_session(message):
            log.warning("the condition change to %r could not be queued for MCAP", condition)
        self._zenoh.publish_session(message)
        with self._lock:
            self.current = message
            self._c.condition = condition
            self._c.condition_changes += 1
        log.info("condition %r from sample %d (t = %.3f s)", condition, index, message["t_s"])
        return {
            "ok": True,
            **{k: message[k] for k in ("robot", "joint", "sample_index", "t_s", "condition")},
        }

    # ------------------------------------------------------------------ replies
    def _count_refused(self, reason: str) -> None:
        with self._lock:
            self._c.refused += 1
            self._c.refused_by_reason[reason] = self._c.refused_by_reason.get(reason, 0) + 1

    def _reply(self, request: Request, body: dict[str, Any]) -> None:
        if request.query is None:
            return
        key = self._zenoh.keys[request.kind]
        try:
            with request.query:
                request.query.reply(key, encode_json(body))
        except Exception as exc:  # the asker left: nothing to tell
            log.debug("reply on %s failed: %s", key, exc)

    def _reply_error(self, request: Request, text: str) -> None:
        if request.query is None:
            log.debug("a put on mark/in was refused: %s", text)
            return
        what = "the marker" if request.kind == "mark" else "the condition"
        message = f"{printable(text)}; {what} was NOT recorded"
        try:
            with request.query:
                request.query.reply_err(encode_json({"error": message}))
        except Exception as exc:
            log.debug("error reply failed: %s", exc)
