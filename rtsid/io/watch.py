"""``rtsid watch``: subscribe to estimates and status over zenoh and show them.

A live table redrawn in place when stdout is a terminal; one plain line per estimate
otherwise (pipes, logs, tests). Rows lead with the tracked stiffness K_track and its 95 % band,
the window's K beside it; held I and B show as held. Every payload is checked
(:mod:`rtsid.io.validate`); a malformed one is skipped and counted ("rejected N malformed
messages"). Rendering is pure (:func:`format_estimate_line`,
:func:`render_view`) so it is tested without a terminal.

:class:`LabFeed` is the subscribing side shared by the table and the web view
(:mod:`rtsid.io.web`): estimates, status and the daemons' liveliness tokens of every
``robot/joint`` under a key, straight from a peer or through a router, plus the recent history
the daemons answer (``--since``). A row leaves the table, with a note, when its daemon's
liveliness token goes; it comes back when the daemon does.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, TextIO

from rtsid.io.validate import (
    MalformedMessage,
    check_replies,
    decode_message,
    error_reply_text,
    joint_of_key,
    printable,
)

__all__ = [
    "FeedEvent",
    "LabFeed",
    "WatchState",
    "format_estimate_line",
    "format_marker_line",
    "format_session_line",
    "render_view",
    "watch",
]

_CLEAR = "\x1b[H\x1b[J"  # cursor home, clear to the end of the screen
_REDRAW_S = 0.1
_POLL_S = 0.001  # idle poll of the subscription channels, s


#: The 95 % band of a value: ± this many standard errors.
Z95 = 1.96


def _num(value: Any, fmt: str) -> str:
    if value is None or isinstance(value, bool) or not isinstance(value, int | float):
        return "-"
    if isinstance(value, float) and not math.isfinite(value):
        return "-"
    return format(value, fmt)


def is_held(message: Mapping[str, Any], name: str) -> bool:
    """True when ``name`` (``"I"`` or ``"B"``) is a held value, not this window's fit
    (``I_held``/``B_held``; messages before those fields: a value without a standard error)."""
    held = message.get(f"{name}_held")
    if held is not None:
        return bool(held)
    return message.get(name) is not None and message.get(f"{name}_se") is None


def _band(message: Mapping[str, Any], name: str, fmt: str) -> str:
    """``value±half-width of the 95 % band``; a held value as ``value (held)``, never a band."""
    value = _num(message.get(name), fmt)
    if name in ("I", "B") and is_held(message, name):
        return f"{value} (held)"
    se = message.get(f"{name}_se")
    if value == "-" or se is None or _num(se, fmt) == "-":
        return value
    return f"{value}±{_num(Z95 * se, fmt)}"


def window_ms(message: Mapping[str, Any]) -> float | None:
    """The window's length, ms, from its sample indices and times (None: not known)."""
    try:
        n = int(message["window_end_index"]) - int(message["window_start_index"])
        span_s = float(message["t_end_s"]) - float(message["t_start_s"])
    except (KeyError, TypeError, ValueError):
        return None
    if n < 1 or not span_s > 0:
        return None
    return span_s * (n + 1) / n * 1e3


def window_k_label(message: Mapping[str, Any]) -> str:
    """``K (300 ms window)``: what the window's own K is, beside the tracked one."""
    length = window_ms(message)
    return "K (window)" if length is None else f"K ({length:.0f} ms window)"


def format_estimate_line(message: Mapping[str, Any], received_ns: int | None = None) -> str:
    """One line per estimate, leading with the tracked stiffness, e.g.
    ``rig/ankle seq=12 t=1.234s K_track=120.3±3.9 K(300ms)=121.0±5.9 B=0.900 (held)
    I=0.01200±0.00196 VAF=95.5% lat=4.1ms ok`` (± the 95 % band, 1.96 standard errors).

    Parameters
    ----------
    message : Mapping
        An estimate (ESTIMATE_SCHEMA), checked (:mod:`rtsid.io.validate`).
    received_ns : int, optional
        Host UNIX time it arrived, ns: adds ``age=`` (publication → here, ms).
    """
    parts = [
        f"{message.get('robot')}/{message.get('joint')}",
        f"seq={message.get('seq')}",
        f"t={_num(message.get('t_end_s'), '.3f')}s",
    ]
    if message.get("ok"):
        length = window_ms(message)
        k_name = "K" if length is None else f"K({length:.0f}ms)"
        parts += [
            f"K_track={_band(message, 'K_track', '.1f')}",
            f"{k_name}={_band(message, 'K', '.1f')}",
            f"B={_band(message, 'B', '.3f')}".replace(" (held)", "(held)"),
            f"I={_band(message, 'I', '.5f')}".replace(" (held)", "(held)"),
            f"VAF={_num(message.get('vaf'), '.1f')}%",
        ]
    parts.append(f"lat={_num(message.get('latency_ms'), '.1f')}ms")
    if received_ns is not None and isinstance(message.get("host_time_ns"), int):
        parts.append(f"age={(received_ns - message['host_time_ns']) / 1e6:.1f}ms")
    state = "ok" if message.get("ok") else f"withheld:{message.get('reason')}"
    flags = message.get("flags") or []
    parts.append(state + (f" flags={','.join(flags)}" if flags else ""))
    return " ".join(parts)


@dataclass
class JointView:
    """What the watcher knows about one robot/joint."""

    estimate: dict[str, Any] | None = None
    status: dict[str, Any] | None = None
    estimates: int = 0
    withheld: int = 0
    last_age_ms: float | None = None
    alive: bool | None = None  # liveliness token seen (True) / withdrawn (False)
    session: dict[str, Any] | None = None  # the newest /session message
    markers: list[dict[str, Any]] = field(default_factory=list)  # the last few /marker


def joint_name(key: str) -> str:
    """``rtsid/rig/ankle/alive`` (or ``…/estimate``) → ``rig/ankle``."""
    return "/".join(key.rstrip("/").split("/")[-3:-1])


@dataclass
class WatchState:
    """Latest estimate and status per ``robot/joint`` (fed by :meth:`update`).

    Every payload is checked (:func:`rtsid.io.validate.decode_message`); one that is not a
    well-formed message of its channel, from the daemon its key names, is skipped and counted
    in :attr:`rejected` (the view shows "rejected N malformed messages"), never shown.
    A joint whose liveliness token went is removed (and noted in :attr:`notes`); what it
    still sends is ignored until its token is back.
    """

    joints: dict[str, JointView] = field(default_factory=dict)
    received: int = 0
    rejected: int = 0
    last_rejection: str | None = None
    notes: list[str] = field(default_factory=list)
    gone: set[str] = field(default_factory=set)

    def reject(self, why: str) -> None:
        """Count one malformed message (``why``: one printable line)."""
        self.rejected += 1
        self.last_rejection = why

    def update(self, key: str, payload: bytes, received_ns: int) -> dict[str, Any] | None:
        """Take one sample (key expression, JSON payload). Returns it if it is a new estimate
        (not one already seen, e.g. from both the history and the live subscription), a
        session message or a new marker."""
        self.received += 1
        kind = key.rstrip("/").rsplit("/", 1)[-1]
        try:
            message = decode_message(kind, payload, key)
        except MalformedMessage as exc:
            self.reject(f"{printable(key, 120)}: {exc}")
            return None
        name = f"{message['robot']}/{message['joint']}"
        if name in self.gone:
            return None
        view = self.joints.setdefault(name, JointView())
        if kind == "status":
            view.status = message
            return None
        if kind == "session":
            view.session = message
            return message
        if kind == "marker":
            if all(m.get("marker_id") != message["marker_id"] for m in view.markers):
                view.markers = [*view.markers[-(MARKERS_SHOWN - 1) :], message]
                return message
            return None
        if kind != "estimate":
            return None
        if _seen_before(view.estimate, message):
            return None
        view.estimate = message
        view.estimates += 1
        view.withheld += 0 if message.get("ok") else 1
        view.last_age_ms = (received_ns - message["host_time_ns"]) / 1e6
        return message

    def set_alive(self, token_key: str, alive: bool, now_s: float | None = None) -> str:
        """Record a liveliness change of ``<prefix>/<robot>/<joint>/alive``; returns the
        ``robot/joint`` name. A joint whose token went leaves :attr:`joints` with a note."""
        name = joint_name(token_key)
        if alive:
            self.gone.discard(name)
            self.joints.setdefault(name, JointView()).alive = True
            return name
        self.gone.add(name)
        if self.joints.pop(name, None) is not None:
            stamp = time.strftime("%H:%M:%S", time.localtime(now_s))
            self.notes = [*self.notes[-4:], f"{name} left at {stamp} (liveliness token gone)"]
        return name


def _seen_before(previous: Mapping[str, Any] | None, message: Mapping[str, Any]) -> bool:
    """True when ``message`` is not newer than ``previous`` (same daemon run)."""
    if previous is None:
        return False
    try:
        return bool(
            message["seq"] <= previous["seq"]
            and message["host_time_ns"] <= previous["host_time_ns"]
        )
    except (KeyError, TypeError):
        return False


#: Markers each joint's view keeps (the newest).
MARKERS_SHOWN = 5


def format_session_line(message: Mapping[str, Any]) -> str:
    """``rig/ankle subject S01  session 2  condition fatigue (from t=12.345s)``: one
    printable line (names are checked, and cleaned of control characters again here)."""
    return (
        f"{message.get('robot')}/{message.get('joint')} "
        f"subject {printable(str(message.get('subject') or '-'), 64)}  "
        f"session {printable(str(message.get('session') or '-'), 64)}  "
        f"condition {printable(str(message.get('condition') or '-'), 64)} "
        f"(from t={_num(message.get('t_s'), '.3f')}s)"
    )


def format_marker_line(message: Mapping[str, Any]) -> str:
    """``rig/ankle marker 'trial 3 start' at t=12.345s (sample 30862, zenoh)``."""
    return (
        f"{message.get('robot')}/{message.get('joint')} marker "
        f"{printable(str(message.get('label')), 120)!r} at t={_num(message.get('t_s'), '.3f')}s "
        f"(sample {message.get('sample_index')}, {message.get('source')})"
    )


def _status_line(name: str, s: Mapping[str, Any]) -> str:
    acq = s.get("acquisition") or {}
    wk = s.get("worker") or {}
    mc = s.get("mcap") or {}
    zn = s.get("zenoh") or {}
    withheld = wk.get("withheld") or {}
    withheld_txt = ",".join(f"{k}:{v}" for k, v in sorted(withheld.items())) or "0"
    mcap_file = printable(str(mc.get("file") or "-").rsplit("/", 1)[-1], 80)
    return "\n".join(
        [
            f"  {name}: up {_num(s.get('uptime_s'), '.0f')} s"
            f"  cpu {_num(s.get('cpu_percent'), '.0f')}%  rss {_num(s.get('rss_mb'), '.0f')} MiB",
            f"    link: samples {acq.get('samples', '-')}  gaps {acq.get('gaps', '-')}"
            f"  lost {acq.get('lost_samples', '-')}  bus errors {acq.get('bus_errors', '-')}",
            f"    worker: estimates {wk.get('estimates', '-')}  withheld {withheld_txt}"
            f"  overruns {wk.get('overruns', '-')}  misses {wk.get('deadline_misses', '-')}",
            f"    mcap {mc.get('state', '-')} {mcap_file}  dropped {mc.get('dropped', '-')}"
            f"  |  zenoh {zn.get('state', '-')}",
            *_session_counters(s.get("session")),
        ]
    )


def _session_counters(session: Any) -> list[str]:
    """``markers 3 (refused 1, duplicates 0)  condition changes 1``, or nothing (a daemon
    from before sessions)."""
    if not isinstance(session, Mapping):
        return []
    return [
        f"    markers {session.get('markers', '-')} (refused {session.get('refused', '-')}, "
        f"duplicates {session.get('duplicates', '-')})  condition changes "
        f"{session.get('condition_changes', '-')}"
    ]


def render_view(state: WatchState, *, title: str, now_s: float | None = None) -> str:
    """The live table (no terminal control codes; the caller adds them).

    Parameters
    ----------
    state : WatchState
    title : str
        First line (key expression, endpoint).
    now_s : float, optional
        UNIX time for the clock in the title (default: now).
    """
    now = time.time() if now_s is None else now_s
    lines = [f"{title}   {time.strftime('%H:%M:%S', time.localtime(now))}", ""]
    first = next((v.estimate for _, v in sorted(state.joints.items()) if v.estimate), None)
    k_window = window_k_label(first or {})
    header = (
        f"{'robot/joint':<18}{'seq':>8}  {'K_track N·m/rad':>16}  {k_window:>18}  "
        f"{'B N·m·s/rad':>16}  {'I kg·m²':>18}  {'VAF %':>6}  {'lat ms':>7}  {'age ms':>7}  state"
    )
    lines.append(header)
    if not state.joints:
        lines.append("  (waiting for estimates…)")
    for name, view in sorted(state.joints.items()):
        e = view.estimate
        if e is None:
            lines.append(f"{name:<18}{'-':>8}  (alive, no estimate yet)")
            continue
        ok = bool(e.get("ok"))
        state_txt = "ok" if ok else f"withheld: {e.get('reason')}"
        if e.get("flags"):
            state_txt += " [" + ",".join(e["flags"]) + "]"
        lines.append(
            f"{name:<18}{e.get('seq', '-')!s:>8}  "
            f"{_band(e, 'K_track', '.1f') if ok else '-':>16}  "
            f"{_band(e, 'K', '.1f') if ok else '-':>18}  "
            f"{_band(e, 'B', '.3f') if ok else '-':>16}  "
            f"{_band(e, 'I', '.5f') if ok else '-':>18}  "
            f"{_num(e.get('vaf'), '.1f') if ok else '-':>6}  "
            f"{_num(e.get('latency_ms'), '.1f'):>7}  {_num(view.last_age_ms, '.1f'):>7}  "
            f"{state_txt}"
        )
    lines += [f"note: {note}" for note in state.notes]
    lines += ["", "status:"]
    shown = False
    for name, view in sorted(state.joints.items()):
        if view.status is not None:
            lines.append(_status_line(name, view.status))
            shown = True
    if not shown:
        lines.append("  (no status yet)")
    sessions = [(n, v) for n, v in sorted(state.joints.items()) if v.session or v.markers]
    if sessions:
        lines += ["", "session:"]
    for _name, view in sessions:
        if view.session is not None:
            lines.append(f"  {format_session_line(view.session)}")
        lines += [f"    {format_marker_line(m)}" for m in view.markers]
    lines.append("")
    lines.append(
        f"received {state.received}  estimates "
        f"{sum(v.estimates for v in state.joints.values())}  withheld "
        f"{sum(v.withheld for v in state.joints.values())}  "
        f"{rejected_text(state.rejected)}  (± is the 95 % band; Ctrl-C to quit)"
    )
    if state.last_rejection:
        lines.append(f"last rejected: {state.last_rejection}")
    return "\n".join(lines)


def rejected_text(count: int) -> str:
    """``rejected 3 malformed messages``: the counter every view shows."""
    return f"rejected {count} malformed message{'' if count == 1 else 's'}"


@dataclass(frozen=True)
class FeedEvent:
    """One thing a :class:`LabFeed` saw.

    Attributes
    ----------
    kind : str
        ``"estimate"``, ``"status"`` (``payload`` is the message's JSON), ``"alive"`` or
        ``"gone"`` (a daemon's liveliness token appeared / went; ``payload`` is empty).
    key : str
        The key expression (``<prefix>/<robot>/<joint>/<channel>``).
    payload : bytes
    received_ns : int
        Host UNIX time it arrived, ns.
    """

    kind: str
    key: str
    payload: bytes
    received_ns: int


class LabFeed:
    """Every channel (but raw samples) and the liveliness of each daemon under ``key``
    (a context manager).

    Parameters
    ----------
    key : str
        ``<prefix>/<robot>/<joint>`` with wildcards, e.g. ``rtsid/*/*``.
    connect : tuple of str
        Endpoints: a router's, or the daemons' own (peer to peer).
    mode : str
        ``"peer"`` or ``"client"`` (through a router).

    One subscription to ``<key>/*`` — estimates, status and whatever channel a daemon adds —
    read as a channel polled by :meth:`poll` (no Python callbacks on zenoh's threads: a
    callback subscriber showed a 4 ms p99 one-way latency against < 1 ms for a channel,
    docs/io.md). Raw sample batches (``publish_samples``) are left out.
    """

    #: Samples taken per :meth:`poll` at most (the rest wait for the next call).
    POLL_BATCH = 256

    def __init__(self, key: str, connect: tuple[str, ...], mode: str = "peer") -> None:
        self.key = key.rstrip("/")
        self.connect = connect
        self.mode = mode
        self._session: Any = None
        self._channels: Any = None
        self._alive: Any = None

    def __enter__(self) -> LabFeed:
        import zenoh

        from rtsid.io.zenoh_link import subscriber_config

        self._session = zenoh.open(subscriber_config(self.connect, self.mode))
        self._channels = self._session.declare_subscriber(
            f"{self.key}/*", zenoh.handlers.RingChannel(4096)
        )
        self._alive = self._session.liveliness().declare_subscriber(
            f"{self.key}/alive", zenoh.handlers.RingChannel(64), history=True
        )
        return self

    def __exit__(self, *exc_info: object) -> None:
        for entity in (self._channels, self._alive):
            if entity is not None:
                entity.undeclare()
        if self._session is not None:
            self._session.close()
        self._session, self._channels, self._alive = None, None, None

    def poll(self) -> list[FeedEvent]:
        """What arrived since the last call (at most :attr:`POLL_BATCH`; never blocks)."""
        import zenoh

        events = []
        for _ in range(self.POLL_BATCH):
            sample = self._channels.try_recv() if self._channels is not None else None
            if sample is None:
                break
            key = str(sample.key_expr)
            kind = key.rsplit("/", 1)[-1]
            if kind != "samples":
                events.append(FeedEvent(kind, key, sample.payload.to_bytes(), time.time_ns()))
        token = self._alive.try_recv() if self._alive is not None else None
        if token is not None:
            kind = "alive" if token.kind == zenoh.SampleKind.PUT else "gone"
            events.append(FeedEvent(kind, str(token.key_expr), b"", time.time_ns()))
        return events

    def session(self, *, timeout_s: float = 2.0) -> HistoryEvents:
        """Each daemon's current session message (its ``session`` queryable; a daemon from
        before sessions does not answer), checked like :meth:`history`."""
        from rtsid.io.zenoh_link import query

        answer = query(self._session, f"{self.key}/session", timeout_s=timeout_s)
        return history_events(answer.replies, answer.errors)

    def history(self, since_s: float, *, timeout_s: float = 5.0) -> HistoryEvents:
        """The messages of the last ``since_s`` that the daemons still hold, every reply
        checked (:func:`rtsid.io.validate.check_replies`); what fails is counted, not shown."""
        from rtsid.io.zenoh_link import query

        answer = query(self._session, f"{self.key}/history?since={since_s:g}s", timeout_s=timeout_s)
        return history_events(answer.replies, answer.errors)


@dataclass
class HistoryEvents:
    """A history query's answer as feed events.

    Attributes
    ----------
    events : list of FeedEvent
        Oldest first (by publication time).
    notes : list of str
        Where a daemon's history starts later than asked, and error replies (printable).
    rejected : list of str
        Why each malformed reply or message was refused.
    """

    events: list[FeedEvent]
    notes: list[str]
    rejected: list[str]


def history_events(replies: list[tuple[str, bytes]], errors: list[str]) -> HistoryEvents:
    """Check a history query's replies and turn them into feed events (pure: no session)."""
    checked = check_replies(replies)
    notes = [f"error reply: {error_reply_text(error)}" for error in errors]
    notes += [
        f"{part['robot']}/{part['joint']}: {printable(part['note'])}"
        for part in checked.parts
        if part["note"] and part["part"] == 0
    ]
    now = time.time_ns()
    events = [
        FeedEvent(kind, key, json.dumps(message).encode(), now)
        for kind, key, message in checked.messages
    ]
    return HistoryEvents(events, notes, checked.rejected)


def _worth_saying(count: int) -> bool:
    """Plain mode says the 1st, 10th, 100th, … rejection (a flood cannot flood stderr)."""
    return count == 1 or (count % 10 == 0 and str(count).rstrip("0") == "1")


def watch(
    key: str,
    connect: tuple[str, ...],
    *,
    mode: str = "peer",
    count: int | None = None,
    timeout_s: float | None = None,
    out: TextIO | None = None,
    live: bool | None = None,
    since_s: float | None = None,
) -> int:
    """Subscribe to ``<key>/estimate`` and ``<key>/status`` and show what arrives.

    Parameters
    ----------
    key : str
        Key expression of the daemon(s), e.g. ``rtsid/*/*`` or ``rtsid/rig/ankle``.
    connect : tuple of str
        Endpoints to connect to (the daemon's listen endpoint, or a router's).
    mode : str
        ``"peer"`` (tolerates a daemon that starts later) or ``"client"`` (through a router).
    count : int, optional
        Exit after this many estimates.
    timeout_s : float, optional
        Exit after this long, s.
    out : TextIO, optional
        Output stream (default ``sys.stdout``).
    live : bool, optional
        Redraw in place (default: when ``out`` is a terminal).
    since_s : float, optional
        First show the last ``since_s`` of history the daemons hold (a history query).

    Returns
    -------
    int
        0 on Ctrl-C, after ``count`` estimates, or at the timeout with at least one estimate
        (and ``count`` reached if given); 1 otherwise (a message says what was missing).
    """
    out = sys.stdout if out is None else out
    live = out.isatty() if live is None else live
    key = key.rstrip("/")
    state = WatchState()
    title = f"rtsid watch {key} via {', '.join(connect)} ({mode})"
    start = time.monotonic()
    deadline = None if timeout_s is None else start + timeout_s
    seen = 0
    next_draw = start

    def take(event: FeedEvent) -> None:
        nonlocal seen
        before = state.rejected
        _take(event)
        if state.rejected > before and not live and _worth_saying(state.rejected):
            print(
                f"rtsid watch: {rejected_text(state.rejected)}; last: {state.last_rejection}",
                file=sys.stderr,
                flush=True,
            )

    def _take(event: FeedEvent) -> None:
        nonlocal seen
        if event.kind in ("alive", "gone"):
            try:
                joint_of_key(event.key)
            except MalformedMessage as exc:
                state.reject(str(exc))
                return
            name = state.set_alive(event.key, event.kind == "alive")
            if not live:
                print(
                    f"rtsid watch: {name} "
                    + (
                        "daemon alive"
                        if event.kind == "alive"
                        else "daemon gone (liveliness token lost)"
                    ),
                    file=sys.stderr,
                    flush=True,
                )
            return
        if event.kind not in ("estimate", "status", "session", "marker"):
            return  # another channel (the table shows estimates, status and the session)
        est = state.update(event.key, event.payload, event.received_ns)
        if est is not None and event.kind in ("session", "marker"):
            if not live:
                line = format_session_line if event.kind == "session" else format_marker_line
                print(line(est), file=out, flush=True)
            return
        if est is not None:
            seen += 1
            if not live:
                print(format_estimate_line(est, event.received_ns), file=out, flush=True)

    try:
        with LabFeed(key, connect, mode) as feed:
            print(
                f"rtsid watch: waiting for estimates on {key}/estimate via {', '.join(connect)}",
                file=sys.stderr,
                flush=True,
            )
            for event in feed.session().events:  # who and what, however old
                take(event)
            if since_s is not None:
                past = feed.history(since_s)
                for note in past.notes:
                    print(f"rtsid watch: {note}", file=sys.stderr, flush=True)
                for why in past.rejected:
                    state.reject(why)
                if past.rejected:
                    print(
                        f"rtsid watch: history: {rejected_text(len(past.rejected))}; first: "
                        f"{past.rejected[0]}",
                        file=sys.stderr,
                        flush=True,
                    )
                for event in past.events:
                    take(event)
            while count is None or seen < count:
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    break
                events = feed.poll()
                for event in events:
                    take(event)
                if live and now >= next_draw:
                    out.write(_CLEAR + render_view(state, title=title) + "\n")
                    out.flush()
                    next_draw = now + _REDRAW_S
                if not events:
                    time.sleep(_POLL_S)
    except KeyboardInterrupt:
        return 0
    finally:
        if live:
            out.write(_CLEAR + render_view(state, title=title) + "\n")
            out.flush()
    if state.rejected and not live:
        print(f"rtsid watch: {rejected_text(state.rejected)} in all", file=sys.stderr)
    if seen == 0:
        print(
            f"rtsid watch: no estimates on {key}/estimate within {timeout_s:g} s; is the daemon "
            f"running and listening on {', '.join(connect)}?",
            file=sys.stderr,
        )
        return 1
    if count is not None and seen < count:
        print(
            f"rtsid watch: received {seen} of {count} estimates before the timeout", file=sys.stderr
        )
        return 1
    return 0
